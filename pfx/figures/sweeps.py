"""Figures of a metric against the particle count, from summary.csv: one line per other setting.

Each line is one combination of the cell labels other than ``n_particles`` (arm, resampler,
...), drawn as the mean over trials with its 95% t-interval. The registered names fix the
metric:

================================  ===============================================
figure                            metric (summary.csv prefix)
================================  ===============================================
``rmse_vs_particles``             rmse_position (RMS position error over time)
``final_error_vs_particles``      error_distance_final
``convergence_vs_particles``      convergence_step (converged trials only) and the share converged
``error_at_convergence_vs_particles``  error_at_convergence
================================  ===============================================

How the axes are chosen, so that lines a few percent apart and lines orders of magnitude apart
both stay readable:

* **N on a log axis** when the counts span a decade or more (largest / smallest >= 10), with a
  tick at each count; a linear axis otherwise.
* **The metric on a log axis** when its plotted means are all positive and span a decade or more
  (one arm's error a hundred times another's would flatten the rest on a linear axis).
* **Points with error bars** for a line with fewer than :data:`FEWEST_COUNTS_FOR_A_BAND` values
  of N (a band between two points suggests a trend between them that nobody measured); a
  filled band for denser sweeps.
* **A dodge in N**: with several lines, each is shifted slightly along the N axis (a common
  factor per line on a log axis, a common step on a linear one), centred on the true N, so that
  lines with nearly equal values at one N do not hide each other's points. The shift between
  neighbouring lines is at most :data:`MOST_DODGE_DECADES` of a decade (a factor of about 1.06)
  and all the lines at one N together take at most :data:`DODGE_SHARE_OF_GAP` of the smallest
  gap between counts, so a group never reaches the next N; the ticks stay at the true counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

FEWEST_COUNTS_FOR_A_BAND = 4    # a line with fewer values of N gets points with error bars
DECADE = 10.0                   # a range at least this wide (largest / smallest) goes on a log axis
MOST_DODGE_DECADES = 0.025      # between neighbouring lines at one N on a log axis: a factor 10^0.025
MOST_DODGE_SHARE_OF_RANGE = 0.01    # between neighbouring lines on a linear axis: of the counts' range
DODGE_SHARE_OF_GAP = 0.5        # all the lines at one N spread over at most this share of the smallest gap


def _line_labels(result: ResultFolder, summary):
    columns = [c for c in result.manifest.get("legend_columns", []) if c != "n_particles" and c in summary]
    summary = summary.copy()           # one block: adding a column to a wide frame stays cheap
    if not columns:
        summary["_line"] = "all"
        return summary
    label = summary[columns[0]].astype(str)
    for column in columns[1:]:
        label = label + ", " + column + "=" + summary[column].astype(str)
    summary["_line"] = label
    return summary


def spans_a_decade(values) -> bool:
    """Whether ``values`` (their finite ones) are all positive and the largest is at least ten
    times the smallest: the range a log axis is for."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return values.size > 0 and values.min() > 0 and values.max() / values.min() >= DECADE


@dataclass(frozen=True)
class ParticleAxis:
    """The N axis of a sweep figure: the counts, its scale, and where each line is drawn on it."""

    counts: list[int]             # the particle counts of the sweep, ascending
    log: bool                     # a log axis: the counts span a decade or more
    shifts: dict[str, float]      # line -> its dodge: a factor of N (log axis) or an addition to N

    def positions(self, line: str, counts) -> np.ndarray:
        """Where the line's points at ``counts`` are drawn: N, shifted by the line's dodge."""
        counts = np.asarray(counts, dtype=float)
        return counts * self.shifts[line] if self.log else counts + self.shifts[line]

    def apply(self, axes) -> None:
        """The axis's scale and ticks: on a log axis a labelled tick at each count, no minor ones."""
        if self.log:
            axes.set_xscale("log")
            axes.set_xticks(self.counts, [str(n) for n in self.counts])
            axes.minorticks_off()


def particle_axis(lines) -> ParticleAxis:
    """The N axis for ``lines`` (summary.csv's rows with their ``_line``; see the module docstring)."""
    counts = sorted(int(n) for n in lines["n_particles"].unique())
    log = counts[0] > 0 and counts[-1] / counts[0] >= DECADE
    names = list(dict.fromkeys(lines["_line"]))
    if log:
        scale = np.log10(counts)
        gaps = np.diff(scale)
        step = min(MOST_DODGE_DECADES, DODGE_SHARE_OF_GAP * (gaps.min() if gaps.size else 1.0) / len(names))
    else:
        gaps = np.diff(counts)
        spread = (counts[-1] - counts[0]) or abs(counts[0]) or 1.0
        step = min(MOST_DODGE_SHARE_OF_RANGE * spread,
                   DODGE_SHARE_OF_GAP * (gaps.min() if gaps.size else spread) / len(names))
    offsets = {name: (index - (len(names) - 1) / 2) * step for index, name in enumerate(names)}
    shifts = {name: 10.0 ** offset if log else offset for name, offset in offsets.items()}
    return ParticleAxis(counts, log, shifts)


def _log_metric_axis(axes, means) -> None:
    """A log y axis labelled in plain numbers (0.1, 0.2, 0.5, 1, ...): a log axis's default
    labels only the decades, which leaves a range of one or two decades with one or two labels."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axes.set_yscale("log")
    means = np.asarray(means, dtype=float)
    means = means[np.isfinite(means) & (means > 0)]
    if np.log10(means.max() / means.min()) <= 3:
        axes.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axes.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axes.yaxis.set_minor_formatter(NullFormatter())


def metric_versus_particles(result: ResultFolder, metric: str, ylabel: str, title: str, axes=None):
    """Draw the mean of ``metric`` with its 95% CI against n_particles, one line per other setting
    (axes, bars or bands, and the dodge: the module docstring)."""
    import matplotlib.pyplot as plt

    summary = result.summary
    if summary.empty or f"{metric}_mean" not in summary or summary["n_particles"].isna().all():
        return None
    summary = _line_labels(result, summary.dropna(subset=["n_particles"]))
    n_axis = particle_axis(summary)
    figure = None
    if axes is None:
        figure, axes = plt.subplots(figsize=(7.5, 4.6), layout="constrained")
    styles = set()
    for name, group in summary.groupby("_line", sort=False):
        group = group.sort_values("n_particles")
        x = n_axis.positions(name, group["n_particles"])
        mean = group[f"{metric}_mean"].to_numpy(dtype=float)
        low = group[f"{metric}_ci95_low"].to_numpy(dtype=float)
        high = group[f"{metric}_ci95_high"].to_numpy(dtype=float)
        if len(group) < FEWEST_COUNTS_FOR_A_BAND:
            # A bar's ends as distances from the mean; an interval that misses (NaN) draws no bar.
            below, above = np.clip(mean - low, 0, None), np.clip(high - mean, 0, None)
            axes.errorbar(x, mean, yerr=[below, above], marker="o", linewidth=1.0, capsize=3, label=name)
            styles.add("bars")
        else:
            line, = axes.plot(x, mean, marker="o", label=name)
            axes.fill_between(x, low, high, color=line.get_color(), alpha=0.15)
            styles.add("band")
    n_axis.apply(axes)
    if spans_a_decade(summary[f"{metric}_mean"]):
        _log_metric_axis(axes, summary[f"{metric}_mean"])
        ylabel += " (log scale)"
    trials = int(summary["trials"].max())
    interval = "bars and bands" if styles == {"bars", "band"} else next(iter(styles))
    dodge = "\nlines shifted slightly in N so that no point hides another" if len(n_axis.shifts) > 1 else ""
    axes.set_xlabel("number of particles N" + (" (log scale)" if n_axis.log else ""))
    axes.set_ylabel(ylabel)
    axes.set_title(f"{result.manifest.get('name', '')}: {title}\n(mean over {trials} trials per point, "
                   f"{interval}: 95% confidence interval){dodge}", fontsize=11)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    return figure if figure is not None else axes.figure


def _unit(result: ResultFolder) -> str:
    unit = result.units.get("position", "")
    return f" [{unit}]" if unit else ""


@FIGURES.register("rmse_vs_particles")
def rmse_vs_particles(result: ResultFolder):
    """Position RMSE (mean over trials, 95% CI) against the number of particles.

    One line per other setting, shifted slightly in N so that no point hides another; log axes where N or the means span a decade or more; points with error bars for a line of fewer than 4 values of N, a band for denser sweeps (so do the other `*_vs_particles` figures).
    """
    return metric_versus_particles(result, "rmse_position", f"position RMSE{_unit(result)}",
                                   "position RMSE against particle count")


@FIGURES.register("final_error_vs_particles")
def final_error_vs_particles(result: ResultFolder):
    """Final error distance (mean, 95% CI) against the number of particles."""
    return metric_versus_particles(result, "error_distance_final", f"final error distance{_unit(result)}",
                                   "final error against particle count")


@FIGURES.register("convergence_vs_particles")
def convergence_vs_particles(result: ResultFolder):
    """Mean convergence step (converged trials; 95% CI) and share converged, against N."""
    import matplotlib.pyplot as plt

    summary = result.summary
    if summary.empty or "convergence_step_mean" not in summary or summary["n_particles"].isna().all():
        return None
    unit = result.units.get("time", "s")
    steps_label = "steps" if unit in ("s", "step") else f"{unit}s"
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 7), layout="constrained", sharex=True,
                                         height_ratios=[2, 1])
    metric_versus_particles(result, "convergence_step", f"convergence time [{steps_label}]",
                            "convergence time against particle count", axes=top)
    lines = _line_labels(result, summary.dropna(subset=["n_particles"]))
    n_axis = particle_axis(lines)          # the top panel's: the same dodge, so the points align
    for name, group in lines.groupby("_line", sort=False):
        group = group.sort_values("n_particles")
        bottom.plot(n_axis.positions(name, group["n_particles"]), group["converged_mean"], marker="o", label=name)
    bottom.set_ylabel("share of trials converged")
    bottom.set_xlabel(top.get_xlabel())
    bottom.set_ylim(-0.05, 1.05)
    bottom.grid(alpha=0.3)
    top.set_xlabel("")
    return figure


@FIGURES.register("error_at_convergence_vs_particles")
def error_at_convergence_vs_particles(result: ResultFolder):
    """Error distance at the convergence step (converged trials; 95% CI) against N."""
    return metric_versus_particles(result, "error_at_convergence", f"error distance at convergence{_unit(result)}",
                                   "error at convergence against particle count")
