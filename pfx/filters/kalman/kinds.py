"""The registered Gaussian filter kinds: ``kf``, ``ekf`` and ``ukf`` (see :mod:`pfx.filters.kalman`)."""

from __future__ import annotations

import numpy as np

from pfx.filters.base import FILTERS, FilterKind
from pfx.filters.kalman.linearisation import measurement_jacobian, process_noise_in_state, transition_jacobian
from pfx.filters.kalman.recursion import gaussian_recursion, linear_update, transpose
from pfx.filters.kalman.unscented import UnscentedParameters, run_unscented


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


@FILTERS.register_kind
class KalmanFilter(FilterKind):
    """Kalman filter: the exact posterior of a linear_gaussian model."""

    kind = "kf"
    model_needs = ("matrices",)

    @classmethod
    def plan(cls, model, settings, prior) -> "KalmanFilter":
        if getattr(model, "matrices", None) is None:
            raise ValueError(f"@kind: the Kalman filter (kf) needs a linear_gaussian model, not {model.kind}; "
                             "use ekf or ukf for nonlinear models")
        return cls()

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None):
        A, H = model.matrices
        Q = model.process_noise.covariance()
        noise_r = model.measurement_noise.covariance()

        def predict(mean, covariance, k):
            return linear_prediction(A, Q, model.control(k), mean, covariance)

        def update(mean, covariance, z, k):
            H_batch = np.broadcast_to(H, mean.shape[:-1] + H.shape)
            return linear_update("kf", model, k, mean, covariance, z, mean @ H.T, H_batch, noise_r)

        return gaussian_recursion("kf", model, measurements, prior, predict, update)


@FILTERS.register_kind
class ExtendedKalmanFilter(FilterKind):
    """Extended Kalman filter: linearise the model at the current mean (analytic or numerical Jacobians)."""

    kind = "ekf"

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None):
        noise_r = model.measurement_noise.covariance()

        def predict(mean, covariance, k):
            predicted, predicted_covariance, _ = extended_prediction(model, model.control(k), mean, covariance)
            return predicted, predicted_covariance

        def update(mean, covariance, z, k):
            H = measurement_jacobian(model, mean, covariance)
            return linear_update("ekf", model, k, mean, covariance, z, model.measurement_mean(mean), H, noise_r)

        return gaussian_recursion("ekf", model, measurements, prior, predict, update)


@FILTERS.register_kind
class UnscentedKalmanFilter(FilterKind):
    """Unscented Kalman filter: propagate 2d+1 sigma points (settings.unscented: alpha, beta, kappa)."""

    kind = "ukf"
    settings = {"unscented": (UnscentedParameters, "kind ukf: sigma-point parameters alpha, beta, kappa")}

    def __init__(self, parameters: UnscentedParameters = UnscentedParameters()):
        self.parameters = parameters

    @classmethod
    def plan(cls, model, settings, prior) -> "UnscentedKalmanFilter":
        parameters = getattr(settings, "unscented", None) or UnscentedParameters()
        try:
            parameters.check(model.state_dimension)
        except ValueError as error:
            raise ValueError(f"@unscented.{str(error)[1:]}") from None
        return cls(parameters)

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None):
        return run_unscented(model, measurements, prior, self.parameters)
