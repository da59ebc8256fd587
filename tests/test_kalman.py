"""The Gaussian filters kf, ekf and ukf (pfx.filters.kalman).

* ``kf`` against an independent textbook Kalman filter (plain loops, one trial at a time,
  standard covariance form) on random linear-Gaussian systems;
* ``ekf`` and ``ukf`` reduce to the KF on a linear model (the unscented transform is exact for
  linear maps; the EKF's Jacobians are then exact or central differences of a linear map);
* the falling body (variant jud, docs/reference-facts.md#falling-body, Julier, Uhlmann & Durrant-Whyte 2000):
  the UKF keeps a symmetric positive definite covariance and is consistent, the EKF is not;
* finite-difference Jacobians equal the models' analytic ones;
* errors: kf refuses nonlinear models, non-finite values name filter, model and step.

"Relative" below is normwise per (trial, step): ||a - b|| <= tol * ||b|| for covariances (Frobenius)
and log-likelihoods; for means the reference size is ||m|| + sqrt(trace P), the state's scale
(a mean component may pass through 0, where an elementwise relative error means nothing).
"""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from pfx.errors import ConfigError, ModelNumericalError
from pfx.filters import FILTERS, run_filter
from pfx.filters.kalman.linearisation import finite_difference_jacobian
from pfx.filters.kalman.unscented import UnscentedParameters, robust_square_root, run_unscented
from pfx.laws.initial import GaussianLaw, PointLaw
from pfx.models.base import bind_law
from pfx.models.falling_body import FallingBody
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.range_beacons import RangeBeacons
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams

SETTINGS = types.SimpleNamespace(unscented=UnscentedParameters())
SHAPES = [(d, m) for d in (1, 2, 4) for m in (1, 3)]


def run(kind, model, measurements, prior, settings=SETTINGS):
    return run_filter(kind, model, measurements, None, settings=settings, prior=prior)


# -- an independent textbook Kalman filter -----------------------------------------------------------

def textbook_kalman(measurements, A, H, Q, R, m0, P0, controls=None):
    """One trial at a time, plain loops, standard covariance form:
    predict m = A m + B u, P = A P A' + Q; update S = H P H' + R, K = P H' S^-1,
    m = m + K (z - H m), P = (I - K H) P; log-likelihood sum log N(z; H m_pred, S)."""
    trials, steps, _ = measurements.shape
    d = A.shape[0]
    means = np.empty((trials, steps, d))
    covariances = np.empty((trials, steps, d, d))
    log_likelihood = np.zeros(trials)
    nis = np.empty((trials, steps))
    for r in range(trials):
        m, P = np.array(m0, dtype=float), np.array(P0, dtype=float)
        for k in range(steps):
            m = A @ m + (controls[k] if controls is not None else 0.0)
            P = A @ P @ A.T + Q
            S = H @ P @ H.T + R
            S_inv = np.linalg.inv(S)
            K = P @ H.T @ S_inv
            nu = measurements[r, k] - H @ m
            nis[r, k] = nu @ S_inv @ nu
            log_likelihood[r] += -0.5 * (len(nu) * math.log(2 * math.pi) + np.linalg.slogdet(S)[1] + nu @ S_inv @ nu)
            m = m + K @ nu
            P = (np.eye(d) - K @ H) @ P
            means[r, k], covariances[r, k] = m, P
    return means, covariances, nis, log_likelihood


def random_spd(rng, n):
    M = rng.standard_normal((n, n))
    return M @ M.T / n + 0.2 * np.eye(n)


def random_system(d, m, seed, *, control=False, steps=20):
    """A stable random linear-Gaussian model (spectral radius 0.95) with full Q, R and a Gaussian
    prior, as a LinearGaussian whose initial law is that prior."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((d, d))
    A *= 0.95 / max(np.abs(np.linalg.eigvals(A)).max(), 1e-12)
    H = rng.standard_normal((m, d))
    Q, R, P0 = random_spd(rng, d), random_spd(rng, m), random_spd(rng, d)
    m0 = rng.standard_normal(d) * 3
    extra = {}
    if control:
        extra = dict(control_matrix=rng.standard_normal((d, 2)).tolist(),
                     controls=rng.standard_normal((steps, 2)).tolist())
    model = LinearGaussian(transition_matrix=A.tolist(), measurement_matrix=H.tolist(), steps=steps,
                           process_noise={"family": "gaussian", "variance": Q.tolist()},
                           measurement_noise={"family": "gaussian", "variance": R.tolist()},
                           initial={"kind": "gaussian", "mean": m0.tolist(), "covariance": P0.tolist()},
                           **extra)
    return model, model.initial, (A, H, Q, R, m0, P0)


def simulate(model, trials, seed):
    states, measurements = simulate_truth(model, TrialStreams.from_seeds(range(seed, seed + trials)))
    return states[:, 1:], measurements


def assert_traces_close(trace, means, covariances, log_likelihood, tol, nis=None, nis_tol=None):
    scale = np.linalg.norm(means, axis=-1) + np.sqrt(np.trace(covariances, axis1=-2, axis2=-1))
    assert (np.linalg.norm(trace.estimates - means, axis=-1) <= tol * scale).all()
    assert (np.linalg.norm(trace.covariances - covariances, axis=(-2, -1))
            <= tol * np.linalg.norm(covariances, axis=(-2, -1))).all()
    assert (np.abs(trace.log_likelihood - log_likelihood) <= tol * np.abs(log_likelihood)).all()
    if nis is not None:
        assert (np.abs(trace.nis - nis) <= (nis_tol or tol) * np.maximum(nis, 1.0)).all()


# -- 1. kf = textbook Kalman filter ------------------------------------------------------------------

def test_textbook_helper_on_hand_example():
    """1-D step by hand: A = H = Q = R = 1, m0 = 0, P0 = 1, z = 2: P- = 2, S = 3, K = 2/3,
    m = 4/3, P = 2/3, log p(z) = log N(2; 0, 3). Checks the reference and kf alike."""
    one = np.eye(1)
    means, covariances, nis, ll = textbook_kalman(np.array([[[2.0]]]), one, one, one, one, [0.0], one)
    expected_ll = -0.5 * (math.log(2 * math.pi * 3) + 4 / 3)
    assert (means[0, 0, 0], covariances[0, 0, 0, 0], nis[0, 0]) == pytest.approx((4 / 3, 2 / 3, 4 / 3))
    assert ll[0] == pytest.approx(expected_ll)
    model = LinearGaussian(transition_matrix=[[1.0]], measurement_matrix=[[1.0]], steps=1)
    prior = bind_law(GaussianLaw(mean=[0.0], covariance=1.0), 1, "initial")
    trace = run("kf", model, np.array([[[2.0]]]), prior)
    assert (trace.estimates[0, 0, 0], trace.covariances[0, 0, 0, 0]) == pytest.approx((4 / 3, 2 / 3), rel=1e-15)
    assert (trace.nis[0, 0], trace.log_likelihood[0]) == pytest.approx((4 / 3, expected_ll), rel=1e-15)
    assert trace.spread[0, 0] == pytest.approx(math.sqrt(2 / 3))


@pytest.mark.parametrize("d, m", SHAPES)
def test_kf_matches_textbook_kalman_filter(d, m):
    """Both are O(T d^3) double-precision recursions on well-conditioned matrices (eigenvalues of
    Q, R, P0 >= 0.2, stable A), differing only in the algebraic form of the update (Joseph's vs
    (I - K H) P, solve vs inverse) and the order of operations: their round-off differences are
    ~1e-14; 1e-9 leaves a wide margin, while any algorithmic slip (a transposition, a missing
    control, the prior instead of the predicted covariance) is an O(1) relative error."""
    for seed, control in ((10 * d + m, False), (100 + 10 * d + m, True)):
        model, prior, (A, H, Q, R, m0, P0) = random_system(d, m, seed, control=control)
        _, measurements = simulate(model, 5, seed)
        controls = [model.control(k) for k in range(1, model.steps + 1)] if control else None
        reference = textbook_kalman(measurements, A, H, Q, R, m0, P0, controls)
        trace = run("kf", model, measurements, prior)
        assert trace.estimates.shape == (5, model.steps, d) and trace.covariances.shape == (5, model.steps, d, d)
        assert_traces_close(trace, *reference[:2], reference[3], 1e-9, nis=reference[2])
        assert np.array_equal(trace.covariances, np.swapaxes(trace.covariances, -1, -2))


# -- 2. ekf and ukf on a linear model ----------------------------------------------------------------

class NumericalLinearGaussian(LinearGaussian):
    """The linear model without its analytic Jacobians: the EKF must use finite differences."""

    def transition_jacobian(self, state, control):
        return None

    def process_noise_jacobian(self, state, control):
        return None

    def measurement_jacobian(self, state):
        return None


@pytest.mark.parametrize("d, m", SHAPES)
def test_ekf_and_ukf_reduce_to_kf_on_linear_model(d, m):
    """EKF with the analytic Jacobians (F = A, L = I, H) does the KF's arithmetic (measured: 0).
    EKF with central differences: on a linear map the truncation error is zero and the rounding
    error is ~eps / FD_STEP = eps^(2/3) ~ 4e-11 relative per Jacobian entry (measured <= 2e-10
    after 20 steps); 1e-8.
    UKF: the unscented transform is exact for linear maps. At alpha = 1 (the original transform,
    beta = 0, kappa = 3 - d) only ordinary round-off remains (measured <= 2e-14): 1e-11. At the
    default alpha = 1e-3 the mean's second-difference term amplifies the sigma points' round-off
    by 1/alpha^2 (module docstring): ~1e-10 relative (measured <= 2.6e-10): 1e-9; NIS, a
    quadratic form in the innovation over sigma_z, carries it as an absolute ~1e-9 (measured
    <= 6.2e-9): 1e-7."""
    model, prior, _ = random_system(d, m, 7 * d + m, control=True)
    _, measurements = simulate(model, 5, 40 + d)
    kf = run("kf", model, measurements, prior)
    reference = (kf.estimates, kf.covariances, kf.log_likelihood)
    assert_traces_close(run("ekf", model, measurements, prior), *reference, 1e-12, nis=kf.nis)
    numerical = NumericalLinearGaussian(**model.model_dump())
    assert numerical.transition_jacobian(np.zeros(d), None) is None
    assert_traces_close(run("ekf", numerical, measurements, prior), *reference, 1e-8, nis=kf.nis)
    assert_traces_close(run("ukf", model, measurements, prior), *reference, 1e-9, nis=kf.nis, nis_tol=1e-7)
    original = types.SimpleNamespace(unscented=UnscentedParameters(alpha=1.0, beta=0.0, kappa=3.0 - d))
    assert_traces_close(run("ukf", model, measurements, prior, original), *reference, 1e-11, nis=kf.nis)


def test_ukf_with_point_prior_equals_kf():
    """A point prior (P0 = 0) has no square root's worth of spread: the sigma points coincide
    with the mean (zero-variance components are left out of the factor, no jitter is added),
    P1- = Q exactly as in the KF."""
    model, _, (_, _, _, _, m0, _) = random_system(2, 1, 3)
    prior = bind_law(PointLaw(state=m0.tolist()), 2, "initial")
    _, measurements = simulate(model, 3, 5)
    kf, ukf = run("kf", model, measurements, prior), run("ukf", model, measurements, prior)
    assert_traces_close(ukf, kf.estimates, kf.covariances, kf.log_likelihood, 1e-9)


# -- 3. the falling body (variant jud) -------------------------------------------------------------

@pytest.fixture(scope="module")
def falling_body_runs():
    model = FallingBody(variant="jud")
    prior = bind_law(model.default_prior(), 3, "initial")
    truth, measurements = simulate(model, 50, 1000)
    diagnostics = {}
    ukf = run_unscented(model, measurements, prior, UnscentedParameters(), diagnostics)
    ekf = run("ekf", model, measurements, prior)
    return model, truth, ukf, ekf, diagnostics


def per_trial_nees(trace, truth, mask):
    """Each trial's NEES (e' P^-1 e), averaged over the steps in ``mask``."""
    error = trace.estimates - truth
    nees = np.einsum("rtd,rtd->rt", error, np.linalg.solve(trace.covariances, error[..., None])[..., 0])
    return nees[:, mask].mean(axis=1)


def test_ukf_covariance_stays_positive_definite_on_falling_body(falling_body_runs):
    """20 trials, 60 steps: every reported covariance is exactly symmetric and has a Cholesky
    factor (positive definite), although it spans ~15 orders of magnitude (x3's variance falls
    below 1e-11 1/ft^2 while the altitude's is ~1e3 ft^2)."""
    _, _, ukf, _, _ = falling_body_runs
    covariances = ukf.covariances[:20]
    assert covariances.shape == (20, 60, 3, 3)
    assert np.array_equal(covariances, np.swapaxes(covariances, -1, -2))
    np.linalg.cholesky(covariances)          # raises LinAlgError if any is not positive definite
    assert (np.linalg.eigvalsh(covariances) > 0).all()


def test_ekf_is_inconsistent_and_ukf_consistent_on_falling_body(falling_body_runs):
    """The known result (Julier, Uhlmann & Durrant-Whyte 2000): after the body passes the radar's
    altitude (t = 10.1 s) the EKF is overconfident, NEES ~1e5 against an expected 3; the UKF is
    close to consistent and more accurate. Measured with these seeds (50 trials, t > 11 s): mean
    NEES EKF 3.7e5, UKF 3.4; final altitude RMSE EKF 225 ft, UKF 36 ft.
    Robustness, from 1000 other trials cut into 20 blocks of 50: the UKF's per-trial mean NEES
    has a heavy tail (median 2.3, 99th percentile 34, max 630), so its block means range from
    2.4 to 20 and are not asserted; the EKF/UKF ratio of block means was >= 1.2e4 (asserted:
    > 10), the UKF's block medians 1.9 to 2.6 (asserted: < 6), the ratio of final altitude
    RMSEs >= 3.4 (asserted: UKF < EKF)."""
    model, truth, ukf, ekf, _ = falling_body_runs
    late = model.times() > 11.0
    ekf_nees, ukf_nees = per_trial_nees(ekf, truth, late), per_trial_nees(ukf, truth, late)
    assert ekf_nees.mean() > 10 * ukf_nees.mean()
    assert np.median(ukf_nees) < 6
    rmse = lambda trace: np.sqrt(np.mean((trace.estimates[:, -1, 0] - truth[:, -1, 0]) ** 2))  # noqa: E731
    assert rmse(ukf) < rmse(ekf)


def test_robust_square_root_repairs_indefinite_and_badly_scaled_matrices():
    """A falling-body-like covariance (variances 1e6 and 1e-10, correlation 0.9) made slightly
    indefinite (correlation 1 + 1e-9) is repaired relative to each variance; a clearly indefinite
    one (correlation 1.5) by eigenvalue clipping, which keeps the variances; zero-variance
    components stay zero."""
    scales = np.array([1e3, 1e-5])
    good = np.outer(scales, scales) * np.array([[1.0, 0.9], [0.9, 1.0]])
    barely = np.outer(scales, scales) * np.array([[1.0, 1.0 + 1e-9], [1.0 + 1e-9, 1.0]])
    bad = np.outer(scales, scales) * np.array([[1.0, 1.5], [1.5, 1.0]])
    point = np.zeros((2, 2))
    repairs = {"jitter": 0, "clipped": 0}
    root, repaired = robust_square_root(np.stack([good, barely, bad, point]), repairs)
    assert repairs == {"jitter": 1, "clipped": 1}
    assert np.array_equal(repaired[0], good) and np.array_equal(repaired[3], point)
    for r in range(3):
        np.testing.assert_allclose(root[r] @ root[r].T, repaired[r], rtol=1e-12, atol=0)
        assert np.linalg.eigvalsh(repaired[r] / np.outer(scales, scales)).min() > 0
        np.testing.assert_allclose(np.diag(repaired[r]), scales ** 2, rtol=1e-5)
    np.testing.assert_allclose(repaired[1], barely, rtol=1e-5)


# -- 4. finite-difference Jacobians against the analytic ones ---------------------------------------

def test_finite_difference_jacobians_match_analytic():
    """Central differences with h = eps^(1/3) |x|: truncation ~h^2 |h'''| and rounding ~eps |f| / h,
    both < 1e-8 relative here (the beacons' ranges are >= 1, so |h'''| <= 1/r^2 is bounded);
    the Jacobians' rows have norm <= 1, so an absolute 1e-6 is a relative 1e-6."""
    rng = np.random.default_rng(11)
    body = FallingBody(variant="jud")
    states = np.column_stack([rng.uniform(2e4, 3e5, 200), rng.uniform(1e2, 2e4, 200), rng.uniform(1e-5, 2e-3, 200)])
    states[0, 0] = body.radar_altitude                       # the body level with the radar: dr/dx1 = 0
    analytic = body.measurement_jacobian(states)
    assert analytic.shape == (200, 1, 3)
    np.testing.assert_allclose(finite_difference_jacobian(body.measurement_mean, states), analytic, rtol=0, atol=1e-6)

    beacons = RangeBeacons(beacons=[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [-5.0, 7.0]], motion="odometry")
    points = rng.uniform(-20, 25, (400, 2))
    distances = np.linalg.norm(points[:, None, :] - np.asarray(beacons.beacons), axis=-1)
    points = points[(distances >= 1.0).all(axis=-1)]
    analytic = beacons.measurement_jacobian(points)
    assert analytic.shape == (len(points), 4, 2)
    np.testing.assert_allclose(np.linalg.norm(analytic, axis=-1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(finite_difference_jacobian(beacons.measurement_mean, points), analytic, rtol=0, atol=1e-6)
    zero = np.zeros(points.shape)
    numerical = finite_difference_jacobian(lambda x: beacons.propagate(x, beacons.control(3), np.zeros(x.shape)), points)
    np.testing.assert_allclose(numerical, beacons.transition_jacobian(points, beacons.control(3)), rtol=0, atol=1e-6)
    noise = finite_difference_jacobian(lambda w: beacons.propagate(points[:, None, :], None, w), zero)
    np.testing.assert_allclose(noise, beacons.process_noise_jacobian(points, None), rtol=0, atol=1e-6)
    assert beacons.measurement_jacobian(np.array([10.0, 0.0]))[1].tolist() == [0.0, 0.0]   # at a beacon


# -- errors ------------------------------------------------------------------------------------------

def test_kf_refuses_nonlinear_models_and_ukf_checks_kappa():
    model = FallingBody(variant="jud")
    prior = bind_law(model.default_prior(), 3, "initial")
    measurements = np.zeros((1, model.steps, 1))
    with pytest.raises(ConfigError, match="linear_gaussian") as caught:
        run("kf", model, measurements, prior)
    assert caught.value.key == "filter.kind"
    with pytest.raises(ValueError, match="@kind"):
        FILTERS["kf"].plan(model, SETTINGS, prior)
    FILTERS["ekf"].plan(model, SETTINGS, prior)
    bad = types.SimpleNamespace(unscented=UnscentedParameters(kappa=-3.0))
    with pytest.raises(ValueError, match="@unscented.kappa"):
        FILTERS["ukf"].plan(model, bad, prior)
    with pytest.raises(ConfigError) as caught:
        run("ukf", model, measurements, prior, bad)
    assert caught.value.key == "filter.unscented.kappa"
    with pytest.raises(ValueError):
        UnscentedParameters(alpha=0.0)


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_non_finite_state_names_filter_model_and_step(kind):
    """A negative ballistic coefficient makes the drag equation blow up in finite time
    (dv/dt = +|x3| e^(-gamma x1) v^2): the filter must stop with ModelNumericalError."""
    model = FallingBody(variant="jud")
    prior = bind_law(GaussianLaw(mean=[3e5, 2e4, -100.0], covariance=[1e6, 4e6, 1e-4]), 3, "initial")
    with pytest.raises(ModelNumericalError, match=rf"filter {kind}: model falling_body .* at step \d+"):
        run(kind, model, np.full((2, model.steps, 1), 2e5), prior)
