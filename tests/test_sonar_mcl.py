"""kim-mcl's sonar_mcl model: the ray caster against hand-computed distances, the paper's motion
statistics, the noise-free arm's determinism, the free-space prior, the censored max-range
likelihood, angles (circular mean, wrapped errors), map files and config errors."""

from __future__ import annotations

import copy
import math
import types

import numpy as np
import pytest
from conftest import REPO_ROOT, write_config_file
from matplotlib.path import Path as PolygonPath
from scipy import integrate, stats

import pfx
from pfx.analysis.metrics import error_distance, state_error
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.filters.particle.cloud import posterior_mean, weighted_mean
from pfx.laws.noise import NOISE_FAMILIES
from pfx.models.range_beacons import RangeBeacons
from pfx.models.simulation import simulate_truth
from pfx.models.sonar_mcl import FreeSpaceLaw, SonarMCL
from pfx.models.walls import WallMap
from pfx.numerics.seeding import TrialStreams
from pfx.run.batch import run_batch
from pfx.safe_yaml import load_config_file

EXAMPLE = REPO_ROOT / "configs" / "examples" / "sonar-mcl.yaml"
SQUARE = [[0.0, 0.0, 100.0, 0.0], [100.0, 0.0, 100.0, 100.0], [100.0, 100.0, 0.0, 100.0], [0.0, 100.0, 0.0, 0.0]]
# the square with a 20 x 20 box obstacle at (60..80, 20..40)
BOX = [[60.0, 20.0, 80.0, 20.0], [80.0, 20.0, 80.0, 40.0], [80.0, 40.0, 60.0, 40.0], [60.0, 40.0, 60.0, 20.0]]


def _cast(walls, x, y, heading_degrees) -> np.ndarray:
    radians = np.radians(heading_degrees)
    return WallMap(walls).ray_distance(np.asarray(x, float), np.asarray(y, float), np.cos(radians), np.sin(radians))


def _model(**changes) -> SonarMCL:
    settings = dict(walls=SQUARE, route=["move 30", "turn 90"], initial={"kind": "point", "state": [50.0, 50.0, 0.0]})
    settings.update(changes)
    return SonarMCL(**settings)


# -- ray casting --------------------------------------------------------------------------------------

@pytest.mark.parametrize("x, y, heading, expected", [
    (50.0, 50.0, 0.0, 50.0),                    # straight at the east wall
    (50.0, 50.0, 90.0, 50.0),
    (10.0, 20.0, 180.0, 10.0),
    (10.0, 20.0, 270.0, 20.0),
    (10.0, 20.0, -90.0, 20.0),                  # the same heading, written negative
    (50.0, 50.0, 45.0, 50.0 * math.sqrt(2.0)),  # into the corner (100, 100): both walls end there
    (1.0, 1.0, 45.0, 99.0 * math.sqrt(2.0)),    # along the diagonal into the far corner
    (20.0, 30.0, 30.0, 80.0 / math.cos(math.radians(30.0))),   # oblique: meets x = 100 at y = 76.2
    (20.0, 30.0, 60.0, 70.0 / math.sin(math.radians(60.0))),   # oblique: meets y = 100 at x = 60.4
])
def test_ray_distance_in_a_square_room(x, y, heading, expected):
    assert _cast(SQUARE, x, y, heading) == pytest.approx(expected, rel=1e-12)


def test_ray_distance_special_cases():
    """Parallel walls are never met, a wall behind the sensor is ignored, the nearest of several
    walls wins, a ray past a wall's end misses it, a ray through its end point meets it."""
    corridor = [[0.0, 0.0, 100.0, 0.0], [0.0, 10.0, 100.0, 10.0]]        # two parallel walls
    assert _cast(corridor, 5.0, 5.0, 0.0) == np.inf                         # along both: a miss
    assert _cast(corridor, 5.0, 5.0, 180.0) == np.inf
    assert _cast(corridor, 5.0, 5.0, 90.0) == pytest.approx(5.0)            # across: the nearer one
    assert _cast(corridor, 5.0, 5.0, 270.0) == pytest.approx(5.0)
    two = [[30.0, -50.0, 30.0, 50.0], [60.0, -50.0, 60.0, 50.0]]
    assert _cast(two, 0.0, 0.0, 0.0) == pytest.approx(30.0)                 # the nearest of two
    assert _cast(two, 45.0, 0.0, 0.0) == pytest.approx(15.0)                # the one behind is ignored
    assert _cast(two, 45.0, 0.0, 180.0) == pytest.approx(15.0)
    assert _cast(two, 90.0, 0.0, 0.0) == np.inf                             # both behind: nothing ahead
    wall = [[100.0, -50.0, 100.0, 50.0]]
    assert _cast(wall, 0.0, 0.0, 20.0) == pytest.approx(100.0 / math.cos(math.radians(20.0)))
    assert _cast(wall, 0.0, 0.0, 30.0) == np.inf                            # passes above its end (y = 57.7)
    end = math.degrees(math.atan2(50.0, 100.0))                             # straight at the end point
    assert _cast(wall, 0.0, 0.0, end) == pytest.approx(math.hypot(100.0, 50.0))
    diagonal = [[0.0, 100.0, 100.0, 0.0]]                                   # the line x + y = 100
    assert _cast(diagonal, 0.0, 0.0, 45.0) == pytest.approx(50.0 * math.sqrt(2.0))
    assert _cast(diagonal, 0.0, 0.0, 0.0) == pytest.approx(100.0)           # meets it at its end (100, 0)


def test_ray_distance_around_an_obstacle():
    room = SQUARE + BOX
    assert _cast(room, 10.0, 30.0, 0.0) == pytest.approx(50.0)              # the box's west face at x = 60
    assert _cast(room, 10.0, 50.0, 0.0) == pytest.approx(90.0)              # above the box: the east wall
    assert _cast(room, 70.0, 90.0, 270.0) == pytest.approx(50.0)            # down onto its top face (y = 40)
    assert _cast(room, 90.0, 30.0, 180.0) == pytest.approx(10.0)            # back onto its east face


def test_ray_distance_is_vectorised_over_leading_dimensions():
    """A (5, 7) batch of poses gives a (5, 7) array equal, point by point, to single casts."""
    random = np.random.default_rng(3)
    x, y = random.uniform(1, 99, (5, 7)), random.uniform(1, 99, (5, 7))
    heading = random.uniform(0, 360, (5, 7))
    together = _cast(SQUARE + BOX, x, y, heading)
    assert together.shape == (5, 7)
    one_by_one = np.vectorize(lambda a, b, c: float(_cast(SQUARE + BOX, a, b, c)))(x, y, heading)
    np.testing.assert_allclose(together, one_by_one, rtol=1e-12)


def test_sonar_reading_saturates_at_max_range():
    """A wall farther than max_range reads max_range (noise-free reading and simulated readings)."""
    wide = [[0.0, 0.0, 400.0, 0.0], [400.0, 0.0, 400.0, 100.0], [400.0, 100.0, 0.0, 100.0], [0.0, 100.0, 0.0, 0.0]]
    model = _model(walls=wide, max_range=255.0)
    poses = np.array([[10.0, 50.0, 0.0], [300.0, 50.0, 0.0], [10.0, 50.0, 90.0]])
    np.testing.assert_allclose(model.measurement_mean(poses)[:, 0], [255.0, 100.0, 50.0])
    readings = model.measure(np.broadcast_to(poses[0], (1000, 3)), np.random.default_rng(1).normal(size=(1000, 1)))
    assert np.all(readings == 255.0)


# -- the censored likelihood --------------------------------------------------------------------------

def test_likelihood_of_a_saturated_reading_is_the_tail_mass():
    """A wall 1 cm inside the max range (sd 1): P(reading = max range) = P(v >= 1) = 0.1587.
    Simulated readings (n = 20000, seed 5) saturate at that rate within 4 standard errors, and
    exp(log p) integrates to 1 over the readings below max range plus the saturated one."""
    model = _model(max_range=49.0)
    pose = np.array([[52.0, 50.0, 0.0]])           # the east wall (x = 100) is 48 cm ahead
    expected_tail = stats.norm.sf(1.0)
    log_tail = model.log_likelihood(np.array([[49.0]]), pose)[0]
    assert math.exp(log_tail) == pytest.approx(expected_tail, rel=1e-12)
    n = 20000
    readings = model.measure(np.broadcast_to(pose, (n, 3)), np.random.default_rng(5).normal(size=(n, 1)))
    share = np.mean(readings == 49.0)
    assert abs(share - expected_tail) < 4 * math.sqrt(expected_tail * (1 - expected_tail) / n)
    density = lambda z: math.exp(model.log_likelihood(np.array([[z]]), pose)[0])  # noqa: E731
    below, _ = integrate.quad(density, 48.0 - 12.0, 49.0, limit=200)
    assert below + math.exp(log_tail) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("family", NOISE_FAMILIES.names())
def test_noise_log_tail_matches_the_integrated_density(family):
    """log P(z > c) of every noise family equals the log of its density integrated from c."""
    noise = NOISE_FAMILIES[family]
    df = 5.0
    for c in (-3.0, -1.0, -0.3, 0.0, 0.4, 1.7, 2.4, 4.0):
        kinks = [k for k in (-math.sqrt(6), -math.sqrt(3), 0.0, math.sqrt(3), math.sqrt(6)) if k > c]
        mass, _ = integrate.quad(lambda z: math.exp(noise.log_density_standard(np.array(z), df)), c, 60.0,
                                 points=kinks, limit=200)
        assert math.exp(noise.log_tail_standard(np.array(c), df)) == pytest.approx(mass, abs=1e-8)


# -- motion -------------------------------------------------------------------------------------------

BIG_ROOM = [[0.0, 0.0, 1e4, 0.0], [1e4, 0.0, 1e4, 1e4], [1e4, 1e4, 0.0, 1e4], [0.0, 1e4, 0.0, 0.0]]


def _transition(model: SonarMCL, step: int, poses, streams: TrialStreams) -> np.ndarray:
    return model.transition(np.asarray(poses, dtype=float)[None], step, streams)[0]


def test_truth_motion_has_the_papers_bias_and_variance():
    """The real robot (motion noisy, defaults): a move of 30 cm covers 0.92 * 30 = 27.6 cm with
    variance 9.0 and keeps the heading; a turn of 90 degrees turns 1.03 * 90 = 92.7 degrees with
    variance 13.0 and keeps the position. n = 40000 draws per action (fixed seeds); means within
    4 standard errors (sd / sqrt n), variances within 4 standard errors (var sqrt(2 / (n - 1)))."""
    model = _model(walls=BIG_ROOM, initial={"kind": "point", "state": [5000.0, 5000.0, 0.0]})
    n = 40000
    moved = _transition(model, 1, np.tile([5000.0, 5000.0, 30.0], (n, 1)), TrialStreams.from_seeds([101]))
    covered = np.hypot(moved[:, 0] - 5000.0, moved[:, 1] - 5000.0)
    np.testing.assert_array_equal(moved[:, 2], 30.0)
    np.testing.assert_allclose(np.degrees(np.arctan2(moved[:, 1] - 5000.0, moved[:, 0] - 5000.0)), 30.0, atol=1e-6)
    turned = _transition(model, 2, np.tile([5000.0, 5000.0, 100.0], (n, 1)), TrialStreams.from_seeds([102]))
    np.testing.assert_array_equal(turned[:, :2], 5000.0)
    for executed, mean, variance in ((covered, 27.6, 9.0), (turned[:, 2] - 100.0, 92.7, 13.0)):
        assert abs(executed.mean() - mean) < 4 * math.sqrt(variance / n)
        assert abs(executed.var(ddof=1) - variance) < 4 * variance * math.sqrt(2.0 / (n - 1))


def test_a_move_stops_short_of_a_wall():
    """A move that would cross a wall stops `clearance` (1 cm) before it, forwards and backwards."""
    model = _model(route=["move 30", "move -30"], motion="noise-free")
    streams = TrialStreams.from_seeds([0])
    np.testing.assert_allclose(_transition(model, 1, [[80.0, 50.0, 0.0], [50.0, 90.0, 90.0]], streams),
                               [[99.0, 50.0, 0.0], [50.0, 99.0, 90.0]], atol=1e-12)
    np.testing.assert_allclose(_transition(model, 2, [[20.0, 50.0, 0.0]], streams), [[1.0, 50.0, 0.0]], atol=1e-12)


def test_noise_free_motion_is_the_commanded_action_and_draws_nothing():
    """motion: noise-free moves exactly d along the heading and turns exactly alpha, whatever
    move_bias, turn_bias and process_noise say, and draws no random numbers."""
    model = _model(motion="noise-free", move_bias=0.5, turn_bias=2.0, process_noise={"variance": [9.0, 13.0]})
    assert model.move_bias == 1.0 and model.turn_bias == 1.0 and not model.process_noise.covariance().any()
    streams = TrialStreams.from_seeds([7])
    before = copy.deepcopy(streams.generators[0].bit_generator.state)
    moved = _transition(model, 1, [[50.0, 50.0, 0.0], [40.0, 10.0, 90.0], [70.0, 60.0, 225.0]], streams)
    turned = _transition(model, 2, moved, streams)
    assert streams.generators[0].bit_generator.state == before
    diagonal = 30.0 / math.sqrt(2.0)
    np.testing.assert_allclose(moved, [[80.0, 50.0, 0.0], [40.0, 40.0, 90.0], [70.0 - diagonal, 60.0 - diagonal, 225.0]],
                               rtol=0, atol=1e-12)
    np.testing.assert_array_equal(turned[:, :2], moved[:, :2])
    np.testing.assert_array_equal(turned[:, 2], [90.0, 180.0, 315.0])


def _filter(model, measurements, seed: int, prior, particles: int):
    return pfx.particle_filter(model, prior=prior, particles=particles, resampler="systematic", ess_threshold=1.0)(measurements, seeds=[seed]).trace


def _example_models(**filter_changes):
    config = load_config_file(EXAMPLE)["model"]
    truth = SonarMCL(**config)
    return truth, SonarMCL(**{**config, **filter_changes})


def test_noise_free_filter_follows_the_commanded_route_exactly():
    """One particle started at the true start pose under the noise-free model: its estimate at
    every step is the commanded route replayed from the start (x += d cos(theta),
    y += d sin(theta), theta += alpha), whatever the (biased, noisy) truth measured."""
    truth, assumed = _example_models(motion="noise-free")
    _, measurements = simulate_truth(truth, TrialStreams.from_seeds([3]))
    trace = _filter(assumed, measurements, seed=4, prior=truth.initial, particles=1)
    x, y, heading = truth.initial.state
    replayed = []
    for action in truth.route:
        x += action.get("move", 0.0) * math.cos(math.radians(heading))
        y += action.get("move", 0.0) * math.sin(math.radians(heading))
        heading = (heading + action.get("turn", 0.0)) % 360.0
        replayed.append([x, y, heading])
    np.testing.assert_allclose(trace.estimates[0], replayed, rtol=0, atol=1e-9)


def test_noise_free_filter_depends_on_its_stream_only_through_the_prior_and_the_resampling():
    """The same filter seed gives bit-identical runs; the noise settings the noise-free arm ignores
    (bias and motion variance) change nothing, bit for bit; another seed (another prior draw and
    other resampling draws) changes the run."""
    truth, assumed = _example_models(motion="noise-free")
    _, other_noise = _example_models(motion="noise-free", move_bias=0.7, process_noise={"variance": [100.0, 50.0]})
    _, measurements = simulate_truth(truth, TrialStreams.from_seeds([3]))
    runs = [_filter(model, measurements, seed, assumed.default_prior(), 50)
            for model, seed in ((assumed, 9), (assumed, 9), (other_noise, 9), (assumed, 10))]
    for run in runs[1:3]:
        np.testing.assert_array_equal(run.estimates, runs[0].estimates)
        np.testing.assert_array_equal(run.ess, runs[0].ess)
    assert not np.array_equal(runs[3].estimates, runs[0].estimates)


# -- the prior: uniform over free space -----------------------------------------------------------------

def test_free_space_prior_is_in_free_space_and_uniform():
    """200000 draws (seed 11) on the square room with its box: every draw lies inside the room
    and outside the box (checked with matplotlib's polygon test, an independent implementation);
    counts in the 96 free 10 x 10 cm cells pass a chi-square test of uniformity and the headings
    a Kolmogorov-Smirnov test against U[0, 360) (p > 0.001 each); the box gets no draw."""
    law = FreeSpaceLaw(walls=SQUARE + BOX)
    draws = law.sample(TrialStreams.from_seeds([11]), (200000,))[0]
    assert draws.shape == (200000, 3)
    room = PolygonPath([(0, 0), (100, 0), (100, 100), (0, 100)])
    box = PolygonPath([(60, 20), (80, 20), (80, 40), (60, 40)])
    assert room.contains_points(draws[:, :2]).all() and not box.contains_points(draws[:, :2]).any()
    cells = np.floor(draws[:, 0] / 10).astype(int) * 10 + np.floor(draws[:, 1] / 10).astype(int)
    counts = np.bincount(cells, minlength=100)
    in_box = [(i * 10 + j) for i in (6, 7) for j in (2, 3)]
    assert counts[in_box].sum() == 0
    free_counts = np.delete(counts, in_box)
    assert stats.chisquare(free_counts).pvalue > 0.001
    assert (draws[:, 2] >= 0).all() and (draws[:, 2] < 360).all()
    assert stats.kstest(draws[:, 2], stats.uniform(0.0, 360.0).cdf).pvalue > 0.001


def test_free_space_prior_draws_do_not_depend_on_the_batch():
    """Each trial's draws come from its own stream: trials drawn together equal trials drawn alone."""
    law = FreeSpaceLaw(walls=load_config_file(EXAMPLE)["model"]["walls"])
    together = law.sample(TrialStreams.from_seeds([1, 2, 3]), (300,))
    for row, seed in enumerate([1, 2, 3]):
        np.testing.assert_array_equal(law.sample(TrialStreams.from_seeds([seed]), (300,))[0], together[row])


def test_free_space_prior_moments():
    """The moments the Gaussian filters read: the square with its box has its centroid at
    ((100^2/2 * 100 - 400 * 70) / 9600, (100^2/2 * 100 - 400 * 30) / 9600) = (49.17, 50.83), heading
    mean 180 and variance 360^2 / 12 (grid of 256^2 points: within 0.5 cm)."""
    law = FreeSpaceLaw(walls=SQUARE + BOX)
    np.testing.assert_allclose(law.mean_vector(), [(500000 - 28000) / 9600, (500000 - 12000) / 9600, 180.0], atol=0.5)
    assert law.covariance_matrix()[2, 2] == pytest.approx(360.0 ** 2 / 12)


# -- angles -------------------------------------------------------------------------------------------

def test_heading_estimate_is_the_circular_mean():
    """A cloud straddling 0 / 360 degrees (headings 350..10, and 340..20 weighted towards 20)
    averages near 0 (resp. the circular weighted mean), not near 180; position components keep
    the ordinary weighted mean."""
    model = _model()
    headings = np.concatenate([np.linspace(350.0, 359.0, 10), np.linspace(0.0, 10.0, 11)])
    particles = np.stack([np.full(21, 10.0), np.arange(21.0), headings], axis=-1)[None]
    weights = np.full((1, 21), 1.0 / 21)
    estimate = posterior_mean(model, weights, particles)[0]
    assert min(estimate[2], 360.0 - estimate[2]) < 1e-9
    np.testing.assert_allclose(estimate[:2], [10.0, 10.0])
    skewed = np.array([[0.1, 0.1, 0.8]])
    three = np.array([[[0.0, 0.0, 340.0], [0.0, 0.0, 0.0], [0.0, 0.0, 20.0]]])
    expected = math.degrees(math.atan2(0.1 * math.sin(math.radians(-20)) + 0.8 * math.sin(math.radians(20)),
                                       0.1 * math.cos(math.radians(-20)) + 0.1 + 0.8 * math.cos(math.radians(20))))
    assert posterior_mean(model, skewed, three)[0, 2] == pytest.approx(expected)


def test_models_without_angles_keep_the_weighted_mean_bit_for_bit():
    model = RangeBeacons(beacons=[[0.0, 0.0]])
    random = np.random.default_rng(2)
    weights = random.dirichlet(np.ones(30), size=4)
    particles = random.normal(size=(4, 30, 2)) * 1e3
    np.testing.assert_array_equal(posterior_mean(model, weights, particles), weighted_mean(weights, particles))


def test_heading_errors_are_wrapped():
    """Truth 359, estimate 1: the heading error is +2 degrees (not -358); 10 vs 190: 180."""
    model = _model()
    truth = np.array([[[0.0, 0.0, 359.0], [5.0, 5.0, 10.0], [0.0, 0.0, 90.0]]])
    estimate = np.array([[[1.0, 2.0, 1.0], [5.0, 5.0, 190.0], [0.0, 0.0, 45.0]]])
    np.testing.assert_allclose(state_error(truth, estimate, model)[0],
                               [[1.0, 2.0, 2.0], [0.0, 0.0, 180.0], [0.0, 0.0, -45.0]])


def test_an_angular_position_component_has_its_error_wrapped_in_the_distance():
    """A position that is an angle (a pendulum's theta, in a plugin): truth -0.076 rad, circular
    mean 6.233 rad (in [0, 2 pi)): the error distance is the wrapped 0.0262, not 6.309."""
    model = types.SimpleNamespace(position_components=(0,), angular_components=(0,), full_turn=2 * np.pi)
    truth, estimate = np.array([[[-0.076, 0.5]]]), np.array([[[6.233, 0.7]]])
    assert error_distance(truth, estimate, model)[0, 0] == pytest.approx(6.233 - 2 * np.pi + 0.076, abs=1e-12)
    plain = types.SimpleNamespace(position_components=(0, 1), angular_components=(), full_turn=2 * np.pi)
    assert error_distance(truth, estimate, plain)[0, 0] == pytest.approx(np.hypot(6.309, 0.2), abs=1e-12)


# -- the example, map files, config errors ------------------------------------------------------------

def test_example_runs_and_its_truth_stays_in_free_space():
    """The example config, 4 trials at 100 particles: finite metrics in both arms, and the true
    robot (noisy, biased) stays in free space along the whole route."""
    raw = load_config_file(EXAMPLE)
    raw["sweep"] = {"filter.particles": [100]}
    plan = build_plan(raw, str(EXAMPLE), trials=4)
    assert {cell.labels["arm"] for cell in plan.cells} == {"noise-free", "noisy"}
    truth_model = plan.cells[0].truth_model
    states, _ = simulate_truth(truth_model, TrialStreams.from_seeds(range(50)))
    assert truth_model.wall_map.contains(states[..., 0], states[..., 1]).all()
    for cell in plan.cells:
        rows = run_batch(cell, raw["seed"], [0, 1, 2, 3], trace_trials=1).trials
        for column in ("rmse_x", "rmse_y", "rmse_heading", "error_distance_final", "ess_mean"):
            assert np.isfinite(rows[column]).all(), column
        assert (rows["rmse_heading"] <= 180.0).all()


def _map_config(**model_changes) -> dict:
    raw = load_config_file(EXAMPLE)
    raw["model"].update(model_changes)
    return raw


def test_map_file_is_read_relative_to_the_config_file(tmp_path, monkeypatch):
    """map_file as YAML or CSV, relative to the config's folder (not the working directory): the
    plan holds the same walls as the inline config, and the resolved config lists them."""
    walls = load_config_file(EXAMPLE)["model"]["walls"]
    maps = tmp_path / "experiment" / "maps"
    maps.mkdir(parents=True)
    (maps / "arena.csv").write_text("x1,y1,x2,y2\n" + "".join(",".join(f"{v:g}" for v in w) + "\n" for w in walls))
    write_config_file(maps, {"walls": walls}, "arena.yaml")
    monkeypatch.chdir(tmp_path)            # elsewhere than the config
    inline = build_plan(load_config_file(EXAMPLE), str(EXAMPLE))
    for name in ("maps/arena.csv", "maps/arena.yaml"):
        raw = _map_config(map_file=name)
        del raw["model"]["walls"]
        plan = build_plan(raw, str(tmp_path / "experiment" / "config.yaml"))
        assert plan.cells[0].truth_model.walls == inline.cells[0].truth_model.walls
        assert plan.resolved["model"]["walls"] == inline.resolved["model"]["walls"]
        assert plan.resolved["model"]["map_file"] is None
        assert [c.key for c in plan.cells] == [c.key for c in inline.cells]


@pytest.mark.parametrize("changes, key, reason", [
    ({"walls": [[0.0, 0.0, 100.0, 0.0], [100.0, 0.0, 0.0, 0.0]]}, "model.walls", "at least 3 walls"),
    ({"walls": [[0.0, 0.0, 100.0, 0.0], [100.0, 0.0, 100.0, 100.0], [100.0, 100.0, 0.0, 100.0]]},
     "model.walls[", "closed polygons"),
    ({"initial": {"kind": "point", "state": [500.0, 30.0, 0.0]}}, "model.initial.state", "free space"),
    ({"initial": {"kind": "point", "state": [110.0, 75.0, 0.0]}}, "model.initial.state", "free space"),  # in the box
    ({"route": ["move 30", "jump 4"]}, "model.route[1]", "expected 'move <cm>' or 'turn <degrees>'"),
    ({"route": [{"move": 0.0}]}, "model.route[0]", "does nothing"),
    ({"map_file": "missing.csv"}, "model.map_file", "cannot read map file"),
    ({"steps": 41}, "model.steps", "only 40 action(s)"),
])
def test_bad_maps_and_routes_are_located_errors(changes, key, reason):
    raw = _map_config(**changes)
    if "map_file" in changes:
        del raw["model"]["walls"]
    with pytest.raises(ConfigError) as raised:
        build_plan(raw, "sonar.yaml")
    text = str(raised.value)
    assert "\n" not in text and text.startswith("sonar.yaml: ") and key in text and reason in text, text


def test_bad_map_is_one_line_exit_2_through_the_command_line(tmp_path, pfx_in_process):
    """Through `pfx run`: fewer than 3 walls, a NaN coordinate (YAML .nan), a start pose outside
    the arena: one line on stderr naming the file and the key, exit status 2, nothing written."""
    text = EXAMPLE.read_text()
    cases = {
        "two-walls": text.replace("  walls:", "  walls: [[0.0, 0.0, 9.0, 0.0], [9.0, 0.0, 0.0, 0.0]]\n  old_walls:", 1),
        "nan": text.replace("[250.0, 0.0, 250.0, 130.0]", "[250.0, 0.0, .nan, 130.0]"),
        "outside": text.replace("state: [30.0, 30.0, 0.0]", "state: [-30.0, 30.0, 0.0]"),
    }
    expected = {"two-walls": "model.old_walls", "nan": "model.walls[1]", "outside": "model.initial.state"}
    jobs = {}
    for name, content in cases.items():
        write_config_file(tmp_path, content, f"{name}.yaml")
        jobs[name] = (["run", f"{name}.yaml", "--out", f"out-{name}"], tmp_path)
    results = pfx_in_process.many(jobs)
    for name, result in results.items():
        assert result.returncode == 2, (name, result.output)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in result.output, result.output
        assert lines[0].startswith(f"pfx: error: {name}.yaml") and expected[name] in lines[0], lines[0]
        assert not (tmp_path / f"out-{name}").exists()
