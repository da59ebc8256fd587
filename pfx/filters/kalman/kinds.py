"""The registered Gaussian filter kinds: ``kf``, ``ekf`` and ``ukf`` (see :mod:`pfx.filters.kalman`)."""

from __future__ import annotations

import numpy as np

from pfx.filters.base import FILTERS, FilterKind
from pfx.filters.kalman.linear_form import check_linear_form, linear_form
from pfx.filters.kalman.linearisation import measurement_jacobian
from pfx.filters.kalman.measurement_form import check_measurement_form
from pfx.filters.kalman.prediction import extended_prediction, linear_step_prediction
from pfx.filters.kalman.recursion import gaussian_recursion, linear_update
from pfx.filters.kalman.smoothing import smooth_after
from pfx.filters.kalman.unscented import UnscentedParameters, run_unscented
from pfx.filters.smoothers import check_smoothers

# What a refusal of the Gaussian filters on a model's own likelihood suggests instead.
PARTICLE_REMEDY = "use the particle filter (kind: particle), which weighs by the model's own log_likelihood"


@FILTERS.register_kind
class KalmanFilter(FilterKind):
    """Kalman filter: the exact posterior of a linear-Gaussian model (linear_gaussian, or a plugin that declares its matrices)."""

    kind = "kf"
    model_needs = ("matrices",)
    reads = frozenset({"smoothers"})
    computes_scores = True

    @classmethod
    def plan(cls, model, settings, prior) -> "KalmanFilter":
        check_linear_form(model, "the Kalman filter (kf)", "kind")
        check_measurement_form(model, "the kf filter", "kind", PARTICLE_REMEDY)
        check_smoothers(cls.kind, model, settings)
        return cls()

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None, scores=False):
        form = linear_form(model)
        H = form.measurement
        noise_r = model.measurement_noise.covariance()

        def predict(mean, covariance, k):
            predicted, predicted_covariance, _ = linear_step_prediction(model, form, k, mean, covariance)
            return predicted, predicted_covariance

        def update(mean, covariance, z, k):
            H_batch = np.broadcast_to(H, mean.shape[:-1] + H.shape)
            return linear_update("kf", model, k, mean, covariance, z, mean @ H.T, H_batch, noise_r)

        return smooth_after(gaussian_recursion("kf", model, measurements, prior, predict, update, scores=scores), model, settings, "kf")


@FILTERS.register_kind
class ExtendedKalmanFilter(FilterKind):
    """Extended Kalman filter: linearise the model at the current mean (analytic or numerical Jacobians)."""

    kind = "ekf"
    reads = frozenset({"smoothers"})
    computes_scores = True

    @classmethod
    def plan(cls, model, settings, prior) -> "ExtendedKalmanFilter":
        check_measurement_form(model, "the ekf filter", "kind", PARTICLE_REMEDY)
        check_smoothers(cls.kind, model, settings)
        return super().plan(model, settings, prior)

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None, scores=False):
        noise_r = model.measurement_noise.covariance()

        def predict(mean, covariance, k):
            predicted, predicted_covariance, _ = extended_prediction(model, k, mean, covariance)
            return predicted, predicted_covariance

        def update(mean, covariance, z, k):
            H = measurement_jacobian(model, mean, covariance)
            return linear_update("ekf", model, k, mean, covariance, z, model.measurement_mean(mean), H, noise_r)

        return smooth_after(gaussian_recursion("ekf", model, measurements, prior, predict, update, scores=scores), model, settings,
                            "ekf")


@FILTERS.register_kind
class UnscentedKalmanFilter(FilterKind):
    """Unscented Kalman filter: propagate 2d+1 sigma points (settings.unscented: alpha, beta, kappa)."""

    kind = "ukf"
    reads = frozenset({"smoothers"})
    computes_scores = True
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
        check_measurement_form(model, "the ukf filter", "kind", PARTICLE_REMEDY)
        check_smoothers(cls.kind, model, settings)
        return cls(parameters)

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None, scores=False):
        return smooth_after(run_unscented(model, measurements, prior, self.parameters, scores=scores), model, settings, "ukf",
                            self.parameters)
