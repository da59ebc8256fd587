r"""A likelihood profile and its Monte Carlo adjusted confidence interval, from profile.csv,
profile_smoothed.csv and profile_interval.csv (``estimation.method: profile``).

The profile of a parameter :math:`\psi` is the log-likelihood maximised over the others at each
value of :math:`\psi`; a profile run estimates it by IF2 from several starts at each grid value
(the points), smooths the estimates by local quadratic regression (the line) and, by the Monte
Carlo adjusted profile (Ionides, Breto, Park, Smith & King 2017), draws the interval where the
smoothed profile lies within the cutoff :math:`\delta` of its maximum: :math:`\chi^2_1(0.95)/2 =
1.92` widened by the estimates' Monte Carlo error (the dotted line, the shaded band).
"""

from __future__ import annotations

import numpy as np

from pfx.figures.estimation_chains import axis_name
from pfx.figures.layout import legend_outside, one_colour_per_cell
from pfx.figures.registry import FIGURES, draws_from
from pfx.result_folder import ResultFolder


@FIGURES.register("profile_likelihood")
@draws_from("profile", "profile_smoothed", "profile_interval")
def profile_likelihood(result: ResultFolder):
    """Likelihood profile: each grid value's IF2 estimates, the smoothed profile, the cutoff below its maximum and the confidence interval (MCAP).

    From profile.csv (a point per grid value and start), profile_smoothed.csv (the local quadratic fit) and profile_interval.csv (the maximum, the Monte Carlo adjusted cutoff and the interval), a colour per cell.
    """
    points, curves, intervals = (result.optional_table(name)
                                 for name in ("profile", "profile_smoothed", "profile_interval"))
    if points.empty or intervals.empty or "parameter" not in intervals.columns:
        return None
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    parameter = str(intervals["parameter"].iloc[0])
    lines = one_colour_per_cell(result, points)
    figure, axes = plt.subplots(figsize=(6.4, 4.2), layout="constrained")
    titles = []
    for cell, rows in points.groupby("cell", sort=False):
        colour, label = lines[cell].colour, lines[cell].label
        axes.plot(rows[parameter].to_numpy(dtype=float), rows["log_likelihood"].to_numpy(dtype=float), "o",
                  color=colour, alpha=0.6, markersize=4, label=label)
        curve = curves[curves["cell"] == cell]
        axes.plot(curve["value"].to_numpy(dtype=float), curve["smoothed_log_likelihood"].to_numpy(dtype=float),
                  color=colour, linewidth=1.5)
        interval = intervals[intervals["cell"] == cell].iloc[0]
        top, cutoff = float(interval["log_likelihood_maximum"]), float(interval["cutoff"])
        lower, upper = float(interval["lower"]), float(interval["upper"])
        if np.isfinite(cutoff):
            axes.axhline(top - cutoff, color=colour, linestyle=":", linewidth=1.2)
            axes.axvspan(lower, upper, color=colour, alpha=0.12)
            titles.append(f"{float(interval['maximum']):.4g}, {float(interval['level']):.0%} interval "
                          f"[{lower:.4g}, {upper:.4g}], cutoff {cutoff:.2f}" + (f" ({label})" if len(lines) > 1 else ""))
    axes.set_xlabel(axis_name(parameter))
    axes.set_ylabel("profile log-likelihood")
    axes.grid(alpha=0.3)
    axes.set_title("\n".join(titles), fontsize=8)
    figure.suptitle(f"{result.manifest.get('name', '')}: likelihood profile of {parameter}", fontsize=11)
    legend_outside(figure, [Line2D([], [], color="0.3", linewidth=1.5, label="smoothed profile (loess)"),
                            Line2D([], [], color="0.3", linestyle=":", label="maximum - cutoff (MCAP)")])
    return figure
