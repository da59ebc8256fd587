"""The Python door (pfx/filtering.py, pfx/python_arguments.py, docs/python-api.md): every
argument checked as a config's keys are, plugins loaded from Python, numba's cache in a plugin.

* A bad argument of ``pfx.model``, ``pfx.particle_filter``, ``pfx.filter`` or a bound filter's
  call raises ``pfx.ConfigError``, one line naming ``<python>`` and the argument, before
  anything runs: never a number (empty measurements gave log L = 0, a partly NaN row was
  dropped whole, ``trials=0`` ran one trial), never an error from inside numpy.
* A prior may be a dict, read as a config's ``filter.initial``: the same numbers as the object.
* A model with per-step controls filters at most the steps it has controls for.
* ``pfx.load_plugin`` loads a plugin for ``pfx.model``; a config naming the same file then runs
  that code. A plugin module imported by hand is its module's, not "a built-in model of pfx":
  a config naming its file runs, importing it again replaces it, and a config that does not
  name it is told which module registered the name.
* ``@numba.njit(cache=True)`` in a plugin file: a fresh process loads pfx's cached code, and the
  same file imported by hand (the module under another name) neither breaks it nor is broken.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import REPO_ROOT, tiny_config_dict

import pfx

pytestmark = pytest.mark.usefixtures("fresh_plugins")      # each test's plugins unloaded after it

WALK = {"kind": "linear_gaussian", "steps": 4, "transition_matrix": [[1.0, 0.0], [0.0, 1.0]],
        "measurement_matrix": [[1.0, 0.0], [0.0, 1.0]]}
MEASUREMENTS = np.zeros((4, 2))


@pytest.fixture(scope="module")
def walk():
    """A 2-D random walk measured in both components, and a small particle filter bound to it."""
    model = pfx.model(**WALK)
    return model, pfx.particle_filter(model, particles=20)


def refusal(call) -> str:
    """The line of the ConfigError ``call()`` raises (one line, naming <python>)."""
    with pytest.raises(pfx.ConfigError) as caught:
        call()
    line = str(caught.value)
    assert "\n" not in line and line.startswith("<python>: "), line
    return line


# -- measurements --------------------------------------------------------------------------------

PARTLY_NAN = np.array([[0.0, 0.0], [np.nan, 1.0], [0.0, 0.0], [0.0, 0.0]])

BAD_MEASUREMENTS = {
    "empty": (np.zeros((0, 2)), "<python>: measurements: no steps (shape (0, 2))"),
    "no trials": (np.zeros((0, 4, 2)), "<python>: measurements: no"),
    "a partly NaN row": (PARTLY_NAN, "<python>: measurements[1]: partly NaN (component 0 of 2)"),
    "inf": (np.array([[0.0, 0.0], [0.0, 0.0], [0.0, np.inf], [0.0, 0.0]]), "<python>: measurements[2, 1]: inf"),
    "complex": (MEASUREMENTS + 1j, "<python>: measurements: complex values"),
    "text in a list": ([[0.0, 0.0], [0.0, "x"], [0.0, 0.0], [0.0, 0.0]], "<python>: measurements[1, 1]: 'x'"),
    "a text array": (np.full((4, 2), "1.5"), "<python>: measurements: text"),
    "an object array with None": (np.array([[0.0, None]] * 4, dtype=object), "<python>: measurements[0, 1]: None"),
    "booleans": (np.ones((4, 2), dtype=bool), "<python>: measurements: booleans"),
    "ragged rows": ([[0.0, 0.0], [0.0]], "<python>: measurements: rows of different lengths"),
    "the wrong dimension": (np.zeros((4, 3)), "<python>: measurements: shape (4, 3)"),
    "nothing": (None, "<python>: measurements: none given"),
}


@pytest.mark.parametrize("case", list(BAD_MEASUREMENTS))
def test_bad_measurements_are_refused_naming_them(case, walk):
    measurements, expected = BAD_MEASUREMENTS[case]
    _, bound = walk
    assert refusal(lambda: bound(measurements)).startswith(expected)


def test_a_row_of_nan_is_a_missing_measurement_as_a_blank_row_of_a_data_file(walk):
    """A whole row of NaN is a predict-only step (log-likelihood increment 0), in the particle
    filter and the Kalman filter alike; half a row is refused (above), never half-used."""
    model, bound = walk
    gap = MEASUREMENTS.copy()
    gap[2] = np.nan
    for run in (bound(gap, seed=3), pfx.particle_filter(model, kind="kf")(gap)):
        increments = run.trace.log_likelihood_increments[0]
        assert increments[2] == 0.0 and np.all(increments[[0, 1, 3]] < 0.0)
        assert np.isfinite(run.log_likelihood).all()


# -- trials, seeds and the other options ---------------------------------------------------------

BAD_OPTIONS = {
    "trials=0": ({"trials": 0}, "<python>: trials: must be a whole number from 1"),
    "trials=-1": ({"trials": -1}, "<python>: trials: must be a whole number from 1"),
    "trials=2.5": ({"trials": 2.5}, "<python>: trials: must be a whole number from 1"),
    "trials=True": ({"trials": True}, "<python>: trials: must be a whole number from 1"),
    "seed=-1": ({"seed": -1}, "<python>: seed: must be a whole number from 0 to 2**63 - 1"),
    "seed=1.5": ({"seed": 1.5}, "<python>: seed: must be a whole number"),
    "seed=True": ({"seed": True}, "<python>: seed: must be a whole number"),
    "seed=2**63": ({"seed": 2**63}, "<python>: seed: must be a whole number"),
    "seed='1'": ({"seed": "1"}, "<python>: seed: must be a whole number"),
    "seeds=[]": ({"seeds": []}, "<python>: seeds: empty"),
    "seeds=[1, -1]": ({"seeds": [1, -1]}, "<python>: seeds[1]: must be a whole number"),
    "seeds=['a']": ({"seeds": ["a"]}, "<python>: seeds[0]: must be a whole number"),
    "seeds=[1.0]": ({"seeds": [1.0]}, "<python>: seeds[0]: must be a whole number"),
    "seeds='12'": ({"seeds": "12"}, "<python>: seeds: must be a list of seeds"),
    "seeds and seed": ({"seeds": [1, 2], "seed": 3}, "<python>: seed: give seeds"),
    "seeds and other trials": ({"seeds": [1, 2], "trials": 3}, "<python>: trials: 3, and seeds gives 2"),
    "genealogy='yes'": ({"genealogy": "yes"}, "<python>: genealogy: must be True or False"),
    "consistency=None": ({"consistency": None}, "<python>: consistency: must be True or False"),
    "traced=1": ({"traced": 1}, "<python>: traced: must be True or False"),
}


@pytest.mark.parametrize("case", list(BAD_OPTIONS))
def test_bad_trials_seeds_and_options_are_refused_naming_them(case, walk):
    options, expected = BAD_OPTIONS[case]
    _, bound = walk
    assert refusal(lambda: bound(MEASUREMENTS, **options)).startswith(expected)


def test_numpy_integers_are_trials_seeds_and_settings(walk):
    model, bound = walk
    first = bound(MEASUREMENTS, trials=np.int64(2), seed=np.uint32(4))
    again = pfx.filter(model, MEASUREMENTS, seeds=np.array(first.seeds), particles=np.int64(20))
    np.testing.assert_array_equal(first.estimates, again.estimates)
    assert pfx.model("growth", steps=np.int64(7)).steps == 7


# -- the model and its prior ---------------------------------------------------------------------

@pytest.mark.parametrize("given, expected", [
    (dict(WALK), "<python>: model: a dict, not a model: build it with pfx.model(kind, **parameters)"),
    (type(pfx.model(**WALK)), "<python>: model: the class LinearGaussian, not a model: pass an instance, "
                              "pfx.model('linear_gaussian', ...)"),
    ("linear_gaussian", "<python>: model: the text 'linear_gaussian', not a model: build it with "
                        "pfx.model('linear_gaussian', ...)"),
    (None, "<python>: model: None (NoneType), not a model"),
])
def test_a_model_must_be_a_model_object(given, expected):
    assert refusal(lambda: pfx.particle_filter(given, particles=20)).startswith(expected)
    assert refusal(lambda: pfx.filter(given, MEASUREMENTS, particles=20)).startswith(expected)


@pytest.mark.parametrize("call, expected", [
    (lambda: pfx.model("growht"), "<python>: model.kind: unknown model 'growht' (did you mean 'growth'?)"),
    (lambda: pfx.model(3), "<python>: model.kind: must be a model's name"),
    (lambda: pfx.model(["growth"]), "<python>: model.kind: must be a model's name"),
    (lambda: pfx.model({"kind": "growth"}), "<python>: model.kind: a dict: for a config's model: section, write "
                                            "pfx.model(**section)"),
    (lambda: pfx.model("growth", a="x"), "<python>: model.a: input should be a valid number"),
    (lambda: pfx.model("growth", wobble=1.0), "<python>: model.wobble: unknown key 'wobble'"),
])
def test_pfx_model_arguments_are_checked_as_a_model_section(call, expected):
    assert refusal(call).startswith(expected)


def test_a_prior_may_be_a_dict_read_as_a_configs_filter_initial(walk):
    model, _ = walk
    law = {"kind": "gaussian", "mean": [1.0, -1.0], "covariance": [4.0, 0.5]}
    from_dict = pfx.filter(model, MEASUREMENTS, prior=law, seeds=[5, 6], particles=50)
    from_object = pfx.filter(model, MEASUREMENTS, prior=pfx.GaussianLaw(**law), seeds=[5, 6], particles=50)
    from_setting = pfx.filter(model, MEASUREMENTS, initial=law, seeds=[5, 6], particles=50)
    np.testing.assert_array_equal(from_dict.estimates, from_object.estimates)
    np.testing.assert_array_equal(from_dict.estimates, from_setting.estimates)
    default = pfx.filter(model, MEASUREMENTS, seeds=[5, 6], particles=50)
    assert not np.array_equal(from_dict.estimates, default.estimates)


@pytest.mark.parametrize("prior, expected", [
    ({"kind": "gaussian", "mean": [0.0, 0.0]}, "<python>: prior.covariance: required key is missing"),
    ({"kind": "gaussian", "mean": [0.0], "covariance": 1.0}, "<python>: prior.mean: expected 2 value(s), got 1"),
    ({"kind": "gausian", "mean": [0.0, 0.0], "covariance": 1.0}, "<python>: prior.kind: unknown"),
    (pfx.GaussianLaw(mean=[0.0], covariance=1.0), "<python>: prior.mean: expected 2 value(s), got 1"),
    ([0.0, 0.0], "<python>: prior: [0.0, 0.0] (list) is not an initial law: pass pfx.GaussianLaw("),
])
def test_a_bad_prior_is_refused_naming_it(prior, expected, walk):
    model, _ = walk
    assert refusal(lambda: pfx.particle_filter(model, prior=prior, particles=20)).startswith(expected)


def test_a_prior_and_the_initial_setting_are_not_both_given(walk):
    model, _ = walk
    law = {"kind": "gaussian", "mean": [0.0, 0.0], "covariance": 1.0}
    assert refusal(lambda: pfx.particle_filter(model, prior=law, initial=law)).startswith(
        "<python>: prior: give the filter's initial law once")


# -- a model's per-step inputs ---------------------------------------------------------------------

def test_measurements_beyond_a_models_controls_are_refused_naming_both():
    controlled = pfx.model("linear_gaussian", steps=5, transition_matrix=[[1.0]], measurement_matrix=[[1.0]],
                           control_matrix=[[1.0]], controls=[[float(k)] for k in range(5)])
    bound = pfx.particle_filter(controlled, particles=20)
    line = refusal(lambda: bound(np.zeros((7, 1))))
    assert line.startswith("<python>: measurements: 7 steps, and model linear_gaussian has inputs for steps 1..5 "
                           "only (controls: 5 control vectors, for steps 1..5; none for step 6): give at most 5 rows")
    assert refusal(lambda: pfx.particle_filter(controlled, kind="kf")(np.zeros((6, 1)))).startswith(
        "<python>: measurements: 6 steps")
    assert bound(np.zeros((5, 1))).estimates.shape == (1, 5, 1)      # the steps it has controls for: fine
    constant = controlled.model_copy(update={"controls": [[1.0]]})   # one control for every step
    assert pfx.particle_filter(constant, particles=20)(np.zeros((9, 1))).estimates.shape == (1, 9, 1)
    robot = pfx.model("planar_robot", steps=5)                        # commands for 5 steps: an IndexError on main
    assert refusal(lambda: pfx.filter(robot, np.zeros((8, robot.measurement_dimension)), particles=20)).startswith(
        "<python>: measurements: 8 steps, and model planar_robot has inputs for steps 1..5 only (its "
        "control(step=6) raised IndexError)")


# -- plugins from Python -------------------------------------------------------------------------------

def plugin_source(kind: str, class_name: str = "Walk") -> str:
    """A one-dimensional walk registered as model ``kind``."""
    return textwrap.dedent(f'''
        from typing import Literal

        import pfx


        @pfx.register_model
        class {class_name}(pfx.Model):
            kind: Literal["{kind}"] = "{kind}"
            a: float = 0.9

            def presets(self):
                return {{"steps": 5, "process_noise": pfx.Noise(variance=1.0),
                        "measurement_noise": pfx.Noise(variance=1.0),
                        "initial": pfx.GaussianLaw(mean=[0.0], covariance=1.0)}}

            @property
            def state_names(self):
                return ("x",)

            @property
            def measurement_dimension(self):
                return 1

            def propagate(self, state, control, noise):
                return self.a * state + noise

            def measurement_mean(self, state):
                return state
    ''')


def plugin_config(kind: str, plugins: list[str]) -> dict:
    return tiny_config_dict(name=kind.replace("_", "-"), plugins=plugins, model={"kind": kind},
                            outputs={"figures": [], "trace_trials": 0})


def test_load_plugin_then_a_config_naming_the_same_file(tmp_path, monkeypatch):
    (tmp_path / "door_radar.py").write_text(plugin_source("door_radar"))
    monkeypatch.chdir(tmp_path)
    loaded = pfx.load_plugin("door_radar.py")
    assert loaded.registered == ("model door_radar",)
    run = pfx.filter(pfx.model("door_radar", a=0.5), np.zeros((5, 1)), particles=20, seed=1)
    assert np.isfinite(run.log_likelihood).all()
    result = pfx.run(plugin_config("door_radar", ["door_radar.py"]), out=tmp_path / "out")
    assert len(result.trials) == 4
    assert [entry["sha256"] for entry in result.manifest["plugins"]] == [loaded.sha256]


@pytest.mark.parametrize("name, expected", [
    ("missing.py", "<python>: path: plugin file not found: missing.py"),
    ("folder", "<python>: path: folder is a folder: give the plugin's .py file"),
    ("notes.txt", "<python>: path: notes.txt is not a Python file: a plugin file's name ends in .py"),
    ("no_such_module_of_pfx", "<python>: path: no plugin module or installed plugin named 'no_such_module_of_pfx'"),
    (3, "<python>: path: must be a plugin file's path (.py) or a module's name, not 3 (int)"),
])
def test_load_plugin_refuses_a_bad_path_in_one_line(name, expected, tmp_path, monkeypatch):
    (tmp_path / "folder").mkdir()
    (tmp_path / "notes.txt").write_text("not a plugin\n")
    monkeypatch.chdir(tmp_path)
    assert refusal(lambda: pfx.load_plugin(name)).startswith(expected)


def test_load_plugin_names_the_line_of_a_plugin_that_raises(tmp_path, monkeypatch):
    (tmp_path / "broken_door.py").write_text("import pfx\n\nraise RuntimeError('no radar here')\n")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(pfx.ConfigError) as caught:
        pfx.load_plugin("broken_door.py")
    assert str(caught.value) == "broken_door.py:3: RuntimeError: no radar here"


@pytest.fixture
def imported_by_hand():
    """Forget, after the test, what the modules it imports by hand registered (the registries
    outlive a test; a later test in this process should not find them)."""
    from pfx.config import plugin_registration

    yield
    for module in list(plugin_registration.IMPORTED_BY_HAND):
        if module.startswith(("hand_radar", "later_radar")):
            plugin_registration.forget(module)
            del plugin_registration.IMPORTED_BY_HAND[module]
            sys.modules.pop(module, None)


@pytest.mark.usefixtures("imported_by_hand")
def test_a_plugin_imported_by_hand_then_a_config_naming_its_file(tmp_path, monkeypatch):
    """The notebook imports its plugin module itself: the model is the module's (today's main
    called it "a built-in model of pfx" and refused the config that names the file)."""
    (tmp_path / "hand_radar.py").write_text(plugin_source("hand_radar", "HandRadar"))
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("hand_radar")
    assert type(pfx.model("hand_radar")) is module.HandRadar
    assert np.isfinite(pfx.filter(pfx.model("hand_radar"), np.zeros((5, 1)), particles=20).log_likelihood).all()

    # a config that does not name the plugin does not see it, and says what to do
    line = refusal_of_config(lambda: pfx.run(plugin_config("hand_radar", []), out=tmp_path / "unnamed"))
    assert line.startswith("<dict>: model.kind: unknown model kind 'hand_radar'")
    assert line.endswith("a config sees only the plugins it names, not model hand_radar (module hand_radar, "
                         "imported outside pfx: name hand_radar.py in plugins:)")
    assert not (tmp_path / "unnamed").exists()

    # a config naming its file loads and runs it
    result = pfx.run(plugin_config("hand_radar", [str(tmp_path / "hand_radar.py")]), out=tmp_path / "named")
    assert len(result.trials) == 4
    # importing it again (a notebook's reload) replaces pfx's load of the same file, without a clash
    module = importlib.reload(module)
    assert type(pfx.model("hand_radar")) is module.HandRadar
    assert len(pfx.run(plugin_config("hand_radar", [str(tmp_path / "hand_radar.py")]),
                       out=tmp_path / "named").trials) == 4


@pytest.mark.usefixtures("imported_by_hand")
def test_a_config_run_then_its_plugin_imported_and_reloaded_by_hand(tmp_path, monkeypatch):
    (tmp_path / "later_radar.py").write_text(plugin_source("later_radar", "LaterRadar"))
    assert len(pfx.run(plugin_config("later_radar", [str(tmp_path / "later_radar.py")]),
                       out=tmp_path / "out").trials) == 4
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("later_radar")          # main: "taken by plugin ...; choose another name"
    assert type(pfx.model("later_radar")) is module.LaterRadar
    module = importlib.reload(module)                        # main: "is a built-in model of pfx"
    assert type(pfx.model("later_radar")) is module.LaterRadar


def refusal_of_config(call) -> str:
    with pytest.raises(pfx.ConfigError) as caught:
        call()
    return str(caught.value)


# -- numba's cache in a plugin ---------------------------------------------------------------------------

NUMBA_PLUGIN = textwrap.dedent('''
    from typing import Literal

    import numba
    import numpy as np

    import pfx


    @numba.njit(cache=True)
    def damped(state, a):
        out = np.empty_like(state)
        for i in range(state.size):
            out.flat[i] = a * state.flat[i]
        return out


    @pfx.register_model
    class CachedWalk(pfx.Model):
        kind: Literal["cached_walk"] = "cached_walk"
        a: float = 0.9

        def presets(self):
            return {"steps": 5, "process_noise": pfx.Noise(variance=1.0), "measurement_noise": pfx.Noise(variance=1.0),
                    "initial": pfx.GaussianLaw(mean=[0.0], covariance=1.0)}

        @property
        def state_names(self):
            return ("x",)

        @property
        def measurement_dimension(self):
            return 1

        def propagate(self, state, control, noise):
            return damped(np.ascontiguousarray(state), self.a) + noise

        def measurement_mean(self, state):
            return state
''')


def test_numba_cache_in_a_plugin_survives_the_same_file_imported_by_hand(tmp_path):
    """Three fresh processes on one numba cache (the plugin's, in tmp_path/__pycache__; pfx's
    own loops keep theirs, warm): a run (compiles, caches), the plugin imported by hand (main:
    ModuleNotFoundError: pfx_plugin_cached_walk_<hash>, the run's cache entry naming pfx's
    module), a run from another folder (main would load the hand import's entry, naming the
    module cached_walk); the last loads the first run's compiled code from the cache."""
    import yaml

    (tmp_path / "cached_walk.py").write_text(NUMBA_PLUGIN)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(plugin_config("cached_walk", ["cached_walk.py"])))
    (tmp_path / "elsewhere").mkdir()
    environment = {**os.environ, "NUMBA_DEBUG_CACHE": "1",
                   "CI": "1", "PYTHONPATH": str(REPO_ROOT)}

    def fresh(arguments, cwd):
        done = subprocess.run([sys.executable, *arguments], cwd=cwd, env=environment, capture_output=True,
                              text=True, timeout=300, stdin=subprocess.DEVNULL)
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
        return done.stdout + done.stderr

    first = fresh(["-m", "pfx", "run", "config.yaml", "--out", "first", "--quiet"], tmp_path)
    assert "data saved" in first and "cached_walk.damped" in first
    # the arguments' types of the run's calls (trials x particles x 1), so that numba looks for their entry
    by_hand = fresh(["-c", "import numpy as np, cached_walk; print(cached_walk.damped(np.ones((2, 3, 1)), 0.5).sum())"],
                    tmp_path)
    assert "3.0" in by_hand
    last = fresh(["-m", "pfx", "run", "../config.yaml", "--out", "../last", "--quiet"], tmp_path / "elsewhere")
    loaded = [line for line in last.splitlines() if "data loaded" in line and "cached_walk.damped" in line]
    assert loaded and all("pfx_plugin_cached_walk_" in line for line in loaded), last[-2000:]
    assert "cached_walk.damped" not in " ".join(line for line in last.splitlines() if "data saved" in line)


def test_simulate_draws_the_truth_a_config_run_draws(tmp_path, tiny_config_dict):
    """pfx.simulate(model, trials, seed) is the truth of a config's trials with that seed: the
    config's trials.csv numbers come back from filtering it with the trials' filter seeds."""
    config = tiny_config_dict()
    config["seed"] = 17
    result = pfx.run(config, out=tmp_path / "run")
    trials = result.trials.sort_values("trial")
    model = pfx.model(**config["model"])
    simulation = pfx.simulate(model, trials=len(trials), seed=17)
    assert simulation.seeds == [int(seed) for seed in trials["truth_seed"]]
    filtered = pfx.filter(model, simulation.measurements, seeds=[int(s) for s in trials["filter_seed"]],
                          **config["filter"])
    np.testing.assert_array_equal(filtered.log_likelihood, trials["log_likelihood"].to_numpy())
    again = pfx.simulate(model, seeds=simulation.seeds[1:3])
    np.testing.assert_array_equal(again.states, simulation.states[1:3])
    with pytest.raises(pfx.ConfigError, match="seeds"):
        pfx.simulate(model, seeds=[1, 2], seed=3)
