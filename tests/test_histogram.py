"""The growth model and the grid (histogram) filter.

The grid filter is the reference posterior for 1-D and 2-D models; these tests check it against
the exact answer where there is one (the Kalman filter on linear-Gaussian models, a brute-force
log-sum-exp for its predict step, the analytic mass leaving a grid), and check the particle
filter against it where there is not (the growth model, range beacons), at the Monte Carlo
rate. All seeds are fixed.
"""

from __future__ import annotations

import math
import types

import numpy as np
import pytest
from scipy.special import logsumexp
from scipy.stats import norm

import pfx
from pfx.errors import ConfigError
from pfx.filters import run_filter
from pfx.filters.histogram.filter import run_histogram_filter
from pfx.filters.histogram.grid import GridParameters, axis_noises, plan_grid
from pfx.filters.histogram.kernel import Transition
from pfx.filters.particle.recorders import SpreadCriterion
from pfx.laws.initial import GaussianLaw
from pfx.models import MODELS
from pfx.models.base import bind_law
from pfx.models.falling_body import FallingBody
from pfx.models.growth import GrowthModel
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.range_beacons import RangeBeacons
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams


def kalman_filter(measurements, A, H, Q, R, m0, P0):
    """Textbook Kalman filter: filtered means (R, T, d), covariances (T, d, d), NIS (R, T) and
    log p(z_1:T) (R,). predict m = A m, P = A P A' + Q; update S = H P H' + R, K = P H' S^-1."""
    A, H, Q, R, P = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (A, H, Q, R, P0))
    trials, steps, _ = measurements.shape
    d = A.shape[0]
    m = np.broadcast_to(np.asarray(m0, dtype=float), (trials, d)).copy()
    means, covariances = np.empty((trials, steps, d)), np.empty((steps, d, d))
    nis, log_likelihood = np.empty((trials, steps)), np.zeros(trials)
    for k in range(steps):
        m, P = m @ A.T, A @ P @ A.T + Q
        S = H @ P @ H.T + R
        innovation = measurements[:, k] - m @ H.T
        weighted = innovation @ np.linalg.inv(S)
        nis[:, k] = np.sum(weighted * innovation, axis=1)
        log_likelihood += -0.5 * nis[:, k] - 0.5 * np.log(np.linalg.det(2 * np.pi * S))
        K = P @ H.T @ np.linalg.inv(S)
        m, P = m + innovation @ K.T, (np.eye(d) - K @ H) @ P
        means[:, k], covariances[k] = m, P
    return means, covariances, nis, log_likelihood


def linear_model(A, H, Q, R, mean, covariance, steps):
    prior = GaussianLaw(mean=mean, covariance=covariance)
    return LinearGaussian(transition_matrix=A, measurement_matrix=H, steps=steps,
                          process_noise={"variance": Q}, measurement_noise={"variance": R},
                          initial=prior.model_dump())


# -- the growth model -------------------------------------------------------------------------------

def test_growth_model_is_registered_with_the_published_presets():
    model = MODELS["growth"]()
    assert isinstance(model, GrowthModel)
    assert (model.steps, model.dt) == (50, 1.0)
    assert model.process_noise.covariance()[0, 0] == pytest.approx(10.0, rel=1e-15)
    assert model.measurement_noise.covariance()[0, 0] == pytest.approx(1.0, rel=1e-15)
    assert model.initial.mean_vector().tolist() == [0.0]
    assert model.initial.covariance_matrix()[0, 0] == pytest.approx(10.0, rel=1e-15)
    assert (model.state_names, model.position_components, model.measurement_dimension) == (("x",), (0,), 1)


def test_growth_model_equations_on_hand_values():
    """x_k = x/2 + 25 x / (1 + x^2) + 8 cos(1.2 k) + v, z = x^2 / 20 + w, worked by hand."""
    model = GrowthModel()
    # x = 1, k = 1: 0.5 + 12.5 + 8 cos(1.2) = 13 + 8 x 0.36235775 = 15.8988620
    assert model.control(1)[0] == pytest.approx(8 * math.cos(1.2), rel=1e-15)
    x = np.array([[1.0], [-2.0], [0.0]])
    assert model.propagate(x[:1], model.control(1), np.zeros((1, 1)))[0, 0] == pytest.approx(15.8988620358, abs=1e-9)
    # x = -2, k = 3: -1 - 10 + 8 cos(3.6) = -11 - 7.174064...; with noise 0.5 added
    assert model.propagate(x[1:2], model.control(3), np.array([[0.5]]))[0, 0] == \
        pytest.approx(-11 + 8 * math.cos(3.6) + 0.5, rel=1e-15)
    # vectorised over leading dimensions (trials, particles, 1)
    particles = np.arange(-3.0, 3.0, 0.5).reshape(2, 6, 1)
    moved = model.propagate(particles, model.control(2), np.zeros_like(particles))
    assert moved.shape == particles.shape
    assert np.allclose(moved, particles / 2 + 25 * particles / (1 + particles ** 2) + 8 * math.cos(2.4), rtol=1e-15)
    assert model.measurement_mean(np.array([[4.0], [-4.0]]))[:, 0].tolist() == [0.8, 0.8]
    # Gordon et al.'s indexing, cos(1.2 (k - 1)): the forcing at k = 1 is 8
    assert GrowthModel(forcing_offset=1).control(1)[0] == 8.0
    # analytic EKF Jacobians against central differences
    point, h = np.array([[1.7]]), 1e-6
    def f(y):
        return model.propagate(y, None, np.zeros_like(y))

    assert model.transition_jacobian(point, None)[0, 0, 0] == pytest.approx(
        (f(point + h) - f(point - h))[0, 0] / (2 * h), rel=1e-7)
    assert model.measurement_jacobian(point)[0, 0, 0] == pytest.approx(2 * 1.7 / 20)


def test_growth_truth_simulation_follows_the_recursion():
    """With zero process noise the simulated truth is the deterministic recursion from x_0 = 0.1
    (computed here with Python floats); the measurement residuals z - x^2/20 are the N(0, 1)
    noise: over 400 x 30 draws their mean is within 4 standard errors of 0 and their variance
    within 4 standard errors (sqrt(2 / n)) of 1."""
    model = GrowthModel(steps=30, process_noise={"variance": 0.0}, initial={"kind": "point", "state": [0.1]})
    states, measurements = simulate_truth(model, TrialStreams.from_seeds(range(400)))
    x, expected = 0.1, [0.1]
    for k in range(1, 31):
        x = 0.5 * x + 25 * x / (1 + x * x) + 8 * math.cos(1.2 * k)
        expected.append(x)
    assert np.allclose(states[:, :, 0], expected, rtol=1e-12, atol=1e-12)
    residuals = (measurements[..., 0] - states[:, 1:, 0] ** 2 / 20).ravel()
    n = residuals.size
    assert abs(residuals.mean()) < 4 / math.sqrt(n)
    assert abs(residuals.var() - 1.0) < 4 * math.sqrt(2 / n)


# -- the grid filter against exact answers --------------------------------------------------------

def test_grid_filter_equals_kalman_in_1d():
    """On x' = 0.9 x + w, z = x + v the grid posterior is the Kalman posterior.

    Tolerance: the grid's moments are midpoint-rule sums of Gaussian integrands, whose error
    falls like exp(-2 pi^2 sigma^2 / Delta^2) (Poisson summation); here sigma >= 0.6 (the
    narrowest density involved) and Delta < 0.03, so that term is below e^-7800, far under the
    Delta^2/12 = 7e-5 of a cell-average (Sheppard) argument. What is left is the mass beyond the
    grid (recorded, < 1e-9) and rounding over 1000 cells (~1e-13): 1e-9 covers both.
    """
    model = linear_model([[0.9]], [[1.0]], 0.5, 1.0, [1.0], 2.0, steps=20)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(10)))
    grid = plan_grid(model, model.initial, GridParameters(cells=1000))
    assert grid.widths[0] < 0.03
    trace = run_histogram_filter(model, measurements, prior=model.initial, grid=grid)
    means, covariances, nis, log_likelihood = kalman_filter(measurements, 0.9, 1.0, 0.5, 1.0, [1.0], 2.0)
    assert trace.grid_lost_mass.max() < 1e-9
    assert np.abs(trace.estimates - means).max() < 1e-9
    assert np.abs(trace.covariances - covariances).max() < 1e-9
    assert np.abs(trace.nis - nis).max() < 1e-8
    assert np.abs(trace.log_likelihood - log_likelihood).max() < 1e-8
    assert np.isnan(trace.ess).all() and not trace.resampled.any() and not trace.degenerate.any()


TWO_D_DYNAMICS = {                               # A, and on which axes f_c depends on x_c alone
    "separable": ([[0.9, 0.0], [0.0, 0.8]], (True, True)),      # K = K1 (x) K2
    "velocity": ([[1.0, 0.5], [0.0, 0.9]], (False, True)),      # constant-velocity-like: f_2(x_2)
    "first-axis": ([[0.9, 0.0], [0.3, 0.8]], (True, False)),    # f_1(x_1) only
    "general": ([[0.9, 0.2], [-0.1, 0.8]], (False, False)),     # the G x G_c factors
}


@pytest.mark.parametrize("name", list(TWO_D_DYNAMICS))
def test_grid_filter_equals_kalman_in_2d(name):
    """Every 2-D predict path reproduces the Kalman posterior (same tolerance argument as in 1-D:
    cells of at most 0.35 against standard deviations >= 0.55 leave e^-48 or less; the rest is
    the mass beyond the grid, recorded below 1e-6)."""
    A, own_axis = TWO_D_DYNAMICS[name]
    H = [[1.0, 0.0], [0.5, 1.0]]
    model = linear_model(A, H, [0.5, 0.3], 1.0, [1.0, -1.0], [2.0, 1.0], steps=8)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(20, 24)))
    grid = plan_grid(model, model.initial, GridParameters(cells=[140, 70]))
    assert grid.widths.max() < 0.35
    transition = Transition(model, grid, axis_noises(model))
    assert transition.kernel(grid.points, 1, on_grid=True).own_axis == own_axis
    trace = run_histogram_filter(model, measurements, prior=model.initial, grid=grid)
    means, covariances, nis, log_likelihood = kalman_filter(
        measurements, A, H, np.diag([0.5, 0.3]), np.eye(2), [1.0, -1.0], np.diag([2.0, 1.0]))
    assert trace.grid_lost_mass.max() < 1e-6
    assert np.abs(trace.estimates - means).max() < 1e-8
    assert np.abs(trace.covariances - covariances).max() < 1e-8
    assert np.abs(trace.nis - nis).max() < 1e-7
    assert np.abs(trace.log_likelihood - log_likelihood).max() < 1e-8


@pytest.mark.parametrize("dimension", [1, 2])
def test_grid_filter_from_a_point_prior_equals_kalman(dimension):
    """A point prior enters as the kernel from that point at step 1 (one source, however the
    dynamics look), then the grid takes over: the Kalman filter with P0 = 0 is exact."""
    A = [[0.9]] if dimension == 1 else TWO_D_DYNAMICS["general"][0]
    H = [[1.0]] if dimension == 1 else [[1.0, 0.0], [0.5, 1.0]]
    Q = [0.5] * dimension
    start = [2.0] * dimension
    model = LinearGaussian(transition_matrix=A, measurement_matrix=H, steps=6, process_noise={"variance": Q},
                           measurement_noise={"variance": 1.0}, initial={"kind": "point", "state": start})
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(40, 43)))
    grid = plan_grid(model, model.initial, GridParameters(cells=400 if dimension == 1 else 80))
    trace = run_histogram_filter(model, measurements, prior=model.initial, grid=grid)
    means, covariances, _, log_likelihood = kalman_filter(
        measurements, A, H, np.diag(Q), np.eye(len(H)), start, np.zeros((dimension, dimension)))
    assert np.abs(trace.estimates - means).max() < 1e-8
    assert np.abs(trace.covariances - covariances).max() < 1e-8
    assert np.abs(trace.log_likelihood - log_likelihood).max() < 1e-8


@pytest.mark.parametrize("name", ["1-d", *TWO_D_DYNAMICS])
def test_predict_equals_the_log_domain_sum(name):
    """The certified matrix-product predict against a brute-force log-sum-exp, with source
    log-probabilities of narrow bumps (std 0.3) spanning thousands of nats: every entry within
    e^-40 / G of the largest posterior entry agrees to 1e-12 (relative), every other is a lower
    bound; and a likelihood that favours a cell deep in the tail (predicted < e^-300) forces
    its exact recomputation."""
    rng = np.random.default_rng(5)
    if name == "1-d":
        dimension, own_axis = 1, (False,)
        model = linear_model([[0.9]], [[1.0]], 0.5, 1.0, [0.0], 1.0, steps=3)
        grid = plan_grid(model, model.initial, GridParameters(low=[-30.0], high=[30.0], cells=300))
    else:
        dimension, (A, own_axis) = 2, TWO_D_DYNAMICS[name]
        model = linear_model(A, [[1.0, 0.0]], [0.5, 0.3], 1.0, [0.0, 0.0], 1.0, steps=3)
        grid = plan_grid(model, model.initial, GridParameters(low=[-14.0, -10.0], high=[14.0, 10.0], cells=[56, 40]))
    transition = Transition(model, grid, axis_noises(model))
    kernel = transition.kernel(grid.points, 1, on_grid=True)
    assert kernel.own_axis == own_axis
    size = grid.size
    centres = rng.uniform(-5.0, 5.0, (3, 1, dimension))
    log_weights = -0.5 * np.sum((grid.points - centres) ** 2, axis=-1) / 0.3 ** 2 + rng.normal(0, 3, (3, size))
    log_weights -= logsumexp(log_weights, axis=1, keepdims=True)
    # brute force: log K_ij from the same per-axis columns, then log-sum-exp over the sources
    log_kernel = np.zeros((size, size))
    index = np.unravel_index(np.arange(size), grid.cells)
    for c in range(dimension):
        columns = transition.log_column(kernel, c, np.arange(grid.cells[c]))       # (rows_c, G_c)
        rows = index[c] if own_axis[c] else np.arange(size)        # the row of each source
        log_kernel += columns[rows][:, index[c]]
    exact = logsumexp(log_weights[:, :, None] + log_kernel[None], axis=1)
    likelihood = np.zeros((3, size))
    far = int(np.argmin(exact[0]))                      # the least probable cell of trial 0
    likelihood[0] = -5000.0
    likelihood[0, far] = 0.0                            # ... is the only one the measurement allows
    recomputed = []
    exact_sum = transition._exact
    transition._exact = lambda *args: recomputed.append(args[3]) or exact_sum(*args)
    log_q, _ = transition.predict(kernel, log_weights, lambda: likelihood)
    assert exact[0, far] < -300
    assert len(recomputed) == 1 and far in recomputed[0]
    assert log_q[0, far] == pytest.approx(exact[0, far], rel=1e-12)
    candidate = exact + likelihood
    matters = candidate > candidate.max(axis=1, keepdims=True) - 40 - math.log(size)
    assert np.allclose(log_q[matters], exact[matters], rtol=1e-12, atol=1e-12)
    assert np.all(log_q <= exact + 1e-9 * np.abs(exact) + 1e-12)


def test_mass_leaving_the_grid_is_recorded():
    """Random walk x' = x + w, w ~ N(0, 1), prior N(0, 0.25), grid [-3, 3]: the probability of
    leaving at step 1 is P(|x_1| > 3) with x_1 ~ N(0, 1.25), 2 (1 - Phi(3 / sqrt 1.25)) =
    0.00729. The lattice sums are midpoint rules on smooth integrands, off by O(Delta^2 p') at
    the edges (~1e-7 here): 1e-6 absolute. The filter goes on with the renormalised posterior."""
    model = linear_model([[1.0]], [[1.0]], 1.0, 1.0, [0.0], 0.25, steps=3)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(3)))
    grid = plan_grid(model, model.initial, GridParameters(low=[-3.0], high=[3.0], cells=600))
    trace = run_histogram_filter(model, measurements, prior=model.initial, grid=grid)
    expected = 2 * norm.sf(3 / math.sqrt(1.25))
    assert expected == pytest.approx(0.00729, abs=1e-5)
    assert np.abs(trace.grid_lost_mass[:, 0] - expected).max() < 1e-6
    assert (trace.grid_lost_mass[:, 1:] > 0).all()
    assert np.isfinite(trace.estimates).all() and np.all(np.abs(trace.estimates) < 3)


def test_impossible_measurement_is_a_degenerate_step():
    """Uniform measurement noise of variance 1 reaches sqrt(3) = 1.73 from h(x) = x; a
    measurement of 50 on a grid over [-10, 10] has zero likelihood everywhere: the step is
    degenerate, the trial keeps its predicted distribution (mean 0.9 * previous mean) and the
    log-likelihood is -inf, as in the particle filter."""
    model = LinearGaussian(transition_matrix=[[0.9]], measurement_matrix=[[1.0]], steps=2,
                           process_noise={"variance": 0.5}, measurement_noise={"family": "uniform", "variance": 1.0},
                           initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    grid = plan_grid(model, model.initial, GridParameters(low=[-10.0], high=[10.0], cells=500))
    measurements = np.array([[[1.0], [50.0]]])
    trace = run_histogram_filter(model, measurements, prior=model.initial, grid=grid)
    assert trace.degenerate.tolist() == [[False, True]]
    assert trace.log_likelihood[0] == -np.inf
    assert trace.estimates[0, 1, 0] == pytest.approx(0.9 * trace.estimates[0, 0, 0], abs=1e-9)


# -- the particle filter against the grid -----------------------------------------------------------

def test_particle_filter_agrees_with_the_grid_on_the_growth_model():
    """The bootstrap filter's mean against the grid posterior mean, N = 20000, 6 trials x 40
    steps of the growth model (bimodal posteriors).

    Per step, the weighted mean of N particles with effective sample size ESS estimates the
    posterior mean with standard deviation ~ sqrt(Var_post / ESS) (Kong's ESS argument; it
    ignores the error inherited through resampling, which this fast-mixing model, Q = 10,
    forgets quickly). The normalised errors (PF - grid) / sqrt(Var_post / ESS) should then have
    an RMS near 1: six seed sets measured while writing this test gave 0.93 to 1.25 (largest
    single |error| 3.3 to 7.7, the heavy tail of bimodal steps). The test requires an RMS in
    [0.5, 2]: a wrong forcing index, sign or noise in either filter moves the means by many
    posterior standard deviations (RMS >> 2), and comparing a filter with itself gives 0.
    The grid filter's log p(z_1:T) is grid-converged (2000 and 4000 cells, or a grid twice as
    wide, agree to 1e-12); the particle estimate scatters around it with a standard deviation of
    about 0.15 at N = 20000 (0.05 measured at N = 200000, and it scales as N^-1/2): the largest
    of 6 differences was 0.14 to 0.24 over the six seed sets, and the test allows 0.75 (5 sd).
    """
    model = GrowthModel(steps=40)
    trials = 6
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(100, 100 + trials)))
    grid = plan_grid(model, model.initial, None)
    assert grid.cells == (2000,) and grid.low[0] < -30 and grid.high[0] > 30
    reference = run_histogram_filter(model, measurements, prior=model.initial, grid=grid)
    assert reference.grid_lost_mass.max() < 1e-4
    particles = pfx.particle_filter(model, prior=model.initial, particles=20_000, resampler="systematic", ess_threshold=1.0)(measurements, seeds=range(900, 900 + trials)).trace
    variance = reference.covariances[..., 0, 0]
    normalised = (particles.estimates[..., 0] - reference.estimates[..., 0]) / np.sqrt(variance / particles.ess)
    rms = float(np.sqrt(np.mean(normalised ** 2)))
    assert 0.5 < rms < 2.0, rms
    assert np.abs(particles.log_likelihood - reference.log_likelihood).max() < 0.75


def test_grid_filter_on_range_beacons_random_walk_agrees_with_a_large_particle_filter():
    """2-D: four range beacons, random-walk motion (separable kernel), uniform prior over the
    10 m x 10 m region, 6 steps.

    The grid posterior is resolution-converged (100 and 200 cells per axis agree to 1e-6 of the
    posterior standard deviation). The particle filter (N = 100000) agrees at the Monte Carlo
    rate: with the uniform prior the first update keeps an ESS of ~500, and resampling carries
    that step's error forward while the slow random walk (std 0.2 m against posterior std ~0.3 m)
    forgets it, so the error at step k has covariance ~ P_k / min_{j<=k} ESS_j. The squared
    normalised error e' P^-1 e min-ESS / 2 then has mean <= 1 (measured 0.29) and the test
    requires < 3.
    """
    model = RangeBeacons(beacons=[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]], motion="random_walk",
                         steps=6, process_noise={"variance": 0.04}, measurement_noise={"variance": 0.25},
                         initial={"kind": "point", "state": [3.0, 6.0]},
                         region={"low": [0.0, 0.0], "high": [10.0, 10.0]})
    prior = bind_law(model.default_prior(), 2, "initial")
    trials = 4
    states, measurements = simulate_truth(model, TrialStreams.from_seeds(range(300, 300 + trials)))
    settings = types.SimpleNamespace(grid=GridParameters(cells=100))
    coarse = run_filter("histogram", model, measurements, TrialStreams.from_seeds(range(trials)), settings=settings,
                       prior=prior, spread_criterion=SpreadCriterion(radius=1.0, weighted=True))
    fine = run_histogram_filter(model, measurements, prior=prior,
                                grid=plan_grid(model, prior, GridParameters(cells=200)))
    std = np.sqrt(np.trace(fine.covariances, axis1=-2, axis2=-1))
    assert np.abs(coarse.estimates - fine.estimates).max() < 1e-6 * std.min()
    assert np.all((coarse.within_radius > 0.5) & (coarse.within_radius <= 1.0))
    assert np.abs(fine.estimates - states[:, 1:]).max() < 5 * std.max()      # and it tracks the truth

    particles = pfx.particle_filter(model, prior=prior, particles=100_000, resampler="systematic", ess_threshold=1.0)(measurements, seeds=range(900, 900 + trials)).trace
    error = particles.estimates - fine.estimates
    squared = np.einsum("rti,rtij,rtj->rt", error, np.linalg.inv(fine.covariances), error)
    normalised = squared * np.minimum.accumulate(particles.ess, axis=1) / 2
    assert normalised.mean() < 3.0, normalised.mean()


# -- what the grid filter refuses ---------------------------------------------------------------

class _MultiplicativeGrowth(GrowthModel):
    """x' = f(x) (1 + w): not additive."""

    def propagate(self, state, control, noise):
        return super().propagate(state, control, 0.0 * noise) * (1.0 + noise)


@pytest.mark.parametrize("model, prior, grid, key, reason", [
    (FallingBody(), None, None, "filter.kind", "1-D and 2-D"),
    (linear_model([[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0]], [[0.5, 0.1], [0.1, 0.5]], 1.0, [0.0, 0.0], 1.0, 3),
     None, None, "filter.model.process_noise.variance", "diagonal"),
    (linear_model([[1.0]], [[1.0]], 0.0, 1.0, [0.0], 1.0, 3), None, None,
     "filter.model.process_noise.variance", "positive"),
    (linear_model([[1.0]], [[1.0]], 0.01, 1.0, [0.0], 1.0, 3), None, GridParameters(low=[-10.0], high=[10.0], cells=100),
     "filter.grid.cells", "wider than the process noise"),
    (linear_model([[1.0]], [[1.0]], 1.0, 1.0, [0.0], 1.0, 3), None, GridParameters(low=[-1.0, 0.0]),
     "filter.grid.low", "expected 1"),
    (_MultiplicativeGrowth(steps=3, process_noise={"variance": 0.01}), None, None, "filter.kind", "additive"),
    (linear_model([[1.0]], [[1.0]], 1.0, 1.0, [0.0], 1.0, 3), GaussianLaw(mean=[0.0], covariance=0.0), None,
     "filter.initial.covariance", "positive-definite"),
], ids=["3-d", "correlated-noise", "zero-noise", "coarse", "low-length", "multiplicative", "singular-prior"])
def test_grid_filter_refuses_what_it_cannot_do(model, prior, grid, key, reason):
    prior = bind_law(prior, model.state_dimension, "initial") if prior is not None else model.initial
    with pytest.raises(ConfigError, match=reason) as raised:
        plan_grid(model, prior, grid)
    assert raised.value.key == key
