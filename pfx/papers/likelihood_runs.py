r"""Repeated runs of a particle filter's log-likelihood estimate, summarised per particle count:
what the likelihood benchmarks (dacca-cholera, measles-london) set beside the published value
and a reference implementation's runs.

For the runs :math:`\hat\ell_1..\hat\ell_R` of one N: their mean with its 95% t-interval, the
standard deviation and the mean's standard error, and the log-mean-exp
:math:`\log \frac1R \sum_r e^{\hat\ell_r}`, the log of the average of the unbiased estimates of
:math:`L` (pomp's own summary of replicates, :mod:`pfx.numerics.log_mean_exp`); and the mean wall time
per run. Two sets of independent runs agree (:func:`agreement_verdict`) when, at every N both
ran, the difference of their means lies within :data:`Z_LIMIT` standard errors of the
difference, the two standard errors added in quadrature.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from pfx.analysis.summary import describe
from pfx.numerics.log_mean_exp import log_mean_exp
from pfx.papers.base import Verdict, format_number, verdict_from_checks

Z_LIMIT = 3.0              # standard errors of a difference beyond which two means disagree


def estimate_numbers(trials: pd.DataFrame) -> pd.DataFrame:
    """Per N (trials.csv's ``n_particles``): the runs' log-likelihood estimates summarised (module
    docstring), indexed by N."""
    rows = []
    for particles, group in trials.groupby("n_particles"):
        values = group["log_likelihood"].to_numpy(dtype=float)
        statistics = describe(values)
        sd = float(np.std(values, ddof=1))
        rows.append({"N": int(particles), "runs": len(values), "mean": statistics["mean"],
                     "low": statistics["ci95_low"], "high": statistics["ci95_high"], "sd": sd,
                     "se": sd / math.sqrt(len(values)), "log_mean_exp": float(log_mean_exp(values)),
                     "seconds": float(group["run_time_s"].mean())})
    return pd.DataFrame(rows).set_index("N")


def agreement_verdict(claim: str, label: str, pairs: dict[int, tuple[float, float, float, float]]) -> Verdict:
    """Whether two sets of independent runs agree at every N (module docstring): ``pairs`` maps N
    to (first mean, its standard error, second mean, its standard error); ``label`` names the
    difference in the evidence ("pfx - pypomp")."""
    checks, evidence = [], []
    for particles, (first, first_error, second, second_error) in pairs.items():
        difference = first - second
        error = math.hypot(first_error, second_error)
        checks.append(abs(difference) <= Z_LIMIT * error)
        evidence.append(f"N = {particles}: {label} = {format_number(difference, 2)} "
                        f"(standard error {format_number(error, 2)}, z = {difference / error:.1f})")
    return Verdict(claim, verdict_from_checks(checks), "; ".join(evidence) + f" (|z| <= {Z_LIMIT:g} asked).")
