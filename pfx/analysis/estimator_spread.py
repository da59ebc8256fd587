r"""The spread of an estimator for fixed data: repeated filter runs on the same dataset.

With the config key ``datasets`` the trials of a cell share simulated datasets (trial ``t``
filters dataset ``t mod datasets``; ``truth_seed`` in trials.csv names it), so the trials of one
dataset are independent repetitions of the filter on the same measurements; with recorded data
(``data:``) every trial is a repetition on the one dataset. Their spread is the
filter's own Monte Carlo error, without the variation of the data. For a statistic
:math:`\hat\ell` (the log-likelihood estimate, by default) of a cell with datasets
:math:`d = 1..D` holding :math:`n_d` runs each, the pooled within-dataset variance is

.. math::

    s^2 = \frac{\sum_d \sum_r (\hat\ell_{d,r} - \bar\ell_d)^2}{\nu}, \qquad \nu = \sum_d (n_d - 1),

and, for normally distributed runs (the log-likelihood estimate is asymptotically normal in
the particle count), :math:`\nu s^2 / \sigma^2 \sim \chi^2_\nu`: its 95% interval is
:math:`[\nu s^2 / \chi^2_{\nu, 0.975},\ \nu s^2 / \chi^2_{\nu, 0.025}]`. Two cells run with
independent filter streams compare by the ratio of their variances, whose 95% interval is
:math:`[r / F_{0.975}(\nu_1, \nu_2),\ r / F_{0.025}(\nu_1, \nu_2)]` with
:math:`r = s_1^2 / s_2^2` (:func:`variance_ratio_interval`).

Mind the normality: a filter whose weights collapse now and then gives a heavy left tail of
:math:`\hat\ell`, and these intervals are then too narrow (the point estimates stay valid).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

__all__ = ["within_dataset_spread", "variance_ratio_interval"]

SPREAD_COLUMNS = ("runs", "datasets", "degrees_of_freedom", "mean", "variance", "variance_ci95_low",
                  "variance_ci95_high", "sd")


def within_dataset_spread(trials: pd.DataFrame, label_columns: list[str],
                          metric: str = "log_likelihood", *, one_dataset: bool = False) -> pd.DataFrame:
    """One row per cell (its ``label_columns``): the pooled within-dataset variance of ``metric``.

    Datasets are told apart by ``truth_seed``, or, with ``one_dataset`` (a run on recorded
    data, whose trials all filter the same measurements), every trial of a cell is a run on the
    one dataset; non-finite values are left out. Columns: the
    labels, then ``runs``, ``datasets``, ``degrees_of_freedom`` (:math:`\\nu`), ``mean``,
    ``variance`` with its 95% interval, ``sd``. A cell with no dataset run twice has no
    variance (NaN).
    """
    from scipy import stats

    rows = []
    labels = [c for c in label_columns if c in trials]
    for key, cell in trials.groupby("cell", sort=False):
        values = cell[metric].to_numpy(dtype=float)
        usable = cell[np.isfinite(values)]
        dataset = np.zeros(len(usable), dtype=int) if one_dataset else usable["truth_seed"].to_numpy()
        by_dataset = usable.groupby(dataset)[metric]
        squares = float(by_dataset.apply(lambda v: float(((v - v.mean()) ** 2).sum())).sum()) if len(usable) else 0.0
        freedom = int((by_dataset.size() - 1).clip(lower=0).sum()) if len(usable) else 0
        variance = squares / freedom if freedom > 0 else math.nan
        low = high = math.nan
        if freedom > 0:
            low = freedom * variance / float(stats.chi2.ppf(0.975, freedom))
            high = freedom * variance / float(stats.chi2.ppf(0.025, freedom))
        row = {column: cell[column].iloc[0] for column in labels}
        row.update(runs=len(usable), datasets=int(len(set(dataset))), degrees_of_freedom=freedom,
                   mean=float(usable[metric].mean()) if len(usable) else math.nan, variance=variance,
                   variance_ci95_low=low, variance_ci95_high=high, sd=math.sqrt(variance))
        rows.append(row)
    return pd.DataFrame(rows, columns=labels + list(SPREAD_COLUMNS))


def variance_ratio_interval(variance: float, freedom: int, baseline_variance: float,
                            baseline_freedom: int) -> tuple[float, float, float]:
    """``variance / baseline_variance`` with its 95% F-interval (independent normal samples)."""
    from scipy import stats

    if not (freedom > 0 and baseline_freedom > 0 and baseline_variance > 0 and math.isfinite(variance)):
        return math.nan, math.nan, math.nan
    ratio = variance / baseline_variance
    return (ratio, ratio / float(stats.f.ppf(0.975, freedom, baseline_freedom)),
            ratio / float(stats.f.ppf(0.025, freedom, baseline_freedom)))
