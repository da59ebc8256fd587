r"""Figures of the error in every state component (park-mpf Figs. 4-6 and its extended comparison).

* ``state_error_over_time`` (steps.csv): one panel per state component, one line per cell: the
  error :math:`\hat x_{k,j} - x_{k,j}` over time when a single trial is traced, otherwise the
  RMS error over the traced trials at each time, :math:`\sqrt{\tfrac1R \sum_r (\hat x_{k,j} - x_{k,j})^2}`.
* ``relative_change_by_state`` (trials.csv): for every state component, every arm's mean RMSE
  relative to the first arm's, paired by trial, with its 95% interval
  (:func:`pfx.compare.relative_change_interval`); for experiments with one cell per arm.

A filter that diverges (errors many orders of magnitude above the others'; see
:func:`pfx.compare.diverged`) would flatten every other line to zero: over time, its line
stops where it leaves the axes (a triangle marks the edge it crossed) and the panel names it
with that time and its largest error; in the relative change, its count of diverged trials is
written instead of an interval. The figure stays readable and says what it leaves out.
"""

from __future__ import annotations

import numpy as np

from pfx.compare import diverged, relative_change_interval
from pfx.figures.registry import FIGURES, ResultFolder

OFF_SCALE_FACTOR = 100.0          # a line whose peak exceeds 100x the smallest peak is drawn clipped


def _state_names(columns) -> list[str]:
    return [c.removeprefix("truth_") for c in columns if c.startswith("truth_")]


def _label(name: str, unit: str) -> str:
    text = name.replace("_", " ")
    return f"{text} [{unit}]" if unit else text


@FIGURES.register("state_error_over_time")
def state_error_over_time(result: ResultFolder):
    """Estimation error of every state component over time, one line per cell (RMS if several trials)."""
    import matplotlib.pyplot as plt

    steps = result.steps
    if steps.empty:
        return None
    states = _state_names(steps.columns)
    frame = steps.assign(_cell=result.cell_names(steps))
    traced = int(frame.groupby("_cell")["trial"].nunique().max())
    time_unit = result.units.get("time", "s")
    figure, axes_list = plt.subplots(len(states), 1, figsize=(8.5, 2.9 * len(states) + 0.6), sharex=True,
                                     layout="constrained", squeeze=False)
    for axes, state in zip(axes_list[:, 0], states):
        unit = result.units.get(f"state_{state}", "")
        lines = {}
        for name, group in frame.groupby("_cell", sort=False):
            error = (group[f"estimate_{state}"] - group[f"truth_{state}"]).to_numpy(dtype=float)
            series = group.assign(_error=error).groupby("time")["_error"]
            with np.errstate(over="ignore"):
                values = series.first() if traced == 1 else np.sqrt(series.apply(lambda e: np.mean(np.square(e))))
            lines[name] = values
        peaks = {name: float(np.nanmax(np.abs(values.to_numpy()))) for name, values in lines.items()}
        smallest = min(peaks.values())
        in_scale = [name for name, peak in peaks.items() if np.isfinite(peak) and peak <= OFF_SCALE_FACTOR * max(smallest, 1e-300)]
        limit = 1.15 * max(peaks[name] for name in in_scale) if in_scale else 1.0
        notes = []
        for index, (name, values) in enumerate(lines.items()):
            colour = f"C{index}"
            raw = values.to_numpy(dtype=float)
            outside = ~(np.abs(raw) <= limit)
            # Drawn up to where it leaves the axes, then a triangle on the edge it crossed.
            shown = np.where(np.cumsum(outside) > 0, np.nan, raw)
            axes.plot(values.index, shown, label=name, linewidth=1.4, color=colour)
            if outside.any():
                first_index = int(np.argmax(outside))
                first = values.index[first_index]
                upward = not raw[first_index] < 0
                axes.plot([first], [0.985 * limit if upward else -0.985 * limit], marker="^" if upward else "v",
                          color=colour, markersize=9, clip_on=False)
            if name not in in_scale:
                peak = peaks[name]
                notes.append(f"{name}: off scale from t = {first:g} {time_unit} "
                             f"(|error| up to {'∞' if not np.isfinite(peak) else f'{peak:.1e}'} {unit})")
        axes.set_ylim(-limit if traced == 1 else 0, limit)
        if traced == 1:
            axes.axhline(0, color="black", linewidth=0.6)
        axes.set_ylabel(("error" if traced == 1 else "RMS error") + f"\n{_label(state, unit)}", fontsize=9)
        axes.grid(alpha=0.3)
        if notes:                      # above the panel, where it hides no data
            axes.set_title("; ".join(notes), loc="left", fontsize=8, color="C3")
    axes_list[-1, 0].set_xlabel(f"time [{time_unit}]")
    axes_list[0, 0].legend(fontsize=8, loc="upper right", ncol=min(3, len(lines)))
    what = ("estimate - truth, one trial" if traced == 1
            else f"RMS of estimate - truth over {traced} traced trials")
    figure.suptitle(f"{result.manifest.get('name', '')}: estimation error per state ({what})", fontsize=11)
    return figure


@FIGURES.register("relative_change_by_state")
def relative_change_by_state(result: ResultFolder):
    """Each arm's mean RMSE per state relative to the first arm's, paired by trial, with 95% intervals."""
    import matplotlib.pyplot as plt

    trials = result.trials
    if trials.empty or trials["arm"].nunique() < 2 or trials.duplicated(["arm", "trial"]).any():
        return None                    # needs one cell per arm (no sweep)
    arms = list(dict.fromkeys(trials["arm"]))
    baseline, others = arms[0], arms[1:]
    states = [c.removeprefix("rmse_") for c in trials.columns
              if c.startswith("rmse_") and c != "rmse_position"]
    figure, axes_list = plt.subplots(1, len(states), figsize=(4.0 * len(states) + 1.5, 0.55 * len(others) + 2.4),
                                     sharey=True, layout="constrained", squeeze=False)
    positions = np.arange(len(others))[::-1]
    for axes, state in zip(axes_list[0], states):
        table = trials.pivot(index="trial", columns="arm", values=f"rmse_{state}")
        base = table[baseline].to_numpy(dtype=float)
        base_bad = diverged(base, base)
        for position, arm in zip(positions, others):
            value = table[arm].to_numpy(dtype=float)
            bad = diverged(value, base) | base_bad
            estimate, low, high = relative_change_interval(base[~bad], value[~bad])
            if np.isfinite(estimate):
                axes.errorbar(100 * estimate, position, xerr=[[100 * (estimate - low)], [100 * (high - estimate)]],
                              fmt="o", color="C0" if high < 0 else "C3" if low > 0 else "0.4", capsize=4)
            if bad.any():
                axes.annotate(f"diverged in {int(bad.sum())}/{bad.size} trials", (0.98, position),
                              xycoords=("axes fraction", "data"), ha="right", va="center", fontsize=8,
                              color="C3")
        axes.axvline(0, color="black", linewidth=0.8)
        axes.set_title(_label(state, result.units.get(f"state_{state}", "")), fontsize=10)
        axes.set_xlabel(f"mean RMSE vs {baseline} [%]")
        axes.grid(alpha=0.3, axis="x")
    axes_list[0, 0].set_yticks(positions, others)
    axes_list[0, 0].set_ylim(-0.6, len(others) - 0.4)
    figure.suptitle(f"{result.manifest.get('name', '')}: change of mean RMSE against {baseline}, paired by trial "
                    f"({len(table)} trials; 95% interval; blue: lower, red: higher, grey: no detectable change)",
                    fontsize=10.5)
    return figure
