r"""The unscented Kalman filter.

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
:math:`P_k = P_k^- - K S K^\top`. A model with substeps between measurements is predicted by one
such unscented transform per substep (new sigma points from each substep's predicted moments),
after its accumulating components are reset (:func:`unscented_step_prediction`).

**Angular measurements** (a bearing: :mod:`~pfx.filters.kalman.measurement_form`): the images of
an angle are averaged on the circle, about the central one: their deviations
:math:`D_i = \mathcal Y_i - \mathcal Y_0` are wrapped into half a turn either side before the
sums below, so that :math:`\bar y = \mathcal Y_0 + \delta` is their weighted mean on the circle
(invariant to where the angles' branch cut lies), :math:`P_{zz}` and :math:`P_{xz}` are the
weighted products of the wrapped deviations, and the innovation :math:`\nu` is wrapped too. Not
the direction of the weighted resultant, :math:`\operatorname{atan2}(\sum_i W_i \sin
\mathcal Y_i, \sum_i W_i \cos \mathcal Y_i)`: with the scaled transform's large negative
:math:`W^m_0` its cosine sum is a second-order Taylor series of :math:`e^{-\sigma^2/2}`, which
turns negative (and the mean half a turn away) once the angle's spread exceeds about
:math:`\sqrt 2` rad; on the bearings-only example (examples/plugins, 40 trials) the UKF's RMSE was
6.6 with that mean (the covariances about it were not even positive definite: those about
:math:`\mathcal Y_0 + \delta` were used) against 0.24 with the mean about the central image (5.1
without wrapping). The two means agree to second order in the spread.

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

**On JAX arrays.** :func:`unscented_sigma_points` and :func:`unscented_moments` are written
against the array namespace (:mod:`pfx.numerics.arrays`), so that the particle filter's
unscented proposal (:mod:`pfx.filters.particle.proposals`) runs them in the jax backend's
compiled step, with the same numbers on NumPy. The repair above is NumPy's alone (it catches
NumPy's exception and writes rows in place): the UKF runs on numpy, and the proposal on jax
falls back to the transition's factor where Cholesky fails (see there).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat

from pfx.filters.kalman.linearisation import process_noise_in_state
from pfx.filters.kalman.measurement_form import MeasurementAngles, measurement_angles, measurement_innovation
from pfx.filters.kalman.recursion import check_finite, gaussian_recursion, innovation_terms, symmetric, transpose
from pfx.filters.trace import FilterTrace
from pfx.numerics.arrays import namespace

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



def run_unscented(model, measurements, prior, parameters: UnscentedParameters,
               diagnostics: Optional[dict] = None, scores: bool = False) -> FilterTrace:
    """Run the UKF; ``diagnostics`` (if given) counts the covariance repairs (key 'repairs');
    ``scores``: the predictive scores (:func:`~pfx.filters.kalman.recursion.gaussian_recursion`)."""
    d = model.state_dimension
    c, _, _, weight = parameters.weights(d)
    curvature = parameters.beta - parameters.alpha ** 2          # the (beta - alpha^2) delta delta' term
    noise_r = model.measurement_noise.covariance()
    repairs = {"jitter": 0, "clipped": 0}
    factor = {}

    angles = measurement_angles(model)

    def sigma_points(mean, square_root):
        return unscented_sigma_points(mean, square_root, c)

    def predict(mean, covariance, k):
        if "S" not in factor:          # the first step, or one whose update some trials skipped
            factor["S"], covariance = robust_square_root(covariance, repairs)
        return unscented_step_prediction(model, k, mean, covariance, factor["S"], parameters, repairs)

    def update(mean, covariance, z, k):
        square_root, covariance = robust_square_root(covariance, repairs)
        points = sigma_points(mean, square_root)
        images = model.measurement_mean(points)
        predicted_measurement, measurement_spread = unscented_moments(images, images, weight, curvature, angles, angles)
        _, cross = unscented_moments(points, images, weight, curvature, value_angles=angles)
        innovation = measurement_innovation(model, z, predicted_measurement)
        S, nis, log_density = innovation_terms("ukf", model, k, innovation, measurement_spread + noise_r)
        gain = transpose(np.linalg.solve(S, transpose(cross)))
        mean = mean + np.einsum("rdm,rm->rd", gain, innovation)
        covariance = covariance - gain @ S @ transpose(gain)
        check_finite("ukf", model, k, "update", mean, covariance)
        factor["S"], covariance = robust_square_root(covariance, repairs)
        return mean, covariance, nis, log_density, (innovation, S)

    def update_skipped():
        factor.pop("S", None)          # the update's square root covers only the observed trials

    trace = gaussian_recursion("ukf", model, measurements, prior, predict, update, update_skipped, scores)
    if diagnostics is not None:
        diagnostics.update(repairs)
    return trace


def unscented_step_prediction(model, step: int, mean: np.ndarray, covariance: np.ndarray,
                              square_root: np.ndarray, parameters: UnscentedParameters, repairs: dict):
    """The UKF's predict over step k: one :func:`unscented_prediction` per substep (one when the
    model has no substeps), each from the sigma points of the previous substep's moments, after
    the reset of the accumulating components (their means and their rows of S set to 0, so
    that S S' is the reset covariance): (x^-_k, P^-_k). ``square_root`` factors ``covariance``."""
    control = model.control(step)
    components = list(model.accumulating_components)
    if components:
        mean, square_root = model.reset_accumulators(mean), np.array(square_root)
        square_root[..., components, :] = 0.0
    for substep in range(model.propagations_per_step):
        if substep:
            square_root, covariance = robust_square_root(covariance, repairs)
        _, _, mean, covariance = unscented_prediction(model, control, mean, square_root, parameters,
                                                      model.substep_time(step, substep))
    return mean, covariance


def unscented_prediction(model, control, mean: np.ndarray, square_root: np.ndarray,
                         parameters: UnscentedParameters, time: Optional[float] = None):
    """The UKF's predict from N(mean, S S') (S = ``square_root``, the posterior's factor) over one
    ``propagate`` call starting at ``time`` (default: the start of step 1): the sigma points X_i,
    their images Y_i = f(X_i, u_k, 0), the predicted mean
    x^-_k = sum_i W^m_i Y_i and covariance P^-_k = sum_i W^c_i (Y_i - x^-_k)(Y_i - x^-_k)' + L Q L'
    (L at the mean): (X, Y, x^-_k, P^-_k), X and Y of shape (trials, 2d + 1, d)."""
    time = model.substep_time(1, 0) if time is None else time
    c, _, _, weight = parameters.weights(mean.shape[-1])
    points = unscented_sigma_points(mean, square_root, c)
    noise = np.zeros(points.shape[:-1] + (model.process_noise_dimension,))
    images = model.propagate_at(points, control, noise, time)
    predicted, spread = unscented_moments(images, images, weight, parameters.beta - parameters.alpha ** 2)
    return points, images, predicted, spread + process_noise_in_state(model, mean, control, time)


def unscented_moments(points: np.ndarray, values: np.ndarray, weight: float, curvature: float,
                      point_angles: Optional[MeasurementAngles] = None,
                      value_angles: Optional[MeasurementAngles] = None):
    """Mean of ``values`` and cross-covariance of ``points`` and ``values`` (rows: batch; axis 1:
    the 2d + 1 sigma points), in the stable form of the module docstring: W = ``weight``,
    ``curvature`` = beta - alpha^2. ``point_angles`` and ``value_angles`` name angular
    components of each (measurements: :mod:`~pfx.filters.kalman.measurement_form`): their
    deviations D_i = Y_i - Y_0 are wrapped into half a turn either side, so that their mean
    Y_0 + W sum_i D_i is taken on the circle (module docstring). NumPy or JAX alike
    (:mod:`pfx.numerics.arrays`): the unscented proposal runs it in the jax backend's step."""
    xp = namespace(points, values)
    d_points = points[:, 1:] - points[:, :1]
    d_values = values[:, 1:] - values[:, :1]
    if point_angles is not None:
        d_points = point_angles.wrap(d_points)
    if value_angles is not None:
        d_values = value_angles.wrap(d_values)
    shift_points = weight * d_points.sum(axis=1)
    shift_values = weight * d_values.sum(axis=1)
    cross = weight * xp.einsum("rip,riq->rpq", d_points, d_values) \
        + curvature * xp.einsum("rp,rq->rpq", shift_points, shift_values)
    return values[:, 0] + shift_values, cross


def unscented_sigma_points(mean: np.ndarray, square_root: np.ndarray, spread: float) -> np.ndarray:
    """The 2d + 1 sigma points of N(mean, S S') per row: mean, mean + c S[:, j], mean - c S[:, j]
    (c = ``spread``); mean (R, d), S (R, d, d) or one (d, d) for every row; returns (R, 2d + 1, d).
    NumPy or JAX alike."""
    xp = namespace(mean, square_root)
    offsets = spread * transpose(square_root)                     # row j: c S[:, j]
    return xp.concatenate([mean[:, None], mean[:, None] + offsets, mean[:, None] - offsets], axis=1)


def robust_square_root(covariance: np.ndarray, repairs: dict) -> tuple[np.ndarray, np.ndarray]:
    """(S, P) with S S' = P, P the symmetrised covariance, repaired where Cholesky fails."""
    covariance = symmetric(covariance)
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
            repaired[r] = symmetric(factors[r] @ factors[r].T)
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
