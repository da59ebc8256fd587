"""Figures of Monte Carlo sampling itself (bayes-blog): empirical CDFs and importance sampling.

* ``empirical_cdf`` (study ``empirical_cdf``): one panel per sample size, the empirical CDF
  (a step of 1/n at every sample) over the true normal CDF, with the Kolmogorov-Smirnov gap
  marked; a last panel puts the KS distance against n on log-log axes beside its exact
  expectation and the :math:`0.8687/\\sqrt n` law.
* ``importance_sampling_cdf`` (the study of that name): the target density, the uniform
  proposal and the weighted samples as stems; the CDF estimated from them (self-normalised and
  the post's plain 1/n form) against the true CDF; their errors with the theoretical ±2
  standard-error band.
"""

from __future__ import annotations

import math

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder


def _normal_name(mean: float, std: float) -> str:
    return f"N({mean:g}, {std:g}²)"


@FIGURES.register("empirical_cdf")
def empirical_cdf(result: ResultFolder):
    """Empirical CDF of normal samples at each size against the true CDF; KS distance against n.

    Study `empirical_cdf`: the KS gap marked; the KS distance against n (log-log) with its exact expectation and 0.8687/sqrt(n).
    """
    import matplotlib.pyplot as plt

    samples, true, distances = result.table("ecdf"), result.table("true_cdf"), result.table("ks_distance")
    if samples.empty or true.empty or distances.empty:
        return None
    sizes = list(distances["size"])
    panels = len(sizes) + 1
    columns = 2 if panels <= 4 else 3
    rows = -(-panels // columns)
    figure, axes_grid = plt.subplots(rows, columns, figsize=(5.2 * columns, 3.9 * rows), layout="constrained",
                                     squeeze=False)
    axes_list = axes_grid.ravel()
    for extra in axes_list[panels:]:
        extra.set_visible(False)
    low, high = true["x"].min(), true["x"].max()
    for axes, (_, row) in zip(axes_list, distances.iterrows()):
        n = int(row["size"])
        sample = samples[samples["size"] == n].sort_values("rank")
        axes.plot(true["x"], true["cdf"], color="black", linewidth=1.6, label="true CDF F(x)")
        xs = np.concatenate([[min(low, sample["x"].min())], sample["x"], [max(high, sample["x"].max())]])
        ys = np.concatenate([[0.0], sample["ecdf"], [1.0]])
        axes.step(xs, ys, where="post", color="tab:blue", linewidth=1.3, label="empirical CDF $\\hat F_n(x)$")
        if n <= 100:
            axes.plot(sample["x"], np.zeros(n), "|", color="tab:blue", markersize=9, alpha=0.7, label="samples")
        axes.plot([row["ks_at"]] * 2, [row["ks_true_cdf"], row["ks_ecdf_value"]], color="crimson",
                  linewidth=2.5, label="largest gap $D_n$")
        axes.set_title(f"n = {n:,}: $D_n$ = {row['ks_distance']:.3f} "
                       f"(expected {row['expected_ks']:.3f})", fontsize=10)
        axes.set_xlabel("x")
        axes.set_ylabel("cumulative probability")
        axes.set_ylim(-0.04, 1.04)
        axes.grid(alpha=0.3)
        axes.legend(fontsize=8, loc="upper left")
    axes = axes_list[len(sizes)]
    repetitions = int(distances["repetitions"].iloc[0])
    axes.errorbar(distances["size"], distances["ks_mean"], yerr=2 * distances["ks_sem"], marker="o",
                  linestyle="none", color="tab:blue", capsize=3,
                  label=f"mean $D_n$ over {repetitions:,} samples (±2 SE)")
    axes.plot(distances["size"], distances["expected_ks"], marker="x", linestyle="none", color="black",
              markersize=9, label="exact $E[D_n]$")
    span = np.geomspace(distances["size"].min(), distances["size"].max(), 50)
    axes.plot(span, distances["asymptotic_ks"].iloc[0] * math.sqrt(distances["size"].iloc[0]) / np.sqrt(span),
              color="gray", linestyle="--", label="$0.8687/\\sqrt{n}$ (Kolmogorov)")
    axes.scatter(distances["size"], distances["ks_distance"], marker="s", color="crimson", zorder=3,
                 label="the drawn sample's $D_n$")
    axes.set_xscale("log")
    axes.set_yscale("log")
    axes.set_xlabel("sample size n")
    axes.set_ylabel("KS distance $\\sup_x |\\hat F_n - F|$")
    axes.set_title("the gap shrinks like $1/\\sqrt{n}$", fontsize=10)
    axes.grid(alpha=0.3, which="both")
    axes.legend(fontsize=8)
    mean, std = true["normal_mean"].iloc[0], true["normal_std"].iloc[0]
    figure.suptitle(f"Empirical CDF of samples of {_normal_name(mean, std)} against the true CDF", fontsize=12)
    return figure


@FIGURES.register("importance_sampling_cdf")
def importance_sampling_cdf(result: ResultFolder):
    """Normal CDF from uniform-proposal samples: densities and weights, CDF estimates, errors.

    Study `importance_sampling_cdf`: the weighted samples as stems; the self-normalised and plain estimates against the true CDF; their errors within ±2 theoretical standard errors.
    """
    import matplotlib.pyplot as plt

    samples, cdf, summary = result.table("samples"), result.table("cdf"), result.table("summary")
    if samples.empty or cdf.empty or summary.empty:
        return None
    setup = summary.iloc[0]
    low, high, n = setup["proposal_low"], setup["proposal_high"], int(setup["samples"])
    target = _normal_name(setup["target_mean"], setup["target_std"])
    figure, (top, middle, bottom) = plt.subplots(3, 1, figsize=(8.5, 10), layout="constrained", sharex=True,
                                                 height_ratios=[1.1, 1.1, 1])
    top.plot(cdf["x"], cdf["target_density"], color="black", linewidth=1.6, label=f"target p(x) = {target}")
    top.hlines(1 / (high - low), low, high, color="tab:green", linewidth=1.6,
               label=f"proposal q(x) = U({low:g}, {high:g})")
    top.set_ylabel("density")
    stems = top.twinx()
    stems.vlines(samples["x"], 0, samples["normalised_weight"], color="tab:orange", linewidth=0.6, alpha=0.6)
    # Headroom above the curves for the legend, room below for the samples' rug; both axes start
    # at the same fraction of their height so that zero weight sits on zero density.
    peak, heaviest = cdf["target_density"].max(), samples["normalised_weight"].max()
    top.set_ylim(-0.08 * peak, 1.6 * peak)
    stems.set_ylim(-0.08 * heaviest, 1.6 * heaviest)
    top.plot(samples["x"], np.full(len(samples), -0.04 * peak), "|", color="tab:green", markersize=6, alpha=0.5,
             label="sample positions (uniform)")
    top.set_zorder(stems.get_zorder() + 1)      # the curves over the stems
    top.patch.set_visible(False)
    stems.set_ylabel("normalised weight $\\bar w_i$", color="tab:orange")
    stems.tick_params(axis="y", colors="tab:orange")
    handles, labels = top.get_legend_handles_labels()
    from matplotlib.lines import Line2D

    handles.append(Line2D([], [], color="tab:orange", linewidth=1))
    labels.append(f"{n:,} samples of q, stem = weight p/q (normalised)")
    top.legend(handles, labels, fontsize=8, loc="upper left", ncol=2)
    top.set_title("the samples come from q; their weights $w = p/q$ make them represent p", fontsize=10)
    top.grid(alpha=0.3)

    middle.plot(cdf["x"], cdf["true_cdf"], color="black", linewidth=2.2, label="true CDF Φ")
    middle.plot(cdf["x"], cdf["estimate_self_normalised"], color="tab:blue", linewidth=1.3,
                label="self-normalised: $\\sum_i \\bar w_i 1\\{x_i \\leq x\\}$")
    middle.plot(cdf["x"], cdf["estimate_plain"], color="tab:red", linewidth=1.1, linestyle="--",
                label="the post's formula: $\\frac{1}{n}\\sum_i w_i 1\\{x_i \\leq x\\}$")
    middle.set_ylabel("cumulative probability")
    middle.set_title("CDF estimated from the weighted samples", fontsize=10)
    middle.legend(fontsize=8, loc="upper left")
    middle.grid(alpha=0.3)

    for name, color, label in (("self_normalised", "tab:blue", "self-normalised"), ("plain", "tab:red", "post's formula")):
        bottom.plot(cdf["x"], cdf[f"error_{name}"], color=color, linewidth=1.2, label=f"{label}: error")
        band = 2 * cdf[f"standard_error_{name}"]
        bottom.fill_between(cdf["x"], -band, band, color=color, alpha=0.12, label=f"{label}: ±2 SE (theory)")
    bottom.axhline(0, color="black", linewidth=0.8)
    bottom.set_xlabel("x")
    bottom.set_ylabel("estimate − true CDF")
    bottom.set_title("error of the drawn sample's estimates, with the theoretical ±2 standard-error bands",
                     fontsize=10)
    bottom.legend(fontsize=8, ncol=2, loc="lower left")
    bottom.grid(alpha=0.3)
    figure.suptitle(f"Importance sampling: the CDF of {target} from {n:,} uniform samples", fontsize=12)
    return figure
