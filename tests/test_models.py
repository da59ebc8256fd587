"""Model tests: the falling body against the published reference truths (docs/reference-facts.md#falling-body),
the range-beacons geometry and paths, and the linear model's algebra and validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from pfx.models.falling_body import FOOT, FallingBody
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.range_beacons import RangeBeacons
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams


def _truth(model) -> np.ndarray:
    """Noise-free truth x_0..x_T of one trial, shape (T + 1, d)."""
    states, _ = simulate_truth(model, TrialStreams.from_seeds([0]))
    return states[0]


# -- falling body -----------------------------------------------------------------------------

def test_falling_body_jud_reference_truth():
    """Variant jud (Athans 1968 / Julier 2000; RK4 at 64 sub-steps per 1 s step) reproduces the
    reference truth x1 = 102455, 39453, 26732 ft and x2 = 17753, 1239, 104.5 ft/s at t = 10,
    20, 60 s. Tolerance: the values are printed rounded, so +-1 in the last printed digit
    (1 ft; 1 ft/s; 0.1 ft/s for 104.5)."""
    model = FallingBody(variant="jud")
    assert model.dt == 1.0 and model.steps == 60 and not model.process_noise.covariance().any()
    states = _truth(model)
    assert states.shape == (61, 3)
    steps = [10, 20, 60]
    np.testing.assert_allclose(states[steps, 0], [102455, 39453, 26732], rtol=0, atol=1.0)
    assert np.all(np.abs(states[steps, 1] - [17753, 1239, 104.5]) <= [1.0, 1.0, 0.1]), states[steps, 1]
    np.testing.assert_array_equal(states[:, 2], 1e-3)   # x3' = 0


SIMON_STEPS = [20, 40, 60]                       # t = 10, 20, 30 s at dt = 0.5 s
SIMON_X1 = [101026, 38791, 31123]
SIMON_X2 = [-17885, -1268, -518]


def test_falling_body_simon_euler_reproduces_printed_truth():
    """Simon's printed truth (x1 = 101026, 38791, 31123 ft; x2 = -17885, -1268, -518 ft/s at
    t = 10, 20, 30 s) was computed by Euler's method at 1 ms: integrator euler with 500
    sub-steps per 0.5 s step reproduces it within +-1 in the last printed digit."""
    model = FallingBody(variant="simon", integrator="euler", substeps=500)
    assert model.dt == 0.5
    states = _truth(model)
    np.testing.assert_allclose(states[SIMON_STEPS, 0], SIMON_X1, rtol=0, atol=1.0)
    np.testing.assert_allclose(states[SIMON_STEPS, 1], SIMON_X2, rtol=0, atol=1.0)


def test_falling_body_simon_rk4_accuracy():
    """The default RK4 (13 sub-steps) agrees with the Euler-1ms values within 5 ft and 1 ft/s:
    the printed values carry Euler's O(h) global error (a few ft at h = 1 ms), which RK4 does
    not have. RK4 itself is converged: a 20 times finer RK4 agrees within 0.05 ft and
    0.01 ft/s (RK4's O(h^4) error at h = 0.5/13 s is ~1e-5 ft)."""
    default = _truth(FallingBody(variant="simon"))
    euler = _truth(FallingBody(variant="simon", integrator="euler", substeps=500))
    fine = _truth(FallingBody(variant="simon", substeps=260))
    np.testing.assert_allclose(default[SIMON_STEPS, 0], euler[SIMON_STEPS, 0], rtol=0, atol=5.0)
    np.testing.assert_allclose(default[SIMON_STEPS, 1], euler[SIMON_STEPS, 1], rtol=0, atol=1.0)
    np.testing.assert_allclose(default[SIMON_STEPS, 0], SIMON_X1, rtol=0, atol=5.0)
    np.testing.assert_allclose(default[:, 0], fine[:, 0], rtol=0, atol=0.05)
    np.testing.assert_allclose(default[:, 1], fine[:, 1], rtol=0, atol=0.01)
    # and Euler really is the less accurate one (its error exceeds RK4's by orders of magnitude)
    assert np.abs(euler[:, 0] - fine[:, 0]).max() > 100 * np.abs(default[:, 0] - fine[:, 0]).max()


def test_falling_body_si_matches_feet():
    """The SI form of variant simon, converted to feet (x1 / 0.3048, x2 / 0.3048), agrees with
    the feet form within 0.1 %: the parameters are the same physics, except g = 9.81 m/s^2
    against 32.2 ft/s^2 = 9.8146 m/s^2 (a 0.05 % difference in one term)."""
    feet = _truth(FallingBody(variant="simon"))
    si = _truth(FallingBody(variant="simon", units="si"))
    np.testing.assert_allclose(si[:, 0] / FOOT, feet[:, 0], rtol=1e-3)
    np.testing.assert_allclose(si[:, 1] / FOOT, feet[:, 1], rtol=1e-3)


def test_falling_body_si_requires_simon():
    """There is no SI form of variant jud: a pydantic ValidationError naming units."""
    with pytest.raises(ValidationError, match="units"):
        FallingBody(variant="jud", units="si")


def test_falling_body_measurement_is_range():
    """h(x) = sqrt(M^2 + (x1 - H)^2) with M = H = 1e5 ft (hand values: a 3-4-5 triangle, the
    radar's own altitude, and a batched shape)."""
    model = FallingBody(variant="simon")
    states = np.array([[1e5 + 0.75e5, -2e4, 1e-3],     # offset 7.5e4 -> range 1.25e5
                       [1e5, -1e3, 1e-3],              # level with the radar -> range M
                       [0.0, 0.0, 0.0]])               # offset -1e5 -> range 1e5 sqrt 2
    ranges = model.measurement_mean(states)
    assert ranges.shape == (3, 1)
    np.testing.assert_allclose(ranges[:, 0], [1.25e5, 1e5, 1e5 * math.sqrt(2)], rtol=1e-14)
    batched = model.measurement_mean(np.broadcast_to(states, (2, 3, 3)))
    assert batched.shape == (2, 3, 1)
    custom = FallingBody(variant="simon", radar_distance=3.0, radar_altitude=10.0)
    assert custom.measurement_mean(np.array([14.0, 0.0, 0.0]))[0] == pytest.approx(5.0)


# -- range beacons ----------------------------------------------------------------------------

BEACONS = [[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]


def test_range_beacons_measurement_mean():
    """h(x) is the Euclidean distance to each beacon (hand values, 3-4-5 triangles)."""
    model = RangeBeacons(beacons=BEACONS)
    states = np.array([[3.0, 4.0], [10.0, 10.0], [6.0, 8.0]])
    expected = [[5.0, math.hypot(7, 4), math.hypot(3, 6)],
                [math.hypot(10, 10), 10.0, 10.0],
                [10.0, math.hypot(4, 8), math.hypot(6, 2)]]
    np.testing.assert_allclose(model.measurement_mean(states), expected, rtol=1e-14)
    assert model.measurement_dimension == 3


@pytest.mark.parametrize("path", [
    {"kind": "lissajous", "amplitude": [4.0, 3.0], "center": [5.0, 5.0]},
    {"kind": "waypoints", "points": [[1, 1], [8, 1], [8, 6]]},
])
def test_range_beacons_odometry_without_noise_follows_path(path):
    """Odometry motion with zero process noise from the path's start follows the designed path
    exactly (u_k = c_k - c_{k-1} telescopes), up to floating-point accumulation."""
    model = RangeBeacons(beacons=BEACONS, path=path, steps=40, motion="odometry",
                         process_noise={"family": "gaussian", "variance": 0.0})
    states = _truth(model)
    np.testing.assert_allclose(states, model.path_points, rtol=0, atol=1e-12)
    assert model.path_points.shape == (41, 2)


def test_waypoint_path_equal_arc_length():
    """Waypoints [0,0] -> [3,0] -> [3,4] (length 7) at T = 14: the corner falls on sample 6
    and every consecutive pair is 0.5 apart; a closed unit square at T = 8 visits the
    corners and edge midpoints in order."""
    model = RangeBeacons(beacons=BEACONS, steps=14,
                         path={"kind": "waypoints", "points": [[0, 0], [3, 0], [3, 4]]})
    points = model.path_points
    np.testing.assert_allclose(np.hypot(*np.diff(points, axis=0).T), 0.5, rtol=1e-12)
    np.testing.assert_allclose(points[[0, 6, 14]], [[0, 0], [3, 0], [3, 4]], atol=1e-12)

    square = RangeBeacons(beacons=BEACONS, steps=8,
                          path={"kind": "waypoints", "points": [[0, 0], [1, 0], [1, 1], [0, 1]],
                                "closed": True}).path_points
    np.testing.assert_allclose(square, [[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [0.5, 1],
                                        [0, 1], [0, 0.5], [0, 0]], atol=1e-12)


def test_range_beacons_random_walk_has_no_control():
    """Random-walk motion uses no control: with zero noise the truth stays at the start."""
    model = RangeBeacons(beacons=BEACONS, motion="random_walk", steps=5,
                         process_noise={"family": "gaussian", "variance": 0.0})
    assert model.control(1) is None
    states = _truth(model)
    np.testing.assert_array_equal(states, np.broadcast_to(states[0], states.shape))


# -- linear gaussian --------------------------------------------------------------------------

def _linear_model(**extra):
    return LinearGaussian(transition_matrix=[[1.0, 0.5], [0.0, 0.9]],
                          measurement_matrix=[[1.0, 0.0], [2.0, -1.0], [0.0, 3.0]],
                          control_matrix=[[0.5], [1.0]], controls=[[1.0], [2.0], [-3.0]],
                          steps=3, **extra)


def test_linear_gaussian_algebra():
    """propagate = A x + B u_k + w and measurement_mean = H x, on hand-computed values and on
    a batched (trials, N, d) array."""
    model = _linear_model()
    x = np.array([2.0, -1.0])
    # u_2 = [2.0]: B u = [1.0, 2.0]; A x = [2 - 0.5, -0.9] = [1.5, -0.9]
    control = model.control(2)
    np.testing.assert_allclose(control, [1.0, 2.0])
    noise = np.array([0.1, -0.2])
    np.testing.assert_allclose(model.propagate(x, control, noise), [2.6, 0.9], rtol=1e-14)
    np.testing.assert_allclose(model.propagate(x, None, np.zeros(2)), [1.5, -0.9], rtol=1e-14)
    np.testing.assert_allclose(model.measurement_mean(x), [2.0, 5.0, -3.0], rtol=1e-14)

    batch = np.random.default_rng(0).normal(size=(4, 7, 2))
    A, H = model.matrices
    np.testing.assert_allclose(model.measurement_mean(batch), np.einsum("md,rnd->rnm", H, batch))
    B = np.array([[0.5], [1.0]])
    np.testing.assert_allclose(model.propagate(batch, model.control(3), 0.0),
                               np.einsum("ij,rnj->rni", A, batch) + (B @ [-3.0]), rtol=1e-14)


def test_linear_gaussian_single_control_vector_is_reused():
    """One control vector is applied at every step."""
    model = LinearGaussian(transition_matrix=[[1.0]], measurement_matrix=[[1.0]], steps=4,
                           control_matrix=[[2.0]], controls=[[0.25]])
    for k in range(1, 5):
        np.testing.assert_allclose(model.control(k), [0.5])


@pytest.mark.parametrize("changes, key", [
    ({"measurement_matrix": [[1.0, 0.0, 0.0]]}, "measurement_matrix"),   # H with 3 columns, d = 2
    ({"transition_matrix": [[1.0, 0.5]]}, "transition_matrix"),         # A not square
    ({"control_matrix": [[0.5]]}, "control_matrix"),                    # B with 1 row, d = 2
    ({"controls": [[1.0], [2.0]]}, "controls"),                         # 2 vectors for 3 steps
    ({"controls": [[1.0, 2.0]]}, "controls"),                           # u of length 2, B has 1 column
    ({"control_matrix": None}, "controls"),                             # controls without B
])
def test_linear_gaussian_dimension_mismatch(changes, key):
    """Dimension mismatches raise a pydantic ValidationError whose message names the key."""
    arguments = dict(transition_matrix=[[1.0, 0.5], [0.0, 0.9]], measurement_matrix=[[1.0, 0.0]],
                     control_matrix=[[0.5], [1.0]], controls=[[1.0], [2.0], [-3.0]], steps=3)
    arguments.update(changes)
    with pytest.raises(ValidationError, match=key):
        LinearGaussian(**arguments)


def test_linear_gaussian_noise_dimension_mismatch():
    """A measurement noise covariance of the wrong size is rejected (ValidationError)."""
    with pytest.raises(ValidationError, match="measurement_noise"):
        LinearGaussian(transition_matrix=[[1.0]], measurement_matrix=[[1.0], [2.0]],
                       measurement_noise={"family": "gaussian", "variance": [1.0, 1.0, 1.0]})
