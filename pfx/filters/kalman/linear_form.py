r"""The Kalman filter's linear model, read from a model's declared matrices and checked against it.

The Kalman filter (``kf``) and its RTS smoother need the model in the linear form

.. math::

    x_k = A x_{k-1} + c_k + L w_k, \qquad z_k = H x_k + v_k,

with :math:`w_k \sim (0, Q_w)`, :math:`v_k \sim (0, R)` (``process_noise``, ``measurement_noise``).
A model declares :math:`(A, H)` as its ``matrices`` property (:attr:`pfx.models.base.Model.matrices`;
``linear_gaussian`` does, and so may a plugin). The rest is read from the model itself:

* :math:`c_k = f(0, u_k, 0)`, the share of the control input (and of any constant forcing) in
  ``propagate``, evaluated at each step (and substep): for ``linear_gaussian``, :math:`B u_k`;
* :math:`L`: the model's ``process_noise_jacobian`` (a constant), or the identity when it gives
  none and has one noise component per state component; the process noise in state
  coordinates is :math:`Q = L Q_w L^\top` (:math:`Q_w` itself when :math:`L = I`).

**The probe.** A plugin's matrices are a promise about its ``propagate`` and ``measurement_mean``
that nothing else would check: a wrong :math:`A` gives a wrong posterior, silently. Before the
kf (or the locally optimal proposal, which reads :math:`H`) runs on a model that is not pfx's
own, :func:`check_linear_form` verifies on six states drawn from the model's laws (a fixed
private stream) that :math:`f(x, u_k, 0) - f(0, u_k, 0) = A x` at the first and the last step,
that :math:`h(x) = H x`, to a relative :math:`10^{-8}`, and that the process noise enters
additively as :math:`L w` (:func:`pfx.laws.transition_density.enters_additively`, the check the
transition density makes). The measurement's likelihood is probed as for every Gaussian filter
(:mod:`~pfx.filters.kalman.measurement_form`). The verdict is kept per model class and settings.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from pfx.filters.kalman.measurement_form import is_pfx_model, probe_states
from pfx.laws.transition_density import enters_additively
from pfx.numerics.hashing import SettingsCache

RELATIVE_TOLERANCE = 1e-8

_verdicts = SettingsCache()          # linear_form_mismatch's answers


@dataclass(frozen=True)
class LinearForm:
    """A model's linear form (module docstring): A (d, d), H (m, d) and Q = L Q_w L' (d, d)."""

    transition: np.ndarray
    measurement: np.ndarray
    process_noise: np.ndarray

    def offset(self, model, step: int, substep: int = 0) -> Optional[np.ndarray]:
        """c_k = f(0, u_k, 0) for substep ``substep`` of step k, (d,); None where it is 0 (a
        model without controls: nothing is added)."""
        d = model.state_dimension
        zeros = np.zeros((1, d))
        offset = model.propagate_at(zeros, model.control(step), np.zeros((1, model.process_noise_dimension)),
                                    model.substep_time(step, substep))[0]
        return offset if np.any(offset) else None


def linear_form(model) -> LinearForm:
    """The model's linear form, from its ``matrices`` (which must not be None) and its process
    noise; no probe (:func:`check_linear_form` is the plan-time check)."""
    transition, measurement = (np.asarray(matrix, dtype=float) for matrix in model.matrices)
    gain = noise_gain(model)
    covariance = model.process_noise.covariance()
    if gain is not None:
        covariance = gain @ covariance @ gain.T
    return LinearForm(transition, measurement, covariance)


def noise_gain(model) -> Optional[np.ndarray]:
    """L (d, q) from the model's ``process_noise_jacobian`` at the origin; None when the noise is
    added to the state as it is (no Jacobian given, or the identity)."""
    d = model.state_dimension
    jacobian = model.process_noise_jacobian_at(np.zeros((1, d)), model.control(1), model.substep_time(1, 0))
    if jacobian is None:
        return None
    gain = np.asarray(jacobian, dtype=float).reshape(d, model.process_noise_dimension)
    return None if gain.shape == (d, d) and np.array_equal(gain, np.eye(d)) else gain


def check_linear_form(model, user: str, key: str, *, transition: bool = True) -> None:
    """Raise ``ValueError("@<key>: ...")`` unless the model declares ``matrices`` that agree with
    its ``propagate`` (when ``transition``) and ``measurement_mean`` (module docstring); ``user``
    names the filter or proposal in the message. pfx's own models pass unprobed."""
    if model.matrices is None:
        raise ValueError(f"@{key}: {user} needs a linear model that declares its matrices (A, H): linear_gaussian, "
                         f"or a plugin model's `matrices` property (docs/plugins.md); model {model.kind} has none "
                         "(use ekf or ukf)")
    if is_pfx_model(model):
        return
    reason = _verdicts.answer(model, lambda: linear_form_mismatch(model))
    if reason is not None and (transition or reason.startswith(("matrices", "measurement_mean"))):
        raise ValueError(f"@{key}: {user} runs on the matrices model {model.kind} declares, and {reason}; fix the "
                         "matrices, or use ekf or ukf (which linearise propagate and measurement_mean themselves)")


def linear_form_mismatch(model) -> Optional[str]:
    """How the model departs from the linear form of its declared matrices (a clause), or None.
    The matrices and the measurement come first, so that a caller that needs only H (the
    locally optimal proposal) can tell."""
    d, m = model.state_dimension, model.measurement_dimension
    declared = model.matrices
    if not (isinstance(declared, (tuple, list)) and len(declared) == 2):
        return f"matrices returned {type(declared).__name__}; expected a pair (A, H)"
    transition, measurement = (np.asarray(matrix, dtype=float) for matrix in declared)
    if transition.shape != (d, d) or measurement.shape != (m, d):
        return (f"matrices returned A of shape {transition.shape} and H of shape {measurement.shape}; expected "
                f"({d}, {d}) and ({m}, {d})")
    if not (np.isfinite(transition).all() and np.isfinite(measurement).all()):
        return "matrices returned a matrix that is not finite"
    states = probe_states(model)
    with np.errstate(all="ignore"):
        if not _close(model.measurement_mean(states), states @ measurement.T):
            return "measurement_mean(x) is not H x with the declared H (matrices[1])"
        for step in sorted({1, model.steps}):
            control = model.control(step)
            for substep in sorted({0, model.propagations_per_step - 1}):
                time = model.substep_time(step, substep)
                noise = np.zeros((len(states), model.process_noise_dimension))
                moved = model.propagate_at(states, control, noise, time) \
                    - model.propagate_at(np.zeros_like(states), control, noise, time)
                if not _close(moved, states @ transition.T):
                    return (f"propagate(x, u, 0) - propagate(0, u, 0) is not A x with the declared A (matrices[0]) "
                            f"at step {step}")
    gain = noise_gain(model)
    if gain is None and model.process_noise_dimension != d:
        return (f"it gives no process_noise_jacobian L for its {model.process_noise_dimension} noise component(s) "
                f"and {d} state components")
    if not enters_additively(model, np.eye(d) if gain is None else gain):
        return "propagate(x, u, w) - propagate(x, u, 0) is not L w (L: its process_noise_jacobian, or the identity)"
    return None


def _close(value, expected: np.ndarray) -> bool:
    value = np.asarray(value, dtype=float)
    scale = max(float(np.abs(expected).max(initial=0.0)), 1.0)
    return value.shape == expected.shape and bool(np.allclose(value, expected, rtol=RELATIVE_TOLERANCE,
                                                              atol=RELATIVE_TOLERANCE * scale))
