"""Filters that honour a plugin's own model, and plugins that are reproducible (docs/plugins.md).

* The Gaussian filters (kf, ekf, ukf) and the guided proposals read the measurement as
  z = h(x) + v with the innovation z - h(x): a plugin whose own log_likelihood is not of that
  form (another noise family, a bearing that wraps undeclared) is refused before anything runs,
  in one line (pfx/filters/kalman/measurement_form.py); built-in models all pass the probe.
* Declared angular measurement components are wrapped by those filters: on a range-bearing
  plugin whose target crosses the bearing's branch cut, the EKF and UKF then track as well as
  the particle filter (on main, their RMSE was about 40 times the particle filter's).
* kf runs a plugin that declares its matrices, checked against its propagate and
  measurement_mean (pfx/filters/kalman/linear_form.py), with the numbers of linear_gaussian.
* A plugin drawing from a global random generator is refused in one line naming the file and
  the function (pfx/models/contract_checks.py), from a config, an estimation config and the
  Python door; so is an index list that is not one.

The models are plugins written into each test's folder, each with a kind of its own (plugins
of one process must not share a kind); everything runs in-process but one command-line check.
"""

from __future__ import annotations

import itertools
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, write_config_file

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.filters.kalman.linear_form import linear_form_mismatch
from pfx.filters.kalman.measurement_form import MeasurementAngles, measurement_form_mismatch
from pfx.filters.kalman.unscented import unscented_moments
from pfx.models import MODELS
from pfx.models.contract_checks import reproducibility_fault

pytestmark = pytest.mark.usefixtures("fresh_plugins")      # each test's plugins unloaded after it

_kinds = itertools.count()

# A target at nearly constant velocity, seen in range and bearing from the origin; the bearing is
# reported in (-pi, pi]. {members} adds the case's members.
RANGE_BEARING = '''from typing import Literal
import random
import numpy as np
import pfx

TRANSITION = np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]])
GAIN = np.array([[0.5, 0.0], [1.0, 0.0], [0.0, 0.5], [0.0, 1.0]])
OWN_GENERATOR = np.random.default_rng(1)


@pfx.register_model
class RangeBearing(pfx.Model):
    """A target at constant velocity, seen in range and bearing from the origin."""
    kind: Literal["{kind}"] = "{kind}"

    @property
    def state_names(self): return ("x", "vx", "y", "vy")
    @property
    def measurement_dimension(self): return 2
    @property
    def position_components(self): return (0, 2)
    def propagate(self, state, control, noise):
        return state @ TRANSITION.T + noise
    def measurement_mean(self, state):
        return np.stack([np.hypot(state[..., 0], state[..., 2]), np.arctan2(state[..., 2], state[..., 0])], axis=-1)
    def measure(self, state, noise):
        z = self.measurement_mean(state) + noise
        z[..., 1] = np.pi - np.mod(np.pi - z[..., 1], 2 * np.pi)
        return z
{members}'''

DECLARED = '''    @property
    def measurement_angular_components(self): return (1,)
'''
WRAPPING_LIKELIHOOD = '''    def log_likelihood(self, measurement, state):
        innovation = measurement - self.measurement_mean(state)
        innovation[..., 1] = np.pi - np.mod(np.pi - innovation[..., 1], 2 * np.pi)
        return self.measurement_noise.log_density(innovation)
'''
PLAIN_GAUSSIAN_LIKELIHOOD = '''    def log_likelihood(self, measurement, state):      # gaussian, without its constant
        innovation = measurement - self.measurement_mean(state)
        return -0.5 * (innovation[..., 0] ** 2 / 25.0 + innovation[..., 1] ** 2 / 0.0004)
'''
LAPLACE_LIKELIHOOD = '''    def log_likelihood(self, measurement, state):      # heavy tails, whatever measurement_noise says
        innovation = measurement - self.measurement_mean(state)
        return -np.abs(innovation[..., 0]) / 5.0 - np.abs(innovation[..., 1]) / 0.02
'''
REFUSING_LIKELIHOOD = '''    def log_likelihood(self, measurement, state):      # the probe's turn raises; no run's data would
        innovation = measurement - self.measurement_mean(state)
        if np.any(np.abs(innovation[..., 1]) > 3.0):
            raise ValueError("a bearing this far off")
        return self.measurement_noise.log_density(innovation)
'''

# The crossing: the target passes behind the radar (y = 0 at x < 0) at about step 19.
RANGE_BEARING_MODEL = {"steps": 40, "process_noise": {"variance": [0.01, 0.05, 0.01, 0.05]},
                       "measurement_noise": {"variance": [25.0, 0.0004]},
                       "initial": {"kind": "gaussian", "mean": [-300.0, 2.0, 150.0, -8.0],
                                   "covariance": [100.0, 1.0, 100.0, 1.0]}}


def plugin_case(folder: Path, source: str, members: str = "", *, model: dict = RANGE_BEARING_MODEL,
                **config) -> tuple[Path, str]:
    """Write a plugin (``source`` with a kind of its own and ``members``) and a config naming it;
    return (the config's path, the kind)."""
    kind = f"honesty_{next(_kinds)}"
    (folder / f"{kind}.py").write_text(source.replace("{kind}", kind).replace("{members}", members))
    raw = {"name": kind, "plugins": [f"{kind}.py"], "seed": 4, "trials": 2, "model": {"kind": kind, **model},
           "filter": {"particles": 100}, "outputs": {"figures": []}, **config}
    return write_config_file(folder, raw, f"{kind}.yaml"), kind


def plan_of(config: Path):
    return build_plan(yaml.safe_load(config.read_text()), str(config))


def refusal(config: Path) -> ConfigError:
    with pytest.raises(ConfigError) as error:
        plan_of(config)
    text = str(error.value)
    assert "\n" not in text and "Traceback" not in text
    return error.value


# -- the Gaussian form of the measurement ----------------------------------------------------------


def test_declared_bearings_make_the_ekf_and_ukf_track_as_the_particle_filter(tmp_path):
    """The target crosses the bearing's branch cut (pi to -pi) mid-run. Declared, the bearing's
    innovation is wrapped, and the EKF and UKF are within 20 % of the particle filter's RMSE, a
    few metres (on main: 142 m against 3.8 m, the innovation a whole turn at the crossing)."""
    config, _ = plugin_case(tmp_path, RANGE_BEARING, DECLARED, trials=6, filter={"particles": 1000},
                            arms={"particle": {"kind": "particle"}, "ekf": {"kind": "ekf"}, "ukf": {"kind": "ukf"}})
    trials = pfx.run(config, out=tmp_path / "out").trials
    rmse = trials.groupby("arm")["rmse_position"].mean()
    assert rmse["particle"] < 10.0, rmse
    for kind in ("ekf", "ukf"):
        assert abs(rmse[kind] - rmse["particle"]) < 0.2 * rmse["particle"], rmse


GUIDED_AND_KALMAN = {"ekf": ({"kind": "ekf"}, "filter.kind"), "ukf": ({"kind": "ukf"}, "filter.kind"),
                     "ekf proposal": ({"kind": "particle", "proposal": "ekf"}, "filter.proposal"),
                     "ukf proposal": ({"kind": "particle", "proposal": "ukf"}, "filter.proposal")}


@pytest.mark.parametrize("case", list(GUIDED_AND_KALMAN))
def test_an_undeclared_wrap_refuses_the_gaussian_filters_and_the_guided_proposals(tmp_path, case):
    settings, key = GUIDED_AND_KALMAN[case]
    config, kind = plugin_case(tmp_path, RANGE_BEARING, WRAPPING_LIKELIHOOD, filter={"particles": 100, **settings})
    error = refusal(config)
    assert error.key == key
    assert f"model {kind}'s log_likelihood wraps z2 (it gives z2 and z2 + 2 pi the same likelihood)" in error.reason
    assert "declare measurement_angular_components = (1,)" in error.reason
    assert ("use the bootstrap proposal" if "proposal" in case else "use the particle filter") in error.reason


def test_the_particle_filter_takes_any_likelihood(tmp_path):
    for members in (WRAPPING_LIKELIHOOD, LAPLACE_LIKELIHOOD):
        config, _ = plugin_case(tmp_path, RANGE_BEARING, members)
        assert plan_of(config).cells[0].filter.kind == "particle"


def test_another_noise_family_in_log_likelihood_is_refused(tmp_path):
    config, kind = plugin_case(tmp_path, RANGE_BEARING, DECLARED + LAPLACE_LIKELIHOOD, filter={"kind": "ekf"})
    error = refusal(config)
    assert error.key == "filter.kind"
    assert f"model {kind}'s log_likelihood is not the gaussian log-density of measurement_noise" in error.reason


def test_an_angle_declared_but_not_wrapped_is_refused(tmp_path):
    config, _ = plugin_case(tmp_path, RANGE_BEARING, DECLARED + PLAIN_GAUSSIAN_LIKELIHOOD, filter={"kind": "ukf"})
    assert "does not wrap z2, which the model declares an angle" in refusal(config).reason


def test_a_gaussian_log_likelihood_of_its_own_passes(tmp_path):
    """Up to a constant: this one leaves out the normalisation."""
    config, _ = plugin_case(tmp_path, RANGE_BEARING, PLAIN_GAUSSIAN_LIKELIHOOD, filter={"kind": "ekf"})
    assert plan_of(config).cells[0].filter.kind == "ekf"


def test_a_plugins_exception_inside_the_probe_is_located_in_its_file(tmp_path):
    config, kind = plugin_case(tmp_path, RANGE_BEARING, REFUSING_LIKELIHOOD, filter={"kind": "ekf"})
    error = refusal(config)
    lines = (tmp_path / f"{kind}.py").read_text().splitlines()
    assert Path(error.file).name == f"{kind}.py"
    assert error.line == next(n for n, text in enumerate(lines, 1) if "raise ValueError" in text)
    assert error.reason == f"model {kind}: log_likelihood raised ValueError: a bearing this far off"


def test_a_plugins_exception_inside_the_probe_is_located_from_the_python_door_too(tmp_path):
    from pfx.config.plugins import load_plugin

    _, kind = plugin_case(tmp_path, RANGE_BEARING, REFUSING_LIKELIHOOD)
    load_plugin(f"{kind}.py", tmp_path)
    model = pfx.model(kind, **RANGE_BEARING_MODEL)
    with pytest.raises(ConfigError, match=rf"{kind}\.py:\d+: model {kind}: log_likelihood raised ValueError: a "
                                          "bearing this far off$"):
        pfx.particle_filter(model, kind="ekf")


def test_the_python_door_refuses_as_a_config_does(tmp_path):
    config, kind = plugin_case(tmp_path, RANGE_BEARING, WRAPPING_LIKELIHOOD)
    model = plan_of(config).cells[0].truth_model
    with pytest.raises(ConfigError, match=r"<python>: filter\.kind: the ekf filter .* wraps z2"):
        pfx.particle_filter(model, kind="ekf")


def test_the_probe_runs_once_per_model_settings(tmp_path, monkeypatch):
    """PMMH plans a filter at each of thousands of parameter values: the verdict is kept."""
    import pfx.filters.kalman.measurement_form as measurement_form

    config, _ = plugin_case(tmp_path, RANGE_BEARING, DECLARED)
    model = plan_of(config).cells[0].truth_model
    calls = []
    original = measurement_form._probe
    monkeypatch.setattr(measurement_form, "_probe", lambda model: calls.append(1) or original(model))
    for _ in range(3):
        pfx.particle_filter(model, kind="ekf")
    assert len(calls) == 1
    pfx.particle_filter(model.model_copy(update={"steps": 30}), kind="ekf")     # other settings: probed again
    assert len(calls) == 2


def test_an_estimation_cell_is_checked_as_a_run_is(tmp_path):
    estimation = {"method": "pmmh", "chains": 2, "iterations": 5,
                  "parameters": {"model.process_noise.variance": {"prior": {"law": "flat", "lower": 0},
                                                                  "transform": "log", "start": 0.05,
                                                                  "proposal_sd": 0.1}}}
    config, kind = plugin_case(tmp_path, RANGE_BEARING, WRAPPING_LIKELIHOOD, estimation=estimation,
                               filter={"kind": "ekf"})
    raw = yaml.safe_load(config.read_text())
    del raw["trials"]
    config.write_text(yaml.safe_dump(raw))
    assert f"model {kind}'s log_likelihood wraps z2" in refusal(config).reason


# -- angles in the unscented transform ------------------------------------------------------------


def test_the_ukf_averages_the_images_of_an_angle_on_the_circle():
    """Images just either side of pi, as h(x) reports them (3.13, -3.10, 3.08): their mean on the
    circle is the centre, pi - 0.01 (not the linear mean, about 1), and their spread and their
    cross-covariance with a linear component are those of the same images unwrapped."""
    turn = 2 * math.pi
    angles = MeasurementAngles((0,), turn)
    centre, step = math.pi - 0.01, 0.05
    linear = np.array([[[0.0], [step], [-step]]])                  # one row, 3 sigma points (d = 1)
    images = np.pi - np.mod(np.pi - (centre + linear), turn)
    points = np.array([[[0.0], [1.0], [-1.0]]])
    weight, curvature = 0.25, 1.0
    mean, spread = unscented_moments(images, images, weight, curvature, angles, angles)
    assert abs(mean[0, 0] - centre) < 1e-12
    _, expected_spread = unscented_moments(linear, linear, weight, curvature)
    assert np.allclose(spread, expected_spread, rtol=1e-12)
    _, cross = unscented_moments(points, images, weight, curvature, value_angles=angles)
    _, expected_cross = unscented_moments(points, linear, weight, curvature)
    assert np.allclose(cross, expected_cross, rtol=1e-12)


# -- built-in models -----------------------------------------------------------------------------

def example_model(kind: str) -> dict:
    """The model section of the first example config of model ``kind`` (planar_robot with bearings)."""
    for path in sorted((REPO_ROOT / "configs" / "examples").glob("*.yaml")):
        section = yaml.safe_load(path.read_text())["model"]
        if section["kind"] == kind:
            return {**section, "bearings": True} if kind == "planar_robot" else section
    raise AssertionError(f"no example config of model {kind}")


@pytest.mark.parametrize("kind", [name for name in MODELS if MODELS.origin(name) is None])
def test_every_built_in_model_passes_every_probe(kind):
    """pfx's own models are not probed at plan time; they pass. sonar_mcl aside for the
    measurement: its reading saturates at max_range (a censored law, not z = h(x) + v), which
    the Gaussian filters approximate as they always did (left as it is: no config changes)."""
    model = pfx.model(**example_model(kind))
    if kind != "sonar_mcl":
        assert measurement_form_mismatch(model) is None
    assert reproducibility_fault(model) is None
    if model.matrices is not None:
        assert linear_form_mismatch(model) is None


# -- kf on a plugin's matrices -------------------------------------------------------------------

# The constant-velocity target again, pushed by an acceleration command u_k and random
# accelerations (2 components each, through L = B) and its position measured: linear, with
# matrices A and H.
LINEAR_TARGET = RANGE_BEARING.replace('''    def measurement_mean(self, state):
        return np.stack([np.hypot(state[..., 0], state[..., 2]), np.arctan2(state[..., 2], state[..., 0])], axis=-1)
    def measure(self, state, noise):
        z = self.measurement_mean(state) + noise
        z[..., 1] = np.pi - np.mod(np.pi - z[..., 1], 2 * np.pi)
        return z
''', '''    @property
    def process_noise_dimension(self): return 2
    def control(self, step):
        return np.array([0.1 * np.sin(step / 3.0), -0.2])
    def propagate(self, state, control, noise):
        return state @ TRANSITION.T + (control + noise) @ GAIN.T
    def process_noise_jacobian(self, state, control):
        return np.broadcast_to(GAIN, state.shape[:-1] + GAIN.shape)
    def measurement_mean(self, state):
        return state[..., [0, 2]]
    @property
    def matrices(self):
        return MATRICES
''').replace("OWN_GENERATOR =", "MATRICES = (TRANSITION, np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]))\nOWN_GENERATOR =")
LINEAR_MODEL = {"steps": 12, "process_noise": {"variance": [0.3, 0.2]}, "measurement_noise": {"variance": [4.0, 9.0]},
                "initial": {"kind": "gaussian", "mean": [0.0, 1.0, 0.0, -1.0], "covariance": [10.0, 1.0, 10.0, 1.0]}}


def test_kf_runs_a_plugin_that_declares_its_matrices_as_linear_gaussian(tmp_path):
    """The plugin's kf and RTS smoother give linear_gaussian's numbers for the same A, B u_k, H,
    Q = L Q_w L' and R (on main, the kf read Q_w (2 x 2) as the 4 x 4 state noise and failed)."""
    config, _ = plugin_case(tmp_path, LINEAR_TARGET, model=LINEAR_MODEL, filter={"kind": "kf", "smoothers": ["rts"]})
    plugin = plan_of(config).cells[0].truth_model
    transition, measurement = (np.asarray(matrix) for matrix in plugin.matrices)
    gain = np.array([[0.5, 0.0], [1.0, 0.0], [0.0, 0.5], [0.0, 1.0]])
    reference = pfx.model("linear_gaussian", steps=12, transition_matrix=transition.tolist(),
                          measurement_matrix=measurement.tolist(), control_matrix=gain.tolist(),
                          controls=[plugin.control(k).tolist() for k in range(1, 13)],
                          process_noise={"variance": (gain @ np.diag([0.3, 0.2]) @ gain.T).tolist()},
                          measurement_noise={"variance": [4.0, 9.0]}, initial=LINEAR_MODEL["initial"])
    measurements = np.random.default_rng(3).normal(size=(12, 2)) * 3.0 + np.arange(12)[:, None]
    ours = pfx.filter(plugin, measurements, kind="kf", smoothers=["rts"])
    theirs = pfx.filter(reference, measurements, kind="kf", smoothers=["rts"])
    assert np.allclose(ours.estimates, theirs.estimates, rtol=1e-10, atol=1e-10)
    assert np.allclose(ours.log_likelihood, theirs.log_likelihood, rtol=1e-12)
    smoothed = next(iter(ours.smoothed.values())).means
    assert np.allclose(smoothed, next(iter(theirs.smoothed.values())).means, rtol=1e-10, atol=1e-10)


def test_kf_refuses_matrices_that_disagree_with_propagate(tmp_path):
    wrong = LINEAR_TARGET.replace("MATRICES = (TRANSITION,", "MATRICES = (np.eye(4),")
    config, kind = plugin_case(tmp_path, wrong, model=LINEAR_MODEL, filter={"kind": "kf"})
    error = refusal(config)
    assert error.key == "filter.kind"
    assert (f"the Kalman filter (kf) runs on the matrices model {kind} declares, and propagate(x, u, 0) - "
            "propagate(0, u, 0) is not A x with the declared A (matrices[0]) at step 1") in error.reason


def test_kf_on_a_plugin_without_matrices_says_what_to_declare(tmp_path):
    config, _ = plugin_case(tmp_path, RANGE_BEARING, DECLARED, filter={"kind": "kf"})
    assert "declares its matrices (A, H): linear_gaussian, or a plugin model's `matrices`" in refusal(config).reason


# -- reproducibility: no global random generator -------------------------------------------------

GLOBAL_DRAWS = {
    "propagate": ("    def propagate(self, state, control, noise):\n"
                  "        return state @ TRANSITION.T + np.random.normal(size=noise.shape)\n"),
    "log_likelihood": ("    def log_likelihood(self, measurement, state):\n"
                       "        return self.measurement_noise.log_density(measurement - self.measurement_mean(state))"
                       " + 1e-9 * random.random()\n"),
    "simulate_measurement": ("    def simulate_measurement(self, state, random):\n"
                             "        return self.measurement_mean(state) + OWN_GENERATOR.normal(size=(len(state), 2))\n"),
    "measurement_mean": ("    def measurement_mean(self, state):\n"
                         "        return state[..., [0, 2]] + np.random.rand(*state.shape[:-1], 2)\n"),
}


@pytest.mark.parametrize("function", list(GLOBAL_DRAWS))
def test_a_global_random_generator_is_refused_naming_the_function(tmp_path, function):
    members = GLOBAL_DRAWS[function]
    config, kind = plugin_case(tmp_path, RANGE_BEARING, DECLARED + members)
    error = refusal(config)
    source = (tmp_path / f"{kind}.py").read_text()
    lines = source.splitlines()
    assert Path(error.file).name == f"{kind}.py"
    assert error.line == len(lines) - lines[::-1].index(members.splitlines()[0])      # the last def, which counts
    assert error.reason.startswith(f"model {kind}: {function} gave two different results for the same inputs")
    assert "global random generator" in error.reason and "Random draws in a plugin" in error.reason


def test_a_draw_that_ignores_the_stream_but_is_deterministic_passes(tmp_path):
    members = ("    def propagate(self, state, control, noise):\n"
               "        jitter = np.random.default_rng(0).normal(size=noise.shape)\n"
               "        return state @ TRANSITION.T + noise + 0.0 * jitter\n")
    config, _ = plugin_case(tmp_path, RANGE_BEARING, DECLARED + members)
    assert plan_of(config).cells


def test_a_plugin_model_with_a_global_generator_is_refused_by_the_python_door(tmp_path):
    from pfx.config.plugins import load_plugin

    config, kind = plugin_case(tmp_path, RANGE_BEARING, DECLARED + GLOBAL_DRAWS["propagate"])
    load_plugin(f"{kind}.py", tmp_path)
    model = pfx.model(kind, **RANGE_BEARING_MODEL)
    with pytest.raises(ConfigError, match=rf"{kind}\.py:\d+: model {kind}: propagate gave two different results"):
        pfx.filter(model, np.zeros((40, 2)), particles=10)


def test_a_global_generator_is_one_line_with_exit_status_2(run_pfx, tmp_path):
    config, kind = plugin_case(tmp_path, RANGE_BEARING, DECLARED + GLOBAL_DRAWS["propagate"])
    before = sorted(tmp_path.iterdir())
    result = run_pfx("run", config.name, "--out", "out", cwd=tmp_path)
    assert result.returncode == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and re.match(rf"pfx: error: {kind}\.py:\d+: model {kind}: propagate gave two different",
                                        lines[0]), result.output
    assert sorted(tmp_path.iterdir()) == before


# -- declared index lists ------------------------------------------------------------------------

INDEX_SLIPS = {
    "an int": ("accumulating_components", "1", "accumulating_components returned 1, not a tuple; expected indices "
               "of state components (integers 0..3, e.g. (0,) for x)"),
    "names": ("accumulating_components", "('vx',)", "accumulating_components returned ('vx',); expected indices of "
              "state components (integers 0..3, e.g. (0,) for x)"),
    "out of range": ("accumulating_components", "(4,)", "accumulating_components returned (4,); expected indices"),
    "a measurement index out of range": ("measurement_angular_components", "(2,)", "measurement_angular_components "
                                         "returned (2,); expected indices of measurement components (integers 0..1, "
                                         "e.g. (0,) for z1)"),
}


@pytest.mark.parametrize("case", list(INDEX_SLIPS))
def test_an_index_list_that_is_not_one_is_refused_naming_the_property(tmp_path, case):
    name, value, expected = INDEX_SLIPS[case]
    members = f"    @property\n    def {name}(self): return {value}\n"
    config, kind = plugin_case(tmp_path, RANGE_BEARING, members)
    error = refusal(config)
    source = (tmp_path / f"{kind}.py").read_text()
    assert Path(error.file).name == f"{kind}.py"
    assert error.line == len(source.splitlines()) - 1        # the member's first line: its decorator
    assert error.reason.startswith(f"model {kind}: {expected}")


def test_the_trial_table_of_a_declared_bearing_plugin_is_complete(tmp_path):
    """The declared bearing runs with every kind that takes it, the kf aside (no matrices)."""
    config, _ = plugin_case(tmp_path, RANGE_BEARING, DECLARED, filter={"particles": 50},
                            arms={"pf": {"kind": "particle"}, "ekf-proposal": {"proposal": "ekf"},
                                  "ukf-proposal": {"proposal": "ukf"}})
    trials = pfx.run(config, out=tmp_path / "out").trials
    assert isinstance(trials, pd.DataFrame) and np.isfinite(trials["rmse_position"]).all()
