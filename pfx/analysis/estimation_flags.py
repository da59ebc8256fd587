r"""Chains and replicates that should not be trusted yet, named, with what to do about them.

Every threshold is a constant of this module, and both the run (:mod:`pfx.run.estimation`) and
the end-of-run table (:mod:`pfx.analysis.run_summary`) read them from here, so the folder's
``flag`` columns and the lines printed cannot disagree (docs/estimation.md, "Reading the
diagnostics: flagged chains and replicates").

**PMMH** (posterior.csv's ``flag``, per parameter and for the log-likelihood row). Vehtari,
Gelman, Simpson, Carpenter & Bürkner (2021, *Bayesian Analysis* 16) ask, before draws are used,
for

* a rank-normalised split :math:`\hat R \le 1.01` (:data:`R_HAT_LIMIT`; it needs two chains or
  more, so one chain is not checked for it), and
* a bulk and a tail effective sample size of at least 100 per chain
  (:data:`ESS_PER_CHAIN`): 400 for four chains, the paper's and Stan's rule. Per chain, since
  the ESS of the pooled draws grows with the number of chains.

A diagnostic that is not a number is flagged too: with fewer than :data:`MINIMUM_DRAWS` draws per
chain there are no diagnostics at all (too few draws), and an R-hat of NaN means every draw is the
same value.

**What to do, in the order of diagnosis** (:func:`pmmh_advice`, one line per flagged cell):

1. **More particles**, when the likelihood estimate is too noisy: PMMH's chains stick wherever a
   lucky overestimate of :math:`\hat\ell` put them. The run measures
   :math:`\mathrm{sd}(\hat\ell)` at the posterior mean (R runs of the filter, particle filters
   only); above :data:`SPREAD_LIMIT` it is the cause, and the 1/N law
   :math:`\mathrm{Var}\,\hat\ell \approx c/N` gives the N at which the sd is
   :data:`SPREAD_TARGET`, where PMMH's cost per independent draw is least (Doucet, Pitt,
   Deligiannidis & Kohn 2015): :math:`N' = N\,(\mathrm{sd}/1.2)^2`. The law holds once the sd is
   near 1; far above it (:data:`FAR_SPREAD`) the sd first falls faster than :math:`1/\sqrt N`,
   so N' is then likely too many, and the line points to ``particles: auto``, which measures it.
2. **A proposal scale**, given the acceptance rate after the warm-up: below
   :data:`ACCEPTANCE_LOW` the steps are too long, above :data:`ACCEPTANCE_HIGH` too short. The
   reference rates: 0.234 for a random walk on an exact likelihood in many dimensions (0.44 in
   one; Roberts, Gelman & Gilks 1997), about 0.07 to 0.15 with a noisy estimate of sd near 1.2
   (Sherlock, Thiery, Roberts & Rosenthal 2015).
3. **More iterations**, when the chains are sound but short: the ESS grows about linearly with
   the draws, so the worst ESS e reaches its threshold t after about d (t/e - 1) more draws per
   chain (d: the draws per chain so far).

The order matters: a noisy estimate also lowers the acceptance rate, so the spread is measured
first; and a badly scaled proposal makes longer chains a waste, so its scale comes before their
length.

**A correlated posterior**, named beside any of the three (:func:`strongest_correlation`): where
two estimated parameters' draws after the warm-up have a correlation :math:`|\rho|` above
:data:`CORRELATION_LIMIT`, the posterior is a ridge, along which a random walk of independent
steps moves slowly whatever its scale (the user of issue 49 was told to run 26000 iterations
for :math:`\rho = 0.79`). The line names the pair and :math:`\rho`, and what helps: a proposal
that learns the posterior's covariance (Haario, Saksman & Tamminen 2001), which pfx does only
during the warm-up (``estimation.warm_up`` > 0 with ``adapt: true``; ``warm_up`` is 0 unless
set, so by default nothing adapts), or a reparametrisation that estimates what the data pin down
(the two parameters' ratio or product, say) in place of one of them. The correlation is that of
the draws on the natural scale, pooled over the chains: the number ``posterior_pairs`` prints
above its diagonal and a user computes from chains.csv. (The proposal walks on the transformed
scale; for a posterior concentrated enough to be judged, the two correlations differ little.)
Without such a pair, a run whose proposal did not adapt is told so, with the keys that make it:
on pfx's PMMH benchmarks a warm-up with adaptation gave 1.2 to 1.3 times the ESS per iteration
of none (docs/estimation.md, "The proposal").

**IF2** (maximum_likelihood.csv's ``flag``, per replicate). Replicates that reached the maximum
agree within the likelihood-ratio tolerance :math:`\tfrac12\chi^2_p(0.95)` (p estimated
parameters; 1.92 for one, 3.00 for two): points closer than that to the maximum lie inside the
95% likelihood-ratio confidence region. A replicate is flagged when its final log-likelihood
:math:`\ell` is below the best replicate's :math:`\ell_{best}` by more than the tolerance plus
:data:`MONTE_CARLO_SES` standard errors of the difference,

.. math::

    \ell_{best} - \ell > \tfrac12\chi^2_p(0.95) + 2\sqrt{se_{best}^2 + se^2},

so that the Monte Carlo error of the two estimates (maximum_likelihood.csv's
``log_likelihood_se``; taken as 0 where there is none) does not flag a replicate by chance; and
when its log-likelihood is not finite (the likelihood is zero at its estimate).
"""

from __future__ import annotations

import itertools
import math
from typing import Mapping, Optional, Sequence

import numpy as np
import pandas as pd

R_HAT_LIMIT = 1.01
ESS_PER_CHAIN = 100
MINIMUM_DRAWS = 4                # per chain: fewer, and arviz-stats' diagnostics are not computed
SPREAD_LIMIT = 2.0               # sd of the log-likelihood estimate above which particles come first
SPREAD_TARGET = 1.2              # the sd at which PMMH costs least per independent draw (Doucet et al. 2015)
FAR_SPREAD = 5.0                 # above it, the 1/N law's N is likely too many (Var ℓ̂ ≈ c/N holds near sd 1)
SPREAD_RUNS = 40                 # filter runs that measure it: the sd's relative standard error is 11 %
ACCEPTANCE_LOW = 0.05
ACCEPTANCE_HIGH = 0.5
CORRELATION_LIMIT = 0.5          # |rho| of two parameters' kept draws above which the line names the pair
LIKELIHOOD_RATIO_LEVEL = 0.95
MONTE_CARLO_SES = 2.0


def ess_threshold(chains: int) -> int:
    """The least bulk and tail ESS the draws of ``chains`` chains need: 100 per chain."""
    return ESS_PER_CHAIN * int(chains)


def too_few_draws(draws_per_chain: int) -> bool:
    return draws_per_chain < MINIMUM_DRAWS


def posterior_flag(r_hat: float, ess_bulk: float, ess_tail: float, chains: int, draws_per_chain: int) -> str:
    """posterior.csv's ``flag`` for one row: empty when the row passes, else each failed check
    with its value and threshold, joined by "; " (``r_hat 1.92 > 1.01; ess_bulk 6 < 400``)."""
    if too_few_draws(draws_per_chain):
        return f"too few draws for diagnostics: {draws_per_chain} per chain < {MINIMUM_DRAWS}"
    failed = []
    if chains > 1:
        if math.isnan(r_hat):
            failed.append("r_hat NaN (every draw the same value)")
        elif r_hat > R_HAT_LIMIT:
            failed.append(f"r_hat {_apart(r_hat, R_HAT_LIMIT)}")
    threshold = ess_threshold(chains)
    for name, value in (("ess_bulk", ess_bulk), ("ess_tail", ess_tail)):
        if math.isnan(value):
            failed.append(f"{name} NaN")
        elif value < threshold:
            failed.append(f"{name} {math.floor(value)} < {threshold}")   # floored: 399.6 reads "399 < 400"
    return "; ".join(failed)


def flag_texts(flags: pd.Series) -> pd.Series:
    """A ``flag`` column as text, "" where a row passes (pandas reads an empty field as NaN)."""
    return flags.astype(object).where(flags.notna(), "").astype(str)


# -- PMMH: what to do -------------------------------------------------------------------------------------

def suggested_particles(particles: int, sd: float) -> int:
    """The N at which the sd of the log-likelihood estimate is :data:`SPREAD_TARGET`, by the 1/N
    law from ``sd`` measured at ``particles``, to two significant figures."""
    wanted = particles * (sd / SPREAD_TARGET) ** 2
    return max(int(_two_figures(wanted)), particles + 1)


def _two_figures(value: float) -> float:
    """``value`` to two significant figures (2408 -> 2400), at least 1: advice, not a measurement."""
    if value <= 0 or not math.isfinite(value):
        return value
    scale = 10 ** max(math.floor(math.log10(value)) - 1, 0)
    return max(round(value / scale) * scale, 1)


def pmmh_advice(posterior: pd.DataFrame, iterations: int, spread: Optional[Mapping] = None,
                chosen_by_pilot: bool = False, chains: Optional[pd.DataFrame] = None,
                adapt: bool = True, adapt_after: int = 100) -> Optional[str]:
    """One line for a cell's posterior.csv rows ``posterior`` whose ``flag`` is not empty (None
    when none is): what to try first (module docstring). ``iterations``: the chains' iterations so
    far (warm-up included); ``spread``: the cell's row of likelihood_spread.csv (``particles``,
    ``runs``, ``finite``, ``sd``), where the run measured one; ``chosen_by_pilot``: the cell's
    particles are ``auto`` (the manifest's ``particle_count``), so more particles means measuring
    again nearer the posterior; ``chains``: the cell's rows of chains.csv (or its progress rows),
    whose draws after the warm-up name a strongly correlated pair, if any; ``adapt``,
    ``adapt_after``: the config's ``estimation.adapt`` and ``estimation.adapt_after``."""
    flagged = posterior[flag_texts(posterior["flag"]) != ""]
    if flagged.empty:
        return None
    chain_count = int(posterior["chains"].iloc[0])
    draws_per_chain = int(posterior["n"].iloc[0]) // max(chain_count, 1)
    head = f"chains flagged for {', '.join(flagged['parameter'].astype(str))} (posterior.csv, flag{_worst(flagged)}): "
    if too_few_draws(draws_per_chain):
        return head + (f"more iterations: {draws_per_chain} draws per chain after the warm-up are too few to judge the "
                       f"chains (at least {MINIMUM_DRAWS}, and {ESS_PER_CHAIN} effective per chain); raise "
                       "estimation.iterations")
    aside = "" if chains is None else _proposal_aside(chains, _parameters(posterior), adapt, adapt_after, iterations)
    if spread is not None:
        noisy = _noisy_estimate(spread, chosen_by_pilot, posterior)
        if noisy:
            return head + noisy + aside
    acceptance = float(posterior["acceptance_rate"].iloc[0])
    measured = _spread_aside(spread)
    reference = ("a random walk accepts best near 0.234 on an exact likelihood (0.44 in one dimension), about "
                 "0.07-0.15 on an estimate of sd near 1.2 (Sherlock, Thiery, Roberts & Rosenthal 2015)")
    if acceptance < ACCEPTANCE_LOW:
        return head + (f"a smaller proposal scale: the acceptance rate after the warm-up is {acceptance:.3g} < "
                       f"{ACCEPTANCE_LOW}{measured}; try a smaller proposal_sd, or adapt: true with a longer warm_up; "
                       + reference) + aside
    if acceptance > ACCEPTANCE_HIGH:
        return head + (f"a larger proposal scale: the acceptance rate after the warm-up is {acceptance:.3g} > "
                       f"{ACCEPTANCE_HIGH}{measured}; try a larger proposal_sd, or adapt: true with a longer warm_up; "
                       + reference) + aside
    return head + _more_iterations(posterior, chain_count, draws_per_chain, iterations) + measured + aside


def _parameters(posterior: pd.DataFrame) -> list[str]:
    """The estimated parameters of a cell's posterior.csv rows (not its log-likelihood row)."""
    return [str(name) for name in posterior["parameter"] if name != "log_likelihood"]


def correlation(x: np.ndarray, y: np.ndarray) -> float:
    """Pearson's correlation of the draws where both are finite (NaN if either is constant)."""
    both = np.isfinite(x) & np.isfinite(y)
    if both.sum() < 2 or np.std(x[both]) == 0 or np.std(y[both]) == 0:
        return float("nan")
    return float(np.corrcoef(x[both], y[both])[0, 1])


def strongest_correlation(chains: pd.DataFrame, parameters: Sequence[str]) -> Optional[tuple[str, str, float]]:
    """The two of ``parameters`` whose draws after the warm-up (``chains``: a cell's rows of
    chains.csv, chains pooled, natural scale) are most correlated, and their correlation; None
    for fewer than two parameters or no finite correlation."""
    kept = chains[~chains["warm_up"].astype(bool)]
    strongest = None
    for first, second in itertools.combinations(parameters, 2):
        rho = correlation(kept[first].to_numpy(dtype=float), kept[second].to_numpy(dtype=float))
        if math.isfinite(rho) and (strongest is None or abs(rho) > abs(strongest[2])):
            strongest = (first, second, rho)
    return strongest


def _proposal_aside(chains: pd.DataFrame, parameters: Sequence[str], adapt: bool, adapt_after: int, iterations: int) -> str:
    """The aside on the proposal: the pair of parameters correlated beyond
    :data:`CORRELATION_LIMIT`, if any, and what helps given how this run's proposal adapted; or,
    with no such pair, that it did not adapt, where it did not (module docstring); else ""."""
    strongest = strongest_correlation(chains, parameters)
    warm_up = int(chains.loc[chains["warm_up"].astype(bool), "iteration"].max())    # iteration 0, the start, is warm-up
    adapted = adapt and warm_up >= adapt_after
    correlated = strongest is not None and abs(strongest[2]) > CORRELATION_LIMIT
    if adapted and not correlated:
        return ""
    # a quarter of the iterations, and twice adapt_after, so that the adapted covariance has draws behind it
    suggested = max(iterations // 4, 2 * adapt_after)
    example = f"e.g. warm_up: {suggested} with iterations: {iterations + suggested}, keeping as many draws"
    if not adapt:
        how = f"set adapt: true, with a warm_up longer than adapt_after ({adapt_after}), {example}"
    elif warm_up == 0:
        how = f"set estimation.warm_up (0 unless set, so nothing adapted) with adapt: true (the default), {example}"
    else:
        how = f"a warm_up longer than adapt_after ({adapt_after}, the iterations before the first adaptation), {example}"
    learn = f"which it does only during the warm-up: {how} (a new run, --fresh)"
    if not correlated:
        return f"; also, the proposal did not learn the posterior's covariance (Haario et al. 2001), {learn}"
    first, second, rho = strongest
    said = (f"; also, {first} and {second} are correlated (corr {rho:.2f} in the draws after the warm-up, above "
            f"{CORRELATION_LIMIT:g}): a random walk of independent steps moves slowly along such a ridge")
    reparametrise = "or reparametrise, estimating what the data pin down (their ratio or product, say) in place of one"
    if adapted:
        return said + (f"; the proposal adapted to the draws' covariance over the warm-up's {warm_up} iterations: a "
                       f"longer estimation.warm_up learns it better, {reparametrise}")
    return said + f"; let the proposal learn the posterior's covariance (Haario et al. 2001), {learn}, {reparametrise}"


def _worst(flagged: pd.DataFrame) -> str:
    """"; worst R-hat 1.920, worst ESS 6 < 400" over the flagged rows (what is a number)."""
    parts = []
    r_hat = flagged["r_hat"].to_numpy(dtype=float)
    if (r_hat > R_HAT_LIMIT).any():
        parts.append(f"worst R-hat {float(np.max(r_hat[r_hat > R_HAT_LIMIT])):.3g}")
    ess = flagged[["ess_bulk", "ess_tail"]].to_numpy(dtype=float)
    threshold = ess_threshold(int(flagged["chains"].iloc[0]))
    if (ess < threshold).any():
        parts.append(f"worst ESS {math.floor(float(np.min(ess[ess < threshold])))} < {threshold}")
    return "".join(f"; {part}" for part in parts)


def _noisy_estimate(spread: Mapping, chosen_by_pilot: bool = False,
                    posterior: Optional[pd.DataFrame] = None) -> Optional[str]:
    """The "more particles" advice when the measured spread calls for it, else None. For a cell
    whose N the pilot of ``particles: auto`` chose, the pilot measured elsewhere (the chains'
    start, by default), where the estimate can be far less noisy than at the posterior: the
    advice is to measure again at the posterior mean (``estimation.particle_count.at``)."""
    particles, runs, finite, sd = int(spread["particles"]), int(spread["runs"]), int(spread["finite"]), spread["sd"]
    auto = "or `particles: auto`"
    if chosen_by_pilot and posterior is not None:
        means = posterior[posterior["parameter"] != "log_likelihood"]
        at = ", ".join(f"{name} {value:.4g}" for name, value in zip(means["parameter"], means["mean"]))
        auto = (f"or have `particles: auto` (which chose {particles} where it measured) measure at the posterior "
                f"mean, {at} (estimation.particle_count.at)")
    if finite < runs:
        return (f"more particles: the filter's likelihood estimate at the posterior mean was zero in {runs - finite} "
                f"of {runs} runs at N = {particles}; raise filter.particles, {auto}")
    if sd is None or not math.isfinite(float(sd)) or float(sd) <= SPREAD_LIMIT:
        return None
    sd = float(sd)
    measured = (f"more particles: sd of log L̂ at the posterior mean {sd:.3g} over {runs} runs at N = {particles} "
                f"(above {SPREAD_LIMIT:g}); PMMH mixes best near {SPREAD_TARGET}: ")
    wanted = suggested_particles(particles, sd)
    if sd > FAR_SPREAD:
        # Var ℓ̂ ≈ c/N holds once the sd is near 1; far above, the sd falls faster than 1/√N at
        # first, so the law's N is likely far too many: measured, not extrapolated
        return measured + (f"the 1/N law, which holds near sd 1, would say N = {wanted}, likely too many this far "
                           f"from it: raise N by factors of 4 until the sd is near {SPREAD_TARGET}, {auto}")
    return measured + f"about N = {wanted} by the 1/N law, {auto}"


def _spread_aside(spread: Optional[Mapping]) -> str:
    """The measured spread, where it was measured and is not the cause, as an aside."""
    if spread is None or spread["sd"] is None or not math.isfinite(float(spread["sd"])):
        return ""
    return (f" (sd of log L̂ at the posterior mean {float(spread['sd']):.3g} at N = {int(spread['particles'])}, "
            f"not above {SPREAD_LIMIT:g}: not the cause)")


def _more_iterations(posterior: pd.DataFrame, chains: int, draws_per_chain: int, iterations: int) -> str:
    """How many more iterations bring the worst ESS to its threshold (the ESS grows about
    linearly with the draws); twice the draws where only R-hat fails."""
    threshold = ess_threshold(chains)
    values = posterior[["ess_bulk", "ess_tail"]].to_numpy(dtype=float)
    worst = float(np.nanmin(values)) if np.isfinite(values).any() else math.nan
    if math.isfinite(worst) and 0 < worst < threshold:
        more = math.ceil(_two_figures(draws_per_chain * (threshold / worst - 1.0)))
        why = (f"the worst ESS is {math.floor(worst)} < {threshold}, and the ESS grows about linearly with the draws "
               f"({draws_per_chain} per chain so far)")
    else:
        more = draws_per_chain
        why = f"R-hat stays above {R_HAT_LIMIT}: the chains have not met yet; try twice the draws"
    return (f"more iterations: {why}: about {more} more per chain, iterations: {iterations + more} "
            f"(a finished run extends)")


# -- IF2 ---------------------------------------------------------------------------------------------------

def likelihood_ratio_tolerance(parameters: int) -> float:
    """½ χ²_p(0.95): how far below the maximum a log-likelihood may be and its point still lie in
    the 95% likelihood-ratio confidence region (1.9207 for p = 1)."""
    from scipy.stats import chi2

    return 0.5 * float(chi2.ppf(LIKELIHOOD_RATIO_LEVEL, parameters))


def replicate_flags(log_likelihood: Sequence[float], standard_error: Sequence[float], parameters: int) -> list[str]:
    """maximum_likelihood.csv's ``flag`` for a cell's replicates (module docstring): empty, or
    ``below the best by 7.3 > 3.91`` (the gap, and the tolerance plus two standard errors of the
    difference), or the non-finite log-likelihood."""
    values = np.asarray(log_likelihood, dtype=float)
    errors = np.nan_to_num(np.asarray(standard_error, dtype=float), nan=0.0)   # no standard error: compared without one
    finite = np.isfinite(values)
    if not finite.any():
        return [_not_finite(value) for value in values]
    best = int(np.argmax(np.where(finite, values, -np.inf)))
    tolerance = likelihood_ratio_tolerance(parameters)
    flags = []
    for value, error, is_finite in zip(values, errors, finite):
        if not is_finite:
            flags.append(_not_finite(value))
            continue
        gap = values[best] - value
        limit = tolerance + MONTE_CARLO_SES * math.sqrt(errors[best] ** 2 + error ** 2)
        flags.append(f"below the best by {_apart(gap, limit)}" if gap > limit else "")
    return flags


def _not_finite(value: float) -> str:
    return f"log_likelihood {value}: the likelihood is zero at its estimate" if value == -np.inf \
        else f"log_likelihood {value}"


def _apart(gap: float, limit: float) -> str:
    """"gap > limit" with enough digits that the two read differently."""
    for digits in range(3, 10):
        text, bound = f"{gap:.{digits}g}", f"{limit:.{digits}g}"
        if text != bound:
            return f"{text} > {bound}"
    return f"{gap!r} > {limit!r}"


def if2_advice(flags: Sequence[str], parameters: int) -> Optional[str]:
    """One line for a cell whose replicates (their ``flag``) include flagged ones; None otherwise."""
    flags = [flag if isinstance(flag, str) else "" for flag in flags]      # pandas reads an empty flag as NaN
    below = sum(flag.startswith("below the best") for flag in flags)
    zero = sum(flag.startswith("log_likelihood") for flag in flags)
    if not below and not zero:
        return None
    what = []
    if below:
        what.append(f"{below} end below the best's log-likelihood by more than the likelihood-ratio tolerance "
                    f"{likelihood_ratio_tolerance(parameters):.3g} (½ χ²_{parameters}(0.95)) plus "
                    f"{MONTE_CARLO_SES:g} standard errors")
    if zero:
        what.append(f"{zero} {'has' if zero == 1 else 'have'} a log-likelihood that is not finite")
    return (f"{below + zero} of {len(flags)} IF2 replicates flagged (maximum_likelihood.csv, flag): "
            f"{'; '.join(what)}; they have not reached the maximum: try more iterations (passes), a larger starting "
            "random_walk_sd or slower cooling (cooling_fraction_50 nearer 1), or more particles")
