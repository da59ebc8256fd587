"""The binary Bayes filter in log odds (Probabilistic Robotics Table 4.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pfx.filters.log_odds import (
    EPSILON,
    belief,
    binary_bayes_filter,
    corridor_example,
    inverse_range_sensor,
    log_odds,
    run_binary_bayes_filter,
)


def test_a_short_sequence_by_hand():
    # prior 0.2: l0 = log(0.2/0.8) = log(1/4); measurements p(x|z) = 0.7, 0.9, 0.4
    # l1 = log(1/4) + log(7/3) - log(1/4) = log(7/3)
    # l2 = log(7/3) + log(9) - log(1/4) = log(7/3 * 9 * 4) = log(84)
    # l3 = log(84) + log(4/6) - log(1/4) = log(84 * 2/3 * 4) = log(224)
    # bel3 = 224 / 225
    expected = [math.log(7 / 3), math.log(84.0), math.log(224.0)]
    unrolled = run_binary_bayes_filter([0.7, 0.9, 0.4], 0.2)
    assert np.allclose(unrolled, expected, rtol=1e-12)
    step = log_odds(0.2)
    for p, value in zip([0.7, 0.9, 0.4], expected):
        step = binary_bayes_filter(step, p, 0.2)
        assert math.isclose(step, value, rel_tol=1e-12)
    assert math.isclose(belief(unrolled[-1]), 224 / 225, rel_tol=1e-12)
    assert math.isclose(belief(unrolled[-1]), 1 - 1 / (1 + math.exp(unrolled[-1])), rel_tol=1e-12)


def test_symmetric_measurements_cancel():
    # prior 1/2: the pairs p, 1 - p cancel
    log_odds_sequence = run_binary_bayes_filter([0.8, 0.2, 0.65, 0.35, 0.99, 0.01], 0.5)
    assert np.allclose(log_odds_sequence[[1, 3, 5]], 0.0, atol=1e-12)
    # any prior: measurements whose log odds lie symmetrically about the prior's cancel
    prior = 0.35
    mirrored = belief(2 * log_odds(prior) - log_odds(0.8))
    assert math.isclose(belief(run_binary_bayes_filter([0.8, mirrored], prior)[-1]), prior, rel_tol=1e-12)
    # an uninformative measurement (p(x|z) = p(x)) changes nothing
    assert math.isclose(binary_bayes_filter(1.3, prior, prior), 1.3, rel_tol=1e-15)


def test_vectorised_over_cells_equals_cell_by_cell():
    rng = np.random.default_rng(0)
    inverse = rng.uniform(0.05, 0.95, size=(6, 4, 5))
    prior = rng.uniform(0.2, 0.8, size=(4, 5))
    grid = run_binary_bayes_filter(inverse, prior)
    assert grid.shape == (6, 4, 5)
    for i in range(4):
        for j in range(5):
            value = log_odds(prior[i, j])
            for t in range(6):
                value = binary_bayes_filter(value, inverse[t, i, j], prior[i, j])
                assert math.isclose(grid[t, i, j], value, rel_tol=1e-12, abs_tol=1e-12)


def test_certain_measurements_are_clipped_and_contrary_ones_still_count():
    bound = math.log((1 - EPSILON) / EPSILON)
    assert math.isclose(log_odds(1.0), bound, rel_tol=1e-12) and log_odds(0.0) == -log_odds(1.0)
    sequence = run_binary_bayes_filter([1.0, 0.0], 0.5)
    assert np.all(np.isfinite(sequence)) and sequence[-1] == 0.0
    assert belief(1000.0) == 1.0 and belief(-1000.0) == 0.0          # no overflow


@pytest.mark.parametrize("bad", [1.5, -0.1, math.nan])
def test_probabilities_outside_zero_one_are_refused(bad):
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        run_binary_bayes_filter([0.5, bad], 0.5)


def test_inverse_range_sensor_marks_free_surface_and_unseen_cells():
    centres = np.array([0.5, 1.5, 2.5, 3.5, 4.5])
    assert np.array_equal(inverse_range_sensor(centres, 2.2, thickness=1.0, free=0.3, occupied=0.7, prior=0.5),
                          [0.3, 0.3, 0.7, 0.5, 0.5])


def test_corridor_example_maps_the_free_cells_and_the_obstacle_face():
    table = corridor_example(np.random.default_rng(3), cells=40, obstacle=(24, 28), scans=10)
    assert list(table.columns) == ["scan", "cell", "position", "occupied", "measured_range",
                                   "inverse_probability", "log_odds", "belief"]
    assert len(table) == 400
    last = table[table.scan == 10].set_index("cell")
    assert (last.loc[:22, "belief"] < 0.01).all()         # seen through ten times
    assert last.loc[24, "belief"] > 0.9                   # the face that reflects the beam
    assert (last.loc[26:, "belief"] == 0.5).all()         # never seen: the prior
    first = table[table.scan == 1].set_index("cell")
    assert np.allclose(first["belief"], first["inverse_probability"])     # one scan from prior 1/2
