"""Operations on a weighted particle cloud, batched over trials.

A cloud is an array of states (R, N, d) for R trials of N particles, with normalised weights
(R, N). Here: its weighted mean (the estimate, :func:`posterior_mean`), the gather that
resampling does (:func:`resample_rows`, one compiled pass), and the uniform weights of an
adaptive count's active particles (:func:`active_uniform`). The normalisation of log-weights and
the effective sample size live in :mod:`pfx.numerics.log_weights` (the histogram filter uses them too).
"""

from __future__ import annotations

import numpy as np

from pfx.numerics.angles import circular_mean
from pfx.numerics.arrays import namespace, with_values
from pfx.numerics.compiled import compiled


def weighted_mean(weights: np.ndarray, particles: np.ndarray) -> np.ndarray:
    """sum_i w_i x_i per trial: (R, N), (R, N, d) -> (R, d).

    A (1 x N) by (N x d) matrix product per trial: BLAS does it about ten times faster than
    ``einsum`` (which loops over the short last axis d).
    """
    return np.matmul(weights[:, None, :], particles)[:, 0, :]


def resample_rows(state: np.ndarray, rows: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """The resampled particles of the given trials: out[r, i] = state[rows[r], indices[r, i]].

    One compiled pass (:func:`gather_particles`): NumPy's ``take_along_axis`` on (R, N, d)
    costs several times more.
    """
    # Every trial resampled: the same memory layout as the state (models may keep each state
    # component contiguous, see Noise.sample).
    out = np.empty_like(state) if len(rows) == len(state) else np.empty((len(rows),) + state.shape[1:])
    gather_particles(state, np.asarray(rows, dtype=np.intp), indices, out)
    return out


@compiled
def gather_particles(state, rows, indices, out):
    """out[r, i, :] = state[rows[r], indices[r, i], :]."""
    dimension = state.shape[2]
    for r in range(rows.size):
        source = rows[r]
        for c in range(dimension):           # component by component: contiguous writes when
            for i in range(indices.shape[1]):    # the state keeps its components contiguous
                out[r, i, c] = state[source, indices[r, i], c]


def posterior_mean(model, weights, particles):
    """The estimate: the weighted mean, with the model's angular components (if any) averaged
    on the circle (:func:`pfx.numerics.angles.circular_mean`). NumPy or JAX arrays: NumPy takes
    BLAS's product (:func:`weighted_mean`), JAX an ``einsum``."""
    xp = namespace(weights, particles)
    mean = weighted_mean(weights, particles) if xp is np else xp.einsum("rn,rnd->rd", weights, particles)
    angular = list(model.angular_components)
    if angular:
        mean = with_values(mean, (slice(None), angular), circular_mean(weights, particles[..., angular],
                                                                        model.full_turn))
    return mean


def active_uniform(counts: np.ndarray, maximum: int) -> tuple[np.ndarray, np.ndarray]:
    """(log-weights, weights) uniform over the first ``counts[r]`` particles of each row
    (log 1/n, 1/n), -inf and 0 past them: an adaptive count's inactive particles."""
    xp = namespace(counts)         # NumPy or JAX counts (the jax driver's carried ones)
    active = xp.arange(maximum) < counts[:, None]
    # in float64: JAX takes the log of an int32 array in float32, even in a float64 run
    counts = counts.astype(np.float64)
    uniform = 1.0 / counts[:, None]
    return xp.where(active, -xp.log(counts)[:, None], -np.inf), xp.where(active, uniform, 0.0)
