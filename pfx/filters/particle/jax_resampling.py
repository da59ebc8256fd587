r"""The unbiased resamplers on the JAX backend: the inverse of the cumulative weights at N points.

The same four schemes as :mod:`pfx.filters.particle.resampling` (whose docstring states them),
written for a compiled step: every trial draws its points (a trial that does not resample
discards them, the engine selects), and the inverse CDF is a binary search
(``searchsorted``) rather than the NumPy backend's merged walk, which is sequential.

**Precision.** The cumulative weights :math:`C_j` and the points are always float64, whatever
the filter's precision. In float32, :math:`C_j` near 1 is known only to about 6e-8, so at
N = 1e6 particles each offspring count :math:`N (C_j - C_{j-1})` would be off by a few per
cent: the bias Murray, Lee & Jacob (2016) measured for single-precision resamplers above about
1e5 particles. Summing in float64 costs one pass over N numbers; the particles themselves stay
float32.

The round-off guard is the NumPy backend's: :math:`C_j = 1` from the last particle with positive
weight onward, so a point just below 1 never falls past the end nor onto a trailing zero-weight
particle, and zero-weight particles are never chosen.

Each function takes ``weights`` (trials, N), normalised, and a :class:`~pfx.numerics.key_streams.KeyStreams`,
and returns the ancestor indices (trials, N), int32.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from pfx.numerics.key_streams import KeyStreams


def cumulative_weights(weights):
    """C_j = w_1 + ... + w_j in float64, set to 1 from the last positive weight on (module docstring)."""
    weights = weights.astype(jnp.float64)
    count = weights.shape[-1]
    positions = jnp.arange(count)
    positive = weights > 0
    # the last positive weight's index (0 when there is none: such a row is never resampled)
    last_positive = jnp.max(jnp.where(positive, positions, 0), axis=-1, keepdims=True)
    return jnp.where(positions >= last_positive, 1.0, jnp.cumsum(weights, axis=-1))


def inverse_cdf(cumulative, points):
    """Per row, the index j with C_{j-1} <= u < C_j of each point u (points in [0, 1), float64)."""
    count = cumulative.shape[-1]
    indices = jax.vmap(lambda c, u: jnp.searchsorted(c, u, side="right"))(cumulative, points)
    return jnp.minimum(indices, count - 1).astype(jnp.int32)


def _float64_uniforms(random: KeyStreams, shape):
    return random.uniform(shape, jnp.float64)


def systematic(weights, random: KeyStreams):
    """u_i = (i - 1 + V) / N, one V ~ U(0, 1) per trial."""
    count = weights.shape[-1]
    offset = _float64_uniforms(random, (1,))
    return inverse_cdf(cumulative_weights(weights), (jnp.arange(count) + offset) / count)


def stratified(weights, random: KeyStreams):
    """u_i = (i - 1 + V_i) / N, V_i iid U(0, 1)."""
    count = weights.shape[-1]
    return inverse_cdf(cumulative_weights(weights), (jnp.arange(count) + _float64_uniforms(random, (count,))) / count)


def multinomial(weights, random: KeyStreams):
    """N iid draws from the weights: N iid uniforms (a binary search needs them unsorted or not)."""
    return inverse_cdf(cumulative_weights(weights), _float64_uniforms(random, (weights.shape[-1],)))


def residual(weights, random: KeyStreams):
    r"""floor(N w_j) copies of each particle, then the R = N - sum_j floor(N w_j) others iid from
    the residual weights (N w_j - floor(N w_j)) / R. With fixed shapes: position i < N - R takes
    the copy whose cumulative copy count passes i; position i >= N - R takes iid draw i - (N - R)
    of N iid draws from the residual weights (the first R of N iid draws are R iid draws; the
    first R of N *sorted* ones would not be, han-lee Algorithm IV's bias)."""
    count = weights.shape[-1]
    scaled = count * weights.astype(jnp.float64)
    copies = jnp.floor(scaled)
    residual_mass = scaled - copies
    copied = jnp.sum(copies, axis=-1, keepdims=True).astype(jnp.int32)
    positions = jnp.arange(count)
    from_copies = jax.vmap(lambda c, i: jnp.searchsorted(c, i, side="right"))(
        jnp.cumsum(copies, axis=-1), jnp.broadcast_to(positions, copies.shape).astype(jnp.float64))
    residual_weights = residual_mass / jnp.maximum(jnp.sum(residual_mass, axis=-1, keepdims=True), 1e-300)
    draws = inverse_cdf(cumulative_weights(residual_weights), _float64_uniforms(random, (count,)))
    extra = jnp.take_along_axis(draws, jnp.clip(positions - copied, 0, count - 1), axis=-1)
    return jnp.where(positions < copied, jnp.minimum(from_copies, count - 1), extra).astype(jnp.int32)


def han_lee_iv(weights, random: KeyStreams):
    """han-lee Algorithm IV verbatim, as the NumPy backend runs it: the N smallest of N + 1
    sorted uniforms (BIASED: :func:`pfx.filters.particle.resampling.han_lee_iv_expected_counts`)."""
    count = weights.shape[-1]
    points = jnp.sort(_float64_uniforms(random, (count + 1,)), axis=-1)[:, :count]
    return inverse_cdf(cumulative_weights(weights), points)


# the resamplers the JAX backend runs, by the names a config gives (filter.resampler)
JAX_RESAMPLERS = {"systematic": systematic, "stratified": stratified, "multinomial": multinomial,
                  "residual": residual, "han_lee_iv": han_lee_iv}
