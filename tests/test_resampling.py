"""Tests of pfx.filters.particle.resampling: unbiasedness, han-lee Algorithm IV's bias, offspring bounds,
the round-off guard of the inverse CDF, and batch invariance.

Statistical tests draw R resamplings at once (one row and one seeded generator per
resampling) and compare mean offspring counts with their expectation in units of the
standard error estimated from the same draws.
"""

from __future__ import annotations

import numpy as np
import pytest

from pfx.filters.particle.resampling import (
    RESAMPLERS,
    han_lee_iv_expected_counts,
    inverse_cdf,
    offspring_counts,
)
from pfx.numerics.seeding import TrialStreams

UNBIASED = ["multinomial", "stratified", "systematic", "residual"]
ALL = UNBIASED + ["han_lee_iv"]

# Dyadic weights k / 1024 (N = 16): every cumulative sum and every N w_j = k / 64 is exact in
# floating point, so "N w_j is an integer" is an exact statement. The vector mixes large
# weights, tiny ones (1/1024: N w = 1/64, still ~300 expected offspring over R = 20000 draws,
# so its mean is measurable), two exact zeros and two weights with integer N w (384 -> 6,
# 128 -> 2).
_KS = np.array([384, 1, 0, 3, 200, 128, 50, 7, 100, 0, 60, 41, 30, 5, 10, 5], dtype=float)
assert _KS.sum() == 1024
WEIGHTS = _KS / 1024.0
N = WEIGHTS.size
R = 20_000
Z = 4.5  # two-sided P(|Z| > 4.5) = 7e-6 per component; ~100 comparisons in this file


def _draw(name: str, weights: np.ndarray, rows: int, seed: int) -> np.ndarray:
    """Offspring counts (rows, N) from ``rows`` independent resamplings of ``weights``."""
    batch = np.broadcast_to(weights, (rows, weights.size)).copy()
    streams = TrialStreams.from_seeds(range(seed, seed + rows))
    indices = RESAMPLERS[name](batch, streams)
    return offspring_counts(indices, weights.size)


def _assert_mean_counts(counts: np.ndarray, expected: np.ndarray, label: str) -> None:
    """Mean counts within Z standard errors of ``expected``; constant components exactly."""
    mean = counts.mean(axis=0)
    se = counts.std(axis=0, ddof=1) / np.sqrt(counts.shape[0])
    constant = se == 0
    # A component that never varied has mean equal to its (integer) value: unbiasedness then
    # requires the expectation to be exactly that integer (zero weight, or integer N w_j).
    np.testing.assert_allclose(mean[constant], expected[constant], rtol=0, atol=1e-12,
                               err_msg=f"{label}: constant counts differ from expectation")
    z = np.abs(mean[~constant] - expected[~constant]) / se[~constant]
    assert np.all(z < Z), f"{label}: |mean - expected| / SE = {z.round(2)} (limit {Z})"


def test_registry_flags():
    """The four unbiased schemes are flagged unbiased; han-lee Algorithm IV is flagged biased."""
    for name in UNBIASED:
        assert RESAMPLERS[name].unbiased is True
    assert RESAMPLERS["han_lee_iv"].unbiased is False


@pytest.mark.parametrize("name", UNBIASED)
def test_unbiased_mean_offspring(name):
    """E[N_j] = N w_j for each unbiased scheme (docs/reference-facts.md#resampling).

    Mean counts over R = 20000 resamplings of a fixed non-uniform weight vector are compared
    with N w_j within 4.5 standard errors (SE = empirical std of the counts / sqrt(R)).
    Components with zero variance (systematic and residual give floor/ceil or exact copies)
    must equal N w_j exactly, which is possible only where N w_j is an integer.
    """
    counts = _draw(name, WEIGHTS, R, seed=1000)
    assert np.all(counts.sum(axis=1) == N)
    _assert_mean_counts(counts, N * WEIGHTS, name)


def test_han_lee_iv_reference_example():
    """The worked example of docs/reference-facts.md#resampling, w = (.3, .1, .2, .15, .25), N = 5: expected counts under
    Algorithm IV are 1.799, 0.597, 1.157, 0.769, 0.678 (to the 3 printed decimals, so a
    tolerance of half a unit in the last place), and they still sum to N."""
    w = np.array([0.3, 0.1, 0.2, 0.15, 0.25])
    expected = han_lee_iv_expected_counts(w)
    np.testing.assert_allclose(expected, [1.799, 0.597, 1.157, 0.769, 0.678], rtol=0, atol=5e-4)
    assert expected.sum() == pytest.approx(5.0, abs=1e-12)


def test_han_lee_iv_bias_matches_formula_and_is_detectable():
    """Observed mean counts of han_lee_iv match han_lee_iv_expected_counts within 4.5 SE,
    and differ from the unbiased N w_j by many SE where the theoretical bias is large.

    With R = 20000 and counts of variance <= ~1, SE <= 0.008; every component whose
    theoretical bias exceeds 0.09 is therefore more than ~11 SE away from N w_j; we require 8.
    """
    w = np.array([0.3, 0.1, 0.2, 0.15, 0.25])
    n = w.size
    counts = _draw("han_lee_iv", w, R, seed=7)
    expected = han_lee_iv_expected_counts(w)
    _assert_mean_counts(counts, expected, "han_lee_iv vs formula")

    mean = counts.mean(axis=0)
    se = counts.std(axis=0, ddof=1) / np.sqrt(R)
    large_bias = np.abs(expected - n * w) > 0.09
    assert large_bias.sum() == 4           # all but w = 0.15 (bias 0.019)
    z_unbiased = np.abs(mean - n * w) / se
    assert np.all(z_unbiased[large_bias] > 8), z_unbiased


def test_han_lee_iv_formula_on_general_weights():
    """On the dyadic test vector the observed han_lee_iv means match the bias formula too."""
    counts = _draw("han_lee_iv", WEIGHTS, R, seed=99)
    _assert_mean_counts(counts, han_lee_iv_expected_counts(WEIGHTS), "han_lee_iv (N=16)")


def _random_weight_rows(rows: int, n: int, seed: int) -> np.ndarray:
    """Dirichlet weight rows with about a quarter of the entries set exactly to zero and a
    few spanning many orders of magnitude."""
    generator = np.random.default_rng(seed)
    raw = generator.dirichlet(np.full(n, 0.3), size=rows)
    raw *= 10.0 ** generator.uniform(-8, 0, size=(rows, n))
    raw[generator.random((rows, n)) < 0.25] = 0.0
    raw[:, 0] += 1e-3                      # no all-zero row
    return raw / raw.sum(axis=1, keepdims=True)


@pytest.mark.parametrize("name", ALL)
def test_shape_range_and_zero_weights(name):
    """Every resampler returns exactly N indices in [0, N) per row and never picks a
    zero-weight particle (deterministic property, checked on 2000 random rows)."""
    n = 37
    weights = _random_weight_rows(2000, n, seed=3)
    indices = RESAMPLERS[name](weights, TrialStreams.from_seeds(range(2000)))
    assert indices.shape == weights.shape
    assert np.issubdtype(indices.dtype, np.integer)
    assert indices.min() >= 0 and indices.max() < n
    picked = np.take_along_axis(weights, indices, axis=1)
    assert np.all(picked > 0), f"{name} selected a zero-weight particle"
    assert np.all(offspring_counts(indices, n).sum(axis=1) == n)


def test_systematic_counts_are_floor_or_ceil():
    """Systematic resampling gives N_j in {floor(N w_j), ceil(N w_j)} (docs/reference-facts.md#resampling)."""
    n = 37
    weights = _random_weight_rows(2000, n, seed=4)
    counts = offspring_counts(RESAMPLERS["systematic"](weights, TrialStreams.from_seeds(range(2000))), n)
    scaled = n * weights
    assert np.all(counts >= np.floor(scaled))
    assert np.all(counts <= np.ceil(scaled))


def test_residual_counts_at_least_floor():
    """Residual resampling keeps at least floor(N w_j) copies of each particle."""
    n = 37
    weights = _random_weight_rows(2000, n, seed=5)
    counts = offspring_counts(RESAMPLERS["residual"](weights, TrialStreams.from_seeds(range(2000))), n)
    assert np.all(counts >= np.floor(n * weights))


def test_residual_integer_weights_are_deterministic():
    """When every N w_j is an integer, residual resampling draws nothing: counts = N w_j."""
    w = np.array([[0.5, 0.25, 0.0, 0.25]])
    indices = RESAMPLERS["residual"](w, TrialStreams.from_seeds([0]))
    np.testing.assert_array_equal(offspring_counts(indices, 4)[0], [2, 1, 0, 1])


def test_inverse_cdf_round_off_guard():
    """Weights whose cumulative sum ends just below 1 (1 - 1e-12, or float32 rounding) with
    points in the gap (C_N, 1) must return the last particle, never the invalid index N."""
    n = 10
    w = np.full(n, 0.1)
    w[-1] -= 1e-12                          # sum = 1 - 1e-12
    points = np.array([[1 - 1e-13, np.nextafter(1.0, 0.0), 1 - 5e-13, 0.5, 0.0]])
    indices = inverse_cdf(w[None, :], points)
    assert indices.max() < n
    np.testing.assert_array_equal(indices[0, :3], n - 1)

    w32 = np.random.default_rng(0).random((50, 1000)).astype(np.float32)
    w32 /= w32.sum(axis=1, keepdims=True)
    w32 = w32.astype(np.float64)            # rows sum to 1 only up to float32 round-off
    assert np.any(np.abs(w32.sum(axis=1) - 1.0) > 1e-9)
    near_one = np.broadcast_to(1.0 - np.logspace(-16, -6, 11), (50, 11)).copy()
    near_one.sort(axis=1)
    indices = inverse_cdf(w32, near_one)
    assert indices.min() >= 0 and indices.max() < 1000
    np.testing.assert_array_equal(indices[:, -1], 999)


def test_inverse_cdf_guard_never_selects_trailing_zero_weight():
    """With rows summing to 1 - 1e-12 and a zero last weight (a lost particle parked at 0),
    a point in the round-off gap must go to the last particle of positive weight: the
    module promises that zero-weight particles are never selected. Forcing C_N = 1 makes the
    gap belong to particle N - 1 instead (probability ~ gap per point in the engine, so
    rare, but it would resurrect a lost particle)."""
    w = np.array([[0.5, 0.5 - 1e-12, 0.0]])
    assert inverse_cdf(w, np.array([[1 - 1e-13]]))[0, 0] == 1


@pytest.mark.parametrize("name", ["systematic", "stratified", "multinomial"])
def test_resamplers_never_return_n_with_short_sums(name):
    """Resamplers fed rows summing to 1 - 1e-12 never return index N."""
    n = 5
    w = np.full((500, n), 0.2)
    w[:, -1] -= 1e-12
    indices = RESAMPLERS[name](w, TrialStreams.from_seeds(range(500)))
    assert indices.max() < n


@pytest.mark.numpy_only
@pytest.mark.parametrize("name", ALL)
def test_batched_equals_one_by_one(name):
    """Resampling rows together with their generators gives exactly the indices obtained by
    resampling each row alone with a fresh generator of the same seed (TrialStreams
    contract: results do not depend on how trials are batched)."""
    rows, n = 12, 23
    weights = _random_weight_rows(rows, n, seed=11)
    seeds = [int(s) for s in np.random.SeedSequence(2024).generate_state(rows)]
    batched = RESAMPLERS[name](weights, TrialStreams.from_seeds(seeds))
    for row in range(rows):
        alone = RESAMPLERS[name](weights[row:row + 1], TrialStreams.from_seeds([seeds[row]]))
        np.testing.assert_array_equal(batched[row], alone[0])
    # and the draws really are random: different seeds give different index sets somewhere
    other = RESAMPLERS[name](weights, TrialStreams.from_seeds([s + 1 for s in seeds]))
    assert not np.array_equal(batched, other)


def test_offspring_counts():
    """offspring_counts counts each index per row (hand example)."""
    indices = np.array([[0, 0, 2, 3], [1, 1, 1, 1]])
    np.testing.assert_array_equal(offspring_counts(indices, 4), [[2, 0, 1, 1], [0, 4, 0, 0]])
