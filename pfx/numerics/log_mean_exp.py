r"""The log of a mean of likelihoods, from their logarithms: how replicate runs of a particle
filter are summarised, with two standard errors.

A particle filter's likelihood estimate :math:`\hat L` is unbiased for :math:`L = p(z_{1:T})`;
its logarithm :math:`\hat\ell = \log \hat L` is not (it is biased low, by Jensen). So R
independent runs on the same data are averaged on the natural scale and the average is logged,

.. math::

    \operatorname{lme}(\ell_1..\ell_R) = \log \frac1R \sum_r e^{\ell_r}
    = m + \log \frac1R \sum_r e^{\ell_r - m}, \qquad m = \max_r \ell_r,

computed with the shift by the maximum (no likelihood of a long record is representable as
a float: :math:`e^{-3800}` underflows). This is pomp's ``logmeanexp`` (King, Nguyen & Ionides,
*J. Stat. Softw.* 69, 2016). A run whose estimate is zero (:math:`\ell_r = -\infty`: every
particle weight underflowed at some step) counts as zero in the mean; when every run's is zero
the mean is zero and its log :math:`-\infty`. A NaN gives NaN.

**Its standard error** comes in two forms, each used where it fits:

* :func:`log_mean_exp_jackknife`, pomp's ``logmeanexp(x, se = TRUE)``: the jackknife over the
  runs. With :math:`\operatorname{lme}_{-i}` the log-mean-exp of the runs without run i,

  .. math::

      \mathrm{se} = \sqrt{\frac{R-1}{R} \sum_i \big(\operatorname{lme}_{-i} - \overline{\operatorname{lme}_{-\cdot}}\big)^2}

  (pomp writes it :math:`(R-1)\,\mathrm{sd}(\operatorname{lme}_{-\cdot})/\sqrt R`, the same
  number). It needs no assumption on the estimates' distribution, and it is NaN for one run
  (nothing to leave out) and where leaving a run out leaves only zero likelihoods (one run
  carries the whole mean: its spread cannot be judged), as pomp's is. The R leave-one-out
  sums are found from the one total, :math:`S - e^{\ell_i - m}`, in O(R): that difference loses
  no precision (it is at least the largest term, 1, which it keeps) except for the largest run
  itself, whose leave-one-out value is computed again from the others.
* :func:`log_mean_likelihood`, the delta method, row by row: with :math:`w_r = e^{\ell_r - m}`,
  :math:`\mathrm{se} \approx \mathrm{sd}(w) / (\bar w \sqrt R)`, the relative standard error of
  the mean likelihood. IF2 reports it for its few evaluations per replicate
  (:mod:`pfx.estimation.if2`).

Both give the same estimate. summary.csv reports the jackknife's
(``log_mean_likelihood``, ``log_mean_likelihood_se``: :mod:`pfx.analysis.summary`).
"""

from __future__ import annotations

import math

import numpy as np


def log_mean_exp(values: np.ndarray, axis: int = -1) -> np.ndarray:
    r""":math:`\log \frac1R \sum_r e^{v_r}` along ``axis`` (module docstring): -inf where every
    value is -inf, +inf where one is +inf, NaN where one is NaN."""
    values = np.asarray(values, dtype=float)
    top = np.max(values, axis=axis, keepdims=True)
    usable = np.isfinite(top)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.exp(values - np.where(usable, top, 0.0)).mean(axis=axis)
        top = np.squeeze(top, axis=axis)
        return np.where(np.squeeze(usable, axis=axis), top + np.log(mean), top)


def log_mean_exp_jackknife(values: np.ndarray) -> tuple[float, float]:
    """(log-mean-exp, its jackknife standard error) of the 1-D ``values``: pomp's
    ``logmeanexp(x, se = TRUE)`` (module docstring). (NaN, NaN) for no values; the standard
    error is NaN for one value, for an estimate that is not finite, and where a leave-one-out
    value is -inf."""
    values = np.asarray(values, dtype=float).ravel()
    runs = values.size
    if runs == 0:
        return math.nan, math.nan
    estimate = float(log_mean_exp(values))
    if runs == 1 or not math.isfinite(estimate):
        return estimate, math.nan
    top = float(values.max())
    terms = np.exp(values - top)
    total = terms.sum()
    with np.errstate(divide="ignore"):
        left_out = top + np.log((total - terms) / (runs - 1))
    largest = int(np.argmax(values))
    left_out[largest] = float(log_mean_exp(np.delete(values, largest)))
    if not np.isfinite(left_out).all():
        return estimate, math.nan
    # Deviations from the first value, then from their mean: equal values give exactly 0.
    shifted = left_out - left_out[0]
    deviations = shifted - shifted.mean()
    return estimate, float(math.sqrt((runs - 1) / runs * float(np.sum(deviations * deviations))))


def log_mean_likelihood(log_likelihood: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Per row of K log-likelihood estimates (R, K): :math:`\log \frac1K \sum_k \hat L_k` and its
    standard error by the delta method (NaN for K = 1). A row whose every estimate is zero has
    -inf, and no standard error."""
    runs = log_likelihood.shape[1]
    top = log_likelihood.max(axis=1, keepdims=True)
    zero = ~np.isfinite(top[:, 0])
    ratios = np.exp(log_likelihood - np.where(zero[:, None], 0.0, top))
    mean = ratios.mean(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        log_mean = np.where(zero, -np.inf, log_mean_exp(log_likelihood, axis=1))
        standard_error = ratios.std(axis=1, ddof=1) / mean / np.sqrt(runs) if runs > 1 else np.full(len(mean), np.nan)
    return log_mean, np.where(zero, np.nan, standard_error)
