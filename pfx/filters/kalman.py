r"""Gaussian filters: the Kalman filter (``kf``), the extended (``ekf``) and the unscented (``ukf``).

Each carries, per trial, a Gaussian belief :math:`N(\hat x_k, P_k)` instead of particles, batched
over the trials of a batch like the particle engine (means (trials, d), covariances (trials, d, d)). Every step
k = 1..T has two halves.

**Predict** through the transition :math:`x_k = f(x_{k-1}, u_k, w_k)`, :math:`w_k \sim (0, Q)`:

.. math::

    \hat x_k^- = f(\hat x_{k-1}, u_k, 0), \qquad
    P_k^- = F_k P_{k-1} F_k^\top + L_k Q L_k^\top,

with :math:`F_k = \partial f / \partial x` and :math:`L_k = \partial f / \partial w` at
:math:`(\hat x_{k-1}, u_k, 0)`. :math:`L Q L^\top` is the process noise in state coordinates
(:math:`L = I` for the additive noise of every current pfx model).

**Update** with the measurement :math:`z_k = h(x_k) + v_k`, :math:`v_k \sim (0, R)`:

.. math::

    \hat z_k = h(\hat x_k^-), \quad \nu_k = z_k - \hat z_k, \quad
    S_k = H_k P_k^- H_k^\top + R, \quad K_k = P_k^- H_k^\top S_k^{-1},

    \hat x_k = \hat x_k^- + K_k \nu_k, \qquad
    P_k = (I - K_k H_k) P_k^- (I - K_k H_k)^\top + K_k R K_k^\top

(Joseph's form: symmetric and positive semi-definite by construction, equal to the textbook
:math:`(I - K H) P^-` for the optimal gain; the result is also symmetrised). The estimate at step k
is the updated mean :math:`\hat x_k`. Two by-products: the normalised innovation squared
:math:`\mathrm{NIS}_k = \nu_k^\top S_k^{-1} \nu_k` (chi-square with m degrees of freedom when
the filter is consistent), and the log-likelihood
:math:`\log p(z_{1:T}) = \sum_k \log N(z_k; \hat z_k, S_k)`, computed from a Cholesky factor of
:math:`S_k` (:math:`\log|S_k| = 2 \sum_i \log (L_S)_{ii}`).

``kf`` (Kalman 1960): f and h are linear, :math:`f = A x + B u + w`, :math:`h = H x`, from
:attr:`~pfx.models.linear_gaussian.LinearGaussian.matrices`. With gaussian noise it is the exact
posterior; with another noise family, the best linear (minimum-variance affine) estimator, and its
log-likelihood that of the Gaussian approximation. It refuses every other model.

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

``ukf`` (Julier & Uhlmann 1997; scaled form: Julier 2002, Wan & van der Merwe 2000): instead of
linearising, push 2d + 1 *sigma points* through the nonlinear functions (the unscented
transform). With :math:`P = S S^\top` (Cholesky), :math:`\lambda = \alpha^2 (d + \kappa) - d`
and :math:`c = \sqrt{d + \lambda}`:

.. math::

    \mathcal X_0 = \hat x, \quad \mathcal X_{j} = \hat x + c\, S_{:,j}, \quad
    \mathcal X_{d+j} = \hat x - c\, S_{:,j} \quad (j = 1..d),

    W^m_0 = \frac{\lambda}{d + \lambda}, \quad W^c_0 = W^m_0 + 1 - \alpha^2 + \beta, \quad
    W_i = \frac{1}{2 (d + \lambda)} \ (i \ge 1),

    \bar y = \sum_i W^m_i \mathcal Y_i, \qquad
    P_{yy} = \sum_i W^c_i (\mathcal Y_i - \bar y)(\mathcal Y_i - \bar y)^\top, \qquad
    \mathcal Y_i = g(\mathcal X_i).

The mean and covariance are exact for linear g, and correct to second order for any smooth g.
The predict step maps the posterior's sigma points through :math:`f(\cdot, u_k, 0)` and adds
:math:`L Q L^\top` (additive process noise, L as for the EKF at the posterior mean); the update
draws new sigma points from :math:`N(\hat x_k^-, P_k^-)`, maps them through h, and with
:math:`S = P_{zz} + R`, :math:`K = P_{xz} S^{-1}` sets :math:`\hat x_k = \hat x_k^- + K \nu`,
:math:`P_k = P_k^- - K S K^\top`.

For a small :math:`\alpha` the weight :math:`W^m_0 \approx -1/(\alpha^2 d)` is huge and negative
(-3.3e5 for d = 3 at the default :math:`\alpha = 10^{-3}`), and the sums above lose about
:math:`\log_{10} |W^m_0|` digits to cancellation. pfx evaluates them in the algebraically identical form, with
:math:`D_i = \mathcal Y_i - \mathcal Y_0` and :math:`\delta = W \sum_{i \ge 1} D_i`:

.. math::

    \bar y = \mathcal Y_0 + \delta, \qquad
    P_{yz} = W \sum_{i \ge 1} D^y_i D^{z\top}_i + (\beta - \alpha^2)\, \delta^y \delta^{z\top},

in which no large weight appears. One amplification is inherent to a small :math:`\alpha`:
:math:`\delta` is a second difference over a step :math:`\alpha \sigma`, so the round-off of the
sigma points, :math:`\epsilon |\hat x|`, reaches the mean as about
:math:`\epsilon |\hat x| / \alpha^2` (1e-10 relative at the default, far below any statistical
error; 1e-16 at :math:`\alpha = 1`). Parameters (:class:`UnscentedParameters`, the ``unscented``
settings of the filter): :math:`\alpha` sets the spread of the points, :math:`\beta = 2` is
optimal for a Gaussian prior (it adds the fourth moment to :math:`W^c_0`), :math:`\kappa` is a
secondary scaling (the original unscented transform is :math:`\alpha = 1,\ \kappa = 3 - d`).
Which :math:`\alpha` suits a model is a trade-off: see :class:`UnscentedParameters`.

**Keeping the covariance positive definite.** The UKF's :math:`P^- - K S K^\top` is a
difference that round-off can push to indefinite (the falling body's covariance spans 15
orders of magnitude; in pfx's falling-body runs, thousands of trials of both variants, no
repair was ever needed, but nothing guarantees it). Every covariance the UKF factorises (predicted and updated) is
symmetrised, then factorised by Cholesky; if that fails, the matrix is scaled to unit diagonal
(so the repair is relative to each component's own variance), jitter :math:`\epsilon I` is added
with :math:`\epsilon = 10^{-12}, 10^{-11}, \dots, 10^{-6}` until the Cholesky factorisation
succeeds; failing that, the eigenvalues are clipped at :math:`10^{-12}` times the largest and
the result is rescaled to unit diagonal (so every variance is kept; only the correlations move).
The repaired matrix :math:`S S^\top` replaces the covariance (it is the one reported and carried
on). Components of exactly zero variance (a point prior) are left out of the factor, so their
sigma points coincide with the mean. The KF and EKF are not repaired: Joseph's form keeps them
positive semi-definite, and an EKF's failure should show, not be hidden.

**Non-finite values**: a mean or covariance that becomes NaN or infinite, or an innovation
covariance that is not positive definite, raises :class:`~pfx.errors.ModelNumericalError`
naming the filter kind, the model and the step.

References: R. E. Kalman, "A new approach to linear filtering and prediction problems", 1960;
S. J. Julier, J. K. Uhlmann, "A new extension of the Kalman filter to nonlinear systems", 1997;
S. J. Julier, "The scaled unscented transformation", ACC 2002; E. A. Wan, R. van der Merwe,
"The unscented Kalman filter for nonlinear estimation", AS-SPCC 2000; Julier, Uhlmann &
Durrant-Whyte, IEEE TAC 45(3), 2000 (the falling-body comparison of EKF and UKF).
"""

from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat

from pfx.errors import ConfigError, ModelNumericalError, located_value_error
from pfx.filters.registry import FILTERS
from pfx.filters.trace import FilterTrace

FD_STEP = float(np.finfo(float).eps ** (1.0 / 3.0))   # ~6.06e-6: optimal relative step, central differences
JITTERS = tuple(10.0 ** -e for e in range(12, 5, -1))  # 1e-12 .. 1e-6, relative to each variance
EIGENVALUE_FLOOR = 1e-12                               # relative to the largest eigenvalue


class UnscentedParameters(BaseModel):
    """Scaled unscented transform parameters (Julier 2002; Wan & van der Merwe 2000).

    The defaults are Wan & van der Merwe's (also MATLAB's): alpha = 1e-3, beta = 2 (optimal for a
    Gaussian prior), kappa = 0. The original unscented transform of Julier & Uhlmann is
    alpha = 1, beta = 0, kappa = 3 - d.

    Choosing alpha is a trade-off, measured on pfx's models:

    * small alpha keeps the sigma points close to the mean, inside the region where the model is
      defined. On the falling body (variant jud, 10,000 trials) about 1 trial in 10,000 went
      non-finite at alpha = 1e-3 (none of 6000 at alpha = 0.3), 1 in 600 at alpha = 1: sigma
      points, or the mean itself, reach a negative ballistic coefficient, where the drag
      equation blows up, and the filter stops (a 50-trial cell then fails ~8 % of the time);
    * but as alpha -> 0 the transform only sees the derivatives at the mean (it becomes a
      second-order Taylor filter), extrapolated over the whole covariance. Where the
      nonlinearity saturates within the prior's spread this fails badly: on the growth model
      (x/2 + 25 x/(1 + x^2) + ..., prior variance 10) the UKF's RMSE is ~1e6 at alpha = 1e-3,
      ~16 at 0.3, ~8 at alpha = 1 (the EKF's: ~20). Use alpha = 1 there.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    alpha: StrictFloat = Field(1e-3, gt=0.0, le=1.0,
                               description="spread of the sigma points around the mean (0 < alpha <= 1)")
    beta: StrictFloat = Field(2.0, ge=0.0,
                              description="prior knowledge of the distribution (2 is optimal for a Gaussian)")
    kappa: StrictFloat = Field(0.0, ge=-1e6, le=1e6,
                               description="secondary scaling; needs d + kappa > 0 (d: state dimension)")

    def check(self, dimension: int) -> None:
        """Raise ValueError('@kappa: ...') unless the sigma-point spread d + lambda is positive."""
        if dimension + self.kappa <= 0:
            raise ValueError(f"@kappa: must exceed -{dimension} (minus the state dimension) so that the "
                             f"sigma points are real; got {self.kappa}")

    def weights(self, dimension: int) -> tuple[float, float, float, float]:
        """(c, W^m_0, W^c_0, W_i) for a state of the given dimension (see the module docstring)."""
        self.check(dimension)
        spread = self.alpha ** 2 * (dimension + self.kappa)          # d + lambda
        mean_weight0 = 1.0 - dimension / spread                      # lambda / (d + lambda)
        return (math.sqrt(spread), mean_weight0, mean_weight0 + 1.0 - self.alpha ** 2 + self.beta,
                0.5 / spread)


# -- plan-time checks: ``run.check(model, settings, prior)`` (see pfx.filters) -------------------

def _check_kf(model, settings, prior=None) -> None:
    """Raise ValueError('@key: reason') (key under ``filter``) if the kf cannot run on ``model``."""
    if model.kind != "linear_gaussian":
        raise ValueError(f"@kind: the Kalman filter (kf) needs a linear_gaussian model, not {model.kind}; "
                         "use ekf or ukf for nonlinear models")


def _check_ekf(model, settings, prior=None) -> None:
    """Every model can run the EKF."""


def _check_ukf(model, settings, prior=None) -> None:
    try:
        _unscented_parameters(settings).check(model.state_dimension)
    except ValueError as error:
        raise ValueError(f"@unscented.{str(error)[1:]}") from None


def _checked(check: Callable, model, settings, prior) -> None:
    try:
        check(model, settings, prior)
    except ValueError as error:
        raise located_value_error(error, prefix="filter") from None


def _unscented_parameters(settings) -> UnscentedParameters:
    parameters = getattr(settings, "unscented", None)
    return parameters if parameters is not None else UnscentedParameters()


# -- registered filter kinds ---------------------------------------------------------------------

@FILTERS.register("kf")
def kalman_filter(model, measurements, random, *, settings, prior, spread_criterion, consistency=False):
    """Kalman filter: the exact posterior of a linear_gaussian model."""
    _checked(_check_kf, model, settings, prior)
    A, H = model.matrices
    Q = model.process_noise.covariance()
    noise_r = model.measurement_noise.covariance()

    def predict(mean, covariance, k):
        control = model.control(k)
        mean = mean @ A.T if control is None else mean @ A.T + control
        return mean, A @ covariance @ A.T + Q

    def update(mean, covariance, z, k):
        H_batch = np.broadcast_to(H, mean.shape[:-1] + H.shape)
        return _linear_update("kf", model, k, mean, covariance, z, mean @ H.T, H_batch, noise_r)

    return _run("kf", model, measurements, prior, predict, update)


@FILTERS.register("ekf")
def extended_kalman_filter(model, measurements, random, *, settings, prior, spread_criterion, consistency=False):
    """Extended Kalman filter: linearise the model at the current mean (analytic or numerical Jacobians)."""
    _checked(_check_ekf, model, settings, prior)
    noise_r = model.measurement_noise.covariance()

    def predict(mean, covariance, k):
        control = model.control(k)
        F = transition_jacobian(model, mean, control, covariance)
        predicted = model.propagate(mean, control, np.zeros(mean.shape[:-1] + (model.process_noise_dimension,)))
        return predicted, F @ covariance @ _transpose(F) + process_noise_in_state(model, mean, control)

    def update(mean, covariance, z, k):
        H = measurement_jacobian(model, mean, covariance)
        return _linear_update("ekf", model, k, mean, covariance, z, model.measurement_mean(mean), H, noise_r)

    return _run("ekf", model, measurements, prior, predict, update)


@FILTERS.register("ukf")
def unscented_kalman_filter(model, measurements, random, *, settings, prior, spread_criterion, consistency=False):
    """Unscented Kalman filter: propagate 2d+1 sigma points (settings.unscented: alpha, beta, kappa)."""
    _checked(_check_ukf, model, settings, prior)
    return _unscented(model, measurements, prior, _unscented_parameters(settings))


kalman_filter.check = _check_kf
extended_kalman_filter.check = _check_ekf
unscented_kalman_filter.check = _check_ukf


# -- the shared recursion ------------------------------------------------------------------------

def _run(kind: str, model, measurements: np.ndarray, prior, predict, update) -> FilterTrace:
    """Alternate predict(mean, cov, k) and update(mean, cov, z, k) over steps 1..T; build the trace."""
    trials, steps, _ = measurements.shape
    mean, covariance = _prior_moments(prior, trials, model.state_dimension)
    d = mean.shape[-1]
    estimates = np.empty((trials, steps, d))
    covariances = np.empty((trials, steps, d, d))
    nis = np.empty((trials, steps))
    log_likelihood = np.zeros(trials)
    for k in range(1, steps + 1):
        with np.errstate(over="ignore", invalid="ignore"):   # reported by _check_finite
            mean, covariance = predict(mean, covariance, k)
        _check_finite(kind, model, k, "prediction", mean, covariance)
        with np.errstate(over="ignore", invalid="ignore"):
            mean, covariance, nis[:, k - 1], increment = update(mean, covariance, measurements[:, k - 1], k)
        _check_finite(kind, model, k, "update", mean, covariance)
        log_likelihood += increment
        estimates[:, k - 1] = mean
        covariances[:, k - 1] = covariance
    return FilterTrace.for_gaussian_filter(estimates, covariances, nis, log_likelihood,
                                           position=list(model.position_components))


def _prior_moments(prior, trials: int, dimension: int) -> tuple[np.ndarray, np.ndarray]:
    mean = np.asarray(prior.mean_vector(), dtype=float)
    covariance = np.asarray(prior.covariance_matrix(), dtype=float)
    if mean.shape != (dimension,) or covariance.shape != (dimension, dimension):
        raise ConfigError(f"the prior has dimension {mean.shape[-1] if mean.ndim else 0}, the model {dimension}",
                          key="filter.initial")
    return (np.broadcast_to(mean, (trials, dimension)).copy(),
            np.broadcast_to(_symmetric(covariance), (trials, dimension, dimension)).copy())


def _check_finite(kind: str, model, k: int, stage: str, mean: np.ndarray, covariance: np.ndarray) -> None:
    if not (np.isfinite(mean).all() and np.isfinite(covariance).all()):
        what = "mean" if not np.isfinite(mean).all() else "covariance"
        raise ModelNumericalError(f"filter {kind}: model {model.kind} gave a NaN or infinite {what} in the "
                                  f"{stage} at step {k} (check the prior, the noise and the model's domain)")


def _transpose(matrices: np.ndarray) -> np.ndarray:
    return np.swapaxes(matrices, -1, -2)


def _symmetric(matrices: np.ndarray) -> np.ndarray:
    return 0.5 * (matrices + _transpose(matrices))


def _innovation(kind: str, model, k: int, innovation: np.ndarray, innovation_covariance: np.ndarray):
    """(S^-1 nu, NIS, log N(nu; 0, S)) per trial; raises if S is not positive definite."""
    S = _symmetric(innovation_covariance)
    try:
        factor = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise ModelNumericalError(f"filter {kind}: model {model.kind} gave an innovation covariance that is "
                                  f"not positive definite at step {k}") from None
    solved = np.linalg.solve(S, innovation[..., None])[..., 0]
    nis = np.einsum("rm,rm->r", innovation, solved)
    log_determinant = 2.0 * np.sum(np.log(np.diagonal(factor, axis1=-2, axis2=-1)), axis=-1)
    log_density = -0.5 * (nis + log_determinant + innovation.shape[-1] * math.log(2.0 * math.pi))
    return S, nis, log_density


def _linear_update(kind, model, k, mean, covariance, z, predicted_measurement, H, noise_r):
    """Kalman update with measurement matrix H (trials, m, d), Joseph form; returns (mean, P, NIS, log p(z_k))."""
    innovation = z - predicted_measurement
    S, nis, log_density = _innovation(kind, model, k, innovation, H @ covariance @ _transpose(H) + noise_r)
    cross = covariance @ _transpose(H)                                   # P H'  (trials, d, m)
    gain = _transpose(np.linalg.solve(S, _transpose(cross)))             # P H' S^-1 (S symmetric)
    mean = mean + np.einsum("rdm,rm->rd", gain, innovation)
    complement = np.eye(mean.shape[-1]) - gain @ H
    covariance = complement @ covariance @ _transpose(complement) + gain @ noise_r @ _transpose(gain)
    return mean, _symmetric(covariance), nis, log_density


# -- Jacobians (analytic when the model has them, else central differences) ----------------------

def finite_difference_jacobian(function: Callable[[np.ndarray], np.ndarray], point: np.ndarray,
                               scale: Optional[np.ndarray] = None) -> np.ndarray:
    """Central-difference Jacobian of ``function`` at ``point`` (..., n): shape (..., p, n).

    ``function`` maps (..., 2n, n) to (..., 2n, p) in one call (the 2n perturbed points sit on an
    axis inserted before the last). Step h_j = FD_STEP * max(|x_j|, scale_j), or FD_STEP where
    that is zero; the divisor is the difference actually represented in floating point.
    """
    point = np.asarray(point, dtype=float)
    n = point.shape[-1]
    size = np.abs(point)
    if scale is not None:
        size = np.maximum(size, scale)
    step = FD_STEP * np.where(size > 0, size, 1.0)
    offsets = step[..., None, :] * np.eye(n)                       # row j: h_j e_j
    plus = point[..., None, :] + offsets
    minus = point[..., None, :] - offsets
    values = function(np.concatenate([plus, minus], axis=-2))
    width = np.diagonal(plus - minus, axis1=-2, axis2=-1)           # (x_j + h_j) - (x_j - h_j)
    slopes = (values[..., :n, :] - values[..., n:, :]) / width[..., :, None]
    return _transpose(slopes)


def _state_scale(covariance: Optional[np.ndarray]) -> Optional[np.ndarray]:
    if covariance is None:
        return None
    return np.sqrt(np.clip(np.diagonal(covariance, axis1=-2, axis2=-1), 0.0, None))


def transition_jacobian(model, mean: np.ndarray, control, covariance: Optional[np.ndarray] = None) -> np.ndarray:
    """F = d f / d x at (mean, control, w = 0): the model's, or central differences."""
    analytic = model.transition_jacobian(mean, control)
    if analytic is not None:
        return np.broadcast_to(analytic, mean.shape + (mean.shape[-1],))
    zeros_shape = (model.process_noise_dimension,)
    return finite_difference_jacobian(
        lambda states: model.propagate(states, control, np.zeros(states.shape[:-1] + zeros_shape)),
        mean, _state_scale(covariance))


def measurement_jacobian(model, mean: np.ndarray, covariance: Optional[np.ndarray] = None) -> np.ndarray:
    """H = d h / d x at the mean: the model's, or central differences."""
    analytic = model.measurement_jacobian(mean)
    if analytic is not None:
        return np.broadcast_to(analytic, mean.shape[:-1] + (model.measurement_dimension, mean.shape[-1]))
    return finite_difference_jacobian(model.measurement_mean, mean, _state_scale(covariance))


def noise_jacobian(model, mean: np.ndarray, control) -> np.ndarray:
    """L = d f / d w at (mean, control, w = 0): the model's, or central differences over w."""
    analytic = model.process_noise_jacobian(mean, control)
    q = model.process_noise_dimension
    if analytic is not None:
        return np.broadcast_to(analytic, mean.shape + (q,))
    Q = model.process_noise.covariance()
    origin = np.zeros(mean.shape[:-1] + (q,))
    states = mean[..., None, :]
    return finite_difference_jacobian(
        lambda noise: model.propagate(np.broadcast_to(states, noise.shape[:-1] + mean.shape[-1:]).copy(),
                                      control, noise),
        origin, np.sqrt(np.clip(np.diag(Q), 0.0, None)))


def process_noise_in_state(model, mean: np.ndarray, control) -> np.ndarray:
    """L Q L' (trials, d, d): the process noise covariance in state coordinates (0 when Q = 0)."""
    Q = model.process_noise.covariance()
    d = mean.shape[-1]
    if not np.any(Q):
        return np.zeros(mean.shape[:-1] + (d, d))
    L = noise_jacobian(model, mean, control)
    return L @ Q @ _transpose(L)


# -- the unscented Kalman filter -----------------------------------------------------------------

def _unscented(model, measurements, prior, parameters: UnscentedParameters,
               diagnostics: Optional[dict] = None) -> FilterTrace:
    """Run the UKF; ``diagnostics`` (if given) counts the covariance repairs (key 'repairs')."""
    d = model.state_dimension
    c, _, _, weight = parameters.weights(d)
    curvature = parameters.beta - parameters.alpha ** 2          # the (beta - alpha^2) delta delta' term
    noise_r = model.measurement_noise.covariance()
    repairs = {"jitter": 0, "clipped": 0}
    factor = {}

    def moments(points, values):
        """Mean of ``values`` and cross-covariance of points and values, in the stable form."""
        d_points = points[:, 1:] - points[:, :1]
        d_values = values[:, 1:] - values[:, :1]
        shift_points = weight * d_points.sum(axis=1)
        shift_values = weight * d_values.sum(axis=1)
        cross = weight * np.einsum("rip,riq->rpq", d_points, d_values) \
            + curvature * np.einsum("rp,rq->rpq", shift_points, shift_values)
        return values[:, 0] + shift_values, cross

    def sigma_points(mean, square_root):
        offsets = c * _transpose(square_root)                     # row j: c S[:, j]
        return np.concatenate([mean[:, None], mean[:, None] + offsets, mean[:, None] - offsets], axis=1)

    def predict(mean, covariance, k):
        if k == 1:
            factor["S"], covariance = _robust_square_root(covariance, repairs)
        control = model.control(k)
        points = sigma_points(mean, factor["S"])
        noise = np.zeros(points.shape[:-1] + (model.process_noise_dimension,))
        propagated = model.propagate(points, control, noise)
        predicted, spread = moments(propagated, propagated)
        return predicted, spread + process_noise_in_state(model, mean, control)

    def update(mean, covariance, z, k):
        square_root, covariance = _robust_square_root(covariance, repairs)
        points = sigma_points(mean, square_root)
        images = model.measurement_mean(points)
        predicted_measurement, measurement_spread = moments(images, images)
        _, cross = moments(points, images)
        innovation = z - predicted_measurement
        S, nis, log_density = _innovation("ukf", model, k, innovation, measurement_spread + noise_r)
        gain = _transpose(np.linalg.solve(S, _transpose(cross)))
        mean = mean + np.einsum("rdm,rm->rd", gain, innovation)
        covariance = covariance - gain @ S @ _transpose(gain)
        _check_finite("ukf", model, k, "update", mean, covariance)
        factor["S"], covariance = _robust_square_root(covariance, repairs)
        return mean, covariance, nis, log_density

    trace = _run("ukf", model, measurements, prior, predict, update)
    if diagnostics is not None:
        diagnostics.update(repairs)
    return trace


def _robust_square_root(covariance: np.ndarray, repairs: dict) -> tuple[np.ndarray, np.ndarray]:
    """(S, P) with S S' = P, P the symmetrised covariance, repaired where Cholesky fails."""
    covariance = _symmetric(covariance)
    try:
        return np.linalg.cholesky(covariance), covariance
    except np.linalg.LinAlgError:
        pass
    factors = np.empty_like(covariance)
    repaired = covariance.copy()
    for r in range(covariance.shape[0]):
        try:
            factors[r] = np.linalg.cholesky(covariance[r])
        except np.linalg.LinAlgError:
            factors[r] = _repair(covariance[r], repairs)
            repaired[r] = _symmetric(factors[r] @ factors[r].T)
    return factors, repaired


def _repair(covariance: np.ndarray, repairs: dict) -> np.ndarray:
    """A square root of a nearby positive definite matrix (see the module docstring)."""
    d = covariance.shape[0]
    factor = np.zeros((d, d))
    variances = np.diagonal(covariance)
    active = variances > 0
    if not active.any():
        return factor
    scale = np.sqrt(variances[active])
    correlation = covariance[np.ix_(active, active)] / np.outer(scale, scale)
    root = None
    for jitter in (0.0,) + JITTERS:
        try:
            root = np.linalg.cholesky(correlation + jitter * np.eye(correlation.shape[0]))
            repairs["jitter"] += int(jitter > 0)
            break
        except np.linalg.LinAlgError:
            continue
    if root is None:
        values, vectors = np.linalg.eigh(correlation)
        values = np.clip(values, EIGENVALUE_FLOOR * max(values.max(), 1.0), None)
        root = vectors * np.sqrt(values)
        root /= np.sqrt(np.sum(root * root, axis=1, keepdims=True))   # unit diagonal: keep each variance
        repairs["clipped"] += 1
    factor[np.ix_(active, active)] = scale[:, None] * root
    return factor
