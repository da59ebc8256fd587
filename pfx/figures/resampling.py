"""Figures of resampling itself: offspring counts against their unbiased target N w."""

from __future__ import annotations

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder


@FIGURES.register("offspring_bias")
def offspring_bias(result: ResultFolder):
    """Observed mean offspring count per particle (±2 SE) for each resampler against N w.

    Study `offspring_counts`.
    """
    import matplotlib.pyplot as plt

    table = result.table("offspring")
    if table.empty:
        return None
    resamplers = list(dict.fromkeys(table["resampler"]))
    particles = sorted(table["particle"].unique())
    figure, axes = plt.subplots(figsize=(8.5, 4.8), layout="constrained")
    width = 0.8 / len(resamplers)
    positions = np.arange(len(particles))
    for index, name in enumerate(resamplers):
        rows = table[table["resampler"] == name].set_index("particle").loc[particles]
        biased = not bool(rows["unbiased"].iloc[0])
        offset = (index - (len(resamplers) - 1) / 2) * width
        axes.bar(positions + offset, rows["observed_mean"], width * 0.9,
                 yerr=2 * rows["observed_sem"], capsize=2,
                 label=f"{name} (BIASED)" if biased else name,
                 hatch="//" if biased else None, edgecolor="black" if biased else None, linewidth=0.5)
        if biased:
            axes.scatter(positions + offset, rows["expected_count"], marker="x", color="black", zorder=3,
                         label=f"{name}: theoretical E[N_j]")
    target = table.drop_duplicates("particle").set_index("particle").loc[particles]
    for x, value in zip(positions, target["target_count"]):
        axes.hlines(value, x - 0.45, x + 0.45, color="black", linestyle="--", linewidth=1.5,
                    label="unbiased target N w_j" if x == 0 else None)
    weights = ", ".join(f"{w:g}" for w in target["weight"])
    draws = int(table["draws"].iloc[0])
    axes.set_xticks(positions, [f"particle {p}" for p in particles])
    axes.set_ylabel("mean offspring count E[N_j]")
    axes.set_title(f"Offspring counts per particle, w = ({weights}), {draws:,} draws each\n"
                   "bars: observed mean ± 2 SE; dashed: unbiased target N w_j", fontsize=11)
    axes.legend(fontsize=8, ncol=2)
    axes.grid(alpha=0.3, axis="y")
    return figure
