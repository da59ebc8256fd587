r"""The Gaussian filters' predict step, shared by the filters (:mod:`pfx.filters.kalman.kinds`) and
the RTS smoother (:mod:`pfx.filters.kalman.smoothing`), which must predict exactly as the filter did.
(The unscented predict lives with the unscented transform: :func:`pfx.filters.kalman.unscented.unscented_prediction`.)

A step of a model with substeps between measurements (``substeps`` s > 1,
:mod:`pfx.models.base`) is predicted substep by substep, as the model moves: from the moments
with the accumulating components reset (their mean and their covariance rows and columns set to
0: the reset :math:`R` is linear), for j = 1..s

.. math::

    m \leftarrow f(m, u_k, 0), \qquad P \leftarrow F_j P F_j^\top + L_j Q L_j^\top,

with :math:`F_j, L_j` the Jacobians at the substep's starting mean (the EKF), or :math:`A` and
:math:`Q` themselves (the KF: the exact :math:`A^s` and :math:`\sum_j A^j Q A^{j\top}`). The
Jacobian of the whole step, :math:`F = F_s \cdots F_1 R`, is what the RTS smoother's
cross-covariance :math:`C_{k+1} = P_k F^\top` needs. With s = 1 and no accumulating component
this is the one-call prediction, to the bit.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from pfx.filters.kalman.linear_form import LinearForm
from pfx.filters.kalman.linearisation import process_noise_in_state, transition_jacobian
from pfx.filters.kalman.recursion import transpose


def linear_prediction(A: np.ndarray, Q: np.ndarray, offset, mean: np.ndarray, covariance: np.ndarray):
    """The Kalman filter's predict, x^-_k = A x_{k-1} + c_k, P^-_k = A P_{k-1} A' + Q
    (``offset`` = c_k, the control's share B u_k, or None); mean (trials, d), covariance (trials, d, d)."""
    mean = mean @ A.T if offset is None else mean @ A.T + offset
    return mean, A @ covariance @ A.T + Q


def linear_step_prediction(model, form: LinearForm, step: int, mean: np.ndarray, covariance: np.ndarray):
    """The Kalman filter's predict over step k, one :func:`linear_prediction` per substep after
    the reset (module docstring), with the model's linear form (A, its offsets c, Q:
    :mod:`~pfx.filters.kalman.linear_form`): (x^-_k, P^-_k, F) with F = A^s R the Jacobian of
    the step."""
    A, Q = form.transition, form.process_noise
    mean, covariance, jacobian = reset_moments(model, mean, covariance)
    for substep in range(model.propagations_per_step):
        mean, covariance = linear_prediction(A, Q, form.offset(model, step, substep), mean, covariance)
        jacobian = A if jacobian is None else A @ jacobian
    return mean, covariance, jacobian


def extended_prediction(model, step: int, mean: np.ndarray, covariance: np.ndarray):
    """The extended Kalman filter's predict over step k: for each substep j = 1..s (one when the
    model has no substeps), x^- = f(x, u_k, 0), P^- = F_j P F_j' + L_j Q L_j', with F_j = df/dx
    at the substep's starting mean (the model's, or central differences scaled by the
    covariance), after the reset of the accumulating components: (x^-_k, P^-_k, F) with
    F = F_s ... F_1 R the Jacobian of the whole step."""
    control = model.control(step)
    mean, covariance, jacobian = reset_moments(model, mean, covariance)
    zeros = np.zeros(mean.shape[:-1] + (model.process_noise_dimension,))
    for substep in range(model.propagations_per_step):
        time = model.substep_time(step, substep)
        F = transition_jacobian(model, mean, control, covariance, time)
        noise = process_noise_in_state(model, mean, control, time)
        mean = model.propagate_at(mean, control, zeros, time)
        covariance = F @ covariance @ transpose(F) + noise
        jacobian = F if jacobian is None else F @ jacobian
    return mean, covariance, jacobian


def reset_moments(model, mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray, Optional[np.ndarray]]:
    """The moments of R x for the reset R of the model's accumulating components (their means,
    and their covariance rows and columns, 0) and R itself (d, d); (mean, covariance, None)
    untouched when the model has none."""
    components = list(model.accumulating_components)
    if not components:
        return mean, covariance, None
    mean, covariance = model.reset_accumulators(mean), covariance.copy()
    covariance[..., components, :] = 0.0
    covariance[..., :, components] = 0.0
    reset = np.eye(mean.shape[-1])
    reset[components, components] = 0.0
    return mean, covariance, reset
