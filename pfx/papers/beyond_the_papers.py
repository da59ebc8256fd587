r"""The "beyond the papers" report: filter algorithms the five documents do not compare.

Not a document's reproduction: the claims the literature commonly makes for guided proposals,
the auxiliary particle filter, KLD-sampling and augmented MCL, each tested on pfx's runs
(``configs/papers/beyond-the-papers/`` and the configs its ``paper.yaml`` lists under
``also_run``; docs/papers/beyond-the-papers.md says what is run and why).

* ``proposals-<model>``: independent datasets (trial t of every arm filters the same one), so
  each algorithm's position RMSE is paired against the bootstrap filter's trial by trial
  (:func:`pfx.analysis.compare.paired_comparison`, the 95% t-interval of the mean difference that
  ``pfx compare`` prints), and so is its mean ESS. Time per
  particle-step: each cell's filter run time (``run_time_s``) over N x steps.
* ``loglik-<model>``: the same arms on one dataset (``datasets: 1``), so the spread of the
  log-likelihood estimate is the filter's own Monte Carlo error; each arm's variance against
  the bootstrap's with the 95% F-interval of the ratio
  (:mod:`pfx.analysis.estimator_spread`).
* ``kld-sampling``: particles used per step, accuracy and convergence, fixed N against
  KLD-sampling with the same maximum; "the same accuracy" is read as the paired relative change
  of the position RMSE lying within +-:data:`SAME_ACCURACY`.
* ``kidnapped-robot``: a trial *recovers* when its final error is within the convergence radius;
  its *time to recover* is the number of actions from the kidnapping to the first step from which
  the error stays within that radius to the end (steps.csv holds every trial).
* ``smoothing-<model>`` and ``ancestral-tree``: smoothers against the filter, and the size of the
  ancestral tree (:mod:`pfx.papers.beyond_smoothing`).

Verdicts use the words of the papers' sections: *reproduced* when every check of the claim
passes, *partly reproduced* when some do, *not reproduced* when none does
(:func:`pfx.papers.base.verdict_from_checks`).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from pfx.analysis.compare import paired_comparison
from pfx.analysis.estimator_spread import variance_ratio_interval, within_dataset_spread
from pfx.analysis.paired_statistics import relative_change_interval
from pfx.analysis.value_ranges import metric_range
from pfx.papers.base import (
    REPORTS,
    Figure,
    PaperResults,
    Part,
    Section,
    Table,
    Text,
    Verdict,
    assemble,
    format_number,
    interval,
    markdown_table,
    percent,
    verdict_from_checks,
)
from pfx.papers.beyond_smoothing import SMOOTHING_PARTS

PAPER = "beyond-the-papers"
BASELINE = "bootstrap"
MODELS = (("linear-gaussian", "linear-Gaussian, informative sensor"), ("growth", "growth model"),
          ("falling-body", "falling body"), ("stochastic-volatility", "stochastic volatility"))
GUIDED = ("locally_optimal", "ekf", "ukf")
SAME_ACCURACY = 0.10          # KLD: "the same accuracy" = RMSE within +-10 % of the fixed-N filter's
FEW = 0.5                     # KLD: "far fewer" = at most half the particles


def _labels(results: PaperResults, experiment: str) -> list[str]:
    return results.folder(experiment).label_columns


def _nanoseconds(trials: pd.DataFrame) -> pd.Series:
    """Filter run time per particle-step, ns (NaN for a filter without particles)."""
    return trials["run_time_s"] / (trials["n_particles"] * trials["steps"]) * 1e9


def algorithm_table(results: PaperResults, model: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per (arm, N) of ``proposals-<model>`` and ``loglik-<model>``: the numbers of the table.

    Returns (table for the gallery, numbers for the verdicts: rmse and variance intervals).
    """
    accuracy = results.folder(f"proposals-{model}").trials
    labels = _labels(results, f"proposals-{model}")
    paired = paired_comparison(accuracy, "rmse_position", by="arm", baseline=BASELINE, label_columns=labels)
    ess = paired_comparison(accuracy[accuracy["n_particles"].notna()], "ess_mean", by="arm", baseline=BASELINE,
                            label_columns=labels, higher_is_better=True)
    spread = pd.DataFrame()
    if results.has(f"loglik-{model}"):
        spread = within_dataset_spread(results.folder(f"loglik-{model}").trials, _labels(results, f"loglik-{model}"))
    accuracy = accuracy.assign(_ns=_nanoseconds(accuracy))
    rows = []
    for (arm, particles), cell in accuracy.groupby(["arm", "n_particles"], sort=False, dropna=False):
        # The Kalman filter has no particles: no ESS, no time per particle-step, an exact likelihood.
        row = {"arm": arm, "n_particles": particles, "rmse": cell["rmse_position"].mean(),
               "ess_share": (cell["ess_mean"] / particles).mean() if np.isfinite(particles) else math.nan,
               "ns": cell["_ns"].mean() if np.isfinite(particles) else math.nan}
        base = accuracy[(accuracy["arm"] == BASELINE) & (accuracy["n_particles"] == particles)]
        row["time_ratio"] = row["ns"] / base["_ns"].mean() if len(base) else math.nan
        if arm != BASELINE:
            match = paired[(paired["arm"] == arm) & ((paired["n_particles"] == particles)
                                                     if np.isfinite(particles) else True)]
            if np.isfinite(particles) and len(match):
                pair = match.iloc[0]
                row.update(rmse_difference=pair["mean_difference"], rmse_low=pair["ci95_low"],
                           rmse_high=pair["ci95_high"])
                higher = ess[(ess["arm"] == arm) & (ess["n_particles"] == particles)]
                if len(higher):
                    row.update(ess_low=higher.iloc[0]["ci95_low"], ess_high=higher.iloc[0]["ci95_high"])
                row["rmse_change"] = pair["relative_change"]
        if not spread.empty:
            own = spread[(spread["arm"] == arm) & ((spread["n_particles"] == particles)
                                                   if np.isfinite(particles) else spread["n_particles"].isna())]
            reference = spread[(spread["arm"] == BASELINE) & (spread["n_particles"] == particles)]
            if len(own) and np.isfinite(particles):
                row["loglik_sd"] = own.iloc[0]["sd"]
            if len(own) and len(reference) and arm != BASELINE:
                row["variance_ratio"] = variance_ratio_interval(
                    own.iloc[0]["variance"], int(own.iloc[0]["degrees_of_freedom"]),
                    reference.iloc[0]["variance"], int(reference.iloc[0]["degrees_of_freedom"]))
        rows.append(row)
    numbers = pd.DataFrame(rows)
    return _gallery_table(numbers), numbers


def _gallery_table(numbers: pd.DataFrame) -> pd.DataFrame:
    def difference(row) -> str:
        if not np.isfinite(row.get("rmse_difference", math.nan)):
            return ""
        signed = lambda v: ("+" if v > 0 else "") + format_number(v)      # noqa: E731
        return (f"{signed(row['rmse_difference'])} {interval(row['rmse_low'], row['rmse_high'], number=signed)} "
                f"({percent(row['rmse_change'], decimals=0)})")

    def ratio(value) -> str:
        if not isinstance(value, tuple) or not math.isfinite(value[0]):
            return ""
        return f"{format_number(value[0], 2)} {interval(value[1], value[2], number=lambda v: format_number(v, 2))}"

    table = pd.DataFrame({
        "algorithm": numbers["arm"],
        "N": [format_number(n) if np.isfinite(n) else "" for n in numbers["n_particles"]],
        "RMSE": numbers["rmse"],
        "RMSE - bootstrap's [95% CI] (change)": [difference(row) for _, row in numbers.iterrows()],
        "ESS / N": numbers["ess_share"],
        "sd of log-lik (one dataset)": numbers.get("loglik_sd", np.nan),
        "log-lik variance / bootstrap's [95% CI]": [ratio(v) for v in numbers.get("variance_ratio",
                                                                                    [None] * len(numbers))],
        "ns per particle-step": numbers["ns"],
        "time vs bootstrap": numbers["time_ratio"],
    })
    return table


def _model_part(model: str, title: str):
    def part(results: PaperResults) -> Part:
        if not results.has(f"proposals-{model}"):
            return Part()
        table, _ = algorithm_table(results, model)
        items = [Table(f"{title}: each algorithm against the bootstrap filter",
                       markdown_table(table, formats={"ESS / N": lambda v: format_number(v, 2),
                                                      "time vs bootstrap": lambda v: format_number(v, 2)}),
                       _table_note(results, model))]
        for experiment, name, caption in (
                (f"proposals-{model}", "rmse_vs_particles.png", f"{title}: position RMSE against N"),
                (f"loglik-{model}", "log_likelihood_spread_vs_particles.png",
                 f"{title}: spread of the log-likelihood estimate on one dataset against N")):
            if name in results.figures(experiment):
                items.append(Figure(experiment, name, caption))
        return Part(items)
    return part


def _table_note(results: PaperResults, model: str) -> str:
    accuracy = results.folder(f"proposals-{model}").trials
    runs = int(accuracy.groupby("cell").size().min())
    note = (f"{runs} independent datasets per row (RMSE: mean over them; the difference from the bootstrap "
            "filter is paired by dataset, with its 95% t-interval, as `pfx compare` gives it). ESS / N: the mean effective sample "
            "size after the weight update (for the auxiliary filter, of its second-stage weights, which its "
            "first stage has already resampled by the look-ahead: not a measure of the same degeneracy). "
            "Log-likelihood: ")
    if results.has(f"loglik-{model}"):
        spread = results.folder(f"loglik-{model}").trials
        note += (f"{int(spread.groupby('cell').size().min())} runs of each filter on one dataset; the variance "
                 "ratio's interval is the F-interval (it assumes a normal log-likelihood estimate, which a "
                 "filter whose weights collapse now and then is not: its interval is then too narrow). ")
    else:
        note += "not run. "
    note += ("Time: the filter's own run time (not the truth's simulation or the metrics) per particle and "
             "step, on the machine that ran `make reproduce-papers`; the ratio divides by the bootstrap "
             "filter's at the same N.")
    if model == "linear-gaussian":
        exact = _exact_log_likelihood(results)
        if exact is not None:
            note += (f" The Kalman filter is exact here: its RMSE is the smallest any filter can expect, and the "
                     f"dataset's exact log-likelihood is {format_number(exact, 4)}.")
    return note


def _exact_log_likelihood(results: PaperResults):
    if not results.has("loglik-linear-gaussian"):
        return None
    trials = results.folder("loglik-linear-gaussian").trials
    kalman = trials[trials["arm"] == "kalman"]
    return float(kalman["log_likelihood"].iloc[0]) if len(kalman) else None


# -- the verdicts on the proposals and the auxiliary filter -------------------------------------------

def _numbers(results: PaperResults) -> dict[str, pd.DataFrame]:
    return {model: algorithm_table(results, model)[1] for model, _ in MODELS if results.has(f"proposals-{model}")}


def _better_rmse(row) -> bool:
    return bool(np.isfinite(row.get("rmse_high", math.nan)) and row["rmse_high"] < 0)


def _higher_ess(row) -> bool:
    return bool(np.isfinite(row.get("ess_low", math.nan)) and row["ess_low"] > 0)


def _lower_variance(row) -> bool:
    value = row.get("variance_ratio")
    return isinstance(value, tuple) and math.isfinite(value[2]) and value[2] < 1.0


def _where(rows: list[tuple[str, pd.Series]], check) -> str:
    passed = [f"{model} N = {int(row['n_particles'])}" for model, row in rows if check(row)]
    failed = [f"{model} N = {int(row['n_particles'])}" for model, row in rows if not check(row)]
    return (f"better in {len(passed)} of {len(rows)} (model, N) cases"
            + (f" ({', '.join(passed)})" if passed else "")
            + (f"; not in {', '.join(failed)}" if failed else ""))


def proposal_verdicts(results: PaperResults) -> Part:
    numbers = _numbers(results)
    if not numbers:
        return Part()
    claims = results.numbers.get("claims", {})
    verdicts = []
    particle_rows = {model: frame[np.isfinite(frame["n_particles"])] for model, frame in numbers.items()}

    optimal = [(model, row) for model, frame in particle_rows.items() for _, row in frame.iterrows()
               if row["arm"] == "locally_optimal"]
    if optimal:
        verdicts.append(Verdict(
            f"{claims['locally_optimal']['claim']} ({claims['locally_optimal']['source']})",
            verdict_from_checks(_higher_ess(row) and _better_rmse(row) for _, row in optimal),
            "a higher ESS (less variable weights; paired 95% interval above 0) and a lower RMSE (below 0): "
            + _where(optimal, lambda row: _higher_ess(row) and _better_rmse(row))
            + "; the locally optimal proposal applies to the linear-Gaussian measurement only."))

    kalman_rows = [(f"{model} {row['arm']}", row) for model, frame in particle_rows.items()
                   for _, row in frame.iterrows() if row["arm"] in ("ekf", "ukf")]
    if kalman_rows:
        verdicts.append(Verdict(
            f"{claims['kalman_proposals']['claim']} ({claims['kalman_proposals']['source']})",
            verdict_from_checks(_better_rmse(row) for _, row in kalman_rows),
            "lower RMSE than the bootstrap (paired 95% interval below 0): " + _where(kalman_rows, _better_rmse)
            + "; stochastic volatility has no EKF/UKF proposal (E[y | x] = 0 carries no information)."))

    auxiliary = [(model, row) for model, frame in particle_rows.items() for _, row in frame.iterrows()
                 if row["arm"] == "auxiliary"]
    if auxiliary:
        verdicts.append(Verdict(
            f"{claims['auxiliary']['claim']} ({claims['auxiliary']['source']})",
            verdict_from_checks(_lower_variance(row) for _, row in auxiliary),
            "log-likelihood variance below the bootstrap filter's (F-interval below 1): "
            + _where(auxiliary, _lower_variance)
            + "; RMSE: " + _where(auxiliary, _better_rmse).replace("better", "lower") + "."))
    return Part((), verdicts)


def proposals_intro(results: PaperResults) -> Part:
    if not any(results.has(f"proposals-{model}") for model, _ in MODELS):
        return Part()
    return Part([Text(
        "### Guided proposals and the auxiliary particle filter\n\n"
        "Every arm filters the same datasets with systematic resampling when the ESS falls below N/2. "
        "`locally_optimal`, `ekf` and `ukf` draw each particle from a Gaussian built by one Kalman update "
        "around its prediction (exact for a linear-Gaussian measurement); `auxiliary` is Pitt and "
        "Shephard's filter, whose first stage resamples by the likelihood at each particle's point "
        "prediction. A model row is missing an algorithm where pfx refuses it: the locally optimal "
        "proposal needs a measurement linear in the state, and stochastic volatility's return has mean 0 "
        "whatever the volatility, so an EKF or UKF update cannot use it.")])


# -- KLD-sampling -----------------------------------------------------------------------------------

def kld_part(results: PaperResults) -> Part:
    if not results.has("kld-sampling"):
        return Part()
    trials = results.folder("kld-sampling").trials
    arms = list(dict.fromkeys(trials["arm"]))
    fixed, adaptive = arms[0], arms[-1]
    rows = []
    for arm in arms:
        cell = trials[trials["arm"] == arm]
        converged = cell["convergence_step"].dropna()
        rows.append({"filter": arm, "particles per step (mean)": cell["particles_mean"].mean(),
                     "position RMSE [cm]": cell["rmse_position"].mean(),
                     "final error [cm]": cell["error_distance_final"].mean(),
                     "converged": f"{int(cell['converged'].sum())}/{len(cell)}",
                     "convergence time [actions]": converged.mean() if len(converged) else math.nan,
                     "filter time per trial [s]": cell["run_time_s"].mean()})
    both = trials.pivot_table(index="trial", columns="arm", values="rmse_position")
    change, low, high = relative_change_interval(both[fixed], both[adaptive], value_range=metric_range("rmse_position"))
    fraction = trials.loc[trials["arm"] == adaptive, "particles_mean"].mean() / \
        trials.loc[trials["arm"] == fixed, "particles_mean"].mean()
    claims = results.numbers.get("claims", {})
    checks = [fraction <= FEW, -SAME_ACCURACY <= low and high <= SAME_ACCURACY]
    verdict = Verdict(
        f"{claims['kld']['claim']} ({claims['kld']['source']})", verdict_from_checks(checks),
        f"KLD-sampling used {percent(fraction, decimals=0, suffix=' %').lstrip('+')} of the fixed filter's "
        f"particles per step on average (\"far fewer\": at most {FEW:.0%}); its position RMSE changed by "
        f"{percent(change, decimals=1)} {interval(low, high, number=lambda v: percent(v, decimals=1))} "
        f"(paired by trial; \"the same\": within ±{SAME_ACCURACY:.0%}).")
    items = [Text("### KLD-sampling: particles where the posterior needs them\n\n"
                  "Global localisation in the kim-mcl arena from a uniform prior, fixed-N MCL against "
                  "KLD-sampling (Fox 2003) with the same maximum (config `configs/examples/kld-sampling.yaml`)."),
             Table("KLD-sampling against a fixed particle count", markdown_table(pd.DataFrame(rows)),
                   f"{len(both)} trials per arm, paired by trial (the same route and measurements). "
                   "Filter time per trial: the filter's own run time; KLD-sampling's arrays are sized to the "
                   "maximum (so trials stay batched), and its bin counting is extra work, so fewer particles "
                   "do not make it faster here.")]
    for name, caption in (("particles_over_time.png", "KLD-sampling: particles per step over time"),
                          ("error_over_time.png", "KLD-sampling: error over time")):
        if name in results.figures("kld-sampling"):
            items.append(Figure("kld-sampling", name, caption))
    return Part(items, [verdict])


# -- the kidnapped robot ----------------------------------------------------------------------------

def recovery(steps: pd.DataFrame, kidnap_step: int, radius: float) -> pd.DataFrame:
    """Per (arm, trial): recovered (final error within ``radius``) and the actions to recover.

    Time to recover: from the kidnapping to the first step from which the error stays within
    ``radius`` to the end; NaN for a trial that does not recover.
    """
    rows = []
    for (arm, trial), trace in steps.groupby(["arm", "trial"], sort=False):
        trace = trace.sort_values("step")
        after = trace[trace["step"] >= kidnap_step]
        outside = after.loc[after["error_distance"] > radius, "step"]
        recovered = bool(after["error_distance"].iloc[-1] <= radius)
        last_outside = int(outside.max()) if len(outside) else kidnap_step - 1
        rows.append({"arm": arm, "trial": trial, "recovered": recovered,
                     "time_to_recover": last_outside + 1 - kidnap_step if recovered else math.nan})
    return pd.DataFrame(rows)


def wilson_interval(successes: int, trials: int) -> tuple[float, float]:
    """The 95% Wilson score interval of a proportion (scipy's)."""
    if trials == 0:
        return math.nan, math.nan
    found = stats.binomtest(successes, trials).proportion_ci(confidence_level=0.95, method="wilson")
    return float(found.low), float(found.high)


def kidnapped_part(results: PaperResults) -> Part:
    if not results.has("kidnapped-robot"):
        return Part()
    config = results.config("kidnapped-robot")
    kidnap_step = int(config["model"]["kidnap"]["step"])
    radius = float(config["metrics"]["convergence"]["radius"])
    folder = results.folder("kidnapped-robot")
    trials, outcome = folder.trials, recovery(folder.steps, kidnap_step, radius)
    arms = list(dict.fromkeys(trials["arm"]))
    rows = []
    for arm in arms:
        own = outcome[outcome["arm"] == arm]
        recovered = int(own["recovered"].sum())
        low, high = wilson_interval(recovered, len(own))
        times = own["time_to_recover"].dropna()
        rows.append({"filter": arm, "recovered": f"{recovered}/{len(own)}",
                     "recovery rate [95% CI]": f"{recovered / len(own):.0%} "
                                               f"{interval(low, high, number=lambda v: f'{v:.0%}')}",
                     "time to recover [actions], median (quartiles)":
                         (f"{format_number(times.median())} ({format_number(times.quantile(0.25))}–"
                          f"{format_number(times.quantile(0.75))})") if len(times) else "",
                     "final error [cm], median": trials.loc[trials["arm"] == arm, "error_distance_final"].median(),
                     "injected per step": trials.loc[trials["arm"] == arm, "injected_mean"].mean()})
    plain, augmented = arms[0], arms[-1]
    paired = paired_comparison(outcome.assign(recovered=outcome["recovered"].astype(float)), "recovered", by="arm",
                               baseline=plain, higher_is_better=True).set_index("arm").loc[augmented]
    claims = results.numbers.get("claims", {})
    checks = [paired["ci95_low"] > 0, paired["baseline_mean"] < 0.5]
    verdict = Verdict(
        f"{claims['augmented']['claim']} ({claims['augmented']['source']})", verdict_from_checks(checks),
        f"recovered (final error within {radius:g} cm): {augmented} {paired['mean']:.0%}, "
        f"{plain} {paired['baseline_mean']:.0%} of {int(paired['n_pairs'])} trials; paired difference "
        f"{percent(paired['mean_difference'], decimals=0)} "
        f"{interval(paired['ci95_low'], paired['ci95_high'], number=lambda v: percent(v, decimals=0))} "
        "(it must lie above 0, and plain MCL recover in fewer than half the trials).")
    items = [Text("### The kidnapped robot: augmented MCL\n\n"
                  f"The kim-mcl arena; after the filter has localised, at step {kidnap_step}, the true robot is "
                  "carried elsewhere and the filter is not told (config `configs/examples/kidnapped-robot.yaml`). "
                  "Plain MCL against augmented MCL (Probabilistic Robotics, Table 8.3), which adds particles "
                  "from the prior when the short-term average likelihood falls below the long-term one."),
             Table("Recovery from the kidnapping", markdown_table(pd.DataFrame(rows)),
                   f"A trial recovers when its final error is within {radius:g} cm (the convergence radius); "
                   "time to recover: actions from the kidnapping to the first step from which the error stays "
                   "within that radius (recovered trials only). Interval of the rate: Wilson's.")]
    for name, caption in (("error_over_time.png", "The kidnapped robot: error over time, every trial"),
                          ("particle_animation.gif", "The kidnapped robot, trial 0 of each filter: the particle "
                                                     "cloud step by step (the kidnapping is at step "
                                                     f"{kidnap_step})")):
        if name in results.figures("kidnapped-robot"):
            items.append(Figure("kidnapped-robot", name, caption))
    return Part(items, [verdict])


PARTS = (proposals_intro, *(_model_part(model, title) for model, title in MODELS), proposal_verdicts,
         kld_part, kidnapped_part, *SMOOTHING_PARTS)

SUMMARY = """
Filter algorithms the five documents do not compare, run by `make reproduce-papers` like the
reproductions: guided proposals (locally optimal, EKF, UKF) and the auxiliary particle filter
on four models, KLD-sampling and augmented MCL in the kim-mcl arena, smoothers after the
filter on two nonlinear models, and the size of the particles' ancestral tree. Each claim is
the literature's as commonly stated; each verdict is computed from our runs. What is run and
why: docs/papers/beyond-the-papers.md.
"""


@REPORTS.register(PAPER)
def report(results: PaperResults) -> Section:
    items, verdicts = assemble(results, PARTS)
    title = results.numbers.get("title", "Beyond the papers")
    return Section(PAPER, title, SUMMARY, list(items), list(verdicts))
