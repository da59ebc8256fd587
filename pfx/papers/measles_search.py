r"""measles-london's search: IF2 for He et al.'s (2010) ten parameters from a box of starting points.

The ``if2`` experiment (configs/benchmarks/measles-london/if2.yaml) runs IF2 (Ionides et al.
2015) on London's 730 weeks from eight points drawn uniformly over the smallest box holding
He et al.'s maximum-likelihood estimates for their twenty towns (paper.yaml's ``search``;
examples/benchmarks/measles_if2_starts.py drew them). After the last pass, unperturbed filter
runs at each replicate's estimate give its log-likelihood :math:`\hat\ell` (the log of the mean
likelihood) and its standard error (maximum_likelihood.csv).

The verdict: the best replicate reaches the published maximum :math:`\ell^*` (-3804.9) when

.. math::

    \ell^* - \hat\ell_\text{best} \le \tfrac12 \chi^2_p(0.95) + Z\,\sqrt{s_\text{best}^2 + s^{*2}},

the depth of the maximum-likelihood estimate's own 95% likelihood-ratio confidence region in the
p = 10 estimated parameters (an estimate less than this below the maximum is statistically
indistinguishable from it; :func:`pfx.analysis.estimation_flags.likelihood_ratio_tolerance`),
plus :data:`Z_LIMIT` standard errors of the difference of the two Monte Carlo estimates. The
report also sets the best replicate beside pfx's own log-likelihood at the published parameters
(the ``measles`` experiment) and says how the replicates spread.
"""

from __future__ import annotations

import math

import pandas as pd

from pfx.analysis.estimation_flags import likelihood_ratio_tolerance
from pfx.config.estimation import EstimationConfig
from pfx.papers.base import Figure, PaperResults, Part, Table, Text, Verdict, markdown_table, verdict_from_checks
from pfx.papers.likelihood_runs import estimate_numbers

SEARCH = "if2"
LIKELIHOOD = "measles"          # the filter at the published parameters
Z_LIMIT = 3.0


def _value(value: float) -> str:
    return f"{value:.3g}"


def search_part(results: PaperResults) -> Part:
    if not results.has(SEARCH):
        return Part()
    facts = results.numbers
    published = facts.get("published", {})
    target = float(published.get("log_likelihood", math.nan))
    published_error = float(published.get("standard_error", math.nan))
    mle = facts.get("mle", {})
    config = results.config(SEARCH)
    estimation = EstimationConfig.model_validate(config["estimation"])
    columns = estimation.columns
    walk_sd = {settings.random_walk_sd for settings in estimation.parameters.values()}
    paths = results.folder(SEARCH).table("if2")
    finals = results.folder(SEARCH).table("maximum_likelihood").sort_values("log_likelihood", ascending=False)
    starts = paths[paths["iteration"] == 0].set_index("replicate")
    passes = int(paths["iteration"].max())
    rows, below = [], f"below {target:g}"
    for _, row in finals.iterrows():
        start = starts.loc[row["replicate"]]
        rows.append({"replicate": int(row["replicate"]), "log L̂ ± se": f"{row['log_likelihood']:.1f} ± "
                     f"{row['log_likelihood_se']:.1f}", below: f"{target - row['log_likelihood']:.1f}",
                     **{column: f"{_value(row[column])} ({_value(start[column])})" for column in columns}})
    rows.append({"replicate": "He et al.", "log L̂ ± se": f"{target:.1f} ± {published_error:.2f}", below: "",
                 **{column: _value(float(mle[column])) if column in mle else "" for column in columns}})
    dimension = len(columns)
    depth = likelihood_ratio_tolerance(dimension)
    best = finals.iloc[0]
    gap = target - float(best["log_likelihood"])
    tolerance = depth + Z_LIMIT * math.hypot(float(best["log_likelihood_se"]), published_error)
    within = int(((target - finals["log_likelihood"]) <= tolerance).sum())
    cooled = estimation.cooling_fraction_50 ** (passes / 50)
    items = [
        Text("### IF2 from the twenty towns' box\n\n"
             f"IF2 estimated He et al.'s {dimension} parameters (`mu` and the initial fractions held at the published "
             f"values) from {len(finals)} starts drawn uniformly over the smallest box holding He et al.'s estimates "
             f"for their twenty towns: {passes} passes of the bootstrap filter with "
             f"{config['filter']['particles']:,} particles, every particle carrying its own parameters on a random "
             f"walk of sd {' or '.join(f'{sd:g}' for sd in sorted(walk_sd))} a week (log "
             f"scale; logit for the shares), cooled to {' or '.join(f'{sd * cooled:.3g}' for sd in sorted(walk_sd))} by the last pass. Each replicate's "
             f"log-likelihood: {estimation.evaluations} unperturbed runs at its estimate (maximum_likelihood.csv)."),
        Table(f"IF2's estimates after {passes} passes, best first (start in brackets), beside He et al.'s MLE",
              markdown_table(pd.DataFrame(rows)),
              f"The likelihood-ratio depth for {dimension} parameters, ½ χ²_{dimension}(0.95), is {depth:.2f}: a "
              f"point less than this below the maximum lies inside the maximum-likelihood estimate's 95% "
              f"confidence region. The verdict's tolerance adds {Z_LIMIT:g} standard errors of the difference "
              f"of the two Monte Carlo estimates: {tolerance:.2f} for the best replicate.")]
    if "if2_convergence.png" in results.figures(SEARCH):
        items.append(Figure(SEARCH, "if2_convergence.png",
                            "Each replicate's path of estimates and of the filter's log-likelihood, pass by pass"))
    evidence = (f"the best replicate ({int(best['replicate'])}) ends at log L̂ = {best['log_likelihood']:.2f} ± "
                f"{best['log_likelihood_se']:.2f}, {gap:.2f} below the published {target:g} (tolerance {tolerance:.2f}: "
                f"{depth:.2f} + {Z_LIMIT:g} standard errors; 1.92, one parameter's depth, would "
                f"{'also hold' if gap <= 1.92 else 'not'}); {within} of {len(finals)} replicates end within the "
                f"tolerance, the worst {target - float(finals['log_likelihood'].min()):.1f} below")
    if results.has(LIKELIHOOD):
        own = estimate_numbers(results.folder(LIKELIHOOD).trials)
        largest = own.index.max()
        evidence += (f"; pfx's own log-mean-exp at the published parameters is {own.loc[largest, 'log_mean_exp']:.2f} "
                     f"(N = {largest:,}), so the best replicate is "
                     f"{own.loc[largest, 'log_mean_exp'] - float(best['log_likelihood']):.2f} below it")
    claim = facts.get("search", {}).get("claim", "IF2 from the twenty towns' box reaches He et al.'s maximum")
    return Part(items, [Verdict(claim, verdict_from_checks([gap <= tolerance]), evidence + ".")])
