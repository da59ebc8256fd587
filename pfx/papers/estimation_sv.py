r"""estimation-sv: the stochastic-volatility parameters on the GBP/USD returns, the benchmarks'
gallery section for parameter estimation (docs/benchmarks/estimation-sv.md).

The model is :math:`x_k = \mu + \phi (x_{k-1} - \mu) + \sigma w_k`, :math:`y_k = e^{x_k/2} v_k`
on the 201 daily returns of sv-gbp-usd, with Chopin & Papaspiliopoulos' priors
:math:`\mu \sim N(0, 2^2)`, :math:`\phi \sim \mathrm{Beta}(9, 1)`,
:math:`\sigma \sim \mathrm{Gamma}(2, \text{rate } 2)`. Its result folders (the configs in
``configs/benchmarks/estimation-sv/``):

* ``posterior``: PMMH (bootstrap filter, N chosen by the rule below) with 16 chains. Its
  posterior means are compared with those of the particles library's PMMH on the same data
  and priors (``particles_reference`` in paper.yaml): the two agree when every parameter's
  means differ by at most :data:`Z_LIMIT` combined Monte Carlo errors,
  :math:`|m_1 - m_2| \le Z \sqrt{\mathrm{mcse}_1^2 + \mathrm{mcse}_2^2}` (ArviZ's MCSE on both
  sides). No posterior on these returns is published; the numbers published for other data
  are listed as not comparable, with the reason.
* ``exact-posterior``: the same posterior sampled by Metropolis-Hastings on the exact
  likelihood (the histogram filter's), the reference PMMH must reach whatever N: its means
  against PMMH's, by the same rule.
* ``spread``: 1000 runs of the bootstrap filter at the posterior mean at each N of n-choice:
  :math:`\sigma(N)`, the sd of :math:`\log \hat L`, with standard error
  :math:`\sigma / \sqrt{2(R - 1)}`, and :math:`\delta = N \sigma^2`.
* ``n-choice``: PMMH with one fixed random walk at seven N. Each N's integrated
  autocorrelation time :math:`\tau` (mean over the three parameters; ArviZ's estimate and batch
  means, :mod:`pfx.analysis.autocorrelation`) gives the work per effective draw
  :math:`\tau \times N`. The N-choice rule (Doucet, Pitt, Deligiannidis & Kohn 2015; Pitt,
  Silva, Giordani & Kohn 2012) puts its minimum at :math:`\sigma \approx 1.2`, between the two
  limits of the theory: :math:`\sigma = 0.92` where the exact-likelihood chain draws
  independently (inefficiency :math:`\mathrm{IF}_Q = 1`) and 1.68 where it mixes very slowly.
  In those limits the work is proportional to

  .. math::

      \frac{\mathrm{IF}_1(\sigma)}{\sigma^2}, \quad
      \mathrm{IF}_1(\sigma) = E\Big[\frac{2 - \alpha_\sigma(Z)}{\alpha_\sigma(Z)}\Big],\ Z \sim N(\sigma^2/2, \sigma^2),
      \qquad\text{and}\qquad
      \frac{1}{\sigma^2\, 2\Phi(-\sigma/\sqrt2)},

  with :math:`\alpha_\sigma(z) = \Phi(\frac{-z - \sigma^2/2}{\sigma}) + e^{-z}\Phi(\frac{z - \sigma^2/2}{\sigma})`
  the chance that a fresh estimate's noise lets a move through from a current error z. The
  report scales each to the measured points (one factor, by least squares on the log scale).
  Verdict: reproduced when the N with the smallest :math:`\tau \times N` has
  :math:`\sigma` in [0.92, 1.68] by both estimators, partly when by one.

  The repository leaves n-choice's draws out (chains.csv, 83 MB; ``.gitignore``) and keeps
  what the report computes from them, :data:`WORK_TABLE` (:func:`work_per_draw_table`, written
  by ``pfx reproduce`` through :data:`~pfx.papers.base.KEPT_TABLES`): the report reads it where
  chains.csv is absent, to the same verdict, and says the results are missing where both are.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from pfx.analysis.autocorrelation import mean_over_parameters
from pfx.figures.pmmh_efficiency import particle_count_table
from pfx.papers.base import (
    KEPT_TABLES,
    REPORTS,
    Figure,
    PaperResults,
    Part,
    Section,
    Table,
    Text,
    Verdict,
    assemble,
    flag_text,
    format_number,
    markdown_table,
    verdict_from_checks,
)
from pfx.result_folder import ResultFolder, read_table, write_csv

BENCHMARK = "estimation-sv"
POSTERIOR, EXACT, SPREAD, N_CHOICE = "posterior", "exact-posterior", "spread", "n-choice"
Z_LIMIT = 3.0                      # combined Monte Carlo errors within which two posterior means agree
REFERENCE_NAMES = {"phi": "rho"}   # pfx's parameter -> particles' name for it
WORK_TABLE = "work_per_effective_draw.csv"     # n-choice's numbers for the report, kept where chains.csv is not
REPRODUCE = "pfx reproduce estimation-sv --configs configs/benchmarks --out results/benchmarks --plugin-store results/plugins"
HERMITE_NODES, HERMITE_WEIGHTS = np.polynomial.hermite_e.hermegauss(200)     # E f(X), X ~ N(0, 1)


# -- the theory of the N-choice rule -------------------------------------------------------------

def noise_acceptance(z: np.ndarray, sigma: float) -> np.ndarray:
    r""":math:`\alpha_\sigma(z) = E \min(1, e^{W - z})`, :math:`W \sim N(-\sigma^2/2, \sigma^2)`:
    :math:`\Phi(\frac{-z - \sigma^2/2}{\sigma}) + e^{-z} \Phi(\frac{z - \sigma^2/2}{\sigma})`."""
    from scipy.stats import norm

    half = 0.5 * sigma**2
    return norm.cdf((-z - half) / sigma) + np.exp(-z) * norm.cdf((z - half) / sigma)


def inefficiency_perfect(sigma: float) -> float:
    r""":math:`\mathrm{IF}_1(\sigma) = E[(2 - \alpha_\sigma(Z)) / \alpha_\sigma(Z)]`,
    :math:`Z \sim N(\sigma^2/2, \sigma^2)` (Gauss-Hermite): the pseudo-marginal chain's
    inefficiency when the exact chain draws independently (Pitt et al. 2012)."""
    z = 0.5 * sigma**2 + sigma * HERMITE_NODES
    acceptance = noise_acceptance(z, sigma)
    return float(np.sum(HERMITE_WEIGHTS * (2.0 - acceptance) / acceptance) / math.sqrt(2.0 * math.pi))


def relative_inefficiency_slow(sigma: float) -> float:
    r""":math:`\mathrm{IF}/\mathrm{IF}_Q \to 1 / (2\Phi(-\sigma/\sqrt2))` as the exact chain's
    inefficiency grows (Doucet et al. 2015): the noise only slows the exact chain's path down by
    its mean acceptance."""
    from scipy.stats import norm

    return 1.0 / (2.0 * norm.cdf(-sigma / math.sqrt(2.0)))


THEORY = {"perfect": inefficiency_perfect, "inefficient": relative_inefficiency_slow}


def work(limit: str, sigma: float) -> float:
    r"""The work per effective draw in a limit, up to a constant: :math:`\mathrm{IF}(\sigma) / \sigma^2`
    (N is proportional to :math:`1/\sigma^2`)."""
    return THEORY[limit](sigma) / sigma**2


def scale_to(values: np.ndarray, sigmas: np.ndarray, limit: str) -> float:
    """The factor k making k * work(limit, sigma) closest to ``values`` in the log (least squares)."""
    model = np.array([work(limit, s) for s in sigmas])
    keep = np.isfinite(values) & (values > 0)
    return float(np.exp(np.mean(np.log(values[keep]) - np.log(model[keep])))) if keep.any() else math.nan


def misfit(values: np.ndarray, sigmas: np.ndarray, limit: str) -> float:
    """The rms difference of log values and the log of the scaled limit's work (scale_to)."""
    model = np.log([scale_to(values, sigmas, limit) * work(limit, s) for s in sigmas])
    keep = np.isfinite(values) & (values > 0)
    return float(np.sqrt(np.mean((np.log(values[keep]) - model[keep]) ** 2)))


# -- the tables the parts share ------------------------------------------------------------------

def spread_table(results: PaperResults) -> pd.DataFrame:
    """Per N of the spread runs: runs, mean and sd of log L_hat, the sd's standard error, delta = N sd^2."""
    trials = results.folder(SPREAD).trials
    rows = []
    for n, group in trials.groupby("n_particles"):
        values = group["log_likelihood"].to_numpy(dtype=float)
        values = values[np.isfinite(values)]
        sd = float(values.std(ddof=1))
        rows.append({"n_particles": int(n), "runs": len(values), "mean": float(values.mean()), "sd": sd,
                     "sd_se": sd / math.sqrt(2 * (len(values) - 1)), "delta": int(n) * sd**2})
    return pd.DataFrame(rows)


def work_per_draw_table(folder: ResultFolder) -> pd.DataFrame | None:
    r"""n-choice's work per effective draw, from its chains.csv: one row per N and estimator of
    the autocorrelation time (:func:`~pfx.figures.pmmh_efficiency.particle_count_table`, whose
    cells differ in N only) averaged over the parameters, ``tau`` and ``cost`` =
    :math:`\tau \times N`, ``cost_se`` from resampling whole chains, and, of those ``resamples``,
    in how many this N has the smallest cost (``cheapest_in_resamples``). None without chains."""
    tables = particle_count_table(folder)
    if tables is None:
        return None
    table, resampled = tables
    mean = mean_over_parameters(table, resampled, ["n_particles"])
    replicate_costs = (resampled.assign(cost=resampled["tau"] * resampled["n_particles"])
                       .groupby(["estimator", "replicate", "n_particles"])["cost"].mean())
    cheapest = replicate_costs.groupby(["estimator", "replicate"]).idxmin().map(lambda key: key[2])
    counts = cheapest.groupby(level="estimator").value_counts()
    resamples = resampled.groupby("estimator")["replicate"].nunique()
    return mean.assign(
        resamples=mean["estimator"].map(resamples),
        cheapest_in_resamples=[int(counts.get((estimator, n), 0))
                               for estimator, n in zip(mean["estimator"], mean["n_particles"])],
    )[["n_particles", "estimator", "tau", "cost", "cost_se", "resamples", "cheapest_in_resamples"]]


def n_choice_work(results: PaperResults) -> pd.DataFrame | None:
    """n-choice's work per effective draw (:func:`work_per_draw_table`): computed from chains.csv
    where the folder has it, else read from :data:`WORK_TABLE`; None without either."""
    folder = results.folder(N_CHOICE)
    table = work_per_draw_table(folder)
    if table is None and (folder.path / WORK_TABLE).exists():
        table = read_table(folder.path / WORK_TABLE)
    return table


@KEPT_TABLES.register(BENCHMARK)
def keep_tables(experiment: str, folder: Path) -> None:
    """n-choice's :data:`WORK_TABLE`, from its chains.csv (nothing for the other experiments,
    whose files are all kept, nor for a folder without chains)."""
    if experiment == N_CHOICE:
        table = work_per_draw_table(ResultFolder(folder))
        if table is not None:
            write_csv(table, Path(folder) / WORK_TABLE)


# -- the parts -----------------------------------------------------------------------------------

def mean_difference(ours, theirs) -> float:
    r"""Two posterior means' difference in combined Monte Carlo errors,
    :math:`(m_1 - m_2) / \sqrt{\mathrm{mcse}_1^2 + \mathrm{mcse}_2^2}` (each with ``mean`` and
    ``mcse_mean``); they agree when its size is at most :data:`Z_LIMIT`."""
    combined = math.hypot(float(ours["mcse_mean"]), float(theirs["mcse_mean"]))
    return (float(ours["mean"]) - float(theirs["mean"])) / combined


def posterior_part(results: PaperResults) -> Part:
    if not results.has(POSTERIOR):
        return Part()
    numbers = results.numbers
    claims = numbers.get("claims", {})
    posterior = results.folder(POSTERIOR).table("posterior").set_index("parameter")
    reference = numbers.get("particles_reference", {})
    theirs = reference.get("parameters", {})
    rows, checks, evidence = [], [], []
    for name in [p for p in posterior.index if p != "log_likelihood"]:
        ours = posterior.loc[name]
        row = {"parameter": name, "pfx mean ± mcse": f"{ours['mean']:.4f} ± {ours['mcse_mean']:.4f}",
               "pfx sd": format_number(ours["sd"], 3),
               "pfx 2.5%, 50%, 97.5%": ", ".join(format_number(ours[q], 3) for q in
                                                 ("quantile_2_5", "median", "quantile_97_5")),
               "pfx R-hat": f"{ours['r_hat']:.3f}", "pfx bulk ESS": format_number(ours["ess_bulk"], 3),
               "pfx flag": flag_text(ours)}
        other = theirs.get(REFERENCE_NAMES.get(name, name))
        if other:
            z = mean_difference(ours, other)
            checks.append(abs(z) <= Z_LIMIT)
            evidence.append(f"{name} {z:+.2f}")
            row.update({"particles mean ± mcse": f"{other['mean']:.4f} ± {other['mcse_mean']:.4f}",
                        "particles sd": format_number(other["sd"], 3),
                        "difference / combined mcse": f"{z:+.2f}"})
        rows.append(row)
    acceptance = float(posterior["acceptance_rate"].iloc[0])
    config = results.config(POSTERIOR)
    estimation = config.get("estimation", {})
    n = config.get("filter", {}).get("particles")
    items = [Table(
        "The posterior of (mu, phi, sigma): pfx's PMMH against particles' PMMH, same data and priors",
        markdown_table(pd.DataFrame(rows)),
        f"pfx: bootstrap filter with N = {n}, {estimation.get('chains')} chains × {estimation.get('iterations')} "
        f"iterations, warm-up {estimation.get('warm_up')} (adapting), acceptance rate {acceptance:.2f} after it. "
        f"particles: {reference.get('settings', '')}; acceptance rates "
        f"{', '.join(f'{a:.2f}' for a in reference.get('acceptance_rate', []))}. mcse is ArviZ's Monte Carlo "
        "standard error of the mean on both sides (particles' from its chains, "
        "examples/benchmarks/chain_summary.py).")]
    for name in ("posterior_marginals", "posterior_pairs", "chain_traces"):
        if f"{name}.png" in results.figures(POSTERIOR):
            caption = {"posterior_marginals": "pfx's posterior marginals with the priors (dashed)",
                       "posterior_pairs": "pfx's posterior draws, parameter against parameter: phi and sigma trade "
                                          "off (a persistent log-variance with small innovations, or a less "
                                          "persistent one with larger ones)",
                       "chain_traces": "pfx's 16 chains, the warm-up shaded"}[name]
            items.append(Figure(POSTERIOR, f"{name}.png", caption))
    verdicts = []
    if checks:
        verdicts.append(Verdict(
            claims.get("posterior", "pfx's PMMH posterior agrees with particles'"), verdict_from_checks(checks),
            f"difference of the means in combined Monte Carlo errors (|z| ≤ {Z_LIMIT:g} to agree): "
            f"{', '.join(evidence)}."))
    verdicts.append(Verdict(claims.get("published_posterior", "a published posterior on these returns"),
                            "not comparable", " ".join(str(numbers.get("published_posterior", "")).split())))
    return Part(items, verdicts)


def other_data_part(results: PaperResults) -> Part:
    published = results.numbers.get("other_data") or []
    if not published or not results.has(POSTERIOR):
        return Part()
    posterior = results.folder(POSTERIOR).table("posterior").set_index("parameter")
    rows = []
    for entry in published:
        values = entry.get("numbers", {})
        rows.append({"source": entry.get("name", entry["source"]), "data": entry.get("data", ""),
                     "what": entry.get("what", ""), "phi": format_number(values.get("phi"), 4),
                     "sigma": format_number(values.get("sigma"), 4),
                     "beta = exp(mu / 2)": format_number(values.get("beta"), 4), "why not comparable": entry["reason"]})
    chains = results.folder(POSTERIOR).table("chains")
    draws = chains[~chains["warm_up"].astype(str).str.lower().isin(["true", "1"])]
    rows.append({"source": "pfx, this benchmark", "data": "the 201 returns of 1997", "what": "posterior means",
                 "phi": format_number(posterior.loc["phi", "mean"], 4),
                 "sigma": format_number(posterior.loc["sigma", "mean"], 4),
                 "beta = exp(mu / 2)": format_number(np.exp(draws["mu"].to_numpy(dtype=float) / 2).mean(), 4),
                 "why not comparable": ""})
    items = [Table("Published stochastic-volatility numbers on Sterling/US-dollar returns: other data",
                   markdown_table(pd.DataFrame(rows)),
                   "Listed so that a reader need not look for them; none is a posterior of these 201 returns under "
                   "these priors, and nothing here is tuned toward them.")]
    verdict = Verdict(results.numbers.get("claims", {}).get("other_data", "published numbers on other data"),
                      "not comparable",
                      "; ".join(f"{entry.get('name', entry['source'])}: {entry['reason']}" for entry in published)
                      + ".")
    return Part(items, [verdict])


def exact_posterior_part(results: PaperResults) -> Part:
    """PMMH (the particle filter's estimate) against Metropolis-Hastings on the exact likelihood
    (the histogram filter's), both on the same data and priors: the claim PMMH rests on."""
    if not (results.has(POSTERIOR) and results.has(EXACT)):
        return Part()
    pmmh = results.folder(POSTERIOR).table("posterior").set_index("parameter")
    exact = results.folder(EXACT).table("posterior").set_index("parameter")
    rows, checks, evidence = [], [], []
    for name in [p for p in exact.index if p != "log_likelihood" and p in pmmh.index]:
        reference, ours = exact.loc[name], pmmh.loc[name]
        z = mean_difference(ours, reference)
        checks.append(abs(z) <= Z_LIMIT)
        evidence.append(f"{name} {z:+.2f}")
        rows.append({"parameter": name, "exact mean ± mcse": f"{reference['mean']:.4f} ± {reference['mcse_mean']:.4f}",
                     "exact sd": format_number(reference["sd"], 3), "exact R-hat": f"{reference['r_hat']:.3f}",
                     "exact bulk ESS": format_number(reference["ess_bulk"], 3), "exact flag": flag_text(reference),
                     "PMMH mean ± mcse": f"{ours['mean']:.4f} ± {ours['mcse_mean']:.4f}",
                     "PMMH sd": format_number(ours["sd"], 3), "difference / combined mcse": f"{z:+.2f}"})
    config = results.config(EXACT)
    estimation, grid = config.get("estimation", {}), config.get("filter", {}).get("grid", {})
    acceptance = float(exact["acceptance_rate"].iloc[0])
    cells, low, high = (grid.get("cells") or [None])[0], (grid.get("low") or [None])[0], (grid.get("high") or [None])[0]
    note = ""
    if None not in (cells, low, high):
        width = (high - low) / cells
        prior = estimation.get("parameters", {}).get("model.sigma", {}).get("prior", {})
        below = (f" (the prior gives sigma < {width:.3g} a probability of "
                 f"{stats.gamma(prior['shape'], scale=1.0 / prior['rate']).cdf(width):.1%})"
                 if prior.get("law") == "gamma" else "")
        note = (f"exact: Metropolis-Hastings with the histogram filter's log-likelihood ({cells} cells over "
                f"[{low:g}, {high:g}]), {estimation.get('chains')} chains × {estimation.get('iterations')} "
                f"iterations, warm-up {estimation.get('warm_up')} (adapting), acceptance rate {acceptance:.2f} after "
                f"it. A value whose innovation sd sigma is below the cell width ({width:.3g}) is refused by the grid "
                f"and counts as likelihood zero{below}. PMMH: the table above.")
    items = [Table("PMMH against Metropolis-Hastings on the exact likelihood, same data and priors",
                   markdown_table(pd.DataFrame(rows)), note)]
    verdict = Verdict(results.numbers.get("claims", {}).get("exact_posterior", "PMMH samples the exact posterior"),
                      verdict_from_checks(checks),
                      f"difference of the means in combined Monte Carlo errors (|z| ≤ {Z_LIMIT:g} to agree): "
                      f"{', '.join(evidence)}.")
    return Part(items, [verdict])


def n_choice_part(results: PaperResults) -> Part:
    if not (results.has(N_CHOICE) and results.has(SPREAD)):
        return Part()
    numbers = results.numbers
    rule = numbers.get("n_choice", {})
    low, high = rule.get("range", [0.92, 1.68])
    claim = numbers.get("claims", {}).get("n_choice", "the N-choice rule")
    work_table = n_choice_work(results)
    if work_table is None:
        return Part((), [Verdict(claim, "not reproduced",
                                 f"missing: n-choice has neither its chains (chains.csv) nor {WORK_TABLE}, the "
                                 f"numbers kept of them; run `{REPRODUCE}`.")])
    spread = spread_table(results).set_index("n_particles")
    # the work per effective draw of each N (the mean over the parameters), per estimator
    mean = work_table[work_table["n_particles"].isin(spread.index)].set_index(["estimator", "n_particles"])
    costs, cost_se, tau_mean = mean["cost"], mean["cost_se"], mean["tau"]
    sigma = spread["sd"]
    acceptance = results.folder(N_CHOICE).table("posterior").groupby("n_particles")["acceptance_rate"].first()
    estimators = list(dict.fromkeys(work_table["estimator"]))
    ns = sorted(spread.index)
    sigmas = np.array([sigma[n] for n in ns])
    rows = []
    for n in ns:
        row = {"N": n, "sd of log L̂ ± se": f"{sigma[n]:.2f} ± {spread.loc[n, 'sd_se']:.2f}",
               "N × variance": format_number(spread.loc[n, "delta"], 3),
               "acceptance": f"{acceptance.get(n, math.nan):.3f}"}
        for estimator in estimators:
            row[f"τ ({estimator})"] = format_number(tau_mean[(estimator, n)], 3)
            row[f"τ × N ({estimator}) ± se"] = (f"{format_number(costs[(estimator, n)], 3)} ± "
                                                f"{format_number(cost_se[(estimator, n)], 2)}")
        rows.append(row)
    checks, evidence, scales = [], [], {}
    for estimator in estimators:
        values = np.array([costs[(estimator, n)] for n in ns])
        best = int(costs[estimator].idxmin())
        inside = low <= sigma[best] <= high
        checks.append(inside)
        close = [n for n in ns if n != best and costs[(estimator, n)] - costs[(estimator, best)]
                 <= 2 * math.hypot(cost_se[(estimator, n)], cost_se[(estimator, best)])]
        # the resamples in which the cheapest N has its sd in the range
        resamples = int(mean.loc[estimator, "resamples"].iloc[0])
        share = sum(int(count) for n, count in mean.loc[estimator, "cheapest_in_resamples"].items()
                    if low <= sigma[n] <= high) / resamples
        evidence.append(
            f"{estimator}: smallest at N = {best} (sd {sigma[best]:.2f}), "
            + (f"within 2 se of it N = {', '.join(str(n) for n in close)} (sd "
               f"{', '.join(f'{sigma[n]:.2f}' for n in close)})" if close else "no other N within 2 se")
            + f"; in {share:.0%} of {resamples} resamples of the chains the smallest lies in the range")
        scales[estimator] = {limit: scale_to(values, sigmas, limit) for limit in THEORY}
    # the theory's two limits, each scaled to the first estimator's points
    for limit in THEORY:
        k = scales[estimators[0]][limit]
        for row, s in zip(rows, sigmas):
            row[f"theory, {limit} limit (scaled)"] = format_number(k * work(limit, s), 3)
    delta = float(spread["delta"].mean())
    implied = {estimator: scales[estimator]["inefficient"] / delta for estimator in estimators}
    items = [Table(
        "The N-choice curve: work per effective draw, τ × N, against the sd of log L̂",
        markdown_table(pd.DataFrame(rows)),
        "sd of log L̂: spread's 1000 runs at the posterior mean (se = sd / √(2 (R − 1))). τ: the integrated "
        "autocorrelation time averaged over mu, phi and sigma, from n-choice's chains after their warm-up; "
        "± se from resampling whole chains. The theory columns are the two limits' work, IF(σ)/σ², each scaled by one "
        f"factor to the {estimators[0]} points (least squares in the log); the theory's minima are {low:g} (perfect exact "
        f"chain) and {high:g} (inefficient exact chain). The inefficient limit's factor, divided by N × variance "
        f"(mean {delta:.1f}), is the exact chain's own inefficiency IF_Q it implies: "
        + ", ".join(f"{implied[e]:.0f} ({e})" for e in estimators) + ".")]
    if "inefficiency_vs_particles.png" in results.figures(N_CHOICE):
        top = ", ".join(f"N = {n}: sd {sigma[n]:.2f}" for n in ns)
        items.append(Figure(N_CHOICE, "inefficiency_vs_particles.png",
                            f"τ × N against N: the mean over the parameters with ±2 se, each parameter thin "
                            f"(the sd of log L̂ at each N: {top})"))
    posterior_n = results.config(POSTERIOR).get("filter", {}).get("particles") if results.has(POSTERIOR) else None
    if posterior_n in sigma.index:
        items.append(Text(f"posterior.yaml's N = {posterior_n} gives an sd of log L̂ of {sigma[posterior_n]:.2f} ± "
                          f"{spread.loc[posterior_n, 'sd_se']:.2f} at the posterior mean (the rule asks for about "
                          f"{rule.get('recommended', 1.2)})."))
    fits = {limit: misfit(np.array([costs[(estimators[0], n)] for n in ns]), sigmas, limit) for limit in THEORY}
    verdict = Verdict(claim, verdict_from_checks(checks),
                      f"the smallest τ × N should have its sd of log L̂ in [{low:g}, {high:g}]: "
                      + "; ".join(evidence) + ". Neither limit of the theory describes this chain alone: scaled to "
                      f"the {estimators[0]} points, the perfect limit misses them by {fits['perfect']:.2f} and the "
                      f"inefficient one by {fits['inefficient']:.2f} (rms, in the log), and the inefficient limit's "
                      "scale implies an exact chain of inefficiency IF_Q ≈ "
                      + " to ".join(f"{implied[e]:.0f}" for e in sorted(estimators, key=implied.get))
                      + ", neither 1 nor very large.")
    return Part(items, [verdict])


PARTS = (posterior_part, exact_posterior_part, other_data_part, n_choice_part)


@REPORTS.register(BENCHMARK)
def report(results: PaperResults) -> Section:
    items, verdicts = assemble(results, PARTS)
    numbers = results.numbers
    times = []
    for experiment in (POSTERIOR, EXACT, SPREAD, N_CHOICE):
        if results.has(experiment):
            seconds = results.folder(experiment).manifest.get("wall_time_s")
            if seconds is not None:
                times.append(f"{experiment} {float(seconds):.0f} s")
    summary = (f"{numbers.get('title', 'Stochastic-volatility parameters on GBP/USD')}. Data: {numbers.get('data', '')}. "
               "Model x_k = mu + phi (x_(k-1) - mu) + sigma w_k, y_k = exp(x_k / 2) v_k, priors mu ~ N(0, 2²), "
               "phi ~ Beta(9, 1), sigma ~ Gamma(2, rate 2) (Chopin & Papaspiliopoulos' on this series). Sources: "
               f"{' '.join(numbers.get('sources', []))} Setup and sizes: docs/benchmarks/estimation-sv.md."
               + (f" Run times (a shared two-core machine): {', '.join(times)}." if times else ""))
    return Section(BENCHMARK, "estimation-sv: stochastic-volatility parameters on GBP/USD (PMMH; Doucet, Pitt, "
                   "Deligiannidis & Kohn 2015)", summary, list(items), list(verdicts))
