r"""Resampling: draw N offspring indices from normalised weights, for many trials at once.

Every scheme here is the inverse of the cumulative weights :math:`C_j = \sum_{i \le j} w_i`
evaluated at N sorted points in [0, 1); the schemes differ only in how those points are drawn:

============  ================================================================  ==========
name          sorted points u_1 <= ... <= u_N                                     unbiased
============  ================================================================  ==========
multinomial   order statistics of N iid U(0,1), in O(N) by exponential spacings  yes
stratified    u_i = (i - 1 + V_i) / N, V_i iid U(0, 1)                            yes
systematic    u_i = (i - 1 + V) / N, one V ~ U(0, 1) (han-lee Algorithm II,      yes
              Probabilistic Robotics' low-variance sampler)
residual      floor(N w_j) copies, then the rest multinomially from the           yes
              residual weights (N w_j - floor(N w_j)) / R
han_lee_iv    the N smallest of N + 1 sorted uniforms (han-lee Algorithm IV as     **no**
              printed)
============  ================================================================  ==========

Unbiased means :math:`E[N_j] = N w_j` for the offspring count :math:`N_j`. Algorithm IV is kept
verbatim to show its bias: the N smallest of N + 1 uniforms are not the order statistics of N
uniforms, and :math:`E[N_j] = (N+1) w_j - (C_j^{N+1} - C_{j-1}^{N+1})`
(:func:`han_lee_iv_expected_counts`). Residual resampling subtracts the copies from
:math:`N w_j`, not from :math:`w_j` (the bug of filterpy issue 290).

Each resampler has the signature ``resampler(weights, random) -> indices`` with ``weights`` of
shape (trials, N) (rows sum to 1) and ``random`` a :class:`~pfx.numerics.seeding.TrialStreams` with one
stream per row; ``indices`` has shape (trials, N).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from pfx.filters.backends import BOTH, Backends
from pfx.numerics.compiled import compiled
from pfx.numerics.seeding import TrialStreams
from pfx.registry import Registry


def inverse_cdf(weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Indices j with C_{j-1} <= u < C_j for each point u, row by row.

    The points of every resampler are sorted, so one merged pass over the cumulative weights
    and the points finds them all: O(N) per row instead of a binary search per point
    (:func:`inverse_cdf_walk`). Unsorted points are still handled exactly (the walk restarts
    where a point is smaller than the one before).

    Round-off guard: the cumulative weights are set to exactly 1 from the last particle with
    positive weight onward, so a point just below 1 never falls past the end nor onto a
    trailing zero-weight particle; zero-weight particles are never selected.
    """
    weights = np.ascontiguousarray(weights, dtype=float)
    points = np.ascontiguousarray(points, dtype=float)
    indices = np.empty(points.shape, dtype=np.intp)
    inverse_cdf_walk(weights, points, indices)
    return indices


@compiled
def inverse_cdf_walk(weights, points, indices):
    """The loop of :func:`inverse_cdf`: C_j = w_0 + ... + w_j summed left to right (as
    ``numpy.cumsum``), C_j = 1 from the last positive weight on; index = min{j : C_j > u},
    or N - 1 if there is none (the result of ``searchsorted(C, u, 'right')`` clipped to N - 1).
    """
    rows, n = weights.shape
    count = points.shape[1]
    for row in range(rows):
        last_positive = n - 1
        while last_positive >= 0 and not weights[row, last_positive] > 0.0:
            last_positive -= 1
        if last_positive < 0:            # no positive weight (the engine never resamples such a row)
            last_positive = n - 1
        j = 0
        cumulative = 1.0 if last_positive == 0 else weights[row, 0]
        previous = -np.inf
        for i in range(count):
            u = points[row, i]
            if u < previous:             # unsorted points: walk again from the start
                j = 0
                cumulative = 1.0 if last_positive == 0 else weights[row, 0]
            previous = u
            while j < n - 1 and cumulative <= u:
                j += 1
                cumulative = 1.0 if j >= last_positive else cumulative + weights[row, j]
            indices[row, i] = j


def sorted_uniforms(random: TrialStreams, count: int) -> np.ndarray:
    """Order statistics of ``count`` iid U(0, 1) per row, in O(count) by exponential spacings.

    With E_1..E_{n+1} iid Exp(1) and S_k their partial sums, (S_1, ..., S_n) / S_{n+1} are
    distributed as the sorted sample of n uniforms.
    """
    spacings = random.standard_exponential((count + 1,))
    sums = np.cumsum(spacings, axis=-1)
    return sums[:, :count] / sums[:, count:]


def multinomial(weights: np.ndarray, random: TrialStreams) -> np.ndarray:
    """Multinomial resampling: N iid draws from the weights (sorted uniforms, O(N))."""
    return inverse_cdf(weights, sorted_uniforms(random, weights.shape[-1]))


def stratified(weights: np.ndarray, random: TrialStreams) -> np.ndarray:
    """Stratified resampling: one uniform in each of the N strata [(i-1)/N, i/N)."""
    n = weights.shape[-1]
    return inverse_cdf(weights, (np.arange(n) + random.uniform((n,))) / n)


def systematic(weights: np.ndarray, random: TrialStreams) -> np.ndarray:
    """Systematic resampling (han-lee Algorithm II): one uniform offset shared by all strata."""
    n = weights.shape[-1]
    return inverse_cdf(weights, (np.arange(n) + random.uniform((1,))) / n)


def residual(weights: np.ndarray, random: TrialStreams) -> np.ndarray:
    """Residual resampling: floor(N w) copies, the rest multinomially from the residuals."""
    n = weights.shape[-1]
    scaled = n * weights
    copies = np.floor(scaled).astype(np.intp)
    remaining = np.maximum(n - copies.sum(axis=-1), 0)
    indices = np.empty(weights.shape, dtype=np.intp)
    for row in range(weights.shape[0]):
        kept = np.repeat(np.arange(n), copies[row])
        count = int(remaining[row])
        if count:
            residual_weights = (scaled[row] - copies[row])[None, :]
            residual_weights /= residual_weights.sum()
            extra = inverse_cdf(residual_weights, sorted_uniforms(random.subset([row]), count))[0]
            kept = np.concatenate([kept, extra])
        indices[row] = kept[:n]
    return indices


def han_lee_iv(weights: np.ndarray, random: TrialStreams) -> np.ndarray:
    """han-lee Algorithm IV verbatim: the N smallest of N+1 sorted uniforms (BIASED)."""
    n = weights.shape[-1]
    points = np.sort(random.uniform((n + 1,)), axis=-1)[:, :n]
    return inverse_cdf(weights, points)


def han_lee_iv_expected_counts(weights: np.ndarray) -> np.ndarray:
    """E[N_j] under Algorithm IV: (N+1) w_j - (C_j^(N+1) - C_(j-1)^(N+1))."""
    weights = np.asarray(weights, dtype=float)
    n = weights.shape[-1]
    cumulative = np.cumsum(weights, axis=-1)
    cumulative[..., -1] = 1.0
    previous = np.concatenate([np.zeros(weights.shape[:-1] + (1,)), cumulative[..., :-1]], axis=-1)
    return (n + 1) * weights - (cumulative ** (n + 1) - previous ** (n + 1))


def offspring_counts(indices: np.ndarray, n: int) -> np.ndarray:
    """Offspring count of each particle, per row: shape (trials, n)."""
    rows = indices.shape[0]
    flat = indices + n * np.arange(rows)[:, None]
    return np.bincount(flat.ravel(), minlength=rows * n).reshape(rows, n)


@dataclass(frozen=True)
class Resampler:
    function: Callable[[np.ndarray, TrialStreams], np.ndarray]
    unbiased: bool
    backends: Backends = Backends(what="the resampler")

    def __call__(self, weights, random):
        return self.function(weights, random)


RESAMPLERS: Registry[Resampler] = Registry("resampler")
for _function in (multinomial, stratified, systematic, residual):
    RESAMPLERS.add(_function.__name__, Resampler(_function, unbiased=True, backends=Backends(BOTH)),
                   _function.__doc__.splitlines()[0])
RESAMPLERS.add("han_lee_iv", Resampler(han_lee_iv, unbiased=False, backends=Backends(BOTH)),
               "BIASED: han-lee Algorithm IV as printed (N smallest of N+1 sorted uniforms)")


@dataclass(frozen=True)
class Resampling:
    """The resampling stage's rule: which trials resample at a step, and with which resampler.

    A trial resamples when its ESS falls below ``threshold`` times its particle count (N, or
    its active count with an adaptive count): 1 resamples every step, 0 never (``sis``).
    """

    resampler: Resampler
    threshold: float

    def rows(self, ess: np.ndarray, particles: int, active: np.ndarray | None = None) -> np.ndarray:
        """The trials (indices) whose ESS is below the threshold."""
        if self.threshold >= 1.0:
            return np.arange(len(ess))
        if self.threshold > 0.0:
            count = particles if active is None else active
            return np.flatnonzero(ess < self.threshold * count)
        return np.empty(0, dtype=np.intp)

    def indices(self, weights: np.ndarray, random: TrialStreams) -> np.ndarray:
        """Each trial's N ancestor indices, drawn from its normalised weights (R, N)."""
        return self.resampler(weights, random)
