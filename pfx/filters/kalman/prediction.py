"""The Gaussian filters' predict step, shared by the filters (:mod:`pfx.filters.kalman.kinds`) and
the RTS smoother (:mod:`pfx.filters.kalman.smoothing`), which must predict exactly as the filter did.
(The unscented predict lives with the unscented transform: :func:`pfx.filters.kalman.unscented.unscented_prediction`.)
"""

from __future__ import annotations

import numpy as np

from pfx.filters.kalman.linearisation import process_noise_in_state, transition_jacobian
from pfx.filters.kalman.recursion import transpose


def linear_prediction(A: np.ndarray, Q: np.ndarray, control, mean: np.ndarray, covariance: np.ndarray):
    """The Kalman filter's predict, x^-_k = A x_{k-1} + B u_k, P^-_k = A P_{k-1} A' + Q
    (``control`` = B u_k or None); mean (trials, d), covariance (trials, d, d)."""
    mean = mean @ A.T if control is None else mean @ A.T + control
    return mean, A @ covariance @ A.T + Q


def extended_prediction(model, control, mean: np.ndarray, covariance: np.ndarray):
    """The extended Kalman filter's predict, x^-_k = f(x_{k-1}, u_k, 0),
    P^-_k = F P_{k-1} F' + L Q L', with F = df/dx at the mean (the model's, or central
    differences scaled by the covariance): (x^-_k, P^-_k, F)."""
    F = transition_jacobian(model, mean, control, covariance)
    predicted = model.propagate(mean, control, np.zeros(mean.shape[:-1] + (model.process_noise_dimension,)))
    return predicted, F @ covariance @ transpose(F) + process_noise_in_state(model, mean, control), F
