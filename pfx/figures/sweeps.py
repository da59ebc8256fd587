"""Figures of a metric against the particle count, from summary.csv: one line per other setting.

Each line is one combination of the cell labels other than ``n_particles`` (arm, resampler,
...), drawn as the mean over trials with its 95% t-interval as a band. The registered names fix
the metric:

================================  ===============================================
figure                            metric (summary.csv prefix)
================================  ===============================================
``rmse_vs_particles``             rmse_position (RMS position error over time)
``final_error_vs_particles``      error_distance_final
``convergence_vs_particles``      convergence_step (converged trials only) and the share converged
``error_at_convergence_vs_particles``  error_at_convergence
================================  ===============================================
"""

from __future__ import annotations

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder


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


def metric_versus_particles(result: ResultFolder, metric: str, ylabel: str, title: str, axes=None):
    """Draw mean ± 95% CI of ``metric`` against n_particles, one line per other setting."""
    import matplotlib.pyplot as plt

    summary = result.summary
    if summary.empty or f"{metric}_mean" not in summary or summary["n_particles"].isna().all():
        return None
    summary = _line_labels(result, summary.dropna(subset=["n_particles"]))
    figure = None
    if axes is None:
        figure, axes = plt.subplots(figsize=(7.5, 4.6), layout="constrained")
    for name, group in summary.groupby("_line", sort=False):
        group = group.sort_values("n_particles")
        line, = axes.plot(group["n_particles"], group[f"{metric}_mean"], marker="o", label=name)
        axes.fill_between(group["n_particles"], group[f"{metric}_ci95_low"], group[f"{metric}_ci95_high"],
                          color=line.get_color(), alpha=0.15)
    trials = int(summary["trials"].max())
    counts = sorted(int(n) for n in summary["n_particles"].unique())
    if counts[0] > 0 and counts[-1] >= 8 * counts[0]:        # doubling sweeps read best on a log axis
        axes.set_xscale("log")
        axes.set_xticks(counts, [str(n) for n in counts])
        axes.minorticks_off()
    axes.set_xlabel("number of particles N")
    axes.set_ylabel(ylabel)
    axes.set_title(f"{result.manifest.get('name', '')}: {title}\n(mean over {trials} trials per point, "
                   "band: 95% confidence interval)", fontsize=11)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    return figure if figure is not None else axes.figure


def _unit(result: ResultFolder) -> str:
    unit = result.units.get("position", "")
    return f" [{unit}]" if unit else ""


@FIGURES.register("rmse_vs_particles")
def rmse_vs_particles(result: ResultFolder):
    """Position RMSE (mean over trials, 95% CI band) against the number of particles.

    One line per other setting; a log N axis for sweeps spanning 8x or more (so do the other `*_vs_particles` figures).
    """
    return metric_versus_particles(result, "rmse_position", f"position RMSE{_unit(result)}",
                                   "position RMSE against particle count")


@FIGURES.register("final_error_vs_particles")
def final_error_vs_particles(result: ResultFolder):
    """Final error distance (mean, 95% CI band) against the number of particles."""
    return metric_versus_particles(result, "error_distance_final", f"final error distance{_unit(result)}",
                                   "final error against particle count")


@FIGURES.register("convergence_vs_particles")
def convergence_vs_particles(result: ResultFolder):
    """Mean convergence step (converged trials; 95% CI) and share converged, against N."""
    import matplotlib.pyplot as plt

    summary = result.summary
    if summary.empty or "convergence_step_mean" not in summary:
        return None
    unit = result.units.get("time", "s")
    steps_label = "steps" if unit in ("s", "step") else f"{unit}s"
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(7.5, 7), layout="constrained", sharex=True,
                                         height_ratios=[2, 1])
    metric_versus_particles(result, "convergence_step", f"convergence time [{steps_label}]",
                            "convergence time against particle count", axes=top)
    lines = _line_labels(result, summary.dropna(subset=["n_particles"]))
    for name, group in lines.groupby("_line", sort=False):
        group = group.sort_values("n_particles")
        bottom.plot(group["n_particles"], group["converged_mean"], marker="o", label=name)
    bottom.set_ylabel("share of trials converged")
    bottom.set_xlabel("number of particles N")
    bottom.set_ylim(-0.05, 1.05)
    bottom.grid(alpha=0.3)
    top.set_xlabel("")
    return figure


@FIGURES.register("error_at_convergence_vs_particles")
def error_at_convergence_vs_particles(result: ResultFolder):
    """Error distance at the convergence step (converged trials; 95% CI band) against N."""
    return metric_versus_particles(result, "error_at_convergence", f"error distance at convergence{_unit(result)}",
                                   "error at convergence against particle count")
