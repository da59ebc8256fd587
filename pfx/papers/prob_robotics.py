"""The gallery section of ``prob-robotics``: Thrun, Burgard & Fox, *Probabilistic Robotics*, ch. 3-5.

The source (described in docs/papers/prob-robotics.md; the book's corrected motion-model
algorithms are in docs/reference-facts.md) is a set of study notes on the book; neither prints
a number to compare with (the book's figures are drawings of densities and samples, with no
stated parameters), so every verdict here compares our numbers with the *mathematics* the book
states: the Kalman filter's update against Bayes' rule on a grid, importance-weighted moments
against the target's exact moments, a particle histogram against the exact law of a
transformed Gaussian, the particle filter against the histogram filter's near-exact posterior.

**Parts.** The section is assembled from parts (:mod:`pfx.papers.base`), one per experiment
(a folder of ``results/prob-robotics/``), in the order of :data:`PARTS`; a part returns nothing
when its folder is absent. The motion-model figures (5.3, 5.4, 5.8, 5.9) and the binary Bayes
filter are one part of their own, :func:`pfx.papers.prob_robotics_motion.motion_sections`. To
add an experiment: write a part function and put it in :data:`PARTS`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pfx.analysis.compare import paired_comparison
from pfx.analysis.reference_gap import REFERENCE_FILTER, gap_table, slope_summary, trial_gaps, trial_slopes
from pfx.papers.base import (
    REPORTS,
    Figure,
    PaperResults,
    Part,
    Section,
    Table,
    Verdict,
    assemble,
    format_number,
    markdown_table,
    p_value,
    percent,
    verdict_from_checks,
)
from pfx.papers.prob_robotics_motion import motion_sections

PAPER = "prob-robotics"

# Tolerances of the verdicts, stated once.
GRID_AGREEMENT = 1e-6          # relative: Table 3.1 against Bayes' rule on a grid (exact to ~1e-12)
Z_LIMIT = 3.0                  # importance-sampling moments within 3 standard errors
P_LIMIT = 1e-3                 # chi-square: particles pass at p >= 1e-3, the Gaussian fails below it
RATE = -0.5                    # the N^-1/2 rate ...
RATE_TOLERANCE = 0.1           # ... "near": the 95% interval of the slope inside -1/2 +- 0.1 (or holding -1/2)
NEGLIGIBLE = 0.05              # "negligible": the PF's RMSE, 95% upper bound, within 5 % of the grid's


# -- Fig. 3.2: the Kalman filter in 1-D --------------------------------------------------------

def kalman_part(results: PaperResults) -> Part:
    """Fig. 3.2: the 1-D Kalman filter's steps against Bayes' rule on a grid."""
    if not results.has("fig-3.2-kalman"):
        return Part()
    folder = results.folder("fig-3.2-kalman")
    steps = folder.table("steps").set_index("curve")
    unit = folder.units.get("x", "")
    table = pd.DataFrame({
        "panel": steps["panel"], "curve": steps.index,
        f"mean, Table 3.1 [{unit}]": steps["mean"], f"variance, Table 3.1 [{unit}²]": steps["variance"],
        "Kalman gain": steps["kalman_gain"],
        f"mean, Bayes on a grid [{unit}]": steps["grid_mean"],
        f"variance, Bayes on a grid [{unit}²]": steps["grid_variance"],
        "max density difference": steps["max_density_difference"]})
    prior, first, update_1 = (steps.loc[c] for c in ("prior", "measurement_1", "posterior_1"))
    predicted, second, update_2 = (steps.loc[c] for c in ("predicted", "measurement_2", "posterior_2"))
    checks = []
    for before, measured, after in ((prior, first, update_1), (predicted, second, update_2)):
        checks.append(after["variance"] < min(before["variance"], measured["variance"]))
        low, high = sorted((before["mean"], measured["mean"]))
        checks.append(low < after["mean"] < high)
    checks.append(predicted["variance"] > update_1["variance"])
    relative = max(float((np.abs(steps["grid_mean"] - steps["mean"]) / np.maximum(1.0, np.abs(steps["mean"]))).max()),
                   float((np.abs(steps["grid_variance"] - steps["variance"]) / steps["variance"]).max()))
    agrees = relative < GRID_AGREEMENT
    shape = all(checks)
    verdict = verdict_from_checks([shape, agrees])
    evidence = (f"update 1: variance {format_number(prior['variance'])} → "
                f"{format_number(update_1['variance'])} {unit}² (measurement {format_number(first['variance'])}), "
                f"mean {format_number(prior['mean'])} → {format_number(update_1['mean'])} {unit} toward "
                f"z₁ = {format_number(first['mean'])}; motion: variance {format_number(update_1['variance'])} → "
                f"{format_number(predicted['variance'])}; update 2: variance {format_number(predicted['variance'])} → "
                f"{format_number(update_2['variance'])}, mean {format_number(predicted['mean'])} → "
                f"{format_number(update_2['mean'])} toward z₂ = {format_number(second['mean'])}; "
                f"Table 3.1 and Bayes' rule on a grid agree to {relative:.1e} (relative; tolerance "
                f"{GRID_AGREEMENT:g}).")
    return Part(
        items=[Figure("fig-3.2-kalman", "kalman_steps.png",
                      "Fig. 3.2 (a)-(f): the 1-D Kalman filter. Bold: the panel's new belief (blue) or "
                      "measurement (red, the likelihood normalised over x); grey: earlier curves. Numbers "
                      "chosen by pfx (the book gives none): see the config."),
               Table("Fig. 3.2: means and variances, Table 3.1 against Bayes' rule on a grid",
                     markdown_table(table, digits=4),
                     "The book prints no numbers for this figure. 'Bayes on a grid': the update as the "
                     "normalised pointwise product prior × likelihood, the prediction as the numerical "
                     "convolution with the motion noise, on 2001 points; 'max density difference' is the "
                     "largest gap between that density and the Kalman filter's Gaussian.")],
        verdicts=[Verdict("The Kalman update moves the mean toward the measurement and shrinks the variance "
                          "below both the prior's and the measurement's; motion widens it (Fig. 3.2)",
                          verdict, evidence)])


# -- Fig. 4.2: importance sampling -------------------------------------------------------------

def importance_part(results: PaperResults) -> Part:
    """Fig. 4.2: moments of the target from importance-weighted samples of the proposal."""
    if not results.has("fig-4.2-importance-sampling"):
        return Part()
    folder = results.folder("fig-4.2-importance-sampling")
    moments = folder.table("moments").set_index("quantity")
    table = pd.DataFrame({
        "quantity": moments.index, "exact (target f)": moments["exact"],
        "weighted samples of g": moments["weighted_estimate"], "standard error": moments["standard_error"],
        "z": moments["z_score"], "unweighted samples of g": moments["unweighted_estimate"],
        "draws": moments["samples"], "ESS": moments["effective_sample_size"]})
    within = bool((moments["z_score"].abs() < Z_LIMIT).all())
    unweighted_z = ((moments["unweighted_estimate"] - moments["exact"]) / moments["standard_error"]).abs()
    verdict = "reproduced" if within else "not reproduced"
    mean, variance = moments.loc["mean"], moments.loc["variance"]
    evidence = (f"with {int(mean['samples']):,} draws of g (ESS {mean['effective_sample_size']:,.0f}) the weighted "
                f"mean is {format_number(mean['weighted_estimate'], 4)} against f's "
                f"{format_number(mean['exact'], 4)} (z = {mean['z_score']:.2f}) and the weighted variance "
                f"{format_number(variance['weighted_estimate'], 4)} against {format_number(variance['exact'], 4)} "
                f"(z = {variance['z_score']:.2f}), within {Z_LIMIT:g} "
                f"standard errors{'' if within else ' NOT for both'}; unweighted, the same draws give "
                f"{format_number(mean['unweighted_estimate'], 4)} and "
                f"{format_number(variance['unweighted_estimate'], 4)} "
                f"({unweighted_z.min():.0f} or more standard errors off): the weights do the work.")
    return Part(
        items=[Figure("fig-4.2-importance-sampling", "importance_weights.png",
                      "Fig. 4.2: (a) target f, (b) samples of the proposal g, (c) the same samples weighted by "
                      "f/g (stem height ∝ weight), (d) the weighted histogram of all draws against f, and the "
                      "unweighted one, which follows g."),
               Table("Fig. 4.2: moments of f from weighted samples of g", markdown_table(table, digits=4),
                     "The book prints no numbers; f and g are pfx's choice (config). Standard error: the "
                     "delta-method error of the self-normalised estimator, sqrt(Σ w̃² (h(x) - Ê[h])²); the "
                     "rule of thumb sqrt(variance / ESS), ESS = 1 / Σ w̃², is in moments.csv "
                     "(ess_standard_error): wider here, see pfx/studies/importance_sampling.py.")],
        verdicts=[Verdict("Importance weights f/g make samples of g represent f (Fig. 4.2)", verdict, evidence)])


# -- Fig. 4.3: a Gaussian through a nonlinear function ----------------------------------------

def nonlinear_part(results: PaperResults) -> Part:
    """Fig. 4.3: a Gaussian through a nonlinear function, particles against linearisation."""
    if not results.has("fig-4.3-nonlinear-transform"):
        return Part()
    folder = results.folder("fig-4.3-nonlinear-transform")
    fit = folder.table("fit").set_index("method")
    moments = folder.table("moments").set_index("quantity")
    fit_table = pd.DataFrame({"compared with the exact law of y": ["particle histogram", "linearised Gaussian (EKF)"],
                              "chi-square": fit["chi_square"].to_numpy(),
                              "degrees of freedom": fit["degrees_of_freedom"].to_numpy(),
                              "p-value": fit["p_value"].to_numpy(),
                              "total variation distance": fit["total_variation"].to_numpy()})
    moment_table = pd.DataFrame({"quantity": moments.index, "exact": moments["exact"],
                                 "particles": moments["particles"], "linearised (EKF)": moments["linearised"]})
    particles, linear = fit.loc["particles"], fit.loc["linearised"]
    particles_pass = particles["p_value"] >= P_LIMIT
    gaussian_fails = linear["p_value"] < P_LIMIT and linear["total_variation"] > particles["total_variation"]
    verdict = ("reproduced" if particles_pass and gaussian_fails else
               "partly reproduced" if particles_pass else "not reproduced")
    samples = int(particles["samples"])
    evidence = (f"{samples:,} particles: their histogram fits the exact law of y (chi-square "
                f"{particles['chi_square']:.1f} on {int(particles['degrees_of_freedom'])} dof, "
                f"{_p_value(particles['p_value'], in_words=True)}, total variation "
                f"{particles['total_variation']:.3f}), the linearised Gaussian does not (chi-square of the same "
                f"particles against it {linear['chi_square']:.3g}, {_p_value(linear['p_value'], in_words=True)}, "
                f"total variation {linear['total_variation']:.3f}); exact mean "
                f"{format_number(moments.loc['mean', 'exact'])}, particles "
                f"{format_number(moments.loc['mean', 'particles'])}, "
                f"linearised {format_number(moments.loc['mean', 'linearised'])}.")
    return Part(
        items=[Figure("fig-4.3-nonlinear-transform", "nonlinear_particles.png",
                      "Fig. 4.3: particles of a Gaussian X (lower right) pushed through y = g(x) (upper right); "
                      "upper left: their histogram against the exact density of y (change of variables over the "
                      "real roots of g(x) = y) and the EKF's linearised Gaussian."),
               Table("Fig. 4.3: the law of y = g(x), particles against linearisation",
                     markdown_table(fit_table, formats={"p-value": _p_value}),
                     f"Pearson's chi-square over bins fixed by the exact law (its 0.1 % to 99.9 % range, plus "
                     f"both tails), bins expected to hold fewer than 5 draws merged. Verdict thresholds: particles "
                     f"pass at p ≥ {P_LIMIT:g}, the Gaussian fails below it."),
               Table("Fig. 4.3: moments of y", markdown_table(moment_table),
                     "Exact: Gauss-Hermite quadrature (exact for a polynomial g). The book prints no numbers; "
                     "g and the input Gaussian are pfx's choice (config).")],
        verdicts=[Verdict("A Gaussian through a nonlinear function is non-Gaussian; particles capture it, "
                          "linearisation does not (Fig. 4.3)", verdict, evidence)])


def _p_value(p: float, in_words: bool = False) -> str:
    """This section's p-values: Python's two significant digits ("0.32", "6e-135"), "< 1e-300" below."""
    return p_value(p, in_words=in_words, number="{:.2g}".format)


def _percent(fraction: float) -> str:
    """This section's relative changes: "+3.4 %", whole percents from 10 % ("+45 %")."""
    return percent(fraction, significant=2, suffix=" %")


# -- Beyond the book: the histogram filter as the reference for the particle filter ------------

def reference_part(results: PaperResults) -> Part:
    """Beyond the book: the particle filter against the histogram filter's near-exact posterior."""
    if not results.has("histogram-reference"):
        return Part()
    folder = results.folder("histogram-reference")
    labels = folder.label_columns
    steps = folder.steps
    per_trial = trial_gaps(steps, labels)
    gaps = gap_table(per_trial).sort_values("n_particles")
    summary = slope_summary(trial_slopes(per_trial, labels), labels).iloc[0]
    reference = steps[steps["filter"] == REFERENCE_FILTER]
    posterior_sd = float(np.sqrt(np.mean(reference["spread"] ** 2)))
    comparison = paired_comparison(folder.trials, "rmse_position", by="arm",
                                   baseline=str(folder.trials.loc[folder.trials["filter"] == REFERENCE_FILTER,
                                                                  "arm"].iloc[0]),
                                   label_columns=labels)
    comparison = comparison.set_index("arm")
    arm_of = per_trial.drop_duplicates("cell").set_index("arm")["n_particles"]
    table = pd.DataFrame({
        "particles N": gaps["n_particles"].astype(int).to_numpy(), "trials": gaps["trials"].to_numpy(),
        "RMS gap (pooled)": gaps["rms_gap"].to_numpy(),
        "gap / posterior sd": gaps["rms_gap"].to_numpy() / posterior_sd,
        "geometric mean of trial gaps": gaps["geometric_mean_rms_gap"].to_numpy(),
        "median trial gap": gaps["median_rms_gap"].to_numpy(),
        "RMSE vs truth": comparison.loc[gaps["arm"], "mean"].to_numpy(),
        "RMSE increase over the grid's": [_percent(row["relative_change"])
                                          for _, row in comparison.loc[gaps["arm"]].iterrows()],
        "95% CI of the increase": [f"{_percent(row['ci95_low'] / row['baseline_mean'])} to "
                                   f"{_percent(row['ci95_high'] / row['baseline_mean'])}"
                                   for _, row in comparison.loc[gaps["arm"]].iterrows()]})
    grid_rmse = float(comparison["baseline_mean"].iloc[0])
    low, high, slope = summary["ci95_low"], summary["ci95_high"], summary["mean"]
    near = (low <= RATE <= high) or (RATE - RATE_TOLERANCE <= low and high <= RATE + RATE_TOLERANCE)
    verdict = "reproduced" if near else ("partly reproduced" if high < 0 else "not reproduced")
    model = str(steps["model"].iloc[0])
    first, last = gaps.iloc[0], gaps.iloc[-1]
    evidence = (f"on the {model} model ({int(summary['n'])} trials) the per-trial slope of log RMS gap against "
                f"log N averages {slope:.3f} (95% CI {low:.3f} to {high:.3f}; -1/2 expected); the pooled RMS gap "
                f"falls from {format_number(first['rms_gap'])} at N = {int(first['n_particles']):,} to "
                f"{format_number(last['rms_gap'])} at N = {int(last['n_particles']):,}.")
    verdicts = [Verdict("The histogram filter is a near-exact reference: the particle filter converges to it as "
                        "N grows, at the rate N^-1/2 (chapter 4's summary: both nonparametric filters' "
                        "approximation error goes to zero as their parameters grow)", verdict, evidence)]

    # Section 4.2.1: "if the number of particles is not too small (M >= 100) the difference is negligible".
    smallest = arm_of[arm_of >= 100].sort_values()
    if not smallest.empty:
        rows = {arm: comparison.loc[arm] for arm in smallest.index}
        first_arm = smallest.index[0]
        negligible = [arm for arm, row in rows.items() if row["ci95_high"] / row["baseline_mean"] < NEGLIGIBLE]
        typical = smallest.index[(smallest - 1000).abs().argmin()]
        claim = ("With M ≥ 100 particles the particle set's deviation from the posterior is negligible; "
                 "M = 1000 is usual (section 4.2.1)")
        if first_arm in negligible:
            word = "reproduced"
        elif typical in negligible:
            word = "partly reproduced"
        else:
            word = "not reproduced"

        def increase(arm):
            row = rows[arm]
            return (f"N = {int(smallest[arm]):,}: RMSE {format_number(row['mean'])} against the grid's "
                    f"{format_number(grid_rmse)}, {_percent(row['relative_change'])} (95% CI "
                    f"{_percent(row['ci95_low'] / row['baseline_mean'])} to "
                    f"{_percent(row['ci95_high'] / row['baseline_mean'])})")
        gap = float(gaps.set_index("arm").loc[first_arm, "rms_gap"])
        evidence = (f"reading 'negligible' as an RMSE (against the truth) whose paired 95% upper bound is within "
                    f"{NEGLIGIBLE:.0%} of the exact posterior mean's: {increase(first_arm)}; {increase(typical)}; at "
                    f"N = {int(smallest[first_arm]):,} the RMS gap to the posterior mean is "
                    f"{format_number(gap / posterior_sd, 2)} posterior standard deviations.")
        verdicts.append(Verdict(claim, word, evidence))

    return Part(
        items=[Figure("histogram-reference", "reference_gap_vs_particles.png",
                      f"The particle filter against the histogram filter's posterior mean on the {model} model: "
                      f"left, each trial's RMS gap over its steps against N (log-log) with the pooled RMS, the "
                      f"geometric mean and a N^-1/2 line; right, one trial's estimates and gaps over time."),
               Table("Beyond the book: particle filter vs the histogram filter's posterior mean",
                     markdown_table(table),
                     f"Gap: the distance between the particle filter's estimate and the grid posterior mean at "
                     f"each step, RMS over the trial's steps, paired by trial (the arms share the truth and the "
                     f"measurements). Posterior sd: RMS over trials and steps of the grid posterior's standard "
                     f"deviation, {format_number(posterior_sd)}. RMSE increase: paired over trials with "
                     f"`pfx.analysis.compare` (t-interval), against the grid filter's RMSE {format_number(grid_rmse)}. "
                     f"The book runs no such experiment: no numbers to print beside ours.")],
        verdicts=verdicts)


# -- the report -------------------------------------------------------------------------------

PARTS = (kalman_part, importance_part, nonlinear_part, reference_part,
         motion_sections)                                     # Figs. 5.3-5.9 and Table 4.2


@REPORTS.register(PAPER)
def report(results: PaperResults) -> Section:
    numbers = results.numbers
    title = numbers.get("short_title", "Probabilistic Robotics (Thrun, Burgard & Fox 2005), chapters 3-5")
    summary = (f"{numbers.get('source', 'Study notes on Probabilistic Robotics')}. "
               f"{numbers.get('numeric_results', '')} Each verdict below compares our numbers with the "
               "mathematics the book states (closed forms, exact densities, a near-exact grid posterior); "
               "the thresholds are in `pfx/papers/prob_robotics.py`.")
    items, verdicts = assemble(results, PARTS)
    return Section(PAPER, title, summary, items, verdicts)
