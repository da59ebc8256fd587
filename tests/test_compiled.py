"""The compiled loops (numba) give exactly what their NumPy definitions give.

* pfx.numerics.ziggurat: TrialStreams.standard_normal is, draw for draw, each trial's
  ``Generator.standard_normal`` (and ``uniform`` its ``Generator.random``), and leaves every
  generator where NumPy would have left it, subsets of a batch included; other bit generators and
  an unknown PCG64 layout fall back to NumPy's own methods.
* pfx.filters.particle.resampling.inverse_cdf (one merged pass) equals the binary search it replaced,
  ``searchsorted(guarded cumsum, u, 'right')`` clipped to N - 1, index for index.
* pfx.filters.particle.cloud.resample_rows equals ``take_along_axis``, whatever the memory layout.
* pfx.numerics.log_weights.normalise_weights: weights are exp(log-weights), rows sum to 1.
"""

from __future__ import annotations

import numpy as np
import pytest

from pfx.filters.particle.cloud import resample_rows
from pfx.filters.particle.resampling import inverse_cdf
from pfx.numerics.log_weights import log_normalise, normalise_weights
from pfx.numerics.seeding import TrialStreams


@pytest.mark.numpy_only
@pytest.mark.parametrize("count", [1, 2, 7, 300, 50_000])
def test_normal_draws_are_numpys_word_for_word(count):
    seeds = [0, 1, 2024, 2**62 + 5]
    streams = TrialStreams.from_seeds(seeds)
    draws = streams.standard_normal((count,))
    then = [generator.random() for generator in streams.generators]
    for row, seed in enumerate(seeds):
        generator = np.random.default_rng(seed)
        np.testing.assert_array_equal(draws[row], generator.standard_normal(count))
        assert then[row] == generator.random(), "the generator must end where NumPy leaves it"


def test_normal_draws_keep_their_shape_and_mix_with_other_draws():
    streams = TrialStreams.from_seeds([5, 6])
    first = streams.standard_normal((4, 3))
    uniform = streams.uniform((2,))
    second = streams.standard_normal((5,))
    for row, seed in enumerate([5, 6]):
        generator = np.random.default_rng(seed)
        np.testing.assert_array_equal(first[row], generator.standard_normal((4, 3)))
        np.testing.assert_array_equal(uniform[row], generator.random(2))
        np.testing.assert_array_equal(second[row], generator.standard_normal(5))


@pytest.mark.numpy_only
def test_the_tails_and_wedges_are_numpys_too():
    """4e6 draws reach every slow path (tail beyond r: ~1000 draws, wedges: ~1 %)."""
    streams = TrialStreams.from_seeds([77])
    draws = streams.standard_normal((4_000_000,))[0]
    assert np.sum(np.abs(draws) > 3.6541528853610088) > 500
    np.testing.assert_array_equal(draws, np.random.default_rng(77).standard_normal(4_000_000))


def test_subsets_step_the_same_generators():
    """A subset's draws (the rows a resampling step picks) advance the batch's own generators."""
    streams = TrialStreams.from_seeds([1, 2, 3])
    first = streams.standard_normal((5,))
    subset = streams.subset(np.array([2, 0]))
    picked = subset.uniform((3,))
    then = streams.standard_normal((2,))
    for row, seed in enumerate([1, 2, 3]):
        generator = np.random.default_rng(seed)
        np.testing.assert_array_equal(first[row], generator.standard_normal(5))
        if row != 1:
            np.testing.assert_array_equal(picked[[2, 0].index(row)], generator.random(3))
        np.testing.assert_array_equal(then[row], generator.standard_normal(2))
        assert streams.generators[row].bit_generator.state == generator.bit_generator.state


def test_copies_step_their_own_generators():
    """A deep copy or a pickled copy has new generators: it must never step the original's."""
    import copy
    import pickle

    streams = TrialStreams.from_seeds([8, 9])
    streams.standard_normal((3,))                        # the addresses are known from here on
    before = [generator.bit_generator.state for generator in streams.generators]
    for duplicate in (copy.deepcopy(streams), pickle.loads(pickle.dumps(streams))):
        draws = duplicate.standard_normal((4,))
        for row, seed in enumerate([8, 9]):
            generator = np.random.default_rng(seed)
            generator.standard_normal(3)
            np.testing.assert_array_equal(draws[row], generator.standard_normal(4))
    assert [generator.bit_generator.state for generator in streams.generators] == before


@pytest.mark.numpy_only
def test_pcg64_uniforms_are_numpys():
    from pfx.numerics import pcg64

    seeds = (0, 9, 2**63 - 1)
    generators = [np.random.PCG64(seed) for seed in seeds]
    draws = np.empty((3, 5000))
    pcg64.uniforms(pcg64.state_addresses(generators), draws)
    for row, seed in enumerate(seeds):
        numpys = np.random.PCG64(seed)
        np.testing.assert_array_equal(draws[row], np.random.Generator(numpys).random(5000))
        assert generators[row].state == numpys.state


def test_an_unknown_state_layout_falls_back_to_numpy(monkeypatch):
    from pfx.numerics import pcg64

    monkeypatch.setattr(pcg64, "layout_matches", lambda: False)
    streams = TrialStreams.from_seeds(range(4))
    assert streams.compiled_addresses() is None
    normal, uniform = streams.standard_normal((40,)), streams.uniform((3,))
    for row in range(4):
        generator = np.random.default_rng(row)
        np.testing.assert_array_equal(normal[row], generator.standard_normal(40))
        np.testing.assert_array_equal(uniform[row], generator.random(3))


def test_other_bit_generators_use_numpys_loop():
    generators = [np.random.Generator(np.random.MT19937(3)), np.random.Generator(np.random.Philox(4))]
    draws = TrialStreams(generators).standard_normal((10,))
    np.testing.assert_array_equal(draws[0], np.random.Generator(np.random.MT19937(3)).standard_normal(10))
    np.testing.assert_array_equal(draws[1], np.random.Generator(np.random.Philox(4)).standard_normal(10))


def _binary_search(weights, points):
    """The inverse CDF by cumsum and binary search (pfx's implementation before the merged pass)."""
    cumulative = np.cumsum(weights, axis=-1)
    n = weights.shape[-1]
    last_positive = n - 1 - np.argmax(weights[..., ::-1] > 0, axis=-1)
    cumulative[np.arange(n) >= last_positive[..., None]] = 1.0
    indices = np.stack([np.searchsorted(cumulative[row], points[row], side="right")
                        for row in range(points.shape[0])])
    return np.minimum(indices, n - 1)


def test_inverse_cdf_merged_pass_equals_binary_search():
    rng = np.random.default_rng(1)
    for _ in range(2000):
        n, m = int(rng.integers(1, 40)), int(rng.integers(1, 50))
        weights = rng.random((3, n)) ** rng.integers(1, 8)
        weights[rng.random((3, n)) < 0.3] = 0.0                       # zero weights, some trailing
        if rng.random() < 0.3:
            weights[:, -int(rng.integers(1, n + 1)):] = 0.0
        totals = weights.sum(axis=1, keepdims=True)
        weights = np.divide(weights, totals, out=np.zeros_like(weights), where=totals > 0)  # all-zero rows too
        points = rng.random((3, m))
        if rng.random() < 0.7:
            points.sort(axis=1)                                        # resamplers' points are sorted
        if rng.random() < 0.2:
            points[:, -1] = np.nextafter(1.0, 0.0)
        np.testing.assert_array_equal(inverse_cdf(weights, points), _binary_search(weights, points))


@pytest.mark.parametrize("layout", ["rows", "components"])
def test_resample_rows_equals_take_along_axis(layout):
    rng = np.random.default_rng(2)
    trials, n, d = 5, 17, 3
    state = rng.random((trials, n, d))
    if layout == "components":                 # each component contiguous (see Noise.sample)
        state = np.ascontiguousarray(state.transpose(0, 2, 1)).transpose(0, 2, 1)
    for rows in (np.arange(trials), np.array([0, 3, 4]), np.array([2])):
        indices = rng.integers(0, n, (len(rows), n))
        expected = np.take_along_axis(state[rows], indices[..., None], axis=1)
        np.testing.assert_array_equal(resample_rows(state, rows, indices), expected)


def test_normalise_weights():
    rng = np.random.default_rng(3)
    log_weights = rng.normal(0.0, 30.0, (4, 50))
    log_weights[1] = -np.inf
    log_weights[2, :10] = -np.inf
    log_weights[3] += 1e17                    # huge shift: log-sum-exp must not lose it
    normalised, weights, normaliser = normalise_weights(log_weights)
    finite = np.isfinite(normaliser)
    assert list(finite) == [True, False, True, True]
    np.testing.assert_allclose(weights[finite], np.exp(normalised[finite]), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(weights[finite].sum(axis=1), 1.0, rtol=1e-12)
    assert np.all(weights[1] == 0.0) and np.all(np.isneginf(normalised[1]))
    legacy, legacy_normaliser = log_normalise(log_weights)
    np.testing.assert_array_equal(legacy, normalised)
    np.testing.assert_array_equal(legacy_normaliser, normaliser)


def test_ziggurat_tables_satisfy_their_definitions():
    """The frozen tables are the ziggurat of e^{-x^2/2}: strip edges x_i = width_i 2^52 with
    densities e^{-x_i^2/2}; each rectangle bound is 2^52 x_{i-1} / x_i (the base strip's r / x_0);
    and they equal, bit for bit, the copy numba ships (which they were written from)."""
    from pfx.numerics import ziggurat_tables as tables

    edges = tables.STRIP_WIDTHS * 2.0**52
    assert edges[-1] == tables.TAIL_START and tables.TAIL_START * tables.TAIL_START_INVERSE == pytest.approx(1.0)
    np.testing.assert_allclose(tables.DENSITIES[1:], np.exp(-0.5 * edges[1:] ** 2), rtol=1e-15)
    bounds = tables.STRIP_BOUNDS.astype(float) / 2.0**52
    np.testing.assert_allclose(bounds[2:], edges[1:-1] / edges[2:], rtol=0, atol=1e-15)
    assert bounds[0] == pytest.approx(tables.TAIL_START / edges[0], abs=1e-15) and bounds[1] == 0
    shipped = pytest.importorskip("numba.np.random._constants")
    assert np.array_equal(tables.STRIP_BOUNDS, shipped.ki_double)
    assert np.array_equal(tables.STRIP_WIDTHS, shipped.wi_double)
    assert np.array_equal(tables.DENSITIES, shipped.fi_double)
