"""Statistics of paired values: the same trial measured under a baseline and under another value.

Trial t of every cell of a run sees the same true trajectory and measurements, so a metric's
value in trial t under two settings forms a pair, and their difference removes the trial-to-trial
variation of the truth (common random numbers). ``pfx compare`` (:mod:`pfx.analysis.compare`)
matches the pairs and reports these statistics for each; the paper reports and figures reuse
them on their own pairs:

* :func:`statistics_of_pairs`: the columns of a comparison row (below);
* :func:`relative_change_interval`: the relative change of paired means with its delta-method
  t-interval;
* :func:`diverged`: which error values say "diverged" rather than how large the error is;
* :func:`holm_adjusted`: Holm's adjustment of a family of p-values.

**Relative change.** It is divided by the *absolute value* of the baseline mean, here and in
:func:`relative_change_interval`, so that its sign is always the sign of the difference: a
value below the baseline is a negative change, whatever the baseline's sign. (Dividing by a
negative baseline mean, a log-likelihood of -130, would turn a lower, worse log-likelihood
into a positive change.) ``higher_is_better`` (``--higher-is-better``) changes only ``better``
and the wins and losses, never the sign of a difference or of a change.

* **Exclusions.** A pair is used only when both values are finite: a missing value (a trial
  that never converged has no ``convergence_step``) or an infinite one (a diverged filter's
  error is written as ``inf``) in either arm excludes the pair, and ``excluded_pairs`` counts
  them (``pfx compare`` adds any trial present on one side only). Mind that this can favour an
  arm that diverges or fails to converge more often: look at ``excluded_pairs``, and compare
  ``converged`` (True = 1) itself.
* **Interval.** ``ci_method`` ``t``: the 95% t-interval of the mean paired difference,
  ``mean +- t(0.975, n - 1) * sd / sqrt(n)`` (sd with n - 1); ``bootstrap-B``
  (``--bootstrap B``): the 2.5 and 97.5 percentiles of the means of B resamples (with
  replacement) of the paired differences, drawn from ``numpy.random.default_rng(BOOTSTRAP_SEED)``
  afresh for each row, so a row's interval depends only on its own pairs and the same table
  always gives the same intervals (with few pairs, a dozen or less, the percentile bootstrap
  is too narrow: prefer the t-interval there). Empty with fewer than 2 pairs.
* **p-value.** Two-sided paired t-test (the one-sample t-test of the differences against 0,
  identical to ``scipy.stats.ttest_rel``), whatever the interval method. When all differences
  are equal (sd = 0) the interval is [mean, mean] and the p-value its limit: 1 if the
  differences are all 0, else 0.
* **Wins.** ``wins`` counts the pairs in which the compared value did better than the
  baseline: a *lower* metric value, unless ``higher_is_better`` (``better`` says which);
  ``losses`` the opposite, ``ties`` exactly equal values.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from pfx.analysis.value_ranges import ANY_VALUE, ValueRange

BOOTSTRAP_SEED = 20240611          # the fixed seed of every bootstrap interval
BOOTSTRAP_CHUNK = 1000             # resamples drawn at once (bounds memory; same result whatever the count)


def statistics_of_pairs(base: np.ndarray, value: np.ndarray, higher_is_better: bool,
                        bootstrap: Optional[int], seed: int) -> dict[str, Any]:
    """Statistics of the pairs (base[i], value[i]); a missing (NaN) or infinite value excludes a pair."""
    usable = np.isfinite(base) & np.isfinite(value)
    base, value = base[usable], value[usable]
    differences = value - base
    n = differences.size
    result: dict[str, Any] = {
        "n_pairs": n, "excluded_pairs": int((~usable).sum()), "baseline_mean": np.nan, "mean": np.nan,
        "mean_difference": np.nan, "relative_change": np.nan, "ci95_low": np.nan, "ci95_high": np.nan,
        "ci_method": "t" if bootstrap is None else f"bootstrap-{bootstrap}", "p_value": np.nan,
        "better": "higher" if higher_is_better else "lower"}
    better = differences > 0 if higher_is_better else differences < 0
    worse = differences < 0 if higher_is_better else differences > 0
    result.update(wins=int(better.sum()), losses=int(worse.sum()), ties=int((differences == 0).sum()))
    if n == 0:
        return result
    mean_difference = float(differences.mean())
    baseline_mean = float(base.mean())
    # divided by |baseline mean|: the change has the sign of the difference even when the
    # baseline is negative (a log-likelihood); see the module docstring
    result.update(baseline_mean=baseline_mean, mean=float(value.mean()), mean_difference=mean_difference,
                  relative_change=mean_difference / abs(baseline_mean) if baseline_mean != 0 else np.nan)
    if n < 2:
        return result
    from scipy import stats

    sd = float(differences.std(ddof=1))
    if sd == 0 or not np.isfinite(sd):
        low = high = mean_difference
        p_value = 1.0 if mean_difference == 0 else 0.0
    else:
        sem = sd / math.sqrt(n)
        half = float(stats.t.ppf(0.975, n - 1)) * sem
        low, high = mean_difference - half, mean_difference + half
        p_value = float(2 * stats.t.sf(abs(mean_difference / sem), n - 1))
    if bootstrap is not None:
        low, high = _bootstrap_interval(differences, bootstrap, seed)
    result.update(ci95_low=low, ci95_high=high, p_value=p_value)
    return result


def _bootstrap_interval(differences: np.ndarray, resamples: int, seed: int) -> tuple[float, float]:
    """Percentile bootstrap: the 2.5 and 97.5 percentiles of the resampled means."""
    rng = np.random.default_rng(seed)
    n = differences.size
    means = np.empty(resamples)
    for start in range(0, resamples, BOOTSTRAP_CHUNK):
        count = min(BOOTSTRAP_CHUNK, resamples - start)
        means[start:start + count] = differences[rng.integers(0, n, size=(count, n))].mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return float(low), float(high)


def relative_change_interval(base: np.ndarray, value: np.ndarray, level: float = 0.95,
                             value_range: ValueRange = ANY_VALUE) -> tuple[float, float, float]:
    r"""Relative change of paired means, :math:`(\bar v - \bar b) / |\bar b|`, with its t-interval.

    For a positive baseline mean this is :math:`\hat R - 1` with :math:`\hat R = \bar v / \bar b`;
    for a negative one it is :math:`-(\hat R - 1)`, so that the change always has the sign of
    :math:`\bar v - \bar b` (module docstring, "Relative change"). The ratio :math:`\hat R` of
    the means of paired values is a smooth function of two correlated means; to first order
    (the delta method), :math:`\hat R - R \approx \tfrac{1}{\bar b}\,\overline{(v - R b)}`, so its
    standard error (and that of the change, which differs from it by a sign at most) is
    :math:`s_e / (\sqrt n\, |\bar b|)` with :math:`s_e` the standard deviation of the residuals
    :math:`e_i = v_i - \hat R b_i`. The interval is the estimate
    :math:`\pm\, t_{(1+\text{level})/2,\,n-1}\, s_e / (\sqrt n\, |\bar b|)`. Unlike dividing the
    interval of the mean difference by :math:`|\bar b|`, it accounts for the uncertainty of the
    baseline mean too. Pairs with a missing or infinite value are left out. For a nonnegative
    metric (``value_range``, :data:`pfx.analysis.value_ranges.METRIC_RANGES`) the ratio of means is
    at least 0, so the change is at least -100%: the interval is cut there, which never removes
    the true change (as summary.csv's intervals are cut, :mod:`pfx.analysis.summary`).
    Returns (estimate, low, high); NaN where there are fewer than 2 pairs or :math:`\bar b = 0`.
    """
    from scipy import stats

    base, value = np.asarray(base, dtype=float), np.asarray(value, dtype=float)
    usable = np.isfinite(base) & np.isfinite(value)
    base, value = base[usable], value[usable]
    n = base.size
    if n < 2 or base.mean() == 0:
        return math.nan, math.nan, math.nan
    ratio = value.mean() / base.mean()
    residuals = value - ratio * base
    half = float(stats.t.ppf(0.5 + level / 2, n - 1)) * residuals.std(ddof=1) / (math.sqrt(n) * abs(base.mean()))
    change = (value.mean() - base.mean()) / abs(base.mean())     # = ratio - 1 for a positive baseline
    low = change - half
    if value_range.low >= 0 and low < -1.0:
        low = -1.0
    return change, low, change + half


def diverged(values: np.ndarray, reference: np.ndarray, factor: float = 1000.0) -> np.ndarray:
    """True where an error metric (an RMSE) is infinite, missing, or above ``factor`` times the
    median of the finite ``reference`` values (a working filter's errors on the same trials):
    the estimate has left the scale of the problem, so the value says "diverged", not how much.
    """
    values = np.asarray(values, dtype=float)
    reference = np.asarray(reference, dtype=float)
    finite = reference[np.isfinite(reference)]
    bound = factor * float(np.median(finite)) if finite.size else math.inf
    with np.errstate(invalid="ignore"):
        return ~np.isfinite(values) | (values > bound)


def holm_adjusted(p_values) -> np.ndarray:
    """Holm's step-down adjustment of a family of p-values (family-wise error control).

    With the m p-values sorted, p_(1) <= .. <= p_(m): adjusted_(k) = max over j <= k of
    min(1, (m - j + 1) p_(j)). Rejecting where the adjusted value is below alpha keeps the
    chance of any false rejection in the family below alpha (Holm 1979). Missing values stay
    missing and do not count in m.
    """
    p_values = np.asarray(p_values, dtype=float)
    adjusted = np.full(p_values.shape, np.nan)
    present = np.flatnonzero(np.isfinite(p_values))
    order = present[np.argsort(p_values[present], kind="stable")]
    m = order.size
    running = 0.0
    for rank, index in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p_values[index]))
        adjusted[index] = running
    return adjusted
