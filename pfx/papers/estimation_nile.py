r"""estimation-nile: parameter estimation on the Nile local level, the benchmarks' gallery section.

The benchmark is described in docs/benchmarks/estimation-nile.md. The model is Durbin & Koopman's
local level on the Nile's 100 annual flows,

.. math::

    x_t = x_{t-1} + w_t,\ w_t \sim N(0, q), \qquad z_t = x_t + v_t,\ v_t \sim N(0, r),

with the two variances estimated from the flows. Its result folders (the configs in
``configs/benchmarks/estimation-nile/``):

* ``pmmh``: the posterior of (r, q) under flat priors, by Metropolis-Hastings with the Kalman
  filter's exact likelihood (arm ``KF``) and by particle marginal Metropolis-Hastings with the
  bootstrap filter's estimate at N = 200 (arm ``PF``);
* ``if2``: maximum likelihood by IF2 from eight scattered starts.

The report computes its own exact references (:mod:`pfx.papers.estimation_nile_exact`) from the flows (``flows`` in paper.yaml) and the
runs' model (their config.yaml), with no randomness:

* **the exact posterior** on a grid of :math:`(\log r, \log q)`: the density there is
  :math:`p(z_{1:n} \mid r, q)\, \pi(r)\, \pi(q)\, r\, q` (the priors of the run, and the Jacobian of
  the log scale), its likelihood from :func:`local_level_log_likelihood`, the Kalman recursion of
  the local level vectorised over the grid (checked against pfx's ``kf`` at a few points). Its
  error is bounded by the difference between two grids;
* **the maximum of pfx's likelihood**: scipy's Nelder-Mead on pfx's Kalman filter
  (:func:`kalman_log_likelihood`), the model with its initial level :math:`x_0 \sim N(m_0, \kappa)`
  as the runs have it;
* **the maximum of the diffuse likelihood**, Durbin & Koopman's: the level after :math:`z_1` is
  :math:`N(z_1, r)`, the sum runs over t = 2..n and the constant counts all n observations
  (:func:`diffuse_log_likelihood`, pfx's ``kf`` started there).

Verdicts, each with its tolerance from theory:

* PMMH: every posterior mean (PF arm, KF arm) within :math:`Z` = ``tolerances.z`` combined
  standard errors of the exact posterior's (:math:`\sqrt{\mathrm{mcse}^2 + e_\mathrm{grid}^2}`),
  and the two arms within :math:`Z` combined MCSE of each other;
* IF2: every replicate's exact log-likelihood within :math:`\chi^2_p(0.95)/2` (3.00 for p = 2) of
  the maximum, pfx's and Durbin & Koopman's (diffuse), i.e. inside the maximum-likelihood
  estimate's own 95% likelihood-ratio confidence region;
* Durbin & Koopman's MLE: pfx's diffuse maximum equals the published log L to its printed digits,
  and the published point lies within that tolerance of the maximum.
"""

from __future__ import annotations

import math

import pandas as pd
from scipy import stats

from pfx.config.estimation import EstimationConfig
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
    flag_text,
    format_number,
    markdown_table,
    verdict_from_checks,
)
from pfx.papers.estimation_nile_exact import (
    AGREEMENT_POINTS,
    BENCHMARK,
    GRID_POINTS,
    LEVEL,
    LOG_BOX,
    MEASUREMENT,
    QUANTILES,
    diffuse_log_likelihood,
    exact_maxima,
    exact_posterior,
    flows,
    initial_level,
    kalman_log_likelihood,
    local_level,
)
from pfx.papers.score_tables import score_part

PMMH, IF2 = "pmmh", "if2"
ARMS = {"KF": "KF arm: MH, exact likelihood", "PF": "PF arm: PMMH, bootstrap filter"}


SUPERSCRIPTS = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def variance(value: float) -> str:
    """A variance (r or q, in the hundreds to tens of thousands) for a table: a whole number."""
    return f"{value:,.0f}" if abs(value) >= 100 else format_number(value, 3)


def power(value: float) -> str:
    """10⁷ for 1e7; other numbers as :func:`format_number` writes them."""
    exponent = math.log10(value) if value > 0 else 0.5
    return "10" + str(round(exponent)).translate(SUPERSCRIPTS) if exponent == round(exponent) else format_number(value)


# -- the checks (pure functions of numbers: the tests give them synthetic ones) ----------------

def agreement(first: float, first_error: float, second: float, second_error: float, z_limit: float) -> dict:
    r"""Two estimates of one number with independent standard errors: their difference, its
    standard error :math:`\sqrt{s_1^2 + s_2^2}`, z and whether :math:`|z| \le` ``z_limit``."""
    error = math.hypot(first_error, second_error)
    difference = first - second
    z = difference / error if error > 0 else (0.0 if difference == 0 else math.copysign(math.inf, difference))
    return {"difference": difference, "error": error, "z": z, "agrees": bool(abs(z) <= z_limit)}


def confidence_drop(parameters: int, level: float) -> float:
    r"""The likelihood-ratio confidence region's depth: :math:`\chi^2_p(\text{level}) / 2`."""
    return float(stats.chi2.ppf(level, parameters) / 2.0)


def maximum_agrees(published_value: float, published_point_value: float, maximum_value: float,
                   tolerance: float) -> list[bool]:
    """The published maximum's two checks: its log L equals the computed maximum's within
    ``tolerance``, and the log L at the published point is within ``tolerance`` of the maximum."""
    return [abs(maximum_value - published_value) <= tolerance, maximum_value - published_point_value <= tolerance]


# -- the parts ---------------------------------------------------------------------------------

def _tolerances(results: PaperResults) -> dict:
    return {"z": 3.0, "if2_confidence": 0.95, **(results.numbers.get("tolerances") or {})}


class ArmNumbers:
    """posterior.csv's rows of each arm, by the report's parameter names r and q."""

    def __init__(self, posterior: pd.DataFrame, names: dict[str, str]):
        self.names = {**names, "log_likelihood": "log_likelihood"}
        self.arms = [arm for arm in ARMS if arm in set(posterior["arm"])]
        self.rows = {arm: posterior[posterior["arm"] == arm].set_index("parameter") for arm in self.arms}

    def __call__(self, arm: str, parameter: str) -> pd.Series:
        return self.rows[arm].loc[self.names[parameter]]

    def listed(self, arm: str, column: str, parameters=("r", "q"), digits: int = 3) -> str:
        return ", ".join(format_number(self(arm, p)[column], digits) for p in parameters)


def posterior_table(exact: dict, numbers: ArmNumbers, manifest: dict) -> pd.DataFrame:
    """The exact posterior and each arm's, statistic by statistic (rows) and source (columns)."""
    arms, table = numbers.arms, []
    for parameter in ("r", "q"):
        grid = exact["grid"][parameter]
        table.append({"": f"{parameter}: mean ± MCSE", "exact (grid)": variance(grid["mean"]),
                      **{ARMS[arm]: f"{variance(numbers(arm, parameter)['mean'])} ± "
                                    f"{variance(numbers(arm, parameter)['mcse_mean'])}" for arm in arms}})
        table.append({"": f"{parameter}: sd", "exact (grid)": variance(grid["sd"]),
                      **{ARMS[arm]: variance(numbers(arm, parameter)["sd"]) for arm in arms}})
        table.append({"": f"{parameter}: 2.5%, 50%, 97.5%",
                      "exact (grid)": ", ".join(variance(grid[p]) for p in QUANTILES),
                      **{ARMS[arm]: ", ".join(variance(numbers(arm, parameter)[c])
                                              for c in ("quantile_2_5", "median", "quantile_97_5")) for arm in arms}})
    for label, column, parameters in (("R-hat (r, q, log-likelihood)", "r_hat", ("r", "q", "log_likelihood")),
                                      ("bulk ESS (r, q)", "ess_bulk", ("r", "q")),
                                      ("tail ESS (r, q)", "ess_tail", ("r", "q"))):
        table.append({"": label, "exact (grid)": "",
                      **{ARMS[arm]: numbers.listed(arm, column, parameters, 4 if column == "r_hat" else 3)
                         for arm in arms}})
    table.append({"": "flags (posterior.csv: r, q, log-likelihood)", "exact (grid)": "",
                  **{ARMS[arm]: "; ".join(f"{p}: {flag_text(numbers(arm, p))}" for p in ("r", "q", "log_likelihood"))
                     for arm in arms}})
    table.append({"": "acceptance rate", "exact (grid)": "",
                  **{ARMS[arm]: format_number(numbers(arm, "r")["acceptance_rate"], 2) for arm in arms}})
    table.append({"": "draws after the warm-up (chains)", "exact (grid)": f"{GRID_POINTS} × {GRID_POINTS} points",
                  **{ARMS[arm]: f"{int(numbers(arm, 'r')['n']):,} ({int(numbers(arm, 'r')['chains'])})" for arm in arms}})
    cells = {arm: str(numbers.rows[arm]["cell"].iloc[0]) for arm in arms}
    # (not the wall time: the manifest keeps only the last run's, near 0 when a rerun recomputes nothing)
    table.append({"": "the chains' filter runs", "exact (grid)": "",
                  **{ARMS[arm]: "one batch" if manifest.get("batched", {}).get(cells[arm]) else "row by row"
                     for arm in arms}})
    return pd.DataFrame(table)


def mean_comparisons(exact: dict, numbers: ArmNumbers, z_limit: float) -> list[dict]:
    """Each arm's posterior means against the exact ones, and the PF arm's against the KF arm's."""
    rows = []
    for first, second in (("PF", "exact"), ("KF", "exact"), ("PF", "KF")):
        if first not in numbers.arms or (second != "exact" and second not in numbers.arms):
            continue
        for parameter in ("r", "q"):
            if second == "exact":
                other, other_error = exact["grid"][parameter]["mean"], exact["grid_error"][parameter]
            else:
                other, other_error = numbers(second, parameter)["mean"], numbers(second, parameter)["mcse_mean"]
            mine = numbers(first, parameter)
            result = agreement(float(mine["mean"]), float(mine["mcse_mean"]), float(other), float(other_error), z_limit)
            rows.append({"comparison": f"{first} − {second}", "parameter": parameter,
                         "difference": f"{result['difference']:+,.0f}",
                         "combined standard error": f"{result['error']:,.0f}",
                         "z": f"{result['z']:+.2f}", f"|z| ≤ {z_limit:g}": result["agrees"]})
    return rows


def posterior_part(results: PaperResults) -> Part:
    if not results.has(PMMH):
        return Part()
    z_limit = _tolerances(results)["z"]
    exact = exact_posterior(results, PMMH)
    estimation = EstimationConfig.model_validate(results.config(PMMH)["estimation"])
    posterior = results.folder(PMMH).table("posterior")
    numbers = ArmNumbers(posterior, {"r": estimation.column(MEASUREMENT), "q": estimation.column(LEVEL)})
    comparisons = mean_comparisons(exact, numbers, z_limit)
    checks = [row[f"|z| ≤ {z_limit:g}"] for row in comparisons]
    priors = "; ".join(f"{name}: {estimation.parameters[path].prior.label()}"
                       for name, path in (("r", MEASUREMENT), ("q", LEVEL)))
    particles = "".join(f" with {int(n):,} particles" for n in posterior.loc[posterior["arm"] == "PF", "n_particles"][:1])
    grid_text = (f"The exact posterior: the Kalman likelihood on a {GRID_POINTS} × {GRID_POINTS} grid of (log r, "
                 f"log q), r and q each from {power(math.exp(LOG_BOX[0]))} to {power(math.exp(LOG_BOX[1]))}, times "
                 f"the runs' priors ({priors}) and the log scale's Jacobian r q. Its error, bounded by the difference "
                 f"from a grid of half the resolution, is {format_number(exact['grid_error']['r'], 2)} for r and "
                 f"{format_number(exact['grid_error']['q'], 2)} for q; the box's border holds "
                 f"{format_number(exact['grid']['edge_mass'], 2)} of the posterior. The grid's recursion agrees with "
                 f"pfx's `kf` to {format_number(exact['grid_agreement'], 2)} in log L at {len(AGREEMENT_POINTS)} "
                 "points across the box.")
    items = [Table(f"The posterior of the Nile's variances: exact, Metropolis-Hastings with the exact likelihood, "
                   f"PMMH{particles}", markdown_table(posterior_table(exact, numbers, results.folder(PMMH).manifest)),
                   "r is the measurement variance (Durbin & Koopman's σ²_ε), q the level variance (σ²_η). "
                   "MCSE, R-hat (rank-normalised split R-hat, the larger of bulk and tail) and ESS are ArviZ's "
                   "(posterior.csv). The acceptance rate is over the draws after the warm-up. " + grid_text),
             Table("The posterior means against each other", markdown_table(pd.DataFrame(comparisons)),
                   "The combined standard error adds the two numbers' errors in quadrature: the MCSE of each "
                   "chain set, and for the exact posterior the grid's error bound.")]
    for name, caption in (("chain_traces.png", "Each arm's chains: r, q and the log-likelihood, iteration by "
                                               "iteration (the warm-up shaded)"),
                          ("posterior_marginals.png", "The marginal posteriors of r and q, KF and PF arms, with the "
                                                      "prior and the posterior mean")):
        if name in results.figures(PMMH):
            items.append(Figure(PMMH, name, caption))
    if not checks:
        return Part(items)
    listing = "; ".join(f"{row['comparison']} {row['parameter']}: z = {row['z']}" for row in comparisons)
    worst = max(comparisons, key=lambda row: abs(float(row["z"])))
    evidence = (f"{sum(checks)} of {len(checks)} posterior means within {z_limit:g} combined standard errors "
                f"({listing}); the largest, {worst['comparison']} for {worst['parameter']}, is {worst['z']}.")
    if {"PF", "KF"} <= set(numbers.arms):
        r_hat = max(float(value) for arm in numbers.arms for value in numbers.rows[arm]["r_hat"])
        evidence += (f" R-hat at most {r_hat:.3f}; the PF arm's bulk ESS {numbers.listed('PF', 'ess_bulk')} against "
                     f"the KF arm's {numbers.listed('KF', 'ess_bulk')}, its acceptance rate "
                     f"{format_number(numbers('PF', 'r')['acceptance_rate'], 2)} against "
                     f"{format_number(numbers('KF', 'r')['acceptance_rate'], 2)}.")
    claim = results.numbers.get("claims", {}).get("pmmh", "PMMH targets the exact posterior")
    return Part(items, [Verdict(claim, verdict_from_checks(checks), evidence)])


def if2_part(results: PaperResults) -> Part:
    if not results.has(IF2):
        return Part()
    published = results.numbers.get("maximum_likelihood", {})
    config = results.config(IF2)
    settings = local_level(config["model"])
    estimation = EstimationConfig.model_validate(config["estimation"])
    names = {"r": estimation.column(MEASUREMENT), "q": estimation.column(LEVEL)}
    exact = exact_maxima(results, IF2)
    data = flows(results)
    dimension, level = len(estimation.parameters), float(_tolerances(results)["if2_confidence"])
    limit = confidence_drop(dimension, level)
    paths = results.folder(IF2).table("if2")
    finals = results.folder(IF2).table("maximum_likelihood").sort_values("replicate")
    starts = paths[paths["iteration"] == 0].set_index("replicate")
    maximum_value, published_value = exact["maximum"][2], float(published.get("log_likelihood", math.nan))
    rows, drops, diffuse_drops = [], [], []
    for _, row in finals.iterrows():
        r, q = float(row[names["r"]]), float(row[names["q"]])
        value = kalman_log_likelihood(settings, data, r, q)
        diffuse = diffuse_log_likelihood(settings, data, r, q)
        drops.append(maximum_value - value)
        diffuse_drops.append(published_value - diffuse)
        start = starts.loc[row["replicate"]]
        start_drop = maximum_value - kalman_log_likelihood(settings, data, start[names["r"]], start[names["q"]])
        rows.append({"replicate": int(row["replicate"]),
                     "start (r, q)": f"{variance(start[names['r']])}, {variance(start[names['q']])}",
                     "start: below pfx's maximum": f"{start_drop:.2f}",
                     "IF2 (r, q)": f"{variance(r)}, {variance(q)}",
                     "PF log L̄ ± se": f"{row['log_likelihood']:.2f} ± {row['log_likelihood_se']:.2f}",
                     "exact log L": f"{value:.4f}", "below pfx's maximum": f"{drops[-1]:.3f}",
                     "diffuse log L": f"{diffuse:.4f}", "below D&K's": f"{diffuse_drops[-1]:.3f}"})
    mean_r, mean_q = float(finals[names["r"]].mean()), float(finals[names["q"]].mean())
    rows.append({"replicate": "mean", "start (r, q)": "", "start: below pfx's maximum": "",
                 "IF2 (r, q)": f"{variance(mean_r)}, {variance(mean_q)}",
                 "PF log L̄ ± se": "", "exact log L": "", "below pfx's maximum": "", "diffuse log L": "",
                 "below D&K's": ""})
    passes = int(paths["iteration"].max())
    final_sd = [estimation.parameters[path].random_walk_sd * estimation.cooling_fraction_50 ** (passes / 50)
                for path in estimation.parameters]
    items = [Table(f"IF2 after {passes} passes: each replicate's estimate and its exact log-likelihood",
                   markdown_table(pd.DataFrame(rows)),
                   f"Exact log L: pfx's Kalman filter under the runs' model (initial level "
                   f"N({initial_level(settings)[0]:g}, {power(initial_level(settings)[1])})), whose "
                   f"maximum is {maximum_value:.4f} at r = {exact['maximum'][0]:,.1f}, q = "
                   f"{exact['maximum'][1]:,.1f}. Diffuse log L: Durbin & Koopman's likelihood at the "
                   f"same estimate, against their published maximum {published_value}. PF log L̄ ± se: "
                   f"maximum_likelihood.csv, {estimation.evaluations} unperturbed filter runs at the estimate "
                   f"(N = {results.config(IF2)['filter']['particles']:,}). The perturbation's sd at the last pass: "
                   f"{', '.join(f'{sd:.3g}' for sd in final_sd)} on the log scale. The limit, χ²_{dimension}"
                   f"({level:g}) / 2 = {limit:.2f}: an estimate less than this below the maximum lies inside the "
                   f"maximum-likelihood estimate's own {level:.0%} likelihood-ratio confidence region.")]
    if "if2_convergence.png" in results.figures(IF2):
        items.append(Figure(IF2, "if2_convergence.png", "Each replicate's path of estimates and of the "
                                                        "filter's log-likelihood, pass by pass"))
    checks = [drop <= limit for drop in drops] + [drop <= limit for drop in diffuse_drops]
    evidence = (f"after {passes} passes, {sum(d <= limit for d in drops)} of {len(drops)} replicates within "
                f"{limit:.2f} of pfx's maximum ({maximum_value:.4f}; drops {min(drops):.3f} to {max(drops):.3f}) and "
                f"{sum(d <= limit for d in diffuse_drops)} of {len(diffuse_drops)} within {limit:.2f} of Durbin & "
                f"Koopman's diffuse maximum {published_value} (drops {min(diffuse_drops):.3f} to "
                f"{max(diffuse_drops):.3f}), from starts {min(starts[names['r']]):,.0f} to {max(starts[names['r']]):,.0f} "
                f"(r) and {min(starts[names['q']]):,.0f} to {max(starts[names['q']]):,.0f} (q); the replicates' mean "
                f"({mean_r:,.0f}, {mean_q:,.0f}) against the maximum ({exact['maximum'][0]:,.0f}, "
                f"{exact['maximum'][1]:,.0f}).")
    claim = results.numbers.get("claims", {}).get("if2", "IF2 converges to the maximum likelihood")
    return Part(items, [Verdict(claim, verdict_from_checks(checks), evidence)])


def maximum_part(results: PaperResults) -> Part:
    experiment = PMMH if results.has(PMMH) else IF2 if results.has(IF2) else None
    published = results.numbers.get("maximum_likelihood")
    if experiment is None or not published:
        return Part()
    settings = local_level(results.config(experiment)["model"])
    exact = exact_maxima(results, experiment)
    data = flows(results)
    tolerance = float(published.get("log_likelihood_tolerance", 5e-5))
    r, q, value = float(published["r"]), float(published["q"]), float(published["log_likelihood"])
    at_published = diffuse_log_likelihood(settings, data, r, q)
    diffuse_r, diffuse_q, diffuse_value = exact["diffuse_maximum"]
    spread = exact["curvature"]
    wide_r, wide_q, wide_value = exact["maximum"]
    centre, kappa = initial_level(settings)
    rows = [{"": "Durbin & Koopman (published; diffuse)", "r": f"{r:g}", "q": f"{q:g}",
             "diffuse log L": f"{value:.4f} (at this point: {at_published:.6f})",
             f"log L, initial level N({centre:g}, {power(kappa)})": f"{kalman_log_likelihood(settings, data, r, q):.6f}"},
            {"": "pfx's Kalman filter, diffuse initial level: the maximum", "r": f"{diffuse_r:,.2f}",
             "q": f"{diffuse_q:,.2f}", "diffuse log L": f"{diffuse_value:.6f}",
             f"log L, initial level N({centre:g}, {power(kappa)})":
                 f"{kalman_log_likelihood(settings, data, diffuse_r, diffuse_q):.6f}"},
            {"": f"pfx's Kalman filter, the runs' initial level N({centre:g}, {power(kappa)}): the maximum",
             "r": f"{wide_r:,.2f}", "q": f"{wide_q:,.2f}",
             "diffuse log L": f"{diffuse_log_likelihood(settings, data, wide_r, wide_q):.6f}",
             f"log L, initial level N({centre:g}, {power(kappa)})": f"{wide_value:.6f}"}]
    shift = 0.5 * math.log(kappa) + (data[0] - centre) ** 2 / (2.0 * kappa)
    items = [Table("The maximum likelihood: Durbin & Koopman's against pfx's Kalman filter",
                   markdown_table(pd.DataFrame(rows)),
                   "Maxima by Nelder-Mead on (log r, log q). The diffuse log-likelihood counts all "
                   f"n = {len(data)} observations in its constant, as Durbin & Koopman's does."),
             Text(f"**Why two maxima.** The runs give the level a wide Gaussian prior, x₀ ~ N({centre:g}, "
                  f"{power(kappa)}), where Durbin & Koopman's is diffuse (the limit of an infinite variance). As "
                  "κ grows, log L_κ = log L_diffuse − ½ log κ − (z₁ − m₀)² / 2κ + O((r + q)/κ): at the published "
                  f"point the two differ by {at_published - kalman_log_likelihood(settings, data, r, q):.4f}, "
                  f"against ½ log κ + (z₁ − m₀)² / 2κ = {shift:.4f}. The remainder depends on r and q, so it moves "
                  f"the maximum, by ({wide_r - diffuse_r:+.2f}, {wide_q - diffuse_q:+.2f}): "
                  f"{abs(math.log(wide_r / diffuse_r)) / spread['sd_log_r']:.1e} and "
                  f"{abs(math.log(wide_q / diffuse_q)) / spread['sd_log_q']:.1e} asymptotic sd of log r and log q "
                  f"(at pfx's maximum: {spread['sd_log_r']:.2f} and {spread['sd_log_q']:.2f}, correlation "
                  f"{spread['correlation']:+.2f}, from the curvature of log L). PMMH and IF2 run under the "
                  "wide prior, so their reference is pfx's maximum; the published one is the diffuse maximum.")]
    checks = maximum_agrees(value, at_published, diffuse_value, tolerance)
    evidence = (f"pfx's diffuse maximum is {diffuse_value:.6f} at ({diffuse_r:,.2f}, {diffuse_q:,.2f}): "
                f"{diffuse_value - value:+.1e} from the published {value} (tolerance {tolerance:g}, half its last "
                f"digit), and the published point ({r:g}, {q:g}) lies {diffuse_value - at_published:.1e} below the "
                f"maximum (tolerance the same). The estimates differ by {diffuse_r - r:+.2f} and {diffuse_q - q:+.2f}: "
                f"{abs(math.log(diffuse_r / r)) / spread['sd_log_r']:.0e} and "
                f"{abs(math.log(diffuse_q / q)) / spread['sd_log_q']:.0e} asymptotic sd of log r and log q; a flat "
                "maximum's location is fixed only to within what log L resolves.")
    claim = results.numbers.get("claims", {}).get("maximum_likelihood", "Durbin & Koopman's maximum")
    return Part(items, [Verdict(claim, verdict_from_checks(checks), evidence)])


def scores_part(results: PaperResults) -> Part:
    """The bootstrap filter's predictive scores on the Nile against the Kalman filter's exact ones
    (:mod:`pfx.papers.score_tables`)."""
    claim = results.numbers.get("claims", {}).get("scores", "the particle filter's predictive scores equal the "
                                                  "Kalman filter's exact ones")
    return score_part(results, "scores", by="arm", baseline="KF", claim=claim)


PARTS = (posterior_part, if2_part, maximum_part, scores_part)


@REPORTS.register(BENCHMARK)
def report(results: PaperResults) -> Section:
    items, verdicts = assemble(results, PARTS)
    numbers = results.numbers
    summary = (f"{numbers.get('title', 'The Nile local level')}. Data: {numbers.get('data', '')}. Model: "
               f"{numbers.get('model', '')}. Sources: {' '.join(numbers.get('sources', []))} The exact references "
               "(the posterior on a grid, the maxima of the likelihood) are computed by this report from pfx's Kalman "
               "filter. Setup: docs/benchmarks/estimation-nile.md.")
    return Section(BENCHMARK, "estimation-nile: PMMH and IF2 on the Nile local level (Durbin & Koopman 2012; "
                   "Andrieu, Doucet & Holenstein 2010; Ionides et al. 2015)", summary, list(items), list(verdicts))
