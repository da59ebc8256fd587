r"""measles-london: He et al.'s (2010) measles in London, the benchmarks' gallery section.

The benchmark is described in docs/benchmarks/measles-london.md: the 730 weekly measles
reports of London (1950-1963, with He et al.'s correction of one week) under their SEIR model
(7 daily substeps a week of Poisson births with a school-entry cohort, Euler-multinomial exits
and gamma white noise on the term-time force of infection; the week's recoveries accumulated
and reset at each report; population and delayed births read as covariates), filtered at the
published maximum-likelihood parameters by the bootstrap filter at N = 2000 (``measles``).

The report gives the log-likelihood estimate's mean over the runs with its 95% interval, its
standard deviation, its log-mean-exp :math:`\log \frac1R \sum_r \hat L_r` and the time per run,
beside pypomp's own filter run on this machine (``reference_run`` in paper.yaml). Verdicts:

* the published -3804.9: the runs' log-mean-exp within :func:`published_tolerance` of it, the
  likelihood-ratio allowance of paper.yaml (half the 95% point of chi-squared with one degree
  of freedom, 1.92: the scale of He et al.'s own confidence intervals) plus three standard errors
  of the difference of the two Monte Carlo estimates;
* the reference implementation: the difference of the two means within
  :data:`~pfx.papers.likelihood_runs.Z_LIMIT` standard errors of the difference (independent
  runs: the standard errors add in quadrature).

The per-week log-likelihood increments (steps_summary.csv) name the weeks the model explains
worst: the figure and :data:`WORST_WEEKS` of them in a table. The search for the maximum by IF2
from a box of starting points (``if2``) is :mod:`pfx.papers.measles_search`'s part.
"""

from __future__ import annotations

import datetime
import math

import numpy as np
import pandas as pd

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
    verdict_from_checks,
)
from pfx.papers.likelihood_runs import Z_LIMIT, agreement_verdict, estimate_numbers
from pfx.papers.measles_search import search_part

BENCHMARK = "measles-london"
EXPERIMENT = "measles"
WORST_WEEKS = 5
ORIGIN, DAYS_PER_YEAR = 1950.0, 365.25       # pomp's time: 1950 + days since 1950-01-01 / 365.25


def published_tolerance(published: dict, standard_error: float) -> float:
    """How far pfx's log-mean-exp may lie from the published log-likelihood (paper.yaml's
    ``published``): the likelihood-ratio allowance (what two implementations may build
    differently from the same records, on the scale of the paper's own confidence intervals)
    plus :data:`~pfx.papers.likelihood_runs.Z_LIMIT` standard errors of the difference of two
    Monte Carlo estimates (the published one's and ours, ``standard_error``, in quadrature)."""
    return float(published.get("likelihood_ratio_allowance", math.nan)) + Z_LIMIT * math.hypot(
        float(published.get("standard_error", math.nan)), standard_error)


def week_date(time: float) -> str:
    """The report date (YYYY-MM-DD) of a week's decimal time, pomp's 1950 + days / 365.25."""
    days = int(round((time - ORIGIN) * DAYS_PER_YEAR))
    return (datetime.date(1950, 1, 1) + datetime.timedelta(days=days)).isoformat()


def _interval(low: float, high: float) -> str:
    return interval(low, high, number=lambda value: f"{value:.2f}")


def _reference_cell(theirs) -> str:
    return "" if theirs is None else f"{format_number(theirs['mean'], 6)} ± {format_number(theirs['standard_error'], 2)}"


def likelihood_part(results: PaperResults) -> Part:
    if not results.has(EXPERIMENT):
        return Part()
    facts = results.numbers
    published = facts.get("published", {})
    target = float(published.get("log_likelihood", math.nan))
    allowance = float(published.get("likelihood_ratio_allowance", math.nan))
    published_error = float(published.get("standard_error", math.nan))
    ours = estimate_numbers(results.folder(EXPERIMENT).trials)
    reference = {int(row["particles"]): row for row in facts.get("reference_run", {}).get("results", [])}
    rows = []
    for particles, row in ours.iterrows():
        theirs = reference.get(particles)
        rows.append({"N": particles, "pfx runs": row["runs"],
                     "pfx mean log L̂ [95% CI]": f"{row['mean']:.2f} {_interval(row['low'], row['high'])}",
                     "pfx sd": row["sd"], "pfx log-mean-exp": format_number(row["log_mean_exp"], 6),
                     "pfx s per run": row["seconds"],
                     "pypomp mean ± se": _reference_cell(theirs),
                     "pypomp sd": np.nan if theirs is None else theirs["sd"],
                     "pypomp log-mean-exp": "" if theirs is None else format_number(theirs["log_mean_exp"], 6),
                     "pypomp s per run": np.nan if theirs is None else theirs["seconds"]})
    table = pd.DataFrame(rows).sort_values("N")
    software = facts.get("reference_run", {}).get("software", {})
    items = [Text(
        "### The log-likelihood at the maximum-likelihood parameters\n\n"
        f"He et al. report log L = {format_number(target, 6)} for London's 730 weeks at their maximum-likelihood "
        "parameters, from pomp's particle filter. pfx runs the model as a plugin (`examples/plugins/"
        "he10_measles.py`, written on pfx's documented interfaces and count draws) on the reports with He et al.'s "
        "correction of one week, with the bootstrap filter resampling systematically every week, as pomp does; "
        "every run filters the same data, so the runs' spread is the Monte Carlo error of the estimate. pypomp's own "
        f"filter (JAX, 32-bit floats) ran on this machine for the reference (pypomp {software.get('pypomp', '?')}; "
        "times exclude JAX's compilation)."),
        Table("Log-likelihood estimates at the MLE, pfx beside pypomp", markdown_table(table, digits=3),
              "The mean of log L̂ lies below log L by about half its variance (Jensen's inequality); the "
              "log-mean-exp is the log of the unbiased estimate of L averaged over the runs. Times: wall seconds "
              "per filter run; pfx runs a cell's trials as one batch, and its time per run is the batch's share. "
              "pypomp's were measured once (the benchmark's paper.yaml), pfx's at each reproduction, on shared "
              "2-core machines whose load varies: their ratio is rough (docs/benchmarks/measles-london.md "
              "gives one measured in a single session).")]

    verdicts = []
    if math.isfinite(target) and len(ours):
        largest = ours.index.max()
        row = ours.loc[largest]
        gap = row["log_mean_exp"] - target
        tolerance = published_tolerance(published, row["se"])
        verdicts.append(Verdict(
            f"log L = {format_number(target, 6)} at the MLE (He et al. 2010; the log-mean-exp at N = {largest} within "
            f"{tolerance:.2f}: {allowance:g}, the likelihood-ratio allowance, plus "
            f"{Z_LIMIT:g} standard errors of the difference)", verdict_from_checks([abs(gap) <= tolerance]),
            f"pfx's log-mean-exp over {int(row['runs'])} runs at N = {largest} is "
            f"{format_number(row['log_mean_exp'], 6)}, {format_number(gap, 2)} from the published value "
            f"(standard errors {format_number(row['se'], 2)} and {format_number(published_error, 2)}); "
            f"the mean is {row['mean']:.2f} {_interval(row['low'], row['high'])}."))
    pairs = {particles: (ours.loc[particles, "mean"], ours.loc[particles, "se"], reference[particles]["mean"],
                         reference[particles]["standard_error"]) for particles in ours.index if particles in reference}
    if pairs:
        verdicts.append(agreement_verdict(
            "pfx's filter agrees with pypomp's on the same model, data and parameters (reference implementation)",
            "pfx - pypomp", pairs))
    return Part(items, verdicts)


def weeks_part(results: PaperResults) -> Part:
    if not results.has(EXPERIMENT):
        return Part()
    steps = results.folder(EXPERIMENT).steps_summary
    largest = steps[steps["n_particles"] == steps["n_particles"].max()]
    worst = largest.nsmallest(WORST_WEEKS, "log_likelihood_increment_mean")
    increments = largest["log_likelihood_increment_mean"]
    low, median, high = np.percentile(increments, [10, 50, 90])
    table = pd.DataFrame([{"week": week_date(row["time"]), "step": int(row["step"]),
                           "mean log-likelihood increment": row["log_likelihood_increment_mean"]}
                          for _, row in worst.iterrows()])
    items = [Text("### Where the model and the reports disagree\n\n"
                  "Each week's log-likelihood increment, log p̂(y_k | y_1:k-1), averaged over the runs "
                  "(steps.csv's `log_likelihood_increment`; steps_summary.csv's mean): a week far below the "
                  "others is one the model did not expect."),
             Table(f"The {WORST_WEEKS} weeks the model explains worst (N = {int(worst['n_particles'].iloc[0])})",
                   markdown_table(table, digits=4),
                   f"Over all {len(increments)} weeks the median increment is {median:.2f} and 80% lie between "
                   f"{low:.2f} and {high:.2f}; their sum is the log-likelihood.")]
    if "log_likelihood_increment_over_time.png" in results.figures(EXPERIMENT):
        items.append(Figure(EXPERIMENT, "log_likelihood_increment_over_time.png",
                            "Each week's log-likelihood increment, mean over the runs with its 95% band; "
                            "the lowest week ringed"))
    return Part(items, [])


PARTS = (likelihood_part, weeks_part, search_part)


@REPORTS.register(BENCHMARK)
def report(results: PaperResults) -> Section:
    items, verdicts = assemble(results, PARTS)
    facts = results.numbers
    summary = (f"{facts.get('title', 'Measles in London')}. He et al.'s SEIR model as a pfx plugin: 7 daily "
               "substeps a week (`model.substeps`) drawing whole individuals (`pfx.euler_multinomial`, "
               "`pfx.gamma_white_noise`, Poisson births), population and births read at every substep "
               "(`data.covariates`), the week's recoveries accumulated between reports (`accumulating_components`). "
               "Setup and sources: [docs/benchmarks/measles-london.md](../../docs/benchmarks/measles-london.md).")
    return Section(BENCHMARK, "He et al.'s measles in London (pomp's He10 model)", summary, items, verdicts)
