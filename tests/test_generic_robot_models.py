"""The robot and map models written once for both backends (docs/backends.md): planar_robot, range_beacons,
sonar_mcl, the wall map's ray casting and Probabilistic Robotics' motion models.

Group: **bit-exact NumPy vs JAX on the same inputs**. Each method is run twice on the same fixed
inputs ((2, 5, d) clouds, noise, measurements): on NumPy arrays, and under ``jax.jit`` on JAX
arrays (float64), where the control is a traced input as in the JAX engine's scan. The two agree to
rtol 1e-12: the same operations, in another library. The samplers are given the same uniform draws
on both sides (:class:`FixedUniforms`), so they too agree number for number. One test is
**backend-invariant** in distribution: the book's sampler drawing from JAX's KeyStreams has the
moments the Gaussian filters' linearisation gives (what the NumPy test in test_planar_robot.py
checks with TrialStreams).

That the NumPy numbers did not change is checked by the existing tests and by reruns of the example
configs (identical CSV files).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

from pfx.filters.kalman.linearisation import noise_jacobian  # noqa: E402
from pfx.models.planar_robot import PlanarRobot  # noqa: E402
from pfx.models.range_beacons import RangeBeacons  # noqa: E402
from pfx.models.sonar_mcl import FreeSpaceLaw, SonarMCL  # noqa: E402
from pfx.models.walls import WallMap  # noqa: E402
from pfx.motion.odometry import log_densities_odometry, sample_motion_model_odometry  # noqa: E402
from pfx.motion.velocity import log_densities_velocity, sample_motion_model_velocity  # noqa: E402
from pfx.numerics.key_streams import KeyStreams  # noqa: E402

TRIALS, PARTICLES = 2, 5
TOLERANCE = dict(rtol=1e-12, atol=1e-12)     # atol for values that are 0 up to rounding (sin of 0)
ARENA = [[0.0, 0.0, 250.0, 0.0], [250.0, 0.0, 250.0, 130.0], [250.0, 130.0, 190.0, 130.0],
         [190.0, 130.0, 190.0, 200.0], [190.0, 200.0, 60.0, 200.0], [60.0, 200.0, 60.0, 170.0],
         [60.0, 170.0, 0.0, 170.0], [0.0, 170.0, 0.0, 0.0],
         [90.0, 60.0, 130.0, 60.0], [130.0, 60.0, 130.0, 90.0], [130.0, 90.0, 90.0, 90.0], [90.0, 90.0, 90.0, 60.0]]


class FixedUniforms:
    """The Random protocol's ``uniform`` handing out given draws in order: the same numbers to a
    NumPy and a JAX caller (as NumPy arrays, or as JAX arrays)."""

    def __init__(self, draws, as_jax: bool):
        self.draws, self.as_jax, self.used = list(draws), as_jax, 0

    def __len__(self):
        return TRIALS

    def uniform(self, shape):
        draw = self.draws[self.used]
        self.used += 1
        assert draw.shape == (TRIALS, *shape)
        return jnp.asarray(draw) if self.as_jax else draw


def jitted(function, *arguments):
    """``function(*arguments)`` compiled by JAX, the arguments given as JAX arrays (traced)."""
    return np.asarray(jax.jit(function)(*(jnp.asarray(argument) for argument in arguments)))


def cloud(low, high, seed=0) -> np.ndarray:
    """A fixed (2, 5, d) cloud, uniform in the box [low, high]."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    return low + (high - low) * np.random.default_rng(seed).random((TRIALS, PARTICLES, low.size))


# -- planar_robot and the motion models -------------------------------------------------------------

def planar_robot(kind: str, noise: str = "normal", bearings: bool = True) -> PlanarRobot:
    variance = [0.09] * 4 + [0.0025] * 4 if bearings else [0.09] * 4
    return PlanarRobot(motion={"kind": kind, "noise": noise}, bearings=bearings,
                       measurement_noise={"variance": variance})


ROBOT_CLOUD = cloud([-2.0, -3.0, -math.pi], [12.0, 14.0, math.pi])


@pytest.mark.parametrize("kind", ["velocity", "odometry"])
@pytest.mark.parametrize("step", [3, 10])         # straight ahead; inside a quarter turn
def test_planar_robot_propagate_on_jax_equals_numpy(kind, step):
    model = planar_robot(kind)
    control = model.control(step)
    noise = np.random.default_rng(1).standard_normal((TRIALS, PARTICLES, 3))
    expected = model.propagate(ROBOT_CLOUD, control, noise)
    np.testing.assert_allclose(jitted(model.propagate, ROBOT_CLOUD, control, noise), expected, **TOLERANCE)
    assert np.all(np.abs(expected[..., 2]) <= np.pi)


@pytest.mark.parametrize("bearings", [False, True])
def test_planar_robot_measurement_and_likelihood_on_jax_equal_numpy(bearings):
    model = planar_robot("velocity", bearings=bearings)
    noise = np.random.default_rng(2).standard_normal((TRIALS, PARTICLES, model.measurement_dimension))
    mean = model.measurement_mean(ROBOT_CLOUD)
    np.testing.assert_allclose(jitted(model.measurement_mean, ROBOT_CLOUD), mean, **TOLERANCE)
    np.testing.assert_allclose(jitted(model.measure, ROBOT_CLOUD, noise), model.measure(ROBOT_CLOUD, noise),
                               **TOLERANCE)
    # a measurement per trial, against every particle; bearings near +-pi exercise the wrapping
    measurement = mean[:, :1] + 0.3 * noise[:, :1]
    expected = model.log_likelihood(measurement, ROBOT_CLOUD)
    assert expected.shape == (TRIALS, PARTICLES) and np.all(np.isfinite(expected))
    np.testing.assert_allclose(jitted(model.log_likelihood, measurement, ROBOT_CLOUD), expected, **TOLERANCE)


@pytest.mark.parametrize("kind", ["velocity", "odometry"])
@pytest.mark.parametrize("noise", ["normal", "triangular"])
def test_book_sampler_on_jax_equals_numpy_for_the_same_uniforms(kind, noise):
    """transition() samples Table 5.3 / 5.6: given the same uniforms, the same poses."""
    model = planar_robot(kind, noise=noise)
    per_draw = 12 if noise == "normal" else 2
    rng = np.random.default_rng(3)
    draws = [rng.random((TRIALS, PARTICLES, per_draw)) for _ in range(3)]      # three draws a pose
    expected = model.transition(ROBOT_CLOUD, 10, FixedUniforms(draws, as_jax=False))
    moved = jitted(lambda state: model.transition(state, 10, FixedUniforms(draws, as_jax=True)), ROBOT_CLOUD)
    np.testing.assert_allclose(moved, expected, **TOLERANCE)


def test_book_samplers_take_a_traced_control():
    """The samplers of pfx.motion with the control a JAX input (as a compiled scan gives it)."""
    rng = np.random.default_rng(4)
    draws = [rng.random((TRIALS, PARTICLES, 12)) for _ in range(3)]
    alphas = (0.01, 0.01, 0.001, 0.01, 0.0005, 0.005)
    control = np.array([1.0, 0.3])
    expected = sample_motion_model_velocity(control, ROBOT_CLOUD, 0.5, alphas, "normal",
                                            FixedUniforms(draws, as_jax=False))
    np.testing.assert_allclose(jitted(lambda c, pose: sample_motion_model_velocity(
        c, pose, 0.5, alphas, "normal", FixedUniforms(draws, as_jax=True)), control, ROBOT_CLOUD),
        expected, **TOLERANCE)
    before, after = np.array([0.0, 0.0, 0.1]), np.array([1.0, 0.4, 0.5])
    alphas = (0.01, 0.0005, 0.01, 0.001)
    expected = sample_motion_model_odometry(before, after, ROBOT_CLOUD, alphas, "normal",
                                            FixedUniforms(draws, as_jax=False))
    np.testing.assert_allclose(jitted(lambda b, a, pose: sample_motion_model_odometry(
        b, a, pose, alphas, "normal", FixedUniforms(draws, as_jax=True)), before, after, ROBOT_CLOUD),
        expected, **TOLERANCE)


@pytest.mark.parametrize("noise", ["normal", "triangular"])
def test_motion_model_densities_on_jax_equal_numpy(noise):
    """Tables 5.1 and 5.5 (both preimages, and the pose density) evaluated on JAX arrays."""
    before = ROBOT_CLOUD
    now = ROBOT_CLOUD + np.array([0.8, 0.3, 0.2]) + 0.05 * np.random.default_rng(5).standard_normal(ROBOT_CLOUD.shape)
    alphas = (0.01, 0.01, 0.001, 0.01, 0.0005, 0.005)
    control = np.array([1.0, 0.2])
    expected = log_densities_velocity(now, control, before, 1.0, alphas, noise)
    computed = jax.jit(lambda n, c, b: log_densities_velocity(n, c, b, 1.0, alphas, noise))(
        jnp.asarray(now), jnp.asarray(control), jnp.asarray(before))
    for value, reference in zip(computed, expected):
        if noise == "normal":         # the triangular law's bounded support gives -inf here, on both backends
            assert np.all(np.isfinite(reference))
        np.testing.assert_allclose(np.asarray(value), reference, **TOLERANCE)
    alphas = (0.1, 0.05, 0.1, 0.05)
    readings = (np.array([0.0, 0.0, 0.0]), np.array([0.8, 0.3, 0.2]))
    expected = log_densities_odometry(now, *readings, before, alphas, noise)
    computed = jax.jit(lambda n, r0, r1, b: log_densities_odometry(n, r0, r1, b, alphas, noise))(
        *(jnp.asarray(value) for value in (now, *readings, before)))
    for value, reference in zip(computed, expected):
        np.testing.assert_allclose(np.asarray(value), reference, **TOLERANCE)


@pytest.mark.parametrize("kind, alphas", [("velocity", [1e-4, 2e-4, 3e-4, 1e-4, 2e-4, 5e-5]),
                                          ("odometry", [2e-4, 1e-4, 3e-4, 2e-4])])
def test_book_sampler_with_key_streams_has_the_linearised_moments(kind, alphas):
    """Backend-invariant: the transition drawn from JAX's threefry keys has the mean f(x, u, 0)
    and the covariance L L' (Q = I) of the Gaussian filters, within 4 standard errors."""
    model = PlanarRobot(motion={"kind": kind, "alphas": alphas})
    state, step, n = np.array([[2.0, 1.0, 0.4]]), 10, 200_000
    draws = np.asarray(jax.jit(lambda cloud: model.transition(cloud, step, KeyStreams.from_seeds([5])))(
        jnp.broadcast_to(jnp.asarray(state), (1, n, 3))))[0]
    L = noise_jacobian(model, state, model.control(step))[0]
    linearised = L @ L.T
    se = np.sqrt((np.outer(np.diag(linearised), np.diag(linearised)) + linearised ** 2) / n)
    assert np.all(np.abs(np.cov(draws.T) - linearised) < 4 * se + 1e-3 * np.abs(linearised))
    mean = model.propagate(state, model.control(step), np.zeros((1, 3)))[0]
    assert np.all(np.abs(draws.mean(axis=0) - mean) < 4 * np.sqrt(np.diag(linearised) / n) + 1e-4)


# -- range_beacons ----------------------------------------------------------------------------------

@pytest.mark.parametrize("motion", ["odometry", "random_walk"])
def test_range_beacons_on_jax_equal_numpy(motion):
    model = RangeBeacons(beacons=[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]], motion=motion)
    state = cloud([0.0, 0.0], [10.0, 10.0], seed=6)
    noise = 0.1 * np.random.default_rng(7).standard_normal(state.shape)
    control = model.control(5)
    if control is None:
        np.testing.assert_allclose(jitted(lambda x, w: model.propagate(x, None, w), state, noise),
                                   model.propagate(state, None, noise), **TOLERANCE)
    else:
        np.testing.assert_allclose(jitted(model.propagate, state, control, noise),
                                   model.propagate(state, control, noise), **TOLERANCE)
    mean = model.measurement_mean(state)
    np.testing.assert_allclose(jitted(model.measurement_mean, state), mean, **TOLERANCE)
    measurement = mean[:, :1] + 0.5
    np.testing.assert_allclose(jitted(model.log_likelihood, measurement, state),
                               model.log_likelihood(measurement, state), **TOLERANCE)


# -- the wall map and sonar_mcl ---------------------------------------------------------------------

def arena_cloud(seed) -> np.ndarray:
    """Poses in the arena's free space (x, y in cm, heading in degrees), fixed."""
    wall_map, rng, poses = WallMap(ARENA), np.random.default_rng(seed), []
    while len(poses) < TRIALS * PARTICLES:
        x, y = rng.uniform(0.0, 250.0), rng.uniform(0.0, 200.0)
        if wall_map.contains(x, y):
            poses.append([x, y, rng.uniform(0.0, 360.0)])
    return np.array(poses).reshape(TRIALS, PARTICLES, 3)


def test_ray_casting_and_free_space_on_jax_equal_numpy():
    wall_map = WallMap(ARENA)
    rng = np.random.default_rng(8)
    x, y = rng.uniform(-10.0, 260.0, (40, 25)), rng.uniform(-10.0, 210.0, (40, 25))
    heading = rng.uniform(0.0, 2 * np.pi, (40, 25))
    cos, sin = np.cos(heading), np.sin(heading)
    # axis-aligned rays through wall ends and along walls' lines: the parallel and corner cases
    x[0, :4], y[0, :4], cos[0, :4], sin[0, :4] = [30.0, 30.0, 90.0, 60.0], [60.0, 30.0, 30.0, 30.0], \
        [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 1.0, 1.0]
    expected = wall_map.ray_distance(x, y, cos, sin)
    assert np.isinf(expected).any() and np.isfinite(expected).any()      # rays from outside miss
    np.testing.assert_allclose(jitted(wall_map.ray_distance, x, y, cos, sin), expected, **TOLERANCE)
    np.testing.assert_array_equal(jitted(wall_map.contains, x, y), wall_map.contains(x, y))


def sonar(motion: str = "noisy") -> SonarMCL:
    return SonarMCL(walls=ARENA, route=["move 40", "turn 90", "move -30", "move 400"], motion=motion,
                    initial={"kind": "point", "state": [30.0, 30.0, 0.0]})


@pytest.mark.parametrize("step", [1, 2, 3, 4], ids=["move", "turn", "move-back", "move-into-a-wall"])
def test_sonar_propagate_with_a_traced_control_equals_numpy(step):
    model = sonar()
    state = arena_cloud(9)
    noise = np.random.default_rng(10).standard_normal((TRIALS, PARTICLES, 2)) * np.sqrt([9.0, 13.0])
    control = model.control(step)
    expected = model.propagate(state, control, noise)
    np.testing.assert_allclose(jitted(model.propagate, state, control, noise), expected, **TOLERANCE)
    assert np.all(WallMap(ARENA).contains(expected[..., 0], expected[..., 1]))   # never through a wall


def test_sonar_measurement_on_jax_equals_numpy():
    model = sonar()
    state = arena_cloud(11)
    noise = np.random.default_rng(12).standard_normal((TRIALS, PARTICLES, 1))
    np.testing.assert_allclose(jitted(model.measurement_mean, state), model.measurement_mean(state), **TOLERANCE)
    np.testing.assert_allclose(jitted(model.measure, state, noise), model.measure(state, noise), **TOLERANCE)


def test_sonar_censored_likelihood_on_jax_equals_numpy():
    model = sonar()
    state = arena_cloud(13)
    measurement = np.array([[[80.0]], [[model.max_range]]])       # trial 1's reading saturated
    expected = model.log_likelihood(measurement, state)
    assert np.all(np.isfinite(expected))
    np.testing.assert_allclose(jitted(model.log_likelihood, measurement, state), expected, **TOLERANCE)


def test_free_space_prior_drawn_with_key_streams_is_uniform_over_free_space():
    """Backend-invariant: the rejection rounds in a compiled while_loop fill every slot with a pose
    in free space, heading in [0, 360); the share of poses left of the box's centre line x = 110
    is that of the free area (on a fine grid), within 4 binomial standard errors."""
    law = FreeSpaceLaw(walls=ARENA)
    count = 20_000
    poses = np.asarray(jax.jit(lambda keys: law.sample(KeyStreams(keys), (count,)))(
        KeyStreams.from_seeds([3, 4]).keys))
    assert poses.shape == (TRIALS, count, 3) and np.all(np.isfinite(poses))
    assert np.all(WallMap(ARENA).contains(poses[..., 0], poses[..., 1]))
    assert np.all((poses[..., 2] >= 0.0) & (poses[..., 2] < 360.0))
    grid = law._moment_points()
    share = np.mean(grid[:, 0] < 110.0)
    se = math.sqrt(share * (1.0 - share) / count)
    for trial in range(TRIALS):
        assert abs(np.mean(poses[trial, :, 0] < 110.0) - share) < 4 * se + 1e-3      # 1e-3: the grid's error
    assert not np.array_equal(poses[0], poses[1])                                    # each trial its own keys
