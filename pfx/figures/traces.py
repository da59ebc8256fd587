"""Generic figures from steps.csv: error distance and ESS over time, one line per cell."""

from __future__ import annotations

from pfx.figures.registry import FIGURES, ResultFolder


def _over_time(result: ResultFolder, values, ylabel: str, title: str, band: bool):
    """One line per cell: the mean of ``values`` over the traced trials at each time."""
    import matplotlib.pyplot as plt

    steps = result.steps
    unit = result.units.get("time", "s")
    x_column, x_label = ("time", f"time [{unit}]") if unit != "step" else ("step", "step")
    frame = steps.assign(_cell=result.cell_names(steps), _value=values)
    figure, axes = plt.subplots(figsize=(7.5, 4.5), layout="constrained")
    for name, group in frame.groupby("_cell", sort=False):
        by_time = group.groupby(x_column)["_value"]
        mean = by_time.mean()
        axes.plot(mean.index, mean.values, label=name, linewidth=1.6)
        if band and group["trial"].nunique() > 1:
            axes.fill_between(mean.index, by_time.min().values, by_time.max().values, alpha=0.15)
    traced = frame.groupby("_cell")["trial"].nunique().max()
    axes.set_xlabel(x_label)
    axes.set_ylabel(ylabel)
    axes.set_title(f"{result.manifest.get('name', '')}: {title}\n"
                   f"(mean{' and range' if band else ''} of {traced} traced trial{'s' if traced > 1 else ''} per cell)",
                   fontsize=11)
    axes.grid(alpha=0.3)
    if frame["_cell"].nunique() > 4:   # many cells: keep the legend off the data
        axes.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    else:
        axes.legend(fontsize=8)
    return figure, axes


@FIGURES.register("error_over_time")
def error_over_time(result: ResultFolder):
    """Mean position error distance over time per cell (traced trials), with its range."""
    if result.steps.empty:
        return None
    unit = result.units.get("position", "")
    figure, _ = _over_time(result, result.steps["error_distance"],
                           f"error distance [{unit}]" if unit else "error distance",
                           "position error over time", band=True)
    return figure


@FIGURES.register("nees_over_time")
def nees_over_time(result: ResultFolder):
    """Mean NEES over time per cell (log scale) against its expected value d, the state dimension."""
    steps = result.steps
    if steps.empty or steps["nees"].isna().all():
        return None
    dimension = sum(1 for column in steps.columns if column.startswith("truth_"))
    figure, axes = _over_time(result, steps["nees"], "NEES (mean over traced trials)",
                              "normalised estimation error squared", band=False)
    axes.axhline(dimension, color="black", linestyle="--", linewidth=1, label=f"expected: d = {dimension}")
    axes.set_yscale("log")
    axes.legend(fontsize=8)
    return figure


@FIGURES.register("ess_over_time")
def ess_over_time(result: ResultFolder):
    """Mean effective sample size (as a share of N) over time per cell, before resampling."""
    steps = result.steps
    if steps.empty:
        return None
    figure, axes = _over_time(result, steps["ess"] / steps["n_particles"], "ESS / N",
                              "effective sample size before resampling", band=False)
    axes.set_ylim(0, 1.05)
    return figure
