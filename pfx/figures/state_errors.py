r"""Figures of the error in every state component (park-mpf Figs. 4-6 and its extended comparison).

* ``state_error_over_time``: one panel per state component, one line per cell. A folder of
  one trial draws that trial's error :math:`\hat x_{k,j} - x_{k,j}` over time (steps.csv);
  a folder of :math:`n` trials draws the RMS error over all of them at each time,
  :math:`\sqrt{\tfrac1n \sum_r (\hat x_{k,j} - x_{k,j})^2}` (``rms_error_<state>`` of
  steps_summary.csv; an older folder's traced trials, said in the title). An angle's error is
  wrapped into half a turn either side.
* ``relative_change_by_state`` (trials.csv): for every state component, every arm's mean RMSE
  relative to the first arm's, paired by trial, with its 95% interval
  (:func:`pfx.analysis.paired_statistics.relative_change_interval`); for experiments with one cell per arm.

A filter that diverges (errors many orders of magnitude above the others'; see
:func:`pfx.analysis.paired_statistics.diverged`) would flatten every other line to zero: over time, its line
stops where it leaves the axes (a triangle marks the edge it crossed) and the panel names it
with that time and its largest error (:func:`pfx.figures.layout.plot_within`); in the
relative change, its count of diverged trials is written instead of an interval. The figure
stays readable and says what it leaves out. Legends sit below the panels, off the data.

Both draw nothing but estimate - truth, so both declare it (:func:`pfx.figures.registry.draws_truth`):
recorded data without ``data.truth`` have no truth, and either figure is refused in one line
rather than drawn as empty panels (``filtered_over_data`` draws the estimates over the data).
"""

from __future__ import annotations

import numpy as np

from pfx.analysis.paired_statistics import diverged, relative_change_interval
from pfx.analysis.value_ranges import metric_range
from pfx.figures.layout import (
    cell_labels,
    legend_columns_of,
    legend_outside,
    off_scale_limit,
    peak_text,
    plot_within,
    time_axis,
    time_text,
    trials_text,
)
from pfx.figures.registry import FIGURES, draws_truth
from pfx.result_folder import ResultFolder


def _label(name: str, unit: str) -> str:
    text = name.replace("_", " ")
    return f"{text} [{unit}]" if unit else text


@FIGURES.register("state_error_over_time")
@draws_truth
def state_error_over_time(result: ResultFolder):
    """Estimation error of every state component over time, one line per cell (RMS if several trials).

    Estimate - truth of a single-trial run, or its RMS over every trial (steps_summary.csv); a diverging line stops at the axes' edge and is named.
    """
    import matplotlib.pyplot as plt

    summary = result.steps_summary
    if summary.empty:
        return None
    # a component without a single error (no truth) would be an empty panel
    states = [state for state in result.state_names
              if f"rms_error_{state}" in summary and summary[f"rms_error_{state}"].notna().any()]
    if not states:
        return None
    signed = int(summary["trials"].max()) == 1 and not result.steps.empty
    lines = _signed_errors(result, states) if signed else _rms_errors(result, summary, states)
    cells = summary.drop_duplicates("cell")
    labels = dict(zip(cells["cell"], cell_labels(cells, legend_columns_of(result, cells))))
    colours = {cell: f"C{index % 10}" for index, cell in enumerate(cells["cell"])}
    _, x_label = time_axis(result)
    figure, axes_list = plt.subplots(len(states), 1, figsize=(8.5, 2.9 * len(states) + 0.9), sharex=True,
                                     layout="constrained", squeeze=False)
    for axes, state in zip(axes_list[:, 0], states):
        unit = result.units.get(f"state_{state}", "")
        peaks = {cell: float(np.nanmax(np.abs(series[state][1]))) for cell, series in lines.items()}
        limit, in_scale = off_scale_limit(peaks)
        notes = []
        for cell, series in lines.items():
            time, error = series[state]
            first_outside = plot_within(axes, time, error, limit, colours[cell], labels[cell])
            if cell not in in_scale and first_outside is not None:
                notes.append(f"{labels[cell]}: off scale from {time_text(time[first_outside], result)} "
                             f"(|error| up to {peak_text(peaks[cell], unit)})")
        axes.set_ylim(-limit if signed else 0, limit)
        if signed:
            axes.axhline(0, color="black", linewidth=0.6)
        axes.set_ylabel(("error" if signed else "RMS error") + f"\n{_label(state, unit)}", fontsize=9)
        axes.grid(alpha=0.3)
        if notes:                      # above the panel, where it hides no data
            axes.set_title("; ".join(notes), loc="left", fontsize=8, color="C3")
    axes_list[-1, 0].set_xlabel(x_label)
    legend_outside(figure)
    what = ("estimate - truth, one trial" if signed else
            f"RMS of estimate - truth over {trials_text(summary, result.steps_summary_covers_every_trial)} per cell")
    figure.suptitle(f"{result.manifest.get('name', '')}: estimation error per state ({what})", fontsize=11)
    return figure


def _signed_errors(result: ResultFolder, states: list[str]) -> dict:
    """cell -> state -> (time, estimate - truth) of the cell's first traced trial (steps.csv)."""
    steps = result.steps
    x_column, _ = time_axis(result)
    first_trial = steps[steps["trial"] == steps.groupby("cell")["trial"].transform("min")]
    return {cell: {state: (rows[x_column].to_numpy(dtype=float), result.state_error(rows, state))
                   for state in states}
            for cell, rows in first_trial.groupby("cell", sort=False)}


def _rms_errors(result: ResultFolder, summary, states: list[str]) -> dict:
    """cell -> state -> (time, RMS over the trials of estimate - truth) from steps_summary.csv."""
    x_column, _ = time_axis(result)
    return {cell: {state: (rows[x_column].to_numpy(dtype=float), rows[f"rms_error_{state}"].to_numpy(dtype=float))
                   for state in states}
            for cell, rows in summary.groupby("cell", sort=False)}


@FIGURES.register("relative_change_by_state")
@draws_truth
def relative_change_by_state(result: ResultFolder):
    """Each arm's mean RMSE per state relative to the first arm's, paired by trial, with 95% intervals.

    Delta-method intervals, cut at -100% (a ratio of RMSEs is never negative); diverged trials counted; needs one cell per arm.
    """
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
            estimate, low, high = relative_change_interval(base[~bad], value[~bad],
                                                           value_range=metric_range(f"rmse_{state}"))
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
