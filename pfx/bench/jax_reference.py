r"""The plain JAX bootstrap filter ``pfx bench --backend jax`` compares pfx's jax backend with.

The JAX counterpart of :mod:`pfx.bench.reference`: the filter a person writes in JAX in about
sixty lines, on the same falling body (:class:`~pfx.bench.problem.FallingBodyProblem`).

* ``jax.lax.scan`` over the steps, ``jax.vmap`` over the trials, one compiled function per
  (trials, N, T, precision);
* the particles as three component arrays of length N (structure of arrays: what a GPU reads
  best), propagated, then weighted in the log domain, :math:`\log w_i = -\tfrac12 ((z - h(x_i))
  / \sigma)^2`, shifted by the maximum before the exponential;
* the estimate :math:`\hat x = \sum_i w_i x_i / \sum_i w_i`, and the log-likelihood increment
  :math:`\log \hat p(z_t \mid z_{1:t-1}) = \max_i \log w_i + \log \sum_i e^{\log w_i - \max} - \log N
  + c`, with :math:`c = -\log\sigma - \tfrac12\log 2\pi` (:attr:`FallingBodyProblem.log_likelihood_constant`;
  the constants added once, outside the compiled function);
* systematic resampling at every step: the offsets :math:`(i + u)/N` searched
  (``jnp.searchsorted``) in the normalised cumulative weights. The cumulative sum and the offsets
  are float64 in both precisions: in float32 a cumulative sum of 1e5 or more weights drifts by more
  than the gap between offsets, which biases the offspring counts (Murray, Lee and Jacob 2016);
* threefry keys per trial from the trial's filter seed
  (:func:`pfx.numerics.key_streams.threefry_keys`, what ``jax.random.PRNGKey(seed)`` makes):
  the prior draws from ``fold_in(key, 0)``, step t from ``fold_in(key, t)`` (its process noise
  from ``fold_in(., 0)``, its resampling offset from ``fold_in(., 1)``).

The filter turns JAX's 64-bit types on while it runs (``jax.enable_x64``, as pfx's jax backend
does): float32 is asked for by ``precision``, never by leaving float64 off. This module is
imported by the JAX benchmark and its tests only, so it imports JAX at the top.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from pfx.bench.problem import FallingBodyProblem
from pfx.numerics.key_streams import threefry_keys

PRECISIONS = {"float64": np.float64, "float32": np.float32}


def jax_reference_filter(problem: FallingBodyProblem, measurements: np.ndarray, particles: int,
                         seeds: Sequence[int], precision: str = "float64") -> tuple[np.ndarray, np.ndarray]:
    """Estimates (trials, T, 3) and log-likelihoods (trials,) of the trials whose measurements
    are ``measurements`` (trials, T, 1), trial r drawing from the key of ``seeds[r]``."""
    with jax.enable_x64(True):          # float64 sums in both precisions (module docstring)
        dtype = PRECISIONS[precision]
        constants = {name: jnp.asarray(value, dtype) for name, value in _constants(problem).items()}
        estimates, log_likelihoods = _batched_filter(constants, jnp.asarray(threefry_keys(seeds)),
                                                     jnp.asarray(measurements[..., 0], dtype), particles)
    steps = measurements.shape[1]
    return (np.asarray(estimates, dtype=np.float64),
            np.asarray(log_likelihoods) + steps * (problem.log_likelihood_constant - math.log(particles)))


def _constants(problem: FallingBodyProblem) -> dict:
    """The model's numbers, passed to the compiled filter as arguments (not baked into it)."""
    return {"dt": problem.dt, "radar_distance": problem.radar_distance, "radar_altitude": problem.radar_altitude,
            "half_density": problem.half_density, "scale_height": problem.scale_height, "gravity": problem.gravity,
            "process_std": problem.process_std, "measurement_std": problem.measurement_std,
            "prior_mean": problem.prior_mean, "prior_std": problem.prior_std}


@partial(jax.jit, static_argnames="particles")
def _batched_filter(constants: dict, keys, measurements, particles: int):
    return jax.vmap(lambda key, trial: _one_trial(constants, key, trial, particles))(keys, measurements)


def _one_trial(c: dict, key, measurements, particles: int):
    """One trial: (estimates (T, 3), the sum over the steps of max log w + log sum e^(log w - max))
    from its key and measurements (T,); the caller adds the constants, T (c - log N)."""
    dtype = measurements.dtype
    prior = jax.random.normal(jax.random.fold_in(key, 0), (3, particles), dtype)
    state = c["prior_mean"][:, None] + c["prior_std"][:, None] * prior

    def step(state, inputs):
        t, z = inputs
        step_key = jax.random.fold_in(key, t)
        altitude, velocity, coefficient = state
        drag = c["half_density"] * jnp.exp(-altitude / c["scale_height"]) * velocity ** 2 * coefficient
        moved = jnp.stack([altitude + c["dt"] * velocity, velocity + c["dt"] * (drag - c["gravity"]), coefficient])
        state = moved + c["process_std"][:, None] * jax.random.normal(jax.random.fold_in(step_key, 0),
                                                                      (3, particles), dtype)
        innovation = (z - jnp.sqrt(c["radar_distance"] ** 2 + (state[0] - c["radar_altitude"]) ** 2)) \
            / c["measurement_std"]
        log_weights = -0.5 * innovation * innovation
        top = jnp.max(log_weights)
        weights = jnp.exp(log_weights - top)
        total = jnp.sum(weights)
        estimate = state @ weights / total
        increment = top + jnp.log(total)
        cumulative = jnp.cumsum(weights.astype(jnp.float64))
        cumulative = cumulative / cumulative[-1]          # its last entry exactly 1: every offset below it
        start = jax.random.uniform(jax.random.fold_in(step_key, 1), (), jnp.float64)
        offsets = (jnp.arange(particles, dtype=jnp.float64) + start) / particles
        return state[:, jnp.searchsorted(cumulative, offsets)], (estimate, increment)

    steps = jnp.arange(1, measurements.shape[0] + 1)
    _, (estimates, increments) = jax.lax.scan(step, state, (steps, measurements))
    return estimates, jnp.sum(increments.astype(jnp.float64))
