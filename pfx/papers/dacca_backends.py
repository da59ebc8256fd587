r"""dacca-cholera on both backends: the jax backend's runs beside the numpy backend's.

The ``dacca-jax`` experiment (configs/benchmarks/dacca-cholera/dacca-jax.yaml) is ``dacca``'s
filter compiled by JAX, in 32-bit floats: the same model, data, parameters, particle counts and
number of runs, with its own random numbers (each run's threefry key), so its estimates are
independent of the numpy backend's and agree with them in distribution only.

Verdicts:

* the published -3748.6 by pypomp's own test, as for numpy (:mod:`pfx.papers.dacca_cholera`):
  the jax runs' log-mean-exp at N = 1000 within ``published.tolerance`` (2.5) of it;
* the two backends: at every N both ran, the difference of their mean log-likelihood
  estimates within :data:`~pfx.papers.likelihood_runs.Z_LIMIT` standard errors of the difference
  (independent runs: the standard errors add in quadrature).
"""

from __future__ import annotations

import math

import pandas as pd

from pfx.papers.base import PaperResults, Part, Table, Text, Verdict, format_number, markdown_table, verdict_from_checks
from pfx.papers.likelihood_runs import agreement_verdict, estimate_numbers

NUMPY, JAX = "dacca", "dacca-jax"
GATED_PARTICLES = 1000       # pypomp's test reads the runs at N = 1000


def _row(backend: str, particles: int, numbers: pd.Series) -> dict:
    return {"backend": backend, "N": particles, "runs": int(numbers["runs"]),
            "mean log L̂ ± se": f"{numbers['mean']:.2f} ± {numbers['se']:.2f}", "sd": numbers["sd"],
            "log-mean-exp": format_number(numbers["log_mean_exp"], 6), "s per run": numbers["seconds"]}


def backends_part(results: PaperResults) -> Part:
    if not results.has(JAX):
        return Part()
    published = results.numbers.get("published", {})
    target, tolerance = float(published.get("log_likelihood", math.nan)), float(published.get("tolerance", math.nan))
    compiled = estimate_numbers(results.folder(JAX).trials)
    numpy_runs = estimate_numbers(results.folder(NUMPY).trials) if results.has(NUMPY) else None
    rows = []
    for particles, numbers in compiled.iterrows():
        if numpy_runs is not None and particles in numpy_runs.index:
            rows.append(_row("numpy (float64)", particles, numpy_runs.loc[particles]))
        rows.append(_row("jax (float32)", particles, numbers))
    items = [Text("### The same filter on the jax backend\n\n"
                  "`dacca-jax.yaml` runs the filter above compiled by JAX in 32-bit floats (pypomp's precision): the "
                  "20 substeps of a month, the covariates and the month's accumulated deaths inside one compiled "
                  "scan. Its runs draw from their own threefry keys, so they are independent of the numpy runs."),
             Table("Log-likelihood estimates at the MLE on the two backends", markdown_table(pd.DataFrame(rows), digits=3),
                   "Times: wall seconds per run, each run's share of its batch of 40, the jax backend's "
                   "compilation included. The time of a run without the compilation, beside pypomp's in one "
                   "session, is in docs/benchmarks/measles-london.md (\"Time per run\").")]
    verdicts = []
    if GATED_PARTICLES in compiled.index and math.isfinite(target):
        gap = compiled.loc[GATED_PARTICLES, "log_mean_exp"] - target
        verdicts.append(Verdict(
            f"log L = {format_number(target, 6)} at the MLE on the jax backend in 32-bit floats (pypomp's test: "
            f"log-mean-exp at N = {GATED_PARTICLES} within {format_number(tolerance)})",
            verdict_from_checks([abs(gap) <= tolerance]),
            f"the jax runs' log-mean-exp over {int(compiled.loc[GATED_PARTICLES, 'runs'])} runs at N = "
            f"{GATED_PARTICLES} is {format_number(compiled.loc[GATED_PARTICLES, 'log_mean_exp'], 6)}, "
            f"{format_number(gap, 2)} from the published value."))
    pairs = {} if numpy_runs is None else {
        particles: (compiled.loc[particles, "mean"], compiled.loc[particles, "se"], numpy_runs.loc[particles, "mean"],
                    numpy_runs.loc[particles, "se"]) for particles in compiled.index if particles in numpy_runs.index}
    if pairs:
        verdicts.append(agreement_verdict("the jax backend (32-bit floats) agrees with the numpy backend on the same "
                                          "model, data and parameters", "jax - numpy", pairs))
    return Part(items, verdicts)
