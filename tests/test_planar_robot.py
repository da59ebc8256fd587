"""The planar_robot model: motion models as a filter's transition, landmark measurements."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.filters.kalman.linearisation import finite_difference_jacobian, noise_jacobian
from pfx.models import MODELS
from pfx.models.simulation import simulate_truth
from pfx.motion import wrap_to_pi
from pfx.numerics.seeding import TrialStreams

REPO_ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = REPO_ROOT / "configs" / "examples" / "planar-robot.yaml"
PlanarRobot = MODELS["planar_robot"]


def test_presets_make_a_short_config_work_and_the_default_loop_closes():
    model = PlanarRobot()
    assert model.steps == 48 and model.state_names == ("x", "y", "theta")
    assert model.angular_components == (2,) and model.position_components == (0, 1)
    assert model.measurement_dimension == 4
    assert np.allclose(model.nominal_path[-1], [0.0, 0.0, 0.0], atol=1e-12)
    assert np.allclose(model.nominal_path[8], [8.0, 0.0, 0.0])
    assert np.allclose(model.nominal_path[12], [8 + 8 / np.pi, 8 / np.pi, np.pi / 2])


@pytest.mark.parametrize("motion", [{"kind": "velocity", "alphas": [0.0] * 6},
                                    {"kind": "odometry", "alphas": [0.0] * 4, "noise": "triangular"}],
                         ids=["velocity", "odometry"])
def test_noise_free_truth_follows_the_commanded_motion_exactly(motion):
    model = PlanarRobot(motion=motion, controls=[[1.0, 0.0, 3], [0.5, -0.7, 4], [0.0, 1.0, 2], [2.0, 0.2]],
                        dt=0.5, initial={"kind": "point", "state": [1.0, -2.0, 3.0]})
    states, _ = simulate_truth(model, TrialStreams.from_seeds([1, 2]))
    # the commands integrated by hand: straight, then arcs of radius v / w, then a turn on the spot
    pose, expected = np.array([1.0, -2.0, 3.0]), [np.array([1.0, -2.0, 3.0])]
    for v, w in [(1.0, 0.0)] * 3 + [(0.5, -0.7)] * 4 + [(0.0, 1.0)] * 2 + [(2.0, 0.2)]:
        x, y, theta = pose
        if w == 0.0:
            pose = np.array([x + v * 0.5 * np.cos(theta), y + v * 0.5 * np.sin(theta), theta])
        else:
            pose = np.array([x - v / w * np.sin(theta) + v / w * np.sin(theta + w * 0.5),
                             y + v / w * np.cos(theta) - v / w * np.cos(theta + w * 0.5), theta + w * 0.5])
        expected.append(pose)
    expected = np.array(expected)
    for trial in range(2):
        assert np.allclose(states[trial, :, :2], expected[:, :2], atol=1e-12)
        assert np.allclose(wrap_to_pi(states[trial, :, 2] - expected[:, 2]), 0.0, atol=1e-12)
        assert np.all(np.abs(states[trial, :, 2]) <= np.pi)


@pytest.mark.parametrize("kind, alphas", [("velocity", [1e-4, 2e-4, 3e-4, 1e-4, 2e-4, 5e-5]),
                                          ("odometry", [2e-4, 1e-4, 3e-4, 2e-4])])
def test_standardised_process_noise_matches_the_sampled_transition(kind, alphas):
    """The Gaussian filters' L Q L' (Q = I) must be the covariance the book's sampler produces."""
    model = PlanarRobot(motion={"kind": kind, "alphas": alphas})
    state = np.array([[2.0, 1.0, 0.4]])
    step = 10                                       # inside a quarter turn: every term is non-zero
    n = 200_000
    draws = model.transition(np.broadcast_to(state, (1, n, 3)).copy(), step, TrialStreams.from_seeds([5]))[0]
    empirical = np.cov(draws.T)
    L = noise_jacobian(model, state, model.control(step))[0]
    linearised = L @ L.T
    # standard error of a sample variance, sqrt(2/n) relative (normal errors); the noise is small
    # enough (<= 2% of the motion) that linearisation error is far below that
    se = np.sqrt((np.outer(np.diag(linearised), np.diag(linearised)) + linearised ** 2) / n)
    assert np.all(np.abs(empirical - linearised) < 4 * se + 1e-3 * np.abs(linearised))
    mean = model.propagate(state, model.control(step), np.zeros((1, 3)))[0]
    assert np.all(np.abs(draws.mean(axis=0) - mean) < 4 * np.sqrt(np.diag(linearised) / n) + 1e-4)


@pytest.mark.parametrize("kind", ["velocity", "odometry"])
def test_analytic_jacobians_match_finite_differences(kind):
    model = PlanarRobot(motion=kind, bearings=True)
    state = np.array([[3.0, 4.0, 2.8], [-1.0, 0.5, -3.0]])
    for step in (3, 10):
        control = model.control(step)
        analytic = model.transition_jacobian(state, control)
        numeric = finite_difference_jacobian(lambda s: model.propagate(s, control, np.zeros(s.shape)), state, None)
        assert np.allclose(analytic, numeric, atol=1e-7)
    assert np.allclose(model.measurement_jacobian(state),
                       finite_difference_jacobian(model.measurement_mean, state, None), atol=1e-7)


def test_bearings_are_wrapped_in_the_measurement_and_the_likelihood():
    model = PlanarRobot(bearings=True, landmarks=[[-5.0, 0.01]], measurement_noise={"variance": [0.09, 0.01]})
    state = np.array([[0.0, 0.0, 0.0]])
    range_, bearing = model.measurement_mean(state)[0]
    assert math.isclose(range_, math.hypot(5.0, 0.01)) and bearing > 3.1      # just left of straight behind
    across = np.array([[range_, bearing - 2 * np.pi + 0.0]])                  # the same bearing, written as -pi + ...
    assert math.isclose(model.log_likelihood(across, state)[0], model.log_likelihood(np.array([[range_, bearing]]),
                                                                                      state)[0])
    noisy = model.measure(state, np.array([[0.0, 0.1]]))
    assert -np.pi < noisy[0, 1] <= np.pi


def test_configuration_errors_name_the_key():
    raw = yaml.safe_load(EXAMPLE.read_text())
    for dotted, value, key in [("process_noise", {"variance": 2.0}, "model.process_noise"),
                               ("steps", 60, "model.steps"),
                               ("motion", {"kind": "velocity", "alphas": [0.1, 0.2]}, "model.motion.alphas"),
                               ("controls", [[1.0, 0.0, 0]], "model.controls[0].steps")]:
        broken = yaml.safe_load(EXAMPLE.read_text())
        broken["model"][dotted] = value
        with pytest.raises(ConfigError) as error:
            build_plan(broken, "example.yaml")
        assert error.value.key == key, (dotted, str(error.value))
    shorter = dict(raw, model={**raw["model"], "steps": 10})
    model = build_plan(shorter, "example.yaml").cells[0].truth_model
    assert model.commands.shape == (10, 2) and model.nominal_path.shape == (11, 3)


def test_filter_may_assume_another_motion_model_than_the_truth():
    plan = build_plan(yaml.safe_load(EXAMPLE.read_text()), "example.yaml")
    motions = {cell.labels["arm"]: cell.filter_model.motion for cell in plan.cells}
    assert all(cell.truth_model.motion.kind == "velocity" for cell in plan.cells)
    assert motions["odometry"].kind == "odometry" and motions["velocity-triangular"].noise == "triangular"
    odometry_model = next(c.filter_model for c in plan.cells if c.labels["arm"] == "odometry")
    assert odometry_model.process_noise.family == "gaussian" and odometry_model.control(1).shape == (2, 3)


def test_pfx_runs_the_example_and_the_filters_beat_dead_reckoning(tmp_path):
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-m", "pfx", "run", str(EXAMPLE), "--out", str(out), "--trials", "4",
                             "--set", "filter.particles=300", "--quiet"],
                            cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    trials = pd.read_csv(out / "trials.csv")
    steps = pd.read_csv(out / "steps.csv")
    assert set(trials.arm) == {"velocity-normal", "velocity-triangular", "odometry", "ekf"}
    # dead reckoning: the error of the commanded (noise-free) path against the truth
    path = build_plan(yaml.safe_load(EXAMPLE.read_text()), "example.yaml").cells[0].truth_model.nominal_path
    truth = steps[steps.arm == "velocity-normal"].sort_values(["trial", "step"])
    drift = np.hypot(truth.truth_x.to_numpy() - np.tile(path[1:, 0], truth.trial.nunique()),
                     truth.truth_y.to_numpy() - np.tile(path[1:, 1], truth.trial.nunique()))
    dead_reckoning = np.sqrt(np.mean(drift ** 2))
    assert dead_reckoning > 1.0                       # the motion noise matters on this loop
    # every filter corrects the drift with the ranges (sigma 0.3 m): it beats dead reckoning and
    # even a fix from one scan alone, whose RMS error sigma sqrt(trace((H'H)^-1)) is 0.30 to 0.32 m
    # along this loop with these four landmarks
    for arm, group in trials.groupby("arm"):
        assert group.rmse_position.max() < 0.3, arm
