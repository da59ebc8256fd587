"""Inverse-CDF draws of counts and gammas (pfx/numerics/count_quantiles.py, gamma_quantiles.py),
on both backends and in float64 and float32.

* The edges are exact: rate 0, n 0, p 0 and 1, u 0, shape 0.
* The sampler's CDF against scipy's exact one: for each count k, the u at which the draw passes k
  is found by bisection over the floats (exact to one float), and its distance from F(k) is
  bounded by the modules' stated accuracy: 3e-7 in float64 (the asymptotic regimes' truncation:
  Giles' approximation within 1e-7, the fifth-order Cornish-Fisher correction within 2e-7 near
  p = 1/2 and a mean of 20) and 24 * 2^-24 = 1.4e-6 in float32 (one rounding of 2^-24 at most
  per term of the K = 24 term sums, F <= 1). Gamma: |F(x(u)) - u| at shapes of 5 or more, 4e-7
  (the truncation after Temme's fourth term at shape 5: 2.9e-7; float32's rounding below 30:
  3e-7).
* Chi-square goodness of fit of 2^17 draws per case (uniforms from NumPy's Generator, fixed seeds)
  against the exact pmf, at parameters on each side of every regime switch (a mean of 4, counts
  of K = 24, the reflection at p = 1/2, Giles' central region), cells of expected count >= 20,
  rejected above the chi-square law's 1 - 1e-4 quantile; the sample mean and variance within 4
  standard errors of the exact ones.
* They trace under jax.jit with parameter arrays, keep float32 in float32, and give finite
  gradients (zero for counts; the gamma's pathwise derivative against a finite difference).

Every call uses arrays of one length, so JAX compiles each law once per dtype.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import special, stats

from pfx.numerics.count_quantiles import binomial_quantile, poisson_quantile
from pfx.numerics.gamma_quantiles import GAMMA_UNIFORMS, gamma_quantile, gamma_variate

LENGTH = 4096
DRAWS = 32 * LENGTH
DTYPES = [pytest.param(np.float64, id="float64"), pytest.param(np.float32, id="float32")]
CDF_BOUND = {np.float64: 3e-7, np.float32: 24 * 2.0**-24}
GAMMA_BOUND = 4e-7
FALSE_ALARM = 1e-4
_JITTED: dict = {}


def evaluate(backend: str, function, dtype, *arrays) -> np.ndarray:
    """``function`` of ``arrays`` (broadcast to LENGTH on their last axis) in ``dtype``: NumPy
    arrays on numpy; on jax, JAX arrays under jax.jit with 64-bit types allowed."""
    arrays = [np.broadcast_to(np.asarray(array, dtype), np.shape(array)[:-1] + (LENGTH,))
              if np.ndim(array) else np.full(LENGTH, array, dtype) for array in arrays]
    if backend == "numpy":
        result = function(*arrays)
        assert result.dtype == dtype
        return result
    import jax

    with jax.enable_x64(True):
        compiled = _JITTED.setdefault(function, jax.jit(function))
        result = compiled(*(jax.numpy.asarray(array) for array in arrays))
        assert result.dtype == dtype
        return np.asarray(result)


def passing_points(backend: str, quantile, dtype, counts: np.ndarray, *parameters) -> tuple:
    """For each count k, the largest float u with quantile(u, *parameters) <= k and the next float
    up (the draw passes k between them), by bisection over the floats' bit patterns."""
    integer = np.uint32 if dtype == np.float32 else np.uint64
    padded = np.resize(counts, LENGTH).astype(dtype)
    low = np.zeros(LENGTH, integer)
    high = np.full(LENGTH, np.array(1.0, dtype).view(integer))
    for _ in range(8 * np.dtype(dtype).itemsize):
        middle = low + (high - low) // 2
        below = evaluate(backend, quantile, dtype, middle.view(dtype), *parameters) <= padded
        low, high = np.where(below, middle, low), np.where(below, high, middle)
    size = len(counts)
    return low[:size].view(dtype).astype(float), high[:size].view(dtype).astype(float)


def cdf_error(backend: str, quantile, dtype, counts: np.ndarray, exact: np.ndarray, *parameters) -> float:
    """The largest distance of F(k) from the interval where the sampler's draw passes k."""
    low, high = passing_points(backend, quantile, dtype, counts, *parameters)
    return float(np.max(np.maximum(np.maximum(low - exact, exact - high), 0.0)))


def uniforms(dtype, seed: int, shape=(DRAWS,)) -> np.ndarray:
    return np.random.default_rng(seed).random(shape, dtype=dtype)


def draw_in_chunks(backend: str, function, dtype, uniform: np.ndarray, *parameters) -> np.ndarray:
    """DRAWS draws, LENGTH at a time (the uniforms' last axis split into chunks)."""
    chunks = uniform.reshape(uniform.shape[:-1] + (-1, LENGTH))
    return np.concatenate([evaluate(backend, function, dtype, chunks[..., index, :], *parameters)
                           for index in range(chunks.shape[-2])]).astype(float)


def assert_fits(draws: np.ndarray, support: np.ndarray, probabilities: np.ndarray, mean: float,
                variance: float, label: str) -> None:
    """Chi-square over cells of expected count >= 20 (tails merged into the end cells), and the
    sample mean and variance within 4 standard errors of the exact ones."""
    expected = probabilities * len(draws)
    keep = np.flatnonzero(expected >= 20)
    edges = support[keep]
    cell = np.clip(np.searchsorted(edges, draws, side="right") - 1, 0, len(edges) - 1)
    observed = np.bincount(cell, minlength=len(edges)).astype(float)
    cumulative = np.cumsum(probabilities)
    expected_cells = np.diff(np.concatenate([[0.0], cumulative[keep[1:] - 1], [1.0]])) * len(draws)
    statistic = float(np.sum((observed - expected_cells) ** 2 / expected_cells))
    threshold = stats.chi2.isf(FALSE_ALARM, len(edges) - 1)
    assert statistic < threshold, f"{label}: chi-square {statistic:.1f} >= {threshold:.1f} on {len(edges) - 1} dof"
    centred = draws - draws.mean()
    mean_error = np.sqrt(variance / len(draws))
    variance_error = np.sqrt((np.mean(centred**4) - draws.var() ** 2) / len(draws))
    assert abs(draws.mean() - mean) < 4 * mean_error, f"{label}: mean {draws.mean()} vs {mean}"
    assert abs(draws.var(ddof=1) - variance) < 4 * variance_error, f"{label}: variance {draws.var(ddof=1)} vs {variance}"


@pytest.fixture(params=DTYPES)
def dtype(request):
    return request.param


# -- the edges -----------------------------------------------------------------------------------


def test_the_edges_are_exact(backend, dtype):
    information = np.finfo(dtype)
    edge = np.array([0.0, information.tiny, 1e-30, 1e-9, 0.5, 1 - information.eps, 1.0], dtype)
    level = np.resize(edge, LENGTH)
    for rate in (0.0, 1e6):
        counts = evaluate(backend, poisson_quantile, dtype, level, rate)
        assert counts[level == 0].max() == 0, f"rate {rate}: u = 0 gives 0"
        if rate == 0:
            assert not counts.any(), "rate 0 gives 0"
    for count, probability, expected in ((0.0, 0.3, 0.0), (50.0, 0.0, 0.0), (50.0, 1.0, 50.0), (1e7, 1.0, 1e7)):
        draws = evaluate(backend, binomial_quantile, dtype, level, count, probability)
        assert (draws == expected).all(), f"Bin({count}, {probability}) gives {expected}"
    for probability in (0.3, 0.7, 1 - 1e-6):
        assert evaluate(backend, binomial_quantile, dtype, level, 1e4, probability)[level == 0].max() == 0
    assert not evaluate(backend, gamma_quantile, dtype, level, 0.0).any()
    assert evaluate(backend, gamma_quantile, dtype, level, 7.5)[level == 0].max() == 0
    boosts = uniforms(dtype, 5, (GAMMA_UNIFORMS, LENGTH))
    assert not evaluate(backend, gamma_variate, dtype, boosts, 0.0).any()


# -- the sampler's CDF against the exact one -------------------------------------------------------


@pytest.mark.parametrize("rate", [0.3, 3.9, 4.5, 17.0, 30.0, 250.0, 1e4, 1e5])
def test_poisson_cdf_is_within_the_stated_accuracy(backend, dtype, rate):
    rate = float(np.asarray(rate, dtype))
    spread = np.sqrt(rate)
    counts = np.unique(np.concatenate([np.arange(40.0), np.round(rate + spread * np.linspace(-8.5, 8.5, 1024))]))
    counts = counts[counts >= 0]
    error = cdf_error(backend, poisson_quantile, dtype, counts, stats.poisson.cdf(counts, rate), rate)
    assert error < CDF_BOUND[dtype], f"rate {rate}: CDF off by {error:.2e}"


@pytest.mark.parametrize("count, probability", [(20, 0.3), (60, 0.5), (100, 0.1), (1000, 0.01), (300, 0.7),
                                                (1e4, 0.2), (1e5, 0.999)])
def test_binomial_cdf_is_within_the_stated_accuracy(backend, dtype, count, probability):
    probability = float(np.asarray(probability, dtype))
    mean = count * probability
    spread = np.sqrt(mean * (1 - probability))
    counts = np.unique(np.concatenate([np.arange(40.0), count - np.arange(40.0),
                                       np.round(mean + spread * np.linspace(-8.5, 8.5, 1024))]))
    counts = counts[(counts >= 0) & (counts <= count)]
    error = cdf_error(backend, binomial_quantile, dtype, counts, stats.binom.cdf(counts, count, probability),
                      count, probability)
    assert error < CDF_BOUND[dtype], f"Bin({count}, {probability}): CDF off by {error:.2e}"


@pytest.mark.parametrize("shape", [5.0, 8.0, 30.0])
def test_gamma_inverse_cdf_is_within_the_stated_accuracy(backend, dtype, shape):
    level = np.concatenate([np.linspace(0, 1, LENGTH - 64, endpoint=False)[1:], np.geomspace(1e-7, 1e-2, 32),
                            1 - np.geomspace(1e-7, 1e-2, 32), [0.5]]).astype(dtype)
    quantiles = evaluate(backend, gamma_quantile, dtype, level, shape).astype(float)
    error = np.max(np.abs(special.gammainc(shape, quantiles) - level.astype(float)))
    assert error < GAMMA_BOUND, f"shape {shape}: CDF off by {error:.2e}"
    assert np.all(np.diff(quantiles[np.argsort(level, kind="stable")]) >= 0), "monotone in u"


# -- draws against the exact laws ------------------------------------------------------------------


@pytest.mark.parametrize("rate", [3.9, 4.5, 17.0, 24.0, 40.0, 1e4])
def test_poisson_draws_fit_the_exact_law(backend, dtype, rate):
    rate = float(np.asarray(rate, dtype))
    draws = draw_in_chunks(backend, poisson_quantile, dtype, uniforms(dtype, int(rate * 10)), rate)
    support = np.arange(0.0, rate + 12 * np.sqrt(rate) + 30)
    assert_fits(draws, support, stats.poisson.pmf(support, rate), rate, rate, f"Poisson({rate})")


@pytest.mark.parametrize("count, probability", [(30, 0.4), (48, 0.5), (2000, 0.012), (100, 0.75), (1e6, 0.3)])
def test_binomial_draws_fit_the_exact_law(backend, dtype, count, probability):
    probability = float(np.asarray(probability, dtype))
    draws = draw_in_chunks(backend, binomial_quantile, dtype, uniforms(dtype, int(count)), count, probability)
    support = np.arange(0.0, count + 1)
    mean, variance = count * probability, count * probability * (1 - probability)
    assert_fits(draws, support, stats.binom.pmf(support, count, probability), mean, variance,
                f"Bin({count}, {probability})")


@pytest.mark.parametrize("shape", [0.1, 0.36, 1.0, 4.5, 30.0, 1e4])
def test_gamma_draws_fit_the_exact_law(backend, dtype, shape):
    shape = float(np.asarray(shape, dtype))
    draws = draw_in_chunks(backend, gamma_variate, dtype, uniforms(dtype, 7, (GAMMA_UNIFORMS, DRAWS)), shape)
    cells = 100                          # cells of equal exact probability: the draws' CDF levels
    levels = np.clip(np.floor(stats.gamma.cdf(draws, shape) * cells), 0, cells - 1)
    assert_fits(levels, np.arange(float(cells)), np.full(cells, 1.0 / cells), (cells - 1) / 2,
                (cells**2 - 1) / 12, f"Gamma({shape}) cells")
    centred = draws - draws.mean()
    assert abs(draws.mean() - shape) < 4 * np.sqrt(shape / len(draws))
    assert abs(draws.var(ddof=1) - shape) < 4 * np.sqrt((np.mean(centred**4) - draws.var() ** 2) / len(draws))


# -- tracing, dtypes and gradients ---------------------------------------------------------------------


def test_they_trace_under_jit_with_parameter_arrays_and_keep_float32():
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    level = uniforms(np.float32, 11, (LENGTH,))
    rates = np.linspace(0.0, 60.0, LENGTH, dtype=np.float32)
    counts = np.round(np.linspace(0.0, 200.0, LENGTH, dtype=np.float32))
    probabilities = np.linspace(0.0, 1.0, LENGTH, dtype=np.float32)
    shapes = np.linspace(0.0, 50.0, LENGTH, dtype=np.float32)
    boosts = uniforms(np.float32, 12, (GAMMA_UNIFORMS, LENGTH))
    for name, function, arguments in (("poisson", poisson_quantile, (level, rates)),
                                      ("binomial", binomial_quantile, (level, counts, probabilities)),
                                      ("gamma", gamma_variate, (boosts, shapes))):
        with jax.enable_x64(True):       # the program evaluate() compiled: float32 arguments
            traced = _JITTED.setdefault(function, jax.jit(function))(*(jnp.asarray(array) for array in arguments))
        assert traced.dtype == jnp.float32, name
        assert bool(jnp.all(jnp.isfinite(traced))), name
        eager = function(*arguments)
        assert eager.dtype == np.float32, name
        agreeing = np.mean(np.asarray(traced) == eager) if name != "gamma" else \
            np.mean(np.isclose(np.asarray(traced), eager, rtol=1e-5, atol=1e-30))
        assert agreeing > 0.999, f"{name}: NumPy and JAX agree on {agreeing:.4%} of the draws"


def test_gradients_are_finite_where_a_branch_is_unused():
    jax = pytest.importorskip("jax")
    jnp = jax.numpy
    level = np.concatenate([[0.0, 1e-300, 0.5, 1 - 2**-53], uniforms(np.float64, 13, (60,))])[:, None]
    boosts = uniforms(np.float64, 14, (GAMMA_UNIFORMS, 8, 1))
    step = 1e-6                           # the pathwise derivative is the draws' own slope in the shape

    def gradients(rates, counts, probabilities, shapes):
        def total(function, *arguments):
            return function(*arguments).sum()
        slope = (total(gamma_variate, boosts, shapes[2] + step) - total(gamma_variate, boosts, shapes[2] - step)) / (2 * step)
        return (jax.grad(lambda value: total(poisson_quantile, level, value))(rates),
                jax.grad(lambda value: total(binomial_quantile, level, counts, value))(probabilities),
                jax.grad(lambda value: total(gamma_variate, boosts, value))(shapes), slope)

    with jax.enable_x64(True):
        poisson, binomial, gamma, slope = jax.jit(gradients)(
            jnp.asarray([0.0, 3.0, 4.0, 30.0, 1e6]), jnp.asarray([0.0, 50.0, 50.0, 50.0, 1e7]),
            jnp.asarray([0.3, 0.0, 1.0, 0.5, 0.3]), jnp.asarray([0.0, 1e-3, 0.7, 12.0]))
    assert not np.asarray(poisson).any() and not np.asarray(binomial).any(), "counts: zero gradients, not NaN"
    assert np.isfinite(np.asarray(gamma)).all(), gamma
    assert abs(float(gamma[2]) - float(slope)) < 1e-5 * abs(float(slope))
