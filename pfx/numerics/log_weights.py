r"""Weights in the log domain: normalisation by log-sum-exp, and the effective sample size.

A particle filter (and the histogram filter, whose grid weights are the same thing) keeps
:math:`\log \tilde w_i`, never :math:`\tilde w_i`: likelihoods of many measurements underflow.
Normalising a row shifts it by its maximum before exponentiating, so no entry overflows and the
largest weight is exactly representable:

.. math::

    m = \max_i \log \tilde w_i, \quad S = \sum_i e^{\log \tilde w_i - m}, \quad
    \log w_i = \log \tilde w_i - m - \log S, \quad L = m + \log S = \log \sum_i \tilde w_i .

The effective sample size of normalised weights is :math:`\mathrm{ESS} = 1 / \sum_i w_i^2`
(N for equal weights, 1 when one particle holds all the weight), computed here and nowhere else.
"""

from __future__ import annotations

import numpy as np

from pfx.numerics.arrays import is_jax_array, namespace


def log_normalise(log_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise log-sum-exp normalisation; returns (normalised log-weights, log normaliser).

    A row whose entries are all -inf has normaliser -inf and is returned unchanged.
    """
    normalised, _, normaliser = normalise_weights(log_weights)
    return normalised, normaliser


def normalise_weights(log_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Log-sum-exp normalisation, row by row: (log w, w, L).

    With :math:`m = \max_i \log \tilde w_i` and :math:`S = \sum_i e^{\log \tilde w_i - m}`:
    :math:`\log w_i = \log \tilde w_i - m - \log S`, :math:`w_i = e^{\log \tilde w_i - m} / S`
    (the exponentials are computed once, for the sum and the weights) and
    :math:`L = m + \log S`. A row whose entries are all -inf has L = -inf, log-weights
    unchanged and weights 0. A JAX array (traced: no shortcut that depends on the values) takes
    :func:`masked_normalise`, the same arithmetic.
    """
    if is_jax_array(log_weights):
        return masked_normalise(log_weights)
    with np.errstate(under="ignore", over="ignore", invalid="ignore", divide="ignore"):
        return normalise_rows(log_weights)


def normalise_rows(log_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`normalise_weights` without its ``np.errstate`` (the engine's loop sets it once)."""
    peak = np.max(log_weights, axis=-1, keepdims=True)
    # The common case first, without the masks a row of -inf needs: the same arithmetic, a few
    # NumPy calls fewer (each costs about a microsecond, at every step of a small filter). A
    # finite normaliser means a finite peak and a finite log(total); anything else is redone below.
    shifted = log_weights - peak
    weights = np.exp(shifted)
    total = np.sum(weights, axis=-1, keepdims=True)
    log_total = np.log(total)
    normaliser = (log_total + peak)[..., 0]
    if np.isfinite(normaliser).all():
        shifted -= log_total
        weights /= total
        return shifted, weights, normaliser
    return masked_normalise(log_weights, peak)


def masked_normalise(log_weights, peak=None):
    """:func:`normalise_weights` for rows that may be all -inf or hold +inf, on NumPy or JAX
    arrays (``peak``: the rows' maxima, if already taken); a finite row's numbers are those
    of the common case."""
    xp = namespace(log_weights)
    if peak is None:
        peak = xp.max(log_weights, axis=-1, keepdims=True)
    finite_peak = xp.where(xp.isfinite(peak), peak, 0.0)
    shifted = log_weights - finite_peak
    weights = xp.exp(shifted)
    total = xp.sum(weights, axis=-1, keepdims=True)
    log_total = xp.log(total)
    usable = xp.isfinite(log_total)
    # Subtract the shift and log(total) separately: peak + log(total) loses log(total) to
    # rounding when |peak| > ~1e16.
    shifted = shifted - xp.where(usable, log_total, 0.0)
    weights = weights / xp.where(usable, total, 1.0)
    return shifted, weights, (log_total + finite_peak)[..., 0]


def effective_sample_size(weights: np.ndarray) -> np.ndarray:
    """ESS = 1 / sum_i w_i^2 for normalised weights, per row (NumPy or JAX arrays)."""
    if is_jax_array(weights):
        xp = namespace(weights)
        return 1.0 / xp.sum(weights * weights, axis=-1)
    return 1.0 / np.einsum("rn,rn->r", weights, weights)
