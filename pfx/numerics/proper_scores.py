r"""Proper scores of a predictive distribution against the value that came: CRPS, the energy
score, the log score, and the probability integral transform (PIT).

A filter's one-step-ahead predictive distribution of the measurement :math:`z_k` given
:math:`z_{1:k-1}` is, for a particle filter, the mixture :math:`\sum_i w_i\, p(z_k \mid x_{k,i})`
over the predicted particles; pfx represents it by one draw :math:`\tilde z_i \sim p(z \mid
x_{k,i})` per particle, with the particle's weight :math:`w_i` (normalised). The scores below
are the standard sample forms of that weighted sample (Gneiting & Raftery 2007, JASA 102;
Ferro 2014 and Zamo & Naveau 2018 for the fair forms). Every score is negatively oriented: the
smaller, the better the forecast.

* **CRPS** of a scalar :math:`y`, energy form:
  :math:`\mathrm{CRPS}(F, y) = E_F|Z - y| - \tfrac12 E_F|Z - Z'|`. The sample form weighs the
  first term by :math:`w_i` and the second, over the pairs :math:`i \ne j`, by
  :math:`w_i w_j / (1 - \sum_i w_i^2)`: the *fair* estimator, unbiased for the CRPS of the law
  the draws come from (with equal weights, :math:`\frac{1}{N(N-1)} \sum_{i \ne j}`). The
  pairwise sum is computed exactly in :math:`O(N \log N)` from the sorted draws:
  :math:`\sum_{i,j} w_i w_j |z_i - z_j| = 2 \sum_i w_{(i)} z_{(i)} (2 W_{(i)} - w_{(i)} - 1)`,
  with :math:`W_{(i)}` the cumulative weight up to the i-th smallest draw.
* **Energy score** of a vector :math:`y` (the CRPS's multivariate form):
  :math:`E_F\lVert Z - y\rVert - \tfrac12 E_F\lVert Z - Z'\rVert`. Its pairwise term has no
  sorting shortcut, so it is averaged over the pairs :math:`(i, i + s \bmod N)` for
  :data:`ENERGY_SHIFTS` offsets :math:`s` spread evenly over :math:`1..N-1` (every offset, hence
  every pair :math:`i \ne j`, when :math:`N \le` ``ENERGY_SHIFTS + 1``), weighted by
  :math:`w_i w_{i+s}`: the fair estimator on a subset of its pairs, :math:`O(N)` per offset.
* **PIT**: :math:`F(y)`, the predictive probability of a value at most :math:`y`, estimated by
  :math:`\sum_i w_i [\tilde z_i < y] + V \sum_i w_i [\tilde z_i = y]` with :math:`V` uniform on
  (0, 1): the *randomised* PIT, uniform on (0, 1) for a calibrated forecast also when the
  measurement is discrete (counts), where ties have positive probability (Czado, Gneiting &
  Held 2009). For a continuous law ties do not happen and it is the plain PIT.
* **Log score**: :math:`-\log p(y)`, the predictive density at the value that came; for a filter
  it is minus the log-likelihood increment :math:`L_k` (:mod:`pfx.filters.trace`), so it needs
  nothing here.

For a Gaussian predictive law :math:`N(\mu, \sigma^2)` the exact forms are
:func:`gaussian_crps` (:math:`\sigma[z(2\Phi(z) - 1) + 2\varphi(z) - 1/\sqrt\pi]`,
:math:`z = (y - \mu)/\sigma`) and :math:`\mathrm{PIT} = \Phi(z)` (:func:`gaussian_pit`): the
Kalman filters' scores, and the checks of the sample forms.

The functions take a batch of trials first: draws ``(R, N)`` (or ``(R, N, m)``), weights
``(R, N)`` normalised, values ``(R,)`` (or ``(R, m)``), and return ``(R,)``. They are written
against the array namespace (:func:`pfx.numerics.arrays.namespace`), so the JAX backend runs
them compiled, inside its step.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pfx.numerics.arrays import namespace, special_functions

ENERGY_SHIFTS = 16          # the particle-index offsets the energy score's pairwise term averages over


def sample_crps(draws: Any, weights: Any, value: Any) -> Any:
    r"""The fair CRPS of the weighted sample ``draws`` (R, N) against ``value`` (R,) (module
    docstring): :math:`\sum_i w_i |z_i - y| - \frac{1}{2(1 - \sum_i w_i^2)} \sum_{i \ne j} w_i w_j |z_i - z_j|`."""
    xp = namespace(draws, weights)
    centred = draws - value[:, None]                   # the score is invariant to a shift: keeps sums small
    first = xp.sum(weights * xp.abs(centred), axis=-1)
    order = xp.argsort(centred, axis=-1)
    sorted_draws = xp.take_along_axis(centred, order, axis=-1)
    sorted_weights = xp.take_along_axis(weights, order, axis=-1)
    cumulative = xp.cumsum(sorted_weights, axis=-1)
    pairwise = 2.0 * xp.sum(sorted_weights * sorted_draws * (2.0 * cumulative - sorted_weights - 1.0), axis=-1)
    distinct_pairs = 1.0 - xp.sum(weights * weights, axis=-1)     # sum over i != j of w_i w_j
    return first - 0.5 * pairwise / distinct_pairs


def energy_shifts(particles: int) -> np.ndarray:
    """The offsets s of the pairs (i, i + s mod N) the energy score averages over: every one of
    1..N-1 when there are at most :data:`ENERGY_SHIFTS` of them, else that many spread evenly."""
    if particles - 1 <= ENERGY_SHIFTS:
        return np.arange(1, particles)
    return np.unique(np.round(np.linspace(1, particles - 1, ENERGY_SHIFTS)).astype(int))


def sample_energy_score(draws: Any, weights: Any, value: Any) -> Any:
    r"""The energy score of the weighted sample ``draws`` (R, N, m) against ``value`` (R, m)
    (module docstring): :math:`\sum_i w_i \lVert z_i - y \rVert` minus half the weighted mean of
    :math:`\lVert z_i - z_{i+s} \rVert` over the pairs of :func:`energy_shifts`."""
    xp = namespace(draws, weights)
    centred = draws - value[:, None, :]
    first = xp.sum(weights * xp.sqrt(xp.sum(centred * centred, axis=-1)), axis=-1)
    distances, pair_weights = 0.0, 0.0
    for shift in energy_shifts(draws.shape[1]).tolist():
        partner = xp.roll(centred, -shift, axis=1)
        partner_weights = weights * xp.roll(weights, -shift, axis=1)
        difference = centred - partner
        distances = distances + xp.sum(partner_weights * xp.sqrt(xp.sum(difference * difference, axis=-1)), axis=-1)
        pair_weights = pair_weights + xp.sum(partner_weights, axis=-1)
    return first - 0.5 * distances / pair_weights


def sample_pit(draws: Any, weights: Any, value: Any, uniform: Any) -> Any:
    r"""The randomised PIT of ``value`` (R,) under the weighted sample ``draws`` (R, N):
    :math:`\sum_i w_i [z_i < y] + V \sum_i w_i [z_i = y]`, ``uniform`` (R,) the draws of V."""
    xp = namespace(draws, weights)
    below = xp.sum(xp.where(draws < value[:, None], weights, 0.0), axis=-1)
    tied = xp.sum(xp.where(draws == value[:, None], weights, 0.0), axis=-1)
    return below + uniform * tied


def weighted_moments(draws: Any, weights: Any) -> tuple[Any, Any]:
    """The weighted mean and standard deviation of each component of ``draws`` (R, N, m)."""
    xp = namespace(draws, weights)
    mean = xp.sum(weights[..., None] * draws, axis=1)
    centred = draws - mean[:, None, :]
    return mean, xp.sqrt(xp.sum(weights[..., None] * centred * centred, axis=1))


def gaussian_crps(mean: Any, sd: Any, value: Any) -> Any:
    r"""The exact CRPS of :math:`N(\mu, \sigma^2)` at :math:`y`:
    :math:`\sigma [z (2\Phi(z) - 1) + 2 \varphi(z) - 1/\sqrt{\pi}]`, :math:`z = (y - \mu)/\sigma`."""
    xp = namespace(mean, sd, value)
    special = special_functions(xp)
    z = (value - mean) / sd
    cdf = 0.5 * special.erfc(-z / math.sqrt(2.0))
    density = xp.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    return sd * (z * (2.0 * cdf - 1.0) + 2.0 * density - 1.0 / math.sqrt(math.pi))


def gaussian_pit(mean: Any, sd: Any, value: Any) -> Any:
    r"""The PIT of :math:`y` under :math:`N(\mu, \sigma^2)`: :math:`\Phi((y - \mu)/\sigma)`."""
    xp = namespace(mean, sd, value)
    return 0.5 * special_functions(xp).erfc(-(value - mean) / (sd * math.sqrt(2.0)))
