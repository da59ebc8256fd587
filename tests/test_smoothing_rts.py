"""The Rauch-Tung-Striebel smoother of the Gaussian filters (pfx.filters.kalman.smoothing).

* ``kf``: the smoother equals the exact smoothed law computed independently, by conditioning the
  joint Gaussian of the whole path x_1..x_T and z_1..z_T on the measurements (missing ones left
  out of the conditioning);
* at the last step the smoothed moments are the filtered ones; smoothing never increases a
  variance (P_k - P^s_k positive semi-definite), and here strictly reduces the total variance;
* ``ekf`` and ``ukf`` smoothers reduce to the kf's on a linear model;
* on two mildly nonlinear models the ekf and ukf smoothers are closer to the truth than the filters.

"Relative" is normwise per (trial, step), as in tests/test_kalman.py: ||a - b|| <= tol * ||b||
for covariances (Frobenius); for means the reference size is ||m|| + sqrt(trace P).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_kalman import NumericalLinearGaussian  # the linear model without its analytic Jacobians

import pfx
from pfx.errors import ModelNumericalError
from pfx.filters.kalman.smoothing import rts_smooth
from pfx.filters.kalman.unscented import UnscentedParameters
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams

STEPS = 15
# constant velocity, time step 1: position and velocity, the position measured; the control is an
# acceleration (B = [dt^2/2, dt]), so an off-by-one in the control's step would move every mean
TRANSITION = np.array([[1.0, 1.0], [0.0, 1.0]])
MEASUREMENT = np.array([[1.0, 0.0]])
PROCESS = 0.5 * np.array([[1.0 / 3.0, 0.5], [0.5, 1.0]])   # white-noise acceleration, intensity 0.5
NOISE = np.array([[4.0]])
CONTROL_MATRIX = np.array([[0.5], [1.0]])
CONTROLS = 0.3 * np.sin(np.arange(1, STEPS + 1))[:, None]
PRIOR_MEAN = np.array([0.0, 1.0])
PRIOR_COVARIANCE = np.diag([4.0, 1.0])
# (trial, step k) pairs without a measurement: one in the middle of trial 0; in trial 1 an early
# one and the last step (whose smoothed moments are then the prediction's)
MISSING = ((0, 7), (1, 3), (1, STEPS))


def constant_velocity(model_class=LinearGaussian):
    parameters = dict(
        steps=STEPS, transition_matrix=TRANSITION.tolist(), measurement_matrix=MEASUREMENT.tolist(),
        control_matrix=CONTROL_MATRIX.tolist(), controls=CONTROLS.tolist(),
        process_noise={"variance": PROCESS.tolist()}, measurement_noise={"variance": NOISE.tolist()},
        initial={"kind": "gaussian", "mean": PRIOR_MEAN.tolist(), "covariance": PRIOR_COVARIANCE.tolist()})
    if model_class is LinearGaussian:
        return pfx.model("linear_gaussian", **parameters)
    return model_class(**parameters)


def measurements(model, seeds, missing=()):
    _, z = simulate_truth(model, TrialStreams.from_seeds(seeds))
    for trial, k in missing:
        z[trial, k - 1] = np.nan
    return z


def last_measured_steps(z):
    """Per trial, the last step k with a measurement (0 if none)."""
    observed = ~np.isnan(z).any(axis=-1)
    return np.where(observed.any(axis=1), z.shape[1] - np.argmax(observed[:, ::-1], axis=1), 0)


def smooth(model, z, kind, unscented=None):
    settings = {"unscented": unscented.model_dump()} if unscented is not None else {}
    trace = pfx.particle_filter(model, kind=kind, **settings)(z).trace
    return trace, rts_smooth(model, trace, kind, unscented)


def joint_gaussian_smoother(z):
    """The smoothed means (T, d) and covariances (T, d, d) of one trial by brute force: stack the
    path X = (x_1..x_T) and Z = (z_1..z_T). With x_k = A^k x_0 + sum_{j<=k} A^(k-j) (B u_j + w_j),
    X = M x_0 + N (b + w) (M: the blocks A^k; N: block lower triangular, A^(k-j)), so
    E X = M m_0 + N b, Cov X = M P_0 M' + N (I (x) Q) N'; Z = (I (x) H) X + v. Then, over the
    observed rows of Z only, E[X | z] = E X + S_xz S_zz^-1 (z - E Z),
    Cov[X | z] = S_xx - S_xz S_zz^-1 S_zx, whose diagonal blocks are the smoothed covariances.
    Returns also the condition number of Cov X, which bounds the round-off of either computation."""
    d, m = TRANSITION.shape[0], MEASUREMENT.shape[0]
    powers = [np.linalg.matrix_power(TRANSITION, k) for k in range(STEPS + 1)]
    M = np.vstack(powers[1:])
    N = np.zeros((STEPS * d, STEPS * d))
    for k in range(1, STEPS + 1):
        for j in range(1, k + 1):
            N[(k - 1) * d:k * d, (j - 1) * d:j * d] = powers[k - j]
    mean_x = M @ PRIOR_MEAN + N @ (CONTROLS @ CONTROL_MATRIX.T).ravel()
    S_xx = M @ PRIOR_COVARIANCE @ M.T + N @ np.kron(np.eye(STEPS), PROCESS) @ N.T
    H = np.kron(np.eye(STEPS), MEASUREMENT)
    observed = np.repeat(~np.isnan(z).any(axis=-1), m)
    S_xz = (S_xx @ H.T)[:, observed]
    S_zz = (H @ S_xx @ H.T + np.kron(np.eye(STEPS), NOISE))[np.ix_(observed, observed)]
    mean = mean_x + S_xz @ np.linalg.solve(S_zz, z.ravel()[observed] - (H @ mean_x)[observed])
    covariance = S_xx - S_xz @ np.linalg.solve(S_zz, S_xz.T)
    blocks = np.array([covariance[k * d:(k + 1) * d, k * d:(k + 1) * d] for k in range(STEPS)])
    return mean.reshape(STEPS, d), blocks, np.linalg.cond(S_xx)


def assert_moments_close(means, covariances, reference_means, reference_covariances, tol):
    scale = np.linalg.norm(reference_means, axis=-1) + np.sqrt(np.trace(reference_covariances, axis1=-2, axis2=-1))
    assert (np.linalg.norm(means - reference_means, axis=-1) <= tol * scale).all()
    assert (np.linalg.norm(covariances - reference_covariances, axis=(-2, -1))
            <= tol * np.linalg.norm(reference_covariances, axis=(-2, -1))).all()


# -- 1. kf: the exact smoother -----------------------------------------------------------------------

@pytest.mark.parametrize("missing", [(), MISSING], ids=["complete", "missing"])
def test_kf_smoother_equals_joint_gaussian_conditioning(missing):
    """Two computations of the same exact Gaussian conditioning: the RTS recursion (T steps of
    2 x 2 algebra) and one solve with the (T m) x (T m) covariance of the measurements. Each is
    backward stable, so each is within ~cond * eps of the truth, cond (of the path's joint
    covariance) asserted below 1e7 (measured 3.5e5): at most ~2e-9, and 1e-8 covers it (measured
    agreement ~1e-13), while any algorithmic slip (the gain's transpose, the control at step k
    instead of k+1, the filtered instead of the predicted covariance) is an O(1) relative error.
    The smoother must differ from the filter (the test would otherwise not see a smoother that
    returns the filtered moments): at every step before the trial's last measurement, by more
    than 1e-3 of the scale (measured: at least 0.008)."""
    model = constant_velocity()
    z = measurements(model, [11, 12], missing)
    trace, (means, covariances) = smooth(model, z, "kf")
    assert means.shape == (2, STEPS, 2) and covariances.shape == (2, STEPS, 2, 2)
    for trial, last in enumerate(last_measured_steps(z)):
        reference_means, reference_covariances, condition = joint_gaussian_smoother(z[trial])
        assert condition < 1e7
        assert_moments_close(means[trial], covariances[trial], reference_means, reference_covariances, 1e-8)
        scale = np.linalg.norm(reference_means, axis=-1) + np.sqrt(np.trace(reference_covariances, axis1=-2, axis2=-1))
        moved = np.linalg.norm(means[trial] - trace.estimates[trial], axis=-1)
        assert (moved[:last - 1] > 1e-3 * scale[:last - 1]).all()


@pytest.mark.parametrize("missing", [(), MISSING], ids=["complete", "missing"])
def test_smoother_starts_at_the_filter_and_never_increases_a_variance(missing):
    """m^s_T = m_T and P^s_T = P_T exactly (the recursion's start: no arithmetic). After a
    trial's last measurement L (trial 1 of ``missing`` has none at T), the smoothed moments are
    the filtered ones, exactly too: from L to T the filtered moments are predictions, and the
    smoother's prediction is the filter's own function, so m^s_{k+1} - m^-_{k+1} and
    P^s_{k+1} - P^-_{k+1} are exactly 0 for k >= L. For k < T, P_k - P^s_k =
    G_k (P^-_{k+1} - P^s_{k+1}) G_k' is positive semi-definite: its eigenvalues >= -1e-12 ||P_k||
    (round-off of 2 x 2 products of entries of size ||P_k||, ~1e-15 relative); and before L it
    is not zero: trace(P_k - P^s_k) > 0 (a later measurement carries information about x_k
    through the correlated dynamics; measured: at least 1.5)."""
    model = constant_velocity()
    z = measurements(model, [21, 22], missing)
    for kind in ("kf", "ekf", "ukf"):
        trace, (means, covariances) = smooth(model, z, kind)
        for trial, last in enumerate(last_measured_steps(z)):
            assert np.array_equal(means[trial, last - 1:], trace.estimates[trial, last - 1:])
            assert np.array_equal(covariances[trial, last - 1:], trace.covariances[trial, last - 1:])
            reduction = trace.covariances[trial] - covariances[trial]
            size = np.linalg.norm(trace.covariances[trial], axis=(-2, -1))
            assert (np.linalg.eigvalsh(reduction).min(axis=-1) >= -1e-12 * size).all()
            assert (np.trace(reduction[:last - 1], axis1=-2, axis2=-1) > 0).all()
        assert np.array_equal(covariances, np.swapaxes(covariances, -1, -2))


# -- 2. ekf and ukf on a linear model ----------------------------------------------------------------

def test_ekf_and_ukf_smoothers_reduce_to_kf_on_linear_model():
    """The tolerances of tests/test_kalman.py's filter comparison, for the same reasons: the
    smoother's backward pass adds the same kind of arithmetic as the filter's predict, and its
    gains are contractions here, so the filters' differences carry over without growing.
    EKF with the analytic Jacobians (F = A, L = I): the KF's arithmetic (measured: 0): 1e-12.
    EKF with central differences: eps^(2/3) ~ 4e-11 relative per Jacobian entry: 1e-8.
    UKF at alpha = 1 (beta = 0, kappa = 3 - d): ordinary round-off (measured 5e-15): 1e-11.
    UKF at the default alpha = 1e-3: the sigma points' round-off amplified by 1/alpha^2 in the
    predicted mean, ~1e-10 relative (measured 7e-11): 1e-9."""
    model = constant_velocity()
    z = measurements(model, [31, 32], MISSING)
    _, reference = smooth(model, z, "kf")
    _, analytic = smooth(model, z, "ekf")
    assert_moments_close(*analytic, *reference, 1e-12)
    numerical = constant_velocity(NumericalLinearGaussian)
    assert numerical.transition_jacobian(np.zeros(2), None) is None
    _, differences = smooth(numerical, z, "ekf")
    assert_moments_close(*differences, *reference, 1e-8)
    _, unscented = smooth(model, z, "ukf")
    assert_moments_close(*unscented, *reference, 1e-9)
    _, original = smooth(model, z, "ukf", UnscentedParameters(alpha=1.0, beta=0.0, kappa=1.0))
    assert_moments_close(*original, *reference, 1e-11)


# -- 3. nonlinear models: closer to the truth than the filter ----------------------------------------

NONLINEAR = {
    # growth with a gentler bump and forcing: the state stays within ~[1.5, 9] (its prior at 5),
    # so the quadratic measurement's sign ambiguity never arises; the transition's slope
    # a + b (1 - x^2)/(1 + x^2)^2 still ranges over ~0.2..0.8
    "growth": dict(kind="growth", a=0.8, b=5.0, c=1.0, process_noise={"variance": 0.5},
                   measurement_noise={"variance": 1.0}, initial={"kind": "gaussian", "mean": [5.0], "covariance": 0.5}),
    # ranges to three beacons (nonlinear measurement), odometry along the designed path (the
    # control enters the smoother's prediction at step k + 1)
    "range_beacons": dict(kind="range_beacons", beacons=[[0.0, 0.0], [3.0, 0.0], [0.0, 3.0]],
                          initial={"kind": "gaussian", "mean": [0.0, 1.0], "covariance": 0.1}),
}


@pytest.mark.parametrize("name", sorted(NONLINEAR))
@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_nonlinear_smoother_is_closer_to_the_truth_than_the_filter(name, kind):
    """For the exact smoother E||x_k - m^s_k||^2 <= E||x_k - m_k||^2 at every step (it conditions
    on more data); the EKF and UKF smoothers are approximations, with no such theorem, but on
    these mildly nonlinear models (where the filters are nearly linear over their spread) they
    should gain as the exact one does. Paired over 40 trials (the same truth and measurements):
    the difference of each trial's RMSE over the steps, smoother minus filter, has its mean below
    -3 standard errors of the mean, i.e. the smoother is better beyond chance (a one-sided 0.13 %
    level under "no better"). That is stronger than "not worse", on purpose: a smoother that
    returned the filtered estimates would give exactly 0 and fail. (Measured: z = -6 on growth,
    -17 on range_beacons.) The variances never increase (as in the linear test)."""
    parameters = dict(NONLINEAR[name])
    model = pfx.model(parameters.pop("kind"), **parameters)
    states, z = simulate_truth(model, TrialStreams.from_seeds(range(1000, 1040)))
    trace, (means, covariances) = smooth(model, z, kind)
    truth = states[:, 1:]
    filtered = np.sqrt(np.mean(np.sum((trace.estimates - truth) ** 2, axis=-1), axis=-1))
    smoothed = np.sqrt(np.mean(np.sum((means - truth) ** 2, axis=-1), axis=-1))
    difference = smoothed - filtered
    standard_error = difference.std(ddof=1) / np.sqrt(len(difference))
    assert difference.mean() < -3 * standard_error
    reduction = trace.covariances - covariances
    size = np.linalg.norm(trace.covariances, axis=(-2, -1))
    assert (np.linalg.eigvalsh(reduction).min(axis=-1) >= -1e-12 * size).all()


# -- 4. refusals ---------------------------------------------------------------------------------------

def test_refusals():
    """Only a Gaussian filter's trace with covariances; kf only on a linear model; a singular
    predicted covariance (point prior, no process noise) names the kind, model and step."""
    model = constant_velocity()
    z = measurements(model, [41], ())
    trace = pfx.particle_filter(model, kind="kf")(z).trace
    with pytest.raises(ValueError, match="not particle"):
        rts_smooth(model, trace, "particle")
    growth = pfx.model("growth")
    with pytest.raises(ValueError, match="linear_gaussian"):
        rts_smooth(growth, pfx.particle_filter(growth, kind="ekf")(measurements(growth, [41])).trace, "kf")
    trace.covariances = None
    with pytest.raises(ValueError, match="covariances"):
        rts_smooth(model, trace, "kf")
    still = pfx.model("linear_gaussian", steps=3, transition_matrix=[[1.0]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 0.0}, initial={"kind": "point", "state": [0.0]})
    point = pfx.particle_filter(still, kind="kf")(np.ones((1, 3, 1))).trace
    with pytest.raises(ModelNumericalError, match="filter kf: model linear_gaussian gave a singular predicted covariance at step 3"):
        rts_smooth(still, point, "kf")
