r"""summary.csv: per cell, the statistics of every metric over its trials, with 95% intervals.

Only finite values count (``n`` says how many): a never-converged trial has no convergence
step. For every metric: ``n``, ``mean``, ``std`` (with n - 1), ``sem``, the 95% interval of the
mean ``ci95_low``/``ci95_high``, and ``median``.

**The interval** respects the range of values the metric can take, which its column declares
(:data:`pfx.analysis.value_ranges.METRIC_RANGES`: RMSE, error distances, NEES, ESS, counts and run
times are nonnegative; ``converged`` is a share):

* a metric of any sign, or one whose t-interval lies inside its range: the **t-interval**
  :math:`\bar x \pm t_{0.975,\,n-1}\, s / \sqrt n`;
* a bounded metric whose t-interval reaches past a bound (a final error of 40.5 with
  :math:`t s / \sqrt n = 53.8`: [-13.4, 94.3]): the **t-interval cut at the bound**, [0, 94.3]. The
  true mean lies in the metric's range, so removing the part of an interval outside it never
  removes the true mean: the cut interval covers it exactly as often as the t-interval does
  (the intersection of a confidence set with the parameter space; Mandelkern 2002, section 2).
  The mean of values inside the range is inside it, so the cut interval is never empty. Where
  the t-interval already respects the range, nothing changes;
* a **share** (a yes/no per trial, ``converged``): the **Wilson score interval** of k successes
  in n trials (Wilson 1927; ``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")``),
  which lies in [0, 1] by construction and does not collapse to a point when every trial (or
  none) succeeded, where the t-interval of a 0/1 variable (the Wald interval) is [1, 1] or
  [0, 0]; Brown, Cai and DasGupta (2001) recommend it for small n.

All three are closed forms: the same trials give the same interval to the last bit.

**Too few values for an interval.** With fewer than :data:`MINIMUM_VALUES` = 6 values the
interval is empty (and the terminal table says "no CI"). The number is the smallest n for
which any distribution-free 95% statement about the centre of the values exists: the widest
such interval, from the smallest value to the largest, covers the median with probability
:math:`1 - 2 \cdot 2^{-n}`, which is 0.9375 for n = 5 and 0.969 for n = 6 (the sign-test
interval). Below that, a 95% interval would rest wholly on assuming the values normal, which
errors, counts and times are not (two trials gave a final error of 161.7 [-1740, 2063]).

**The log of the mean likelihood.** Beside the statistics of ``log_likelihood`` (over its
finite values), two columns summarise the likelihood estimates as the particle-filtering
field reports them (pomp's ``logmeanexp(ll, se = TRUE)``,
:func:`pfx.numerics.log_mean_exp.log_mean_exp_jackknife`): ``log_mean_likelihood``,
:math:`\log \frac1n \sum_t e^{\ell_t}` over the cell's n trials with a log-likelihood (a
particle filter's likelihood estimate is unbiased, its log is not, so the estimates are
averaged before the log is taken; a trial whose estimate is zero, -inf, counts as a zero), and
``log_mean_likelihood_se``, its jackknife standard error (empty for one trial). A Kalman filter's
log-likelihood is exact: its trials on the same data agree, so the column equals the mean and
the standard error is 0, which is what there is to say. The average is of one likelihood
only where the trials filter the same data (recorded data, ``datasets: 1``); over trials of
independent simulated datasets it averages the likelihoods of different data, which estimates
no one likelihood: compare such cells by ``log_likelihood_mean``. The columns are computed in
every cell with a log-likelihood (this table cannot tell how its trials' data were made);
``pfx run``'s end-of-run table shows them only where the trials share their data.

References: E. B. Wilson, "Probable inference, the law of succession, and statistical
inference", JASA 22 (1927) 209-212; L. D. Brown, T. T. Cai, A. DasGupta, "Interval estimation
for a binomial proportion", Statistical Science 16 (2001) 101-133; M. Mandelkern, "Setting
confidence intervals for bounded parameters", Statistical Science 17 (2002) 149-172.
"""

from __future__ import annotations

import math
from itertools import count
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import stdtrit

from pfx.analysis.value_ranges import ANY_VALUE, ValueRange, metric_range
from pfx.numerics.log_mean_exp import log_mean_exp_jackknife

if TYPE_CHECKING:          # pandas is imported where a table is read
    import pandas as pd

CONFIDENCE = 0.95
# The fewest values an interval is computed from: the smallest n whose range (smallest to
# largest value) covers the median with probability CONFIDENCE whatever the distribution.
MINIMUM_VALUES = next(n for n in count(1) if 1 - 2 * 0.5 ** n >= CONFIDENCE)

# trials.csv columns that are identifiers or settings, not metrics to summarise
NON_METRIC_COLUMNS = {"cell", "trial", "seed", "truth_seed", "filter_seed", "steps"}
LOG_LIKELIHOOD = "log_likelihood"              # the metric whose likelihoods are also averaged (below)
LOG_MEAN_LIKELIHOOD = "log_mean_likelihood"    # summary.csv's column of that average, and _se


def summarize(trials: pd.DataFrame, label_columns: list[str]) -> pd.DataFrame:
    """One row per cell: n, mean, std, sem, 95% interval (module docstring) and median of every metric."""
    import pandas as pd

    keys = ["cell"] + [c for c in label_columns if c != "cell"]
    metrics = [c for c in trials.columns if c not in NON_METRIC_COLUMNS and c not in keys
               and (pd.api.types.is_numeric_dtype(trials[c]) or pd.api.types.is_bool_dtype(trials[c]))]
    rows = []
    for _, group in trials.groupby("cell", sort=False):
        row = {key: group[key].iloc[0] for key in keys}
        row["trials"] = len(group)
        for metric in metrics:
            values = group[metric].to_numpy(dtype=float)
            row.update({f"{metric}_{name}": value
                        for name, value in describe(values[np.isfinite(values)], metric_range(metric)).items()})
            if metric == LOG_LIKELIHOOD:
                row.update(log_mean_likelihood(values))
        rows.append(row)
    return pd.DataFrame(rows)


def log_mean_likelihood(log_likelihoods: np.ndarray) -> dict[str, float]:
    """The log of the mean of a cell's likelihood estimates and its jackknife standard error
    (pomp's ``logmeanexp(ll, se = TRUE)``, module docstring), over every trial with a
    log-likelihood: a -inf (a zero estimate) counts as zero, an empty field (none computed) not at all."""
    estimate, standard_error = log_mean_exp_jackknife(log_likelihoods[~np.isnan(log_likelihoods)])
    return {LOG_MEAN_LIKELIHOOD: estimate, f"{LOG_MEAN_LIKELIHOOD}_se": standard_error}


def describe(values: np.ndarray, value_range: ValueRange = ANY_VALUE) -> dict[str, float]:
    """n, mean, std, sem, 95% interval and median of the values (module docstring): the
    t-interval, cut at the bounds of ``value_range``, or Wilson's for a share; empty when there
    are fewer than MINIMUM_VALUES values."""
    n = values.size
    result = {"n": n, "mean": np.nan, "std": np.nan, "sem": np.nan,
              "ci95_low": np.nan, "ci95_high": np.nan, "median": np.nan}
    if n == 0:
        return result
    result["mean"] = float(values.mean())
    result["median"] = float(np.median(values))
    if n >= 2:
        with np.errstate(over="ignore", invalid="ignore"):   # a diverged filter: std is inf
            std = float(values.std(ddof=1))
        result.update(std=std, sem=std / np.sqrt(n))
    if n >= MINIMUM_VALUES:
        if value_range.share:
            low, high = wilson_interval(int(values.sum()), n)
        else:
            half = float(t_quantile(0.975, n - 1)) * result["sem"]
            low, high = cut_to_range(result["mean"] - half, result["mean"] + half, value_range)
        result.update(ci95_low=float(low), ci95_high=float(high))
    return result


def t_quantile(probability, degrees_of_freedom):
    """The quantile of Student's t at ``0 < probability < 1`` (element-wise; NaN where the degrees
    of freedom are not positive): ``scipy.stats.t.ppf(probability, degrees_of_freedom)`` to the
    last bit, for that is how scipy.stats computes it. scipy.special instead of scipy.stats, which
    would add half a second to the start of every ``pfx run``."""
    return stdtrit(degrees_of_freedom, probability)


def cut_to_range(low, high, value_range: ValueRange):
    """An interval's ends moved inside ``value_range`` where they lie beyond it (element-wise;
    NaN stays NaN): the t-interval cut at the metric's bounds (module docstring)."""
    if value_range.low > -math.inf:
        low = np.where(low < value_range.low, value_range.low, low)
    if value_range.high < math.inf:
        high = np.where(high > value_range.high, value_range.high, high)
    return low, high


def wilson_interval(successes: int, n: int) -> tuple[float, float]:
    """The 95% Wilson score interval of a share: ``successes`` of ``n`` (module docstring)."""
    from scipy import stats

    interval = stats.binomtest(successes, n).proportion_ci(confidence_level=CONFIDENCE, method="wilson")
    return float(interval.low), float(interval.high)
