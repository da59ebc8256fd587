"""Figures of Probabilistic Robotics (Thrun, Burgard & Fox 2005), chapters 3 and 4, from CSV.

* ``kalman_steps`` (Fig. 3.2 a-f) from the ``kalman_1d_steps`` study's ``steps.csv`` and
  ``densities.csv``;
* ``importance_weights`` (Fig. 4.2) from the ``importance_sampling`` study;
* ``nonlinear_particles`` (Fig. 4.3) from the ``nonlinear_transform`` study;
* ``reference_gap_vs_particles`` from a filter experiment whose arms are a histogram filter
  and particle filters at several N (:mod:`pfx.analysis.reference_gap`).
"""

from __future__ import annotations

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

BELIEF = "tab:blue"
MEASUREMENT = "tab:red"
CONTEXT = "0.55"              # earlier curves, drawn thin and grey as in the book

# Panel -> (curves drawn thin for context, the panel's new curve drawn bold), as in Fig. 3.2.
KALMAN_PANELS = {
    "a": ([], "prior"),
    "b": (["prior"], "measurement_1"),
    "c": (["prior", "measurement_1"], "posterior_1"),
    "d": (["posterior_1"], "predicted"),
    "e": (["predicted"], "measurement_2"),
    "f": (["predicted", "measurement_2"], "posterior_2"),
}
KALMAN_TITLES = {
    "prior": "initial belief", "measurement_1": "measurement z₁ (bold)",
    "posterior_1": "belief after the update (bold)", "predicted": "belief after moving right (bold)",
    "measurement_2": "measurement z₂ (bold)", "posterior_2": "belief after the update (bold)",
}


@FIGURES.register("kalman_steps")
def kalman_steps(result: ResultFolder):
    """Fig. 3.2 (a)-(f): the 1-D Kalman filter's beliefs and measurements, six panels.

    Study `kalman_1d_steps` (Probabilistic Robotics).
    """
    import matplotlib.pyplot as plt

    steps, densities = result.table("steps"), result.table("densities")
    if steps.empty or densities.empty:
        return None
    rows = steps.set_index("curve")
    unit = result.units.get("x", "")
    top = float(densities.drop(columns="x").to_numpy().max()) * 1.12
    figure, axes = plt.subplots(3, 2, figsize=(10, 9), sharex=True, sharey=True, layout="constrained")
    for axis, (panel, (context, new)) in zip(axes.ravel(), KALMAN_PANELS.items()):
        for curve in context:
            axis.plot(densities["x"], densities[curve], color=CONTEXT, linewidth=1.0,
                      linestyle="--" if rows.loc[curve, "role"] == "measurement" else "-")
        colour = MEASUREMENT if rows.loc[new, "role"] == "measurement" else BELIEF
        axis.plot(densities["x"], densities[new], color=colour, linewidth=2.6)
        axis.fill_between(densities["x"], densities[new], color=colour, alpha=0.12)
        mean, variance = rows.loc[new, "mean"], rows.loc[new, "variance"]
        axis.axvline(mean, color=colour, linewidth=0.8, linestyle=":")
        axis.set_title(f"({panel}) {KALMAN_TITLES[new]}\nmean {mean:.2f} {unit}, variance {variance:.2f} {unit}²",
                       fontsize=10)
        axis.set_ylim(0, top)
        axis.grid(alpha=0.3)
    for axis in axes[-1]:
        axis.set_xlabel(f"position x [{unit}]" if unit else "position x")
    for axis in axes[:, 0]:
        axis.set_ylabel("probability density")
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=BELIEF, linewidth=2.6, label="belief (new in the panel)"),
               Line2D([], [], color=MEASUREMENT, linewidth=2.6, label="measurement p(z | x), normalised"),
               Line2D([], [], color=CONTEXT, linewidth=1.0, label="earlier belief"),
               Line2D([], [], color=CONTEXT, linewidth=1.0, linestyle="--", label="earlier measurement")]
    figure.legend(handles=handles, loc="outside lower center", ncol=4, fontsize=9)
    figure.suptitle("Kalman filter in one dimension (Probabilistic Robotics, Fig. 3.2): "
                    "update, motion, update", fontsize=12)
    return figure


@FIGURES.register("importance_weights")
def importance_weights(result: ResultFolder):
    """Fig. 4.2: target f, proposal g and its samples, the samples weighted by f/g, the weighted histogram.

    Study `importance_sampling`.
    """
    import matplotlib.pyplot as plt

    densities, samples, histogram = result.table("densities"), result.table("samples"), result.table("histogram")
    moments = result.table("moments")
    if densities.empty or samples.empty:
        return None
    figure, axes = plt.subplots(2, 2, figsize=(11, 7.5), sharex=True, layout="constrained")
    (a, b), (c, d) = axes
    x = densities["x"]
    top = float(densities[["target", "proposal"]].to_numpy().max()) * 1.15
    a.plot(x, densities["target"], color=BELIEF, linewidth=2.2, label="target f")
    a.set_title("(a) the target density f we want samples of", fontsize=10)

    b.plot(x, densities["target"], color=BELIEF, linewidth=1.2, alpha=0.6, label="target f")
    b.plot(x, densities["proposal"], color="tab:green", linewidth=2.2, label="proposal g")
    b.plot(samples["x"], np.full(len(samples), top * 0.03), "|", color="black", markersize=12,
           label=f"{len(samples)} samples of g")
    b.set_title("(b) samples drawn from the proposal g instead", fontsize=10)

    scale = 0.8 * top / samples["weight"].max()
    c.plot(x, densities["target"], color=BELIEF, linewidth=1.2, alpha=0.6, label="target f")
    c.plot(x, densities["proposal"], color="tab:green", linewidth=1.2, alpha=0.6, label="proposal g")
    c.vlines(samples["x"], 0, samples["weight"] * scale, color="black", linewidth=1.4)
    c.plot(samples["x"], samples["weight"] * scale, "o", color="black", markersize=3.5,
           label="samples, height ∝ weight f(x)/g(x)")
    c.set_title("(c) each sample weighted by f(x)/g(x)", fontsize=10)

    total = int(moments["samples"].iloc[0]) if not moments.empty else None
    if not histogram.empty:
        d.stairs(histogram["weighted_density"], np.append(histogram["bin_low"], histogram["bin_high"].iloc[-1]),
                 fill=True, color=BELIEF, alpha=0.3, label="weighted histogram")
        d.stairs(histogram["proposal_sample_density"],
                 np.append(histogram["bin_low"], histogram["bin_high"].iloc[-1]), color="tab:green",
                 linewidth=1.2, label="unweighted histogram (follows g)")
    d.plot(x, densities["target"], color=BELIEF, linewidth=2.2, label="target f")
    ess = f", ESS {moments['effective_sample_size'].iloc[0]:,.0f}" if not moments.empty else ""
    d.set_title(f"(d) all {total:,} samples: the weighted histogram follows f{ess}" if total else
                "(d) the weighted histogram follows f", fontsize=10)
    for axis in axes.ravel():
        axis.set_ylim(0, top)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8, loc="upper right")
    for axis in (c, d):
        axis.set_xlabel("x")
    for axis in (a, c):
        axis.set_ylabel("probability density")
    figure.suptitle("Importance sampling (Probabilistic Robotics, Fig. 4.2)", fontsize=12)
    return figure


@FIGURES.register("nonlinear_particles")
def nonlinear_particles(result: ResultFolder):
    """Fig. 4.3: particles of a Gaussian through g: histogram of y against the exact density and the EKF's Gaussian.

    Study `nonlinear_transform`.
    """
    import matplotlib.pyplot as plt

    function, density, histogram = result.table("function"), result.table("density"), result.table("histogram")
    samples, fit, moments = result.table("samples"), result.table("fit"), result.table("moments")
    if function.empty or density.empty or histogram.empty:
        return None
    figure, axes = plt.subplots(2, 2, figsize=(11, 8.5), layout="constrained",
                                gridspec_kw={"width_ratios": [1, 1.3], "height_ratios": [1.3, 1]})
    output, mapping, notes, source = axes[0, 0], axes[0, 1], axes[1, 0], axes[1, 1]
    edges = np.append(histogram["bin_low"], histogram["bin_high"].iloc[-1])
    total = int(histogram["count"].sum())
    samples_n = int(fit["samples"].iloc[0]) if not fit.empty else total

    # Upper left: p(y), rotated (y upwards) as in the book.
    output.stairs(histogram["particle_density"], edges, orientation="horizontal", fill=True, color="tab:orange",
                  alpha=0.45, label=f"histogram of {samples_n:,} particles")
    output.plot(density["exact_density"], density["y"], color="black", linewidth=2.0, label="exact density of y")
    output.plot(density["linearised_density"], density["y"], color=BELIEF, linewidth=1.8, linestyle="--",
                label="Gaussian of the linearisation (EKF)")
    output.set_xlabel("probability density p(y)")
    output.set_ylabel("y = g(x)")
    output.set_title("output: particles vs exact vs linearised", fontsize=10)
    output.legend(fontsize=8, loc="lower right")

    # Upper right: the function and the particles on it.
    mapping.plot(function["x"], function["g"], color="black", linewidth=2.0, label="y = g(x)")
    if not samples.empty:
        mapping.plot(samples["x"], samples["y"], "o", color="tab:orange", markersize=2.5, alpha=0.6,
                     label=f"{len(samples)} of the particles")
    mean_row = moments.set_index("quantity") if not moments.empty else None
    # The tangent at the input mean (the density's peak), by a central difference on the table.
    at = int(np.argmax(function["input_density"]))
    slope = np.gradient(function["g"].to_numpy(), function["x"].to_numpy())[at]
    tangent = function["g"].iloc[at] + slope * (function["x"] - function["x"].iloc[at])
    mapping.plot(function["x"], tangent, color=BELIEF, linestyle="--", linewidth=1.4,
                 label="tangent at the mean (linearisation)")
    mapping.set_title("the nonlinear function g", fontsize=10)
    mapping.set_xlabel("x")
    mapping.legend(fontsize=8, loc="upper left")
    low = min(edges[0], density["y"].min())
    high = max(edges[-1], density["y"].max())
    for axis in (output, mapping):
        axis.set_ylim(low, high)
        axis.grid(alpha=0.3)

    # Lower right: the input Gaussian.
    source.plot(function["x"], function["input_density"], color="black", linewidth=2.0, label="p(x), Gaussian")
    if not samples.empty:
        source.plot(samples["x"], np.zeros(len(samples)), "|", color="tab:orange", markersize=10,
                    label="particles")
    source.set_xlim(mapping.get_xlim())
    source.set_xlabel("x")
    source.set_ylabel("probability density p(x)")
    source.set_title("input: X ~ Gaussian", fontsize=10)
    source.grid(alpha=0.3)
    source.legend(fontsize=8, loc="upper left")

    # Lower left: the numbers.
    notes.axis("off")
    lines = []
    if mean_row is not None:
        lines += ["moments of y        exact   particles  linearised",
                  f"  mean         {mean_row.loc['mean', 'exact']:10.3f} {mean_row.loc['mean', 'particles']:10.3f}"
                  f" {mean_row.loc['mean', 'linearised']:10.3f}",
                  f"  variance     {mean_row.loc['variance', 'exact']:10.3f} "
                  f"{mean_row.loc['variance', 'particles']:10.3f} {mean_row.loc['variance', 'linearised']:10.3f}", ""]
    for _, row in fit.iterrows():
        who = "particle histogram" if row["method"] == "particles" else "linearised Gaussian"
        lines.append(f"{who} vs exact law:")
        p_value = f"p = {row['p_value']:.3g}" if row["p_value"] >= 1e-300 else "p < 1e-300"
        lines.append(f"  chi-square {row['chi_square']:.1f} on {int(row['degrees_of_freedom'])} dof, {p_value}")
        lines.append(f"  total variation distance {row['total_variation']:.3f}")
    notes.text(0.0, 0.95, "\n".join(lines), family="monospace", fontsize=9, va="top", transform=notes.transAxes)
    notes.set_title("fit (chi-square over bins of equal width)", fontsize=10)
    figure.suptitle("A Gaussian through a nonlinear function (Probabilistic Robotics, Fig. 4.3)", fontsize=12)
    return figure


@FIGURES.register("reference_gap_vs_particles")
def reference_gap_vs_particles(result: ResultFolder):
    """Particle filter against the histogram filter's posterior mean: RMS gap vs N (log-log), and one trial.

    Arms of a `histogram` filter and particle filters at several N; the per-trial slope with its 95% CI (`pfx/analysis/reference_gap.py`).
    """
    import matplotlib.pyplot as plt

    from pfx.analysis.reference_gap import REFERENCE_FILTER, gap_table, slope_summary, trial_gaps, trial_slopes

    steps = result.steps
    if steps.empty or "filter" not in steps or (steps["filter"] == REFERENCE_FILTER).sum() == 0:
        return None
    labels = result.label_columns
    per_trial = trial_gaps(steps, labels)
    if per_trial.empty:
        return None
    table = gap_table(per_trial).sort_values("n_particles")
    summary = slope_summary(trial_slopes(per_trial, labels), labels)
    figure = plt.figure(figsize=(13, 6.2), layout="constrained")
    grid = figure.add_gridspec(2, 2, width_ratios=[1, 1.25])
    left = figure.add_subplot(grid[:, 0])
    upper = figure.add_subplot(grid[0, 1])
    lower = figure.add_subplot(grid[1, 1], sharex=upper)
    jitter = np.exp(np.random.default_rng(0).uniform(-0.06, 0.06, len(per_trial)))   # display only
    left.scatter(per_trial["n_particles"] * jitter, per_trial["rms_gap"], s=9, color="0.6", alpha=0.6,
                 label="one trial (RMS over its steps)")
    left.plot(table["n_particles"], table["rms_gap"], "o-", color="tab:red", linewidth=2,
              label="pooled RMS over trials")
    left.plot(table["n_particles"], table["geometric_mean_rms_gap"], "s-", color=BELIEF, linewidth=2,
              label="geometric mean over trials")
    anchor_n, anchor_gap = table["n_particles"].iloc[0], table["geometric_mean_rms_gap"].iloc[0]
    n = np.geomspace(table["n_particles"].min(), table["n_particles"].max(), 50)
    left.plot(n, anchor_gap * np.sqrt(anchor_n / n), color="black", linestyle="--", linewidth=1.2,
              label=r"$\propto N^{-1/2}$")
    left.set_xscale("log")
    left.set_yscale("log")
    left.set_xlabel("particles N")
    unit = result.units.get("position", "")
    left.set_ylabel(f"RMS gap to the grid posterior mean{f' [{unit}]' if unit else ''}")
    slope_text = ""
    if not summary.empty:
        row = summary.iloc[0]
        slope_text = f"\nmean per-trial slope {row['mean']:.3f} (95% CI {row['ci95_low']:.3f} to {row['ci95_high']:.3f})"
    left.set_title(f"particle filter vs histogram filter, {per_trial['trial'].nunique()} trials{slope_text}",
                   fontsize=10)
    left.grid(alpha=0.3, which="both")
    left.legend(fontsize=8, loc="lower left")

    # Right: one trial over time, the smallest and the largest particle count.
    estimate = [c for c in steps.columns if c.startswith("estimate_")][0]
    state = estimate[len("estimate_"):]
    trial = int(steps["trial"].min())
    one = steps[steps["trial"] == trial]
    reference = one[one["filter"] == REFERENCE_FILTER].set_index("step")
    upper.plot(reference.index, reference[f"truth_{state}"], color="0.5", linewidth=1, marker=".", label="truth")
    upper.plot(reference.index, reference[estimate], color="black", linewidth=2.2, label="grid posterior mean")
    lower.axhline(0.0, color="black", linewidth=2.2, label="grid posterior mean")
    for count, colour in ((table["n_particles"].min(), "tab:orange"), (table["n_particles"].max(), "tab:purple")):
        rows = one[(one["filter"] != REFERENCE_FILTER) & (one["n_particles"] == count)].set_index("step")
        label = f"particle filter, N = {int(count):,}"
        upper.plot(rows.index, rows[estimate], color=colour, linewidth=1.4, linestyle="--", label=label)
        lower.plot(rows.index, rows[estimate] - reference[estimate].reindex(rows.index), color=colour,
                   linewidth=1.4, marker="o", markersize=3, label=label)
    time_unit = result.units.get("time", "step")
    unit_text = f" [{unit}]" if unit else ""
    upper.set_ylabel(f"{state}{unit_text}")
    upper.set_title(f"trial {trial}: estimates over time", fontsize=10)
    lower.set_ylabel(f"particle − grid estimate{unit_text}")
    lower.set_xlabel("step" if time_unit == "step" else f"time [{time_unit}]")
    lower.set_title(f"trial {trial}: the particle filter's gap to the grid", fontsize=10)
    for axis in (upper, lower):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    figure.suptitle(f"{result.manifest.get('name', '')}: the histogram filter as a near-exact reference "
                    "for the particle filter", fontsize=12)
    return figure
