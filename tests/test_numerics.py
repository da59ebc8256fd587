"""Numerical robustness: ESS, log-domain normalisation, noise families, and the engine's
handling of underflowing weights and non-finite model output (degenerate steps, far
measurements and lost particles on both backends: the ``backend`` fixture)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from pydantic import ValidationError
from scipy import stats

import pfx
from pfx.errors import ModelNumericalError
from pfx.laws.initial import GaussianLaw
from pfx.laws.noise import Noise
from pfx.models.base import bind_law
from pfx.models.falling_body import FallingBody
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.simulation import simulate_truth
from pfx.numerics.log_weights import effective_sample_size, log_normalise
from pfx.numerics.seeding import TrialStreams

_trapezoid = getattr(np, "trapezoid", None) or np.trapz  # numpy < 2 has only trapz

FAMILIES = ["gaussian", "uniform", "triangular", "laplace", "student_t"]
Z = 4.5  # standard errors allowed in statistical comparisons (two-sided p = 7e-6)


# -- effective sample size ---------------------------------------------------------------------

def test_ess_uniform_one_hot_and_hand_example():
    """ESS = 1 / sum w^2: N for uniform weights, 1 for a one-hot vector, and
    1 / (.25 + .09 + .01 + .01) = 1 / 0.36 for w = (.5, .3, .1, .1) (exact up to round-off)."""
    n = 64
    weights = np.vstack([np.full(n, 1.0 / n), np.eye(n)[17]])
    np.testing.assert_allclose(effective_sample_size(weights), [n, 1.0], rtol=1e-12)
    assert effective_sample_size(np.array([[0.5, 0.3, 0.1, 0.1]]))[0] == pytest.approx(1 / 0.36, rel=1e-12)


# -- log-domain normalisation -----------------------------------------------------------------

def _reference_normaliser(row) -> float:
    """log sum exp(row), computed independently in Python floats with math.fsum."""
    finite = [x for x in row if x != -math.inf]
    if not finite:
        return -math.inf
    peak = max(finite)
    return peak + math.log(math.fsum(math.exp(x - peak) for x in finite))


EXTREME_ROWS = [
    [-1e308, 0.0, -1e308, -1e308],
    [1e3, 1e3 - 1, 1e3 - 2, 1e3 - 3],
    [-1e4] * 4,
    [-math.inf, 0.0, -math.inf, -2.0],
    [-math.inf, -1e4, -1e4 - 700, -math.inf],
    [700.0, 710.0, -710.0, -745.0],
]


@pytest.mark.parametrize("row", EXTREME_ROWS, ids=range(len(EXTREME_ROWS)))
def test_log_normalise_extreme_rows(row):
    """Extreme log-weights (overflow and underflow of a naive exp, -inf entries) give no NaN,
    normalised weights summing to 1 (to 1e-12: a handful of ulps over 4 entries), and a
    normaliser equal to an fsum reference and to np.logaddexp.reduce (to 1e-12 relative)."""
    log_weights = np.array([row])
    normalised, normaliser = log_normalise(log_weights)
    assert not np.isnan(normalised).any() and not np.isnan(normaliser).any()
    reference = _reference_normaliser(row)
    assert normaliser[0] == pytest.approx(reference, rel=1e-12, abs=1e-12)
    assert normaliser[0] == pytest.approx(np.logaddexp.reduce(log_weights[0]), rel=1e-12, abs=1e-12)
    assert math.fsum(np.exp(normalised[0])) == pytest.approx(1.0, abs=1e-12)
    # -inf entries (zero weights) stay exactly -inf
    np.testing.assert_array_equal(np.isneginf(normalised[0]), np.isneginf(log_weights[0]))


def test_log_normalise_all_minus_inf_row_and_batch_independence():
    """A row of all -inf has normaliser -inf and is returned unchanged; rows are normalised
    independently of each other in a batch (same result as one at a time)."""
    batch = np.array([[-np.inf] * 4, EXTREME_ROWS[0], EXTREME_ROWS[1], EXTREME_ROWS[3]])
    normalised, normaliser = log_normalise(batch.copy())
    assert normaliser[0] == -np.inf
    np.testing.assert_array_equal(normalised[0], batch[0])
    for i in range(1, len(batch)):
        alone, alone_normaliser = log_normalise(batch[i:i + 1])
        np.testing.assert_array_equal(normalised[i], alone[0])
        assert normaliser[i] == alone_normaliser[0]


def test_log_normalise_huge_equal_log_weights():
    """Equal log-weights of magnitude 1e17 (e.g. -0.5 (z - h(x))^2 / R with z far away and tiny R,
    identical particles) must normalise to 1/N each. Subtracting L = peak + log N in one go
    loses log N in peak's round-off (ulp(1e17) = 16): the weights would all be 1 and the
    estimate N times too large. (log w - peak) - log(total) is exact."""
    normalised, _ = log_normalise(np.full((1, 4), -1e17))
    assert np.exp(normalised).sum() == pytest.approx(1.0, abs=1e-12)


# -- noise families ---------------------------------------------------------------------------

def _noise(family: str, variance, df_t: float = 5.0) -> Noise:
    return Noise(family=family, variance=variance, df=df_t if family == "student_t" else None)


@pytest.mark.parametrize("family", FAMILIES)
def test_noise_sample_variance(family):
    """Sample variance of 400000 1-D draws (variance 2.5) matches 2.5 within 4.5 SE, with
    SE = sqrt((m4 - s^4) / n) estimated from the sample (the large-sample SE of a variance
    estimate for a known zero mean). student_t uses df = 10, so that the 4th moment (needed
    for the SE) and the 8th (needed for the SE estimate to be reliable) exist."""
    variance = 2.5
    noise = _noise(family, variance, df_t=10.0).bind(1)
    draws = noise.sample(TrialStreams.from_seeds([11, 12, 13, 14]), (100_000,)).ravel()
    assert draws.shape == (400_000,)
    n = draws.size
    s2 = np.mean(draws ** 2)                # the mean is known to be zero
    m4 = np.mean(draws ** 4)
    se = math.sqrt((m4 - s2 ** 2) / n)
    assert abs(s2 - variance) < Z * se, (s2, se)
    # the mean is zero too (SE = sqrt(s2 / n))
    assert abs(draws.mean()) < Z * math.sqrt(s2 / n)


@pytest.mark.parametrize("family", FAMILIES)
def test_noise_density_integrates_to_one(family):
    """exp(log_density) integrates to 1 (trapezoid on +-60 std, 1.2 million intervals).

    Tolerance: the trapezoid error at a jump of the density (uniform) is at most h * max f,
    the smooth and kinked families err by O(h^2); plus the mass beyond the grid, which is
    negligible except for student_t (df = 5), where it is computed from scipy's t law."""
    variance = 2.5
    std = math.sqrt(variance)
    noise = _noise(family, variance).bind(1, need_density=True)
    grid = np.linspace(-60 * std, 60 * std, 1_200_001)
    h = grid[1] - grid[0]
    density = np.exp(noise.log_density(grid[:, None]))
    integral = _trapezoid(density, grid)
    tail = 0.0
    if family == "student_t":
        scale = std * math.sqrt(3.0 / 5.0)
        tail = 2 * stats.t.sf(60 * std / scale, 5)
    assert abs(integral - (1.0 - tail)) <= h * density.max() + 1e-9, integral


@pytest.mark.parametrize("family", FAMILIES)
def test_noise_full_covariance(family):
    """With a full 2x2 covariance the sample covariance E[x x^T] (zero mean known) matches
    each entry within 4.5 SE, SE = std(x_i x_j) / sqrt(n); student_t uses df = 10."""
    covariance = np.array([[2.0, 0.6], [0.6, 1.0]])
    noise = _noise(family, covariance.tolist(), df_t=10.0).bind(2)
    np.testing.assert_allclose(noise.covariance(), covariance, rtol=1e-12)
    draws = noise.sample(TrialStreams.from_seeds([5, 6]), (100_000,)).reshape(-1, 2)
    products = draws[:, :, None] * draws[:, None, :]
    estimate = products.mean(axis=0)
    se = products.std(axis=0, ddof=1) / math.sqrt(len(draws))
    assert np.all(np.abs(estimate - covariance) < Z * se), (estimate, se)


def test_gaussian_full_covariance_density():
    """The gaussian log-density with a full covariance equals scipy's multivariate normal."""
    covariance = np.array([[2.0, 0.6], [0.6, 1.0]])
    noise = Noise(family="gaussian", variance=covariance.tolist()).bind(2, need_density=True)
    points = np.random.default_rng(1).normal(size=(20, 2)) * 3
    expected = stats.multivariate_normal(mean=[0, 0], cov=covariance).logpdf(points)
    np.testing.assert_allclose(noise.log_density(points), expected, rtol=1e-12)


def test_full_covariance_density_integrates_to_one_2d():
    """A non-gaussian (laplace) 2-D density under a full covariance, p(x) = prod f(z_i)/|det L|
    with z = L^-1 x, integrates to 1 over the plane (trapezoid on +-30 std, 1200^2 cells;
    the error of the kinks is O(h^2) and the tail mass exp(-30 sqrt 2) is negligible, so 1e-3)."""
    covariance = np.array([[2.0, 0.6], [0.6, 1.0]])
    noise = Noise(family="laplace", variance=covariance.tolist()).bind(2, need_density=True)
    axis = np.linspace(-30 * math.sqrt(2.0), 30 * math.sqrt(2.0), 1201)
    x, y = np.meshgrid(axis, axis, indexing="ij")
    density = np.exp(noise.log_density(np.stack([x, y], axis=-1)))
    integral = _trapezoid(_trapezoid(density, axis, axis=1), axis)
    assert integral == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("b", [0.01, 1.0, 7.5])
def test_triangular_density_is_prob_triangular(b):
    """The triangular density of variance b equals Probabilistic Robotics' corrected
    prob_triangular(a, b) = max(0, 1/sqrt(6b) - |a|/(6b)) (docs/reference-facts.md#motion-models),
    including zero outside the support |a| < sqrt(6b)."""
    noise = Noise(family="triangular", variance=b).bind(1, need_density=True)
    a = np.linspace(-1.5, 1.5, 301) * math.sqrt(6 * b)
    expected = np.maximum(0.0, 1 / np.sqrt(6 * b) - np.abs(a) / (6 * b))
    np.testing.assert_allclose(np.exp(noise.log_density(a[:, None])), expected, rtol=1e-12, atol=1e-15)


def test_noise_validation():
    """df goes with student_t only; negative variances and asymmetric matrices are rejected."""
    with pytest.raises(ValidationError):
        Noise(family="student_t", variance=1.0)
    with pytest.raises(ValidationError):
        Noise(family="gaussian", variance=1.0, df=5)
    with pytest.raises(ValidationError):
        Noise(family="student_t", variance=1.0, df=2.0)
    with pytest.raises(ValidationError):
        Noise(variance=[1.0, -1.0])
    with pytest.raises(ValidationError):
        Noise(variance=[[1.0, 0.5], [0.4, 1.0]])


# -- the engine: degenerate steps and model errors --------------------------------------------

def _run(model, measurements, seeds, particles=500, prior=None, backend="numpy"):
    prior = prior if prior is not None else bind_law(model.default_prior(), model.state_dimension, "initial")
    return pfx.particle_filter(model, prior=prior, particles=particles, resampler="systematic", ess_threshold=1.0,
                               backend=backend)(measurements, seeds=seeds).trace


def test_engine_degenerate_steps_are_counted_and_survived(backend):
    """Uniform measurement noise (half-width sqrt 3) and measurements moved to 1e6 at steps 2
    and 4: every weight is exactly zero there. The trace flags exactly those steps as
    degenerate in every trial, weights are reset to uniform (ESS = N), no NaN appears, and the
    run goes on: at the other steps every weighted particle lies within sqrt 3 of z, so the
    estimate does too (a deterministic consequence of the bounded likelihood)."""
    model = LinearGaussian(transition_matrix=[[1.0]], measurement_matrix=[[1.0]], steps=6,
                           measurement_noise={"family": "uniform", "variance": 1.0})
    trials = 8
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(100, 100 + trials)))
    measurements[:, [1, 3]] = 1e6
    n = 500
    trace = _run(model, measurements, range(200, 200 + trials), particles=n, backend=backend)
    expected = np.zeros((trials, 6), dtype=bool)
    expected[:, [1, 3]] = True
    np.testing.assert_array_equal(trace.degenerate, expected)
    assert np.isfinite(trace.estimates).all() and np.isfinite(trace.ess).all()
    np.testing.assert_allclose(trace.ess[:, [1, 3]], n, rtol=1e-9)
    good = ~expected
    assert np.all(np.abs(trace.estimates[..., 0] - measurements[..., 0])[good] <= math.sqrt(3) + 1e-9)
    assert np.all(trace.ess[good] >= 1.0 - 1e-9)
    # log p(z_{1:T}) is -inf (a measurement of zero likelihood), never NaN
    assert np.all(trace.log_likelihood == -np.inf)


def test_engine_far_measurement_gaussian_is_not_degenerate(backend):
    """With gaussian noise a measurement 1e6 away gives log-weights near -5e11 but log-domain
    normalisation keeps them usable: no degenerate step, no NaN, ESS in [1, N] (here ~1: the
    particle nearest z takes all the weight) and a finite log-likelihood."""
    model = LinearGaussian(transition_matrix=[[1.0]], measurement_matrix=[[1.0]], steps=3)
    measurements = np.full((4, 3, 1), 1e6)
    trace = _run(model, measurements, range(4), particles=300, backend=backend)
    assert not trace.degenerate.any()
    assert np.isfinite(trace.estimates).all()
    assert np.all((trace.ess >= 1 - 1e-9) & (trace.ess <= 300 + 1e-9))
    assert np.isfinite(trace.log_likelihood).all()


class _NaNAtStep3(LinearGaussian):
    """A linear model whose transition returns NaN for every particle at step 3."""

    def transition(self, state, step, random):
        moved = super().transition(state, step, random)
        return np.full_like(moved, np.nan) if step == 3 else moved


class _HalfLostAtStep2(LinearGaussian):
    """A linear model whose transition sends every other particle to NaN at step 2, whose substep
    starts at time 1 (a substep written with ``pfx.namespace`` and ``where`` runs on both
    backends: on jax the time is traced)."""

    def sample_substep(self, state, control, time, random):
        moved = super().sample_substep(state, control, time, random)
        if moved.ndim != 3:                 # the truth's simulation: one state per trial
            return moved
        xp = pfx.namespace(moved)
        every_other = (xp.arange(moved.shape[1]) % 2 == 0)[:, None]
        return xp.where((time == 1.0) & every_other, xp.nan, moved)


class _NaNLikelihood(LinearGaussian):
    """A linear model whose log-likelihood is NaN for finite particles."""

    def log_likelihood(self, measurement, state):
        return np.full(state.shape[:-1], np.nan)


def _linear(cls=LinearGaussian, steps=5):
    return cls(transition_matrix=[[1.0]], measurement_matrix=[[1.0]], steps=steps)


def test_model_nan_for_every_particle_raises_with_kind_and_step():
    """Every particle NaN at step 3: ModelNumericalError naming the model kind and step 3."""
    model = _linear(_NaNAtStep3)
    measurements = np.zeros((2, 5, 1))
    with pytest.raises(ModelNumericalError, match=r"linear_gaussian.*step 3\b"):
        _run(model, measurements, [0, 1], particles=50)


def test_truth_nan_raises_with_kind_and_step():
    """A non-finite truth at step 3 is a model error naming the kind and step 3."""
    with pytest.raises(ModelNumericalError, match=r"linear_gaussian.*step 3\b"):
        simulate_truth(_linear(_NaNAtStep3), TrialStreams.from_seeds([0]))


def test_nan_likelihood_raises_with_kind_and_step():
    """A NaN log-likelihood of finite particles raises at the first step, naming the kind."""
    with pytest.raises(ModelNumericalError, match=r"linear_gaussian.*NaN.*step 1\b"):
        _run(_linear(_NaNLikelihood), np.zeros((2, 5, 1)), [0, 1], particles=50)


def test_some_lost_particles_are_counted_not_fatal(backend):
    """Half the particles NaN at step 2: they are counted as lost (N/2 per trial), get zero
    weight (so estimates stay finite and ESS <= N/2 at that step), and the run completes."""
    n = 100
    trace = _run(_linear(_HalfLostAtStep2), np.zeros((3, 5, 1)), [0, 1, 2], particles=n, backend=backend)
    np.testing.assert_array_equal(trace.lost_particles, n // 2)
    assert np.isfinite(trace.estimates).all()
    assert np.all(trace.ess[:, 1] <= n / 2 + 1e-9)


def test_falling_body_absurd_prior_raises():
    """A falling body whose prior has a negative ballistic coefficient (-10) makes the drag
    equation blow up for every particle within the 5 steps: ModelNumericalError naming the
    model kind and a step of the filter."""
    model = FallingBody(variant="simon", steps=5)
    prior = bind_law(GaussianLaw(mean=[3e5, -2e4, -10.0], covariance=[1.0, 1.0, 1e-6]), 3, "initial")
    measurements = np.full((2, 5, 1), 2e5)
    with pytest.raises(ModelNumericalError) as raised:
        _run(model, measurements, [0, 1], particles=50, prior=prior)
    assert "falling_body" in str(raised.value)
    assert re.search(r"step [1-5] of the filter", str(raised.value))
