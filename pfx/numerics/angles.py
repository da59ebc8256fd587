r"""Angles: state components that live on a circle (a robot's heading).

An angle and the same angle plus a full turn :math:`\tau` (360 degrees, or :math:`2\pi`) are one
state, so two operations differ from their linear forms:

* the **difference** of two angles is wrapped into :math:`(-\tau/2, \tau/2]`: a heading of
  359 degrees estimated as 1 degree is 2 degrees off, not 358;
* the **mean** of weighted angles is the circular mean, the direction of the weighted resultant
  vector:

  .. math:: \bar\theta = \operatorname{atan2}\Big(\sum_i w_i \sin\theta_i,\ \sum_i w_i \cos\theta_i\Big),

  so a cloud straddling 0 / 360 degrees averages near 0, not near 180.

Two wrappings, named for their ranges: :func:`wrap_into_turn` reduces an angle into
:math:`[0, \tau)` (a heading as a state), :func:`wrap_to_pi` maps radians into
:math:`(-\pi, \pi]`, as Probabilistic Robotics asks of every angle difference of its motion
models (a change of heading, a bearing, the rotation error :math:`\hat\gamma`):

.. math:: \operatorname{wrap}(a) = \pi - \big((\pi - a) \bmod 2\pi\big) \in (-\pi, \pi].

A model names its angular components (:attr:`pfx.models.base.Model.angular_components`) and its
full turn (:attr:`pfx.models.base.Model.full_turn`); the engine's estimate and the metrics' errors
use these functions for those components only.

Every function takes NumPy or JAX arrays (:mod:`pfx.numerics.arrays`): one code for both backends.
"""

from __future__ import annotations

import numpy as np

from pfx.numerics.arrays import namespace, with_values


def wrap_into_turn(angle: np.ndarray, full_turn: float) -> np.ndarray:
    """An angle reduced into [0, full_turn)."""
    xp = namespace(angle)
    reduced = xp.mod(angle, full_turn)
    # mod of a tiny negative angle rounds up to full_turn itself
    return xp.where(reduced >= full_turn, 0.0, reduced)


def wrap_difference(difference: np.ndarray, full_turn: float) -> np.ndarray:
    """An angle difference wrapped into (-full_turn / 2, full_turn / 2]."""
    half = full_turn / 2.0
    return half - namespace(difference).mod(half - difference, full_turn)


def wrap_to_pi(angle):
    """An angle in radians (any shape) mapped into (-pi, pi]: both -pi and pi become pi."""
    if namespace(angle) is np:       # a number or a list of them is read as float64, as before
        angle = np.asarray(angle, dtype=float)
    return wrap_difference(angle, 2.0 * np.pi)


def circular_mean(weights: np.ndarray, angles: np.ndarray, full_turn: float) -> np.ndarray:
    """Weighted circular mean per row, in [0, full_turn): (R, N), (R, N, k) -> (R, k)."""
    xp = namespace(weights, angles)
    radians = angles * (2.0 * np.pi / full_turn)
    sine = xp.einsum("rn,rnk->rk", weights, xp.sin(radians))
    cosine = xp.einsum("rn,rnk->rk", weights, xp.cos(radians))
    return wrap_into_turn(xp.arctan2(sine, cosine) * (full_turn / (2.0 * np.pi)), full_turn)


def wrap_components(difference: np.ndarray, components, full_turn: float) -> np.ndarray:
    """``difference`` (..., k) with the listed components (indices on the last axis) wrapped
    into (-full_turn / 2, full_turn / 2] (:func:`wrap_difference`); a copy, the other
    components unchanged. The innovation z - h(x) of a model with angular measurements."""
    components = list(components)
    return with_values(difference, (..., components), wrap_difference(difference[..., components], full_turn))
