r"""The extended Kalman filter's linearisation.

``ekf``: the same recursion for any model, with :math:`F, L, H` the Jacobians at the current
mean. A model may provide them analytically (:meth:`~pfx.models.base.Model.transition_jacobian`,
:meth:`~pfx.models.base.Model.process_noise_jacobian`,
:meth:`~pfx.models.base.Model.measurement_jacobian`; each model's docstring says which); otherwise
they are central finite differences,
:math:`J_{:,j} = (g(x + h_j e_j) - g(x - h_j e_j)) / (2 h_j)`, evaluated in one batched call
of ``propagate`` or ``measurement_mean`` on the 2n perturbed states (an axis inserted after the
trial axis, as for particles). The step :math:`h_j = \epsilon^{1/3} \max(|x_j|, s_j)`
(:math:`\epsilon^{1/3} \approx 6\cdot10^{-6}`, which balances the :math:`O(h^2)` truncation
against the :math:`O(\epsilon/h)` rounding error) is relative to the component's scale:
:math:`s_j = \sqrt{P_{jj}}` for the state (the spread the linearisation must cover; a state
component near zero, like the falling body's ballistic coefficient, gets a step that fits its
own size), :math:`s_j = \sqrt{Q_{jj}}` for the noise, 1 where both are zero. The divisor is the
difference actually represented, :math:`(x_j + h_j) - (x_j - h_j)`. :math:`L` is computed only
when Q is not zero.

"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from pfx.filters.kalman.measurement_form import measurement_angles
from pfx.filters.kalman.recursion import transpose
from pfx.numerics.arrays import namespace

FD_STEP = float(np.finfo(float).eps ** (1.0 / 3.0))   # ~6.06e-6: optimal relative step, central differences


def finite_difference_jacobian(function: Callable[[np.ndarray], np.ndarray], point: np.ndarray,
                               scale: Optional[np.ndarray] = None,
                               wrap: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> np.ndarray:
    """Central-difference Jacobian of ``function`` at ``point`` (..., n): shape (..., p, n).

    ``function`` maps (..., 2n, n) to (..., 2n, p) in one call (the 2n perturbed points sit on an
    axis inserted before the last). Step h_j = FD_STEP * max(|x_j|, scale_j), or FD_STEP where
    that is zero; the divisor is the difference actually represented in floating point.
    ``wrap`` (optional) maps the differences g(x + h_j e_j) - g(x - h_j e_j) (..., n, p) before
    the division: the angular outputs' wrap, so that an angle crossing its branch cut between
    the two points is a small difference, not a turn.
    """
    xp = namespace(point)                  # NumPy or JAX alike (a guided proposal on jax)
    if xp is np:
        point = np.asarray(point, dtype=float)
    n = point.shape[-1]
    size = xp.abs(point)
    if scale is not None:
        size = xp.maximum(size, scale)
    step = FD_STEP * xp.where(size > 0, size, 1.0)
    offsets = step[..., None, :] * np.eye(n)                       # row j: h_j e_j
    plus = point[..., None, :] + offsets
    minus = point[..., None, :] - offsets
    values = function(xp.concatenate([plus, minus], axis=-2))
    width = xp.diagonal(plus - minus, axis1=-2, axis2=-1)           # (x_j + h_j) - (x_j - h_j)
    differences = values[..., :n, :] - values[..., n:, :]
    if wrap is not None:
        differences = wrap(differences)
    slopes = differences / width[..., :, None]
    return transpose(slopes)


def _state_scale(covariance: Optional[np.ndarray]) -> Optional[np.ndarray]:
    if covariance is None:
        return None
    return np.sqrt(np.clip(np.diagonal(covariance, axis1=-2, axis2=-1), 0.0, None))


def transition_jacobian(model, mean: np.ndarray, control, covariance: Optional[np.ndarray] = None,
                        time: Optional[float] = None) -> np.ndarray:
    """F = d f / d x at (mean, control, w = 0) for one ``propagate`` call starting at ``time``
    (default: the start of step 1): the model's, or central differences."""
    time = model.substep_time(1, 0) if time is None else time
    analytic = model.transition_jacobian_at(mean, control, time)
    if analytic is not None:
        return np.broadcast_to(analytic, mean.shape + (mean.shape[-1],))
    zeros_shape = (model.process_noise_dimension,)
    return finite_difference_jacobian(
        lambda states: model.propagate_at(states, control, np.zeros(states.shape[:-1] + zeros_shape), time),
        mean, _state_scale(covariance))


def measurement_jacobian(model, mean: np.ndarray, covariance: Optional[np.ndarray] = None) -> np.ndarray:
    """H = d h / d x at the mean: the model's, or central differences (of its angular
    measurement components, wrapped: :mod:`~pfx.filters.kalman.measurement_form`)."""
    analytic = model.measurement_jacobian(mean)
    if analytic is not None:
        xp = namespace(mean, analytic)
        return xp.broadcast_to(analytic, mean.shape[:-1] + (model.measurement_dimension, mean.shape[-1]))
    angles = measurement_angles(model)
    return finite_difference_jacobian(model.measurement_mean, mean, _state_scale(covariance),
                                      None if angles is None else angles.wrap)


def noise_jacobian(model, mean: np.ndarray, control, time: Optional[float] = None) -> np.ndarray:
    """L = d f / d w at (mean, control, w = 0) for one ``propagate`` call starting at ``time``
    (default: the start of step 1): the model's, or central differences over w."""
    time = model.substep_time(1, 0) if time is None else time
    analytic = model.process_noise_jacobian_at(mean, control, time)
    q = model.process_noise_dimension
    if analytic is not None:
        return np.broadcast_to(analytic, mean.shape + (q,))
    Q = model.process_noise.covariance()
    origin = np.zeros(mean.shape[:-1] + (q,))
    states = mean[..., None, :]
    return finite_difference_jacobian(
        lambda noise: model.propagate_at(np.broadcast_to(states, noise.shape[:-1] + mean.shape[-1:]).copy(),
                                         control, noise, time),
        origin, np.sqrt(np.clip(np.diag(Q), 0.0, None)))


def process_noise_in_state(model, mean: np.ndarray, control, time: Optional[float] = None) -> np.ndarray:
    """L Q L' (trials, d, d): the process noise covariance in state coordinates (0 when Q = 0),
    of one ``propagate`` call starting at ``time``."""
    Q = model.process_noise.covariance()
    d = mean.shape[-1]
    if not np.any(Q):
        return np.zeros(mean.shape[:-1] + (d, d))
    L = noise_jacobian(model, mean, control, time)
    return L @ Q @ transpose(L)

