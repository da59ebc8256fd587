r"""The transition density :math:`p(x_k \mid x_{k-1}, u_k)` of a model, in one place.

A particle filter only *samples* the transition; several algorithms also *evaluate* it: guided
proposals (the importance weight :math:`p(x_k \mid x_{k-1}) / q(x_k \mid x_{k-1}, z_k)`), the
MCMC move (its target :math:`p(z_k \mid x_k) p(x_k \mid x_{k-1})`), the histogram filter (its
transition kernel on the grid) and smoothers (the backward weights). They all ask the model,
through the model's :meth:`~pfx.models.base.Model.transition_density` and
:meth:`~pfx.models.base.Model.transition_log_density`, and nowhere else.

For a model whose process noise enters **additively**,

.. math::

    x_k = f(x_{k-1}, u_k, 0) + L w_k, \qquad
    p(x_k \mid x_{k-1}) = p_{Lw}\big(x_k - f(x_{k-1}, u_k, 0)\big),

the density is derived from the noise's law (:class:`AdditiveTransition`). How pfx knows the
noise is additive, in this order:

1. :math:`L` is the model's ``process_noise_jacobian`` if it gives one, the same at every state
   (two probe states are compared); otherwise, with one noise component per state component,
   the identity;
2. pfx checks numerically that ``propagate(x, u, w) - propagate(x, u, 0) = L w`` on seven
   states drawn from the initial law (a fixed private stream) with a fixed pattern of noises of
   both signs and several sizes (a declared Jacobian may belong to a parent class whose
   ``propagate`` a subclass changed).

A model that takes several noisy substeps between two measurements (``substeps`` > 1 with a
process noise that is not zero) has none either: its step is a composition
:math:`f(\cdots f(f(x_{k-1}, w^{(1)}), w^{(2)}) \cdots, w^{(s)})` whose law has, in general, no
closed form (for a linear model it is Gaussian with covariance :math:`\sum_j A^j Q A^{j\top}`,
but pfx does not single linear models out). The mean :math:`f(x_{k-1}, u_k, 0)` is always the
noise-free transition over the whole step (:meth:`~pfx.models.base.Model.mean_transition`).

Otherwise the model has no derived density, and the algorithms that need one refuse it in one
line, with the reason (:attr:`TransitionDensityUnavailable.reason`); a model whose transition
has a density of another form may override ``transition_log_density`` (and then declares
``transition_density_declared = True``).

For Gaussian noise the density is evaluated from the Cholesky factor :math:`C` of
:math:`Q = L Q_w L^\top` (computed once per model, never per step):
:math:`\log N(x; \mu, Q) = -\tfrac12 \lVert C^{-1}(x - \mu) \rVert^2 - \log|C| - \tfrac d2 \log 2\pi`;
for other noise families (``L = I`` only) from the noise law's own ``log_density``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from pfx.laws.noise import Noise
from pfx.numerics.seeding import TrialStreams

LOG_TWO_PI = math.log(2.0 * math.pi)
PROBE_SEED = 20_010_601        # private stream of the states the additivity check propagates


def gaussian_log_density(value: np.ndarray, mean: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """log N(value; mean, C C') for one lower-triangular factor C (d, d): shape (...)."""
    standard = (value - mean) @ np.linalg.inv(factor).T
    d = value.shape[-1]
    return -0.5 * np.sum(standard * standard, axis=-1) - np.sum(np.log(np.diag(factor))) - 0.5 * d * LOG_TWO_PI


@dataclass(frozen=True)
class AdditiveTransition:
    r"""p(x_k | x_{k-1}) = p_{Lw}(x_k - f(x_{k-1}, u_k, 0)): the model's process noise enters additively."""

    gain: np.ndarray                  # L, (d, q); the identity when the noise is added to the state
    noise: Noise                      # the law of w_k
    covariance: Optional[np.ndarray]  # Q = L Q_w L' (d, d), for Gaussian noise
    factor: Optional[np.ndarray]      # its Cholesky factor C; None when Q is singular (no density)
    identity_gain: bool               # L = I (one noise component per state component)

    @property
    def has_density(self) -> bool:
        """Whether the density can be evaluated: a definite Gaussian, or noise added to the state."""
        return self.factor is not None if self.noise.family == "gaussian" else self.identity_gain

    def log_density(self, state: np.ndarray, mean: np.ndarray) -> np.ndarray:
        """log p(x_k | x_{k-1}) for states ``state`` (..., d) whose predictions
        f(x_{k-1}, u_k, 0) are ``mean`` (broadcasting): shape (...)."""
        if self.noise.family == "gaussian":
            return gaussian_log_density(state, mean, self.factor)
        return self.noise.log_density(state - mean)


class TransitionDensityUnavailable(ValueError):
    """A model without a transition density pfx can evaluate; ``reason`` finishes the sentence
    "model <kind> ..." (e.g. "gives no process_noise_jacobian and its noise does not enter additively")."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def derive_transition_density(model) -> AdditiveTransition | TransitionDensityUnavailable:
    """The model's additive transition (module docstring), or why there is none."""
    d, q = model.state_dimension, model.process_noise_dimension
    noise = model.process_noise
    substeps = model.propagations_per_step
    if substeps > 1 and np.any(noise.covariance()):
        return TransitionDensityUnavailable(f"advances {substeps} noisy substeps between measurements "
                                            f"(substeps: {substeps}), and the law of their composition has no "
                                            "closed form")
    probes = np.stack([np.zeros(d), np.ones(d)])[:, None, :]       # two states: is L constant?
    jacobians = model.process_noise_jacobian_at(probes, model.control(1), model.substep_time(1, 0))
    if jacobians is not None:
        if not np.array_equal(jacobians[0], jacobians[1]):
            return TransitionDensityUnavailable("has a process-noise Jacobian L that depends on the state "
                                                "(noise not additive)")
        gain = np.asarray(jacobians[0, 0], dtype=float)
    elif q == d:
        gain = np.eye(d)
    else:
        return TransitionDensityUnavailable(f"gives no process_noise_jacobian and has {q} noise component(s) for "
                                            f"{d} state components (it does not declare its process noise additive)")
    if not enters_additively(model, gain):
        return TransitionDensityUnavailable("has noise that does not enter additively (x' = f(x, u) + L w does not "
                                            "hold for its propagate)")
    identity = gain.shape == (d, d) and np.array_equal(gain, np.eye(d))
    covariance = factor = None
    if noise.family == "gaussian":
        covariance = gain @ noise.covariance() @ gain.T
        try:
            factor = np.linalg.cholesky(covariance)
        except np.linalg.LinAlgError:
            factor = None
    return AdditiveTransition(gain=gain, noise=noise, covariance=covariance, factor=factor, identity_gain=identity)


def enters_additively(model, gain: np.ndarray) -> bool:
    """Whether propagate(x, u, w) - propagate(x, u, 0) = L w, checked numerically on seven states
    drawn from the initial law with a fixed pattern of noises w scaled by the per-component
    noise standard deviations (a model's code cannot be inspected, and a declared Jacobian may
    belong to a parent class whose propagate was overridden; seven points and noises of both
    signs and several sizes catch a multiplicative or nonlinear noise)."""
    points = model.initial.sample(TrialStreams.from_seeds([PROBE_SEED]), (7,))[0]
    std = np.sqrt(np.clip(np.diag(model.process_noise.covariance()), 0.0, None))
    if not std.any():
        std = np.ones_like(std)
    pattern = np.array([0.7, -1.3, 2.1, -0.4, 1.1, -2.2, 0.3])[:, None]
    noise = pattern * std * np.where(np.arange(len(std)) % 2 == 0, 1.0, -0.8)
    control, time = model.control(1), model.substep_time(1, 0)
    with np.errstate(all="ignore"):
        moved = (model.propagate_at(points, control, noise, time)
                 - model.propagate_at(points, control, np.zeros_like(noise), time))
    expected = noise @ gain.T
    return bool(np.allclose(moved, expected, rtol=1e-6, atol=1e-9 * float(np.abs(expected).max() or 1.0)))
