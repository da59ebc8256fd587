r"""Degeneracy figures: how the effective sample size decays without resampling.

``ess_decay`` draws :math:`\widehat N_{\mathrm{eff}} / N` with
:math:`\widehat N_{\mathrm{eff}} = 1 / \sum_i (w_k^i)^2` (han-lee eq. (10)), recorded before
resampling, over time on a **log scale**, one line per cell: the median over the traced trials
with the band between their 10% and 90% quantiles. The floor :math:`1/N` (one particle carries
all the weight) is drawn as a line: SIS (never resampling) falls onto it within a few steps,
while a resampling filter keeps :math:`\widehat N_{\mathrm{eff}}` a sizeable share of :math:`N`.
On a linear axis (``ess_over_time``) the collapse is invisible: everything below 1% of N looks
like zero.
"""

from __future__ import annotations

from pfx.figures.registry import FIGURES, ResultFolder


@FIGURES.register("ess_decay")
def ess_decay(result: ResultFolder):
    """ESS / N over time per cell on a log scale (median and 10-90% band of the traced trials), with the 1/N floor."""
    import matplotlib.pyplot as plt

    steps = result.steps
    if steps.empty or steps["n_particles"].isna().all():
        return None
    frame = steps.assign(_cell=result.cell_names(steps), _share=steps["ess"] / steps["n_particles"])
    unit = result.units.get("time", "s")
    x_column, x_label = ("time", f"time [{unit}]") if unit != "step" else ("step", "step")
    figure, axes = plt.subplots(figsize=(8, 4.8), layout="constrained")
    for name, group in frame.groupby("_cell", sort=False):
        by_time = group.groupby(x_column)["_share"]
        median = by_time.median()
        line, = axes.plot(median.index, median.values, linewidth=1.8,
                          label=f"{name} (median of {group['trial'].nunique()} trials)")
        axes.fill_between(median.index, by_time.quantile(0.1).values, by_time.quantile(0.9).values,
                          color=line.get_color(), alpha=0.18, linewidth=0)
    floors = sorted(set(1.0 / steps["n_particles"].dropna()))
    for index, floor in enumerate(floors):
        axes.axhline(floor, color="black", linestyle=":", linewidth=1.2,
                     label="floor 1/N: one particle carries all the weight" if index == 0 else None)
    axes.set_yscale("log")
    axes.set_ylim(min(floors) / 2, 1.5)
    axes.set_xlabel(x_label)
    axes.set_ylabel("N_eff / N  (N_eff = 1 / Σ w², before resampling)")
    axes.set_title(f"{result.manifest.get('name', '')}: effective sample size over time (log scale)\n"
                   "lines: median over the traced trials; bands: 10%-90% of them", fontsize=11)
    axes.grid(alpha=0.3, which="both")
    axes.legend(fontsize=8, loc="center right")   # the empty decades between the SIS floor and the SIR lines
    return figure
