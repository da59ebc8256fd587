r"""Degeneracy figures: how the effective sample size decays without resampling.

``ess_decay`` draws :math:`\widehat N_{\mathrm{eff}} / N` with
:math:`\widehat N_{\mathrm{eff}} = 1 / \sum_i (w_k^i)^2` (han-lee eq. (10)), recorded before
resampling, over time on a **log scale**, one line per cell: the median over the traced trials
with the band between their 10% and 90% quantiles. The floor :math:`1/N` (one particle carries
all the weight) is drawn as a line: SIS (never resampling) falls onto it within a few steps,
while a resampling filter keeps :math:`\widehat N_{\mathrm{eff}}` a sizeable share of :math:`N`.
On a linear axis (``ess_over_time``) the collapse is invisible: everything below 1% of N looks
like zero. The legend sits below the axes, off the data; a sweep of many cells is drawn as small
multiples (:mod:`pfx.figures.layout`).

The medians and quantiles need every trial's values, so this figure reads the traced trials of
steps.csv (steps_summary.csv holds means and intervals only); configs that use it trace all
their trials (han-lee's degeneracy experiment: ``trace_trials: 20``).
"""

from __future__ import annotations

from pfx.figures.layout import auxiliary_note, small_multiples, time_axis
from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder


@FIGURES.register("ess_decay")
def ess_decay(result: ResultFolder):
    """ESS / N over time per cell on a log scale (median and 10-90% band of the traced trials), with the 1/N floor.

    SIS's collapse, which a linear axis hides. Quantiles need every trial's trace: trace them all (`outputs.trace_trials`) for this figure. The title names the cells of the auxiliary filter, whose ESS is that of its second-stage weights.
    """
    steps = result.steps
    if steps.empty or steps["n_particles"].isna().all():
        return None
    frame = steps.assign(_share=steps["ess"] / steps["n_particles"])
    frame = frame[frame.groupby("cell")["_share"].transform("count") > 0]     # filters with particles only
    x_column, x_label = time_axis(result)
    layout = small_multiples(result, frame, single_size=(8, 4.8), log_y=True)
    for cell, group in frame.groupby("cell", sort=False):
        by_time = group.groupby(x_column)["_share"]
        median = by_time.median()
        line = layout.lines[cell]
        axes = layout.axes_for(cell)
        axes.plot(median.index, median.values, linewidth=1.8, color=line.colour, label=line.label)
        axes.fill_between(median.index, by_time.quantile(0.1).values, by_time.quantile(0.9).values,
                          color=line.colour, alpha=0.18, linewidth=0)
    # Each panel's floors 1/N for the particle counts of its own cells.
    floors = frame.groupby("cell", sort=False)["n_particles"].first().rdiv(1.0)
    for axes, floor in dict.fromkeys((layout.axes_for(cell), floor) for cell, floor in floors.items()):
        floor_line = axes.axhline(floor, color="black", linestyle=":", linewidth=1.2)
    floor_line.set_label("floor 1/N: one particle carries all the weight")
    layout.panels[0].set_ylim(floors.min() / 2, 1.5)
    traced = frame.groupby("cell")["trial"].nunique()
    count = f"{traced.min()}" if traced.min() == traced.max() else f"{traced.min()}-{traced.max()}"
    note = auxiliary_note(result, frame)
    layout.finish(f"{result.manifest.get('name', '')}: effective sample size N_eff = 1 / Σ w² before resampling\n"
                  f"lines: median over the {count} traced trial{'s' if traced.max() > 1 else ''} per cell; "
                  "bands: 10%-90% of them" + (f"\n{note}" if note else ""),
                  x_label, "N_eff / N (log scale)", extra_handles=[floor_line])
    return layout.figure
