r"""The log-likelihood step by step: where the model and the data disagree.

``log_likelihood_increment_over_time`` draws, for every cell, the mean over its trials of the
log-likelihood increment :math:`L_k = \log \hat p(z_k \mid z_{1:k-1})` at each step
(steps_summary.csv's ``log_likelihood_increment_*``, :mod:`pfx.analysis.step_summary`), with the
95% t-interval of that mean as a band. A trial's log-likelihood is the sum of its increments,
so a step far below its neighbours is a measurement the model found improbable given the ones
before it: an outlier, a miscoded observation, a change the model does not allow. Each cell's
lowest step is ringed, and the title names the lowest of them with the cell's median step
beside it, so that one bad step out of hundreds is found at a glance rather than by reading
steps.csv.

A step whose mean is not finite (a degenerate step of a particle filter: every weight
underflowed, an increment of :math:`-\infty`) has no point; the panel's note counts such steps.
The lines are never cut at an axis limit (unlike the error figures of :mod:`pfx.figures.traces`):
the outlying step is what this figure is for. A folder written before the increments were
recorded has nothing to draw.
"""

from __future__ import annotations

import numpy as np

from pfx.figures.layout import small_multiples, time_axis, time_text, trials_text
from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

QUANTITY = "log_likelihood_increment"


@FIGURES.register("log_likelihood_increment_over_time")
def log_likelihood_increment_over_time(result: ResultFolder):
    """Mean log-likelihood increment log p(z_k | z_1:k-1) per step and cell, with the 95% CI of the mean; each cell's lowest step ringed.

    From steps_summary.csv (every trial): the step where the model and the data disagree stands out below the others; the title names the lowest one. Opt-in (`outputs.figures`).
    """
    summary = result.steps_summary
    if summary.empty or f"{QUANTITY}_mean" not in summary or summary[f"{QUANTITY}_mean"].isna().all():
        return None
    x_column, x_label = time_axis(result)
    drawn = summary.groupby("cell", sort=False)[f"{QUANTITY}_mean"].transform(lambda mean: mean.notna().any())
    summary = summary[drawn.astype(bool)]
    layout = small_multiples(result, summary)
    lowest = None                      # (mean, cell, time, the cell's median step)
    for cell, rows in summary.groupby("cell", sort=False):
        line = layout.lines[cell]
        axes = layout.axes_for(cell)
        time = rows[x_column].to_numpy(dtype=float)
        mean, low, high = (rows[f"{QUANTITY}_{statistic}"].to_numpy(dtype=float)
                           for statistic in ("mean", "ci95_low", "ci95_high"))
        finite = np.isfinite(mean)
        axes.plot(time, np.where(finite, mean, np.nan), color=line.colour, label=line.label, linewidth=1.2)
        band = finite & np.isfinite(low) & np.isfinite(high)
        if band.any():
            axes.fill_between(time, np.where(band, low, np.nan), np.where(band, high, np.nan),
                              color=line.colour, alpha=0.2, linewidth=0)
        if (~finite & ~np.isnan(mean)).any():
            layout.note(cell, f"{line.label}: {int((~finite & ~np.isnan(mean)).sum())} step(s) with an infinite "
                              "mean (a degenerate step: every weight underflowed)")
        if not finite.any():
            continue
        worst = int(np.argmin(np.where(finite, mean, np.inf)))
        axes.plot([time[worst]], [mean[worst]], marker="o", markersize=10, markerfacecolor="none",
                  markeredgecolor=line.colour, markeredgewidth=1.5)
        if lowest is None or mean[worst] < lowest[0]:
            lowest = (mean[worst], cell, time[worst], float(np.median(mean[finite])))
    trials = trials_text(summary, result.steps_summary_covers_every_trial)
    title = (f"{result.manifest.get('name', '')}: log-likelihood increment log p(z_k | z_1:k-1) per step\n"
             f"mean over {trials} per cell, band: 95% CI; ring: each cell's lowest step")
    if lowest is not None:
        value, cell, time, median = lowest
        label = layout.lines[cell].label
        title += (f"\nlowest: {time_text(time, result)}"
                  f"{f' ({label})' if len(layout.lines) > 1 else ''}, mean {value:.4g} "
                  f"(the cell's median step: {median:.4g})")
    layout.finish(title, x_label, "log-likelihood increment")
    return layout.figure
