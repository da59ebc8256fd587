r"""measles-london's search: IF2 for He et al.'s (2010) ten parameters, a global stage and a local one.

The search runs in two stages, pomp's usual practice for a likelihood with ridges:

* **global** (``if2``, configs/benchmarks/measles-london/if2.yaml): IF2 (Ionides et al. 2015) on
  London's 730 weeks from eight points drawn uniformly over the smallest box holding He et al.'s
  maximum-likelihood estimates for their twenty towns (paper.yaml's ``search``;
  examples/benchmarks/measles_if2_starts.py drew them);
* **local** (``if2-local``): IF2 again from the global stage's best estimate, with a smaller
  random walk and more particles. The report checks that its start is that estimate (to the
  four significant digits the config holds).

After the last pass of each, unperturbed filter runs at each replicate's estimate give its
log-likelihood :math:`\hat\ell` (the log of the mean likelihood) and its standard error
(maximum_likelihood.csv).

The verdict, on the best replicate of the last stage run: it reaches the published maximum
:math:`\ell^*` (-3804.9) when

.. math::

    \ell^* - \hat\ell_\text{best} \le \tfrac12 \chi^2_p(0.95) + Z\,\sqrt{s_\text{best}^2 + s^{*2}},

the depth of the maximum-likelihood estimate's own 95% likelihood-ratio confidence region in the
p = 10 estimated parameters (an estimate less than this below the maximum is statistically
indistinguishable from it; :func:`pfx.analysis.estimation_flags.likelihood_ratio_tolerance`),
plus :data:`~pfx.papers.likelihood_runs.Z_LIMIT` standard errors of the difference of the two
Monte Carlo estimates. The report also sets the best replicate beside pfx's own log-likelihood at
the published parameters (the ``measles`` experiment) and says how the replicates spread.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import pandas as pd

from pfx.analysis.estimation_flags import likelihood_ratio_tolerance
from pfx.config.estimation import EstimationConfig
from pfx.papers.base import Figure, PaperResults, Part, Table, Text, Verdict, markdown_table, verdict_from_checks
from pfx.papers.likelihood_runs import Z_LIMIT, estimate_numbers

GLOBAL, LOCAL = "if2", "if2-local"
LIKELIHOOD = "measles"          # the filter at the published parameters
START_DIGITS = 4                # the local stage's config holds the global best to 4 significant digits


class Stage(NamedTuple):
    """One stage's settings and results, as the report reads them."""

    experiment: str
    config: dict
    estimation: EstimationConfig
    paths: pd.DataFrame          # if2.csv: every pass's estimates
    finals: pd.DataFrame         # maximum_likelihood.csv, best first

    @property
    def passes(self) -> int:
        return int(self.paths["iteration"].max())

    @property
    def best(self) -> pd.Series:
        return self.finals.iloc[0]


def _value(value: float) -> str:
    return f"{value:.3g}"


def _rounded(value: float) -> float:
    return float(f"{value:.{START_DIGITS}g}")


def read_stage(results: PaperResults, experiment: str) -> Stage:
    config = results.config(experiment)
    folder = results.folder(experiment)
    return Stage(experiment, config, EstimationConfig.model_validate(config["estimation"]), folder.table("if2"),
                 folder.table("maximum_likelihood").sort_values("log_likelihood", ascending=False))


def estimates_table(stage: Stage, target: float, published_error: float, mle: dict) -> str:
    """The stage's replicates, best first: log-likelihood, distance below the target, each
    parameter's estimate with its start in brackets, and He et al.'s MLE as the last row."""
    columns = stage.estimation.columns
    starts = stage.paths[stage.paths["iteration"] == 0].set_index("replicate")
    rows, below = [], f"below {target:g}"
    for _, row in stage.finals.iterrows():
        start = starts.loc[row["replicate"]]
        rows.append({"replicate": int(row["replicate"]), "log L̂ ± se": f"{row['log_likelihood']:.1f} ± "
                     f"{row['log_likelihood_se']:.1f}", below: f"{target - row['log_likelihood']:.1f}",
                     **{column: f"{_value(row[column])} ({_value(start[column])})" for column in columns}})
    rows.append({"replicate": "He et al.", "log L̂ ± se": f"{target:.1f} ± {published_error:.2f}", below: "",
                 **{column: _value(float(mle[column])) if column in mle else "" for column in columns}})
    return markdown_table(pd.DataFrame(rows))


def walk_text(stage: Stage) -> str:
    """'N particles, ... random walk of sd s a week ..., cooled to s' by the last pass'."""
    walk_sd = sorted({settings.random_walk_sd for settings in stage.estimation.parameters.values()})
    cooled = stage.estimation.cooling_fraction_50 ** (stage.passes / 50)
    return (f"{stage.passes} passes of the bootstrap filter with {stage.config['filter']['particles']:,} particles, "
            f"every particle carrying its own parameters on a random walk of sd "
            f"{' or '.join(f'{sd:g}' for sd in walk_sd)} a week (log scale; logit for the shares), cooled to "
            f"{' or '.join(f'{sd * cooled:.3g}' for sd in walk_sd)} by the last pass. Each replicate's "
            f"log-likelihood: {stage.estimation.evaluations} unperturbed runs at its estimate "
            f"(maximum_likelihood.csv).")


def local_start_text(first: Stage, local: Stage) -> str:
    """Whether the local stage starts at the global stage's best estimate (to START_DIGITS digits)."""
    best = first.best
    starts = local.paths[local.paths["iteration"] == 0]
    # the starts come back through the parameter's transform (exp of its log): compare them rounded too
    differing = [column for column in local.estimation.columns
                 if any(_rounded(float(value)) != _rounded(float(best[column])) for value in starts[column])]
    if not differing:
        return (f"All {len(local.finals)} replicates start at the global stage's best estimate (its replicate "
                f"{int(best['replicate'])}, log L̂ = {best['log_likelihood']:.1f}), to {START_DIGITS} significant "
                f"digits.")
    return (f"**The local stage does not start at the global stage's best estimate** (replicate "
            f"{int(best['replicate'])}): {', '.join(differing)} differ; rerun if2-local.yaml with that estimate.")


def search_part(results: PaperResults) -> Part:
    if not results.has(GLOBAL):
        return Part()
    facts = results.numbers
    published = facts.get("published", {})
    target = float(published.get("log_likelihood", math.nan))
    published_error = float(published.get("standard_error", math.nan))
    mle = facts.get("mle", {})
    first = read_stage(results, GLOBAL)
    local = read_stage(results, LOCAL) if results.has(LOCAL) else None
    dimension = len(first.estimation.columns)
    depth = likelihood_ratio_tolerance(dimension)
    items = [Text("### Global stage: IF2 from the twenty towns' box\n\n"
                  f"IF2 estimated He et al.'s {dimension} parameters (`mu` and the initial fractions held at the "
                  f"published values) from {len(first.finals)} starts drawn uniformly over the smallest box holding "
                  f"He et al.'s estimates for their twenty towns: " + walk_text(first)),
             Table(f"The global stage's estimates after {first.passes} passes, best first (start in brackets), "
                   "beside He et al.'s MLE", estimates_table(first, target, published_error, mle),
                   f"The likelihood-ratio depth for {dimension} parameters, ½ χ²_{dimension}(0.95), is {depth:.2f}: "
                   f"a point less than this below the maximum lies inside the maximum-likelihood estimate's 95% "
                   f"confidence region. The verdict's tolerance adds {Z_LIMIT:g} standard errors of the difference "
                   f"of the two Monte Carlo estimates.")]
    if "if2_convergence.png" in results.figures(GLOBAL):
        items.append(Figure(GLOBAL, "if2_convergence.png",
                            "The global stage: each replicate's path of estimates and of the filter's "
                            "log-likelihood, pass by pass"))
    if local is not None:
        items += [Text("### Local stage: IF2 from the global stage's best estimate\n\n"
                       + local_start_text(first, local) + " " + walk_text(local)),
                  Table(f"The local stage's estimates after {local.passes} passes, best first (start in brackets), "
                        "beside He et al.'s MLE", estimates_table(local, target, published_error, mle))]
        if "if2_convergence.png" in results.figures(LOCAL):
            items.append(Figure(LOCAL, "if2_convergence.png",
                                "The local stage: each replicate's path of estimates and of the filter's "
                                "log-likelihood, pass by pass"))
    last = local if local is not None else first
    best = last.best
    gap = target - float(best["log_likelihood"])
    tolerance = depth + Z_LIMIT * math.hypot(float(best["log_likelihood_se"]), published_error)
    within = int(((target - last.finals["log_likelihood"]) <= tolerance).sum())
    stage_name = "local" if local is not None else "global"
    evidence = (f"the {stage_name} stage's best replicate ({int(best['replicate'])}) ends at log L̂ = "
                f"{best['log_likelihood']:.2f} ± {best['log_likelihood_se']:.2f}, {gap:.2f} below the published "
                f"{target:g} (tolerance {tolerance:.2f}: {depth:.2f} + {Z_LIMIT:g} standard errors; 1.92, one "
                f"parameter's depth, would {'also hold' if gap <= 1.92 else 'not'}); {within} of "
                f"{len(last.finals)} replicates end within the tolerance, the worst "
                f"{target - float(last.finals['log_likelihood'].min()):.1f} below")
    if local is not None:
        change = float(best["log_likelihood"] - first.best["log_likelihood"])
        evidence += (f"; the global stage's best was {target - float(first.best['log_likelihood']):.2f} below, so the "
                     f"local stage ended {abs(change):.2f} {'higher' if change > 0 else 'lower'}")
    if results.has(LIKELIHOOD):
        own = estimate_numbers(results.folder(LIKELIHOOD).trials)
        largest = own.index.max()
        evidence += (f"; pfx's own log-mean-exp at the published parameters is {own.loc[largest, 'log_mean_exp']:.2f} "
                     f"(N = {largest:,}), so the best replicate is "
                     f"{own.loc[largest, 'log_mean_exp'] - float(best['log_likelihood']):.2f} below it")
    claim = facts.get("search", {}).get("claim", "IF2 from the twenty towns' box reaches He et al.'s maximum")
    return Part(items, [Verdict(claim, verdict_from_checks([gap <= tolerance]), evidence + ".")])
