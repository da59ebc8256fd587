"""Generic figures from steps.csv: error distance and ESS over time, one line per cell."""

from __future__ import annotations

from pfx.figures.registry import FIGURES, ResultFolder


def _time_axis(result: ResultFolder) -> tuple[str, str]:
    unit = result.units.get("time", "s")
    return ("time", f"time [{unit}]") if unit != "step" else ("step", "step")


@FIGURES.register("error_over_time")
def error_over_time(result: ResultFolder):
    """Mean position error distance over time per cell (traced trials), with its spread."""
    import matplotlib.pyplot as plt

    steps = result.steps
    if steps.empty:
        return None
    x_column, x_label = _time_axis(result)
    figure, axes = plt.subplots(figsize=(7.5, 4.5))
    steps = steps.assign(_cell=result.cell_names(steps))
    for name, group in steps.groupby("_cell", sort=False):
        by_time = group.groupby(x_column)["error_distance"]
        mean = by_time.mean()
        axes.plot(mean.index, mean.values, label=name, linewidth=1.6)
        if group["trial"].nunique() > 1:
            axes.fill_between(mean.index, by_time.min().values, by_time.max().values, alpha=0.15)
    unit = result.units.get("position", "")
    axes.set_xlabel(x_label)
    axes.set_ylabel(f"error distance [{unit}]" if unit else "error distance")
    traced = steps.groupby("_cell")["trial"].nunique().max()
    axes.set_title(f"{result.manifest.get('name', '')}: position error over time "
                   f"(mean and range of {traced} traced trial{'s' if traced > 1 else ''} per cell)")
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    figure.tight_layout()
    return figure


@FIGURES.register("ess_over_time")
def ess_over_time(result: ResultFolder):
    """Mean effective sample size (as a share of N) over time per cell, before resampling."""
    import matplotlib.pyplot as plt

    steps = result.steps
    if steps.empty:
        return None
    x_column, x_label = _time_axis(result)
    figure, axes = plt.subplots(figsize=(7.5, 4.5))
    steps = steps.assign(_cell=result.cell_names(steps), _share=steps["ess"] / steps["n_particles"])
    for name, group in steps.groupby("_cell", sort=False):
        mean = group.groupby(x_column)["_share"].mean()
        axes.plot(mean.index, mean.values, label=name, linewidth=1.6)
    axes.set_xlabel(x_label)
    axes.set_ylabel("ESS / N")
    axes.set_ylim(0, 1.05)
    axes.set_title(f"{result.manifest.get('name', '')}: effective sample size before resampling")
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    figure.tight_layout()
    return figure
