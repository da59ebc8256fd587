"""The number of particles over time, for filters whose count adapts (``filter.adaptive``).

KLD-sampling (:mod:`pfx.filters.particle.adaptive`) draws as many particles as its bound asks
for at each step; steps.csv records the count of every traced trial (``particles``). The
figure draws, per cell, the mean count over the traced trials at each step with the band from
the smallest to the largest; a fixed-count cell is a flat line at its N.
"""

from __future__ import annotations

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder


@FIGURES.register("particles_over_time")
def particles_over_time(result: ResultFolder):
    """Particles used per step (mean over the traced trials, band: min-max) per cell; adaptive counts."""
    import matplotlib.pyplot as plt

    steps = result.steps
    if steps.empty or "particles" not in steps or steps["particles"].isna().all():
        return None
    steps = steps.dropna(subset=["particles"]).assign(_line=lambda frame: result.cell_names(frame))
    figure, axes = plt.subplots(figsize=(7.5, 4.6), layout="constrained")
    for name, cell in steps.groupby("_line", sort=False):
        per_step = cell.groupby("time")["particles"].agg(["mean", "min", "max"])
        line, = axes.plot(per_step.index, per_step["mean"], label=str(name))
        axes.fill_between(per_step.index, per_step["min"], per_step["max"], color=line.get_color(), alpha=0.15)
    unit = result.units.get("time", "s")
    axes.set_xlabel(f"time [{unit}]" if unit not in ("step", "action") else f"{unit}s")
    axes.set_ylabel("particles used")
    axes.set_ylim(bottom=0)
    trials = int(steps["trial"].nunique())
    axes.set_title(f"{result.manifest.get('name', '')}: particles per step\n"
                   f"(mean over {trials} traced trial{'s' if trials > 1 else ''}; band: smallest to largest)",
                   fontsize=11)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8)
    return figure
