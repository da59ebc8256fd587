"""Plugins (docs/plugins.md): components from outside pfx, through the command line (its entry
point in the test's process; `pfx list` in a real process).

The minimal plugin of the docs, from a file, is validated, listed, documented, run by every
filter kind that can run it and resumed, like a built-in model (and run on Dask: in
tests/test_dask.py, on the Dask tests' cluster). Every way a plugin can fail is one exact error line, exit status 2, nothing written. A
changed plugin refuses a resume. The two examples in examples/plugins/ run and pass checks
derived from theory, and installed packages' plugins are found through their entry points.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, write_config_file

EXAMPLES = REPO_ROOT / "examples" / "plugins"
PREFIX = "pfx: error: "

MINIMAL = '''from typing import Literal
import pfx

@pfx.register_model
class DampedWalk(pfx.Model):
    """x_k = a x_{k-1} + w_k, z_k = x_k + v_k."""
    kind: Literal["damped_walk"] = "damped_walk"
    a: float = 0.8

    @property
    def state_names(self): return ("x",)
    @property
    def measurement_dimension(self): return 1
    def propagate(self, state, control, noise): return self.a * state + noise
    def measurement_mean(self, state): return state
'''


def minimal_config(plugin: str = "damped_walk.py", kind: str = "damped_walk", **changes) -> dict:
    config = {"name": "damped", "plugins": [plugin], "trials": 3,
              "model": {"kind": kind, "steps": 15, "process_noise": {"variance": 1.0},
                        "measurement_noise": {"variance": 0.5},
                        "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0}},
              "filter": {"particles": 200}, "outputs": {"figures": []}}
    config.update(changes)
    return config


def write_plugin(folder: Path, source: str = MINIMAL, name: str = "damped_walk.py") -> Path:
    path = folder / name
    path.write_text(source)
    return path


def one_error_line(result) -> str:
    assert result.returncode == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.output, result.output
    return lines[0].removeprefix(PREFIX)


ALL_KINDS = {"pf": {"kind": "particle"}, "sis": {"kind": "sis"}, "hist": {"kind": "histogram"},
             "ekf": {"kind": "ekf"}, "ukf": {"kind": "ukf"}}


def test_minimal_plugin_runs_with_every_filter_kind(pfx_in_process, tmp_path):
    plugin = write_plugin(tmp_path)
    config = write_config_file(tmp_path, minimal_config(arms=ALL_KINDS))
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 0, result.output
    trials = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert set(trials["filter"]) == {"particle", "sis", "histogram", "ekf", "ukf"}
    assert set(trials["model"]) == {"damped_walk"} and len(trials) == 5 * 3
    assert np.isfinite(trials["rmse_position"]).all()
    # a walk of stationary variance 1 / (1 - 0.8^2), seen with noise variance 0.5: every filter
    # does better than the measurements alone (RMSE sqrt(0.5))
    assert (trials.groupby("filter")["rmse_position"].mean() < np.sqrt(0.5)).all()
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["plugins"] == [{"name": "damped_walk.py", "file": str(plugin),
                                    "sha256": hashlib.sha256(plugin.read_bytes()).hexdigest(),
                                    "copy": "plugins/damped_walk.py"}]
    resolved = yaml.safe_load((tmp_path / "out" / "config.yaml").read_text())
    assert resolved["plugins"] == ["plugins/damped_walk.py"] and resolved["model"]["a"] == 0.8


def test_a_config_without_plugins_runs_no_plugin_code(pfx_in_process, tmp_path):
    marker = tmp_path / "imported"
    write_plugin(tmp_path, MINIMAL + f"\nopen({str(marker)!r}, 'w').close()\n")
    config = minimal_config()
    del config["plugins"]
    write_config_file(tmp_path, config)
    result = pfx_in_process("validate", "config.yaml", cwd=tmp_path)
    assert one_error_line(result).startswith("config.yaml: model.kind: unknown model kind 'damped_walk'")
    assert not marker.exists()


FAILURES = {
    "missing file": (None, "config.yaml: plugins[0]: plugin file not found: damped_walk.py"),
    "exception at import": (MINIMAL.replace('    a: float = 0.8\n', '    a: float = 0.8\n    b: float = oops\n'),
                            "damped_walk.py:9: NameError: name 'oops' is not defined"),
    "syntax error": (MINIMAL.replace("a: float = 0.8", "a: float = = 0.8"),
                     "damped_walk.py:8: SyntaxError: invalid syntax"),
    "clash with a built-in": (MINIMAL.replace('"damped_walk"', '"linear_gaussian"'),
                              "damped_walk.py:4: model 'linear_gaussian' is a built-in model of pfx; "
                              "choose another name"),
    "missing method": (MINIMAL.replace("    def measurement_mean(self, state): return state\n", ""),
                       "damped_walk.py:4: model damped_walk (class DampedWalk) does not define measurement_mean, "
                       "which every model must (docs/plugins.md)"),
    "wrong shape": (MINIMAL.replace("return self.a * state + noise", "return (self.a * state + noise)[..., 0]"),
                    "damped_walk.py:14: model damped_walk: propagate returned shape (2, 3) for a batch of 2 trials "
                    "x 3 particles; expected (2, 3, 1)"),
    "wrong dtype": (MINIMAL.replace("def measurement_mean(self, state): return state",
                                    "def measurement_mean(self, state): return state > 0"),
                    "damped_walk.py:15: model damped_walk: measurement_mean returned dtype bool; expected floating "
                    "point (float64)"),
    "kind not registered": (MINIMAL, "config.yaml: model.kind: unknown model kind 'damped_wlak' (did you mean "
                                     "'damped_walk'?); plugins loaded: damped_walk.py (model damped_walk)"),
    "components that are not indices": (
        MINIMAL + "    @property\n    def angular_components(self): return ('x',)\n",
        "damped_walk.py:16: model damped_walk: angular_components returned ('x',); expected indices of state "
        "components (integers 0..0, e.g. (0,) for x)"),
}


@pytest.mark.parametrize("case", list(FAILURES))
def test_plugin_failures_are_one_line(pfx_in_process, tmp_path, case):
    source, expected = FAILURES[case]
    if source is not None:
        write_plugin(tmp_path, source)
    # with arms, as a comparison has: the plugin's mistake is still located in the plugin file
    config = minimal_config(kind="damped_wlak" if case == "kind not registered" else "damped_walk",
                            arms={"particle": {"kind": "particle"}, "ekf": {"kind": "ekf"}})
    write_config_file(tmp_path, config)
    before = sorted(tmp_path.iterdir())
    result = pfx_in_process("run", "config.yaml", "--out", "out", cwd=tmp_path)
    assert one_error_line(result) == expected
    assert sorted(tmp_path.iterdir()) == before            # nothing written


def test_list_and_schema_with_plugin(run_pfx, pfx_in_process, tmp_path):
    """`pfx list` in a real process: in a process that loaded other plugins before (the test's),
    their hidden names would widen the listing's name column."""
    write_plugin(tmp_path)
    listed = run_pfx("list", "models", "--plugin", "damped_walk.py", cwd=tmp_path)
    assert listed.returncode == 0, listed.output
    assert "damped_walk        x_k = a x_{k-1} + w_k, z_k = x_k + v_k. [plugin damped_walk.py]" in listed.stdout
    assert "linear_gaussian" in listed.stdout
    assert "damped_walk" not in run_pfx("list", "models", cwd=tmp_path).stdout
    schema = json.loads(pfx_in_process("schema", "--plugin", "damped_walk.py", cwd=tmp_path).stdout)
    assert "DampedWalk" in schema["$defs"]
    assert schema["$defs"]["DampedWalk"]["properties"]["a"]["default"] == 0.8
    built_in = pfx_in_process("schema", cwd=tmp_path).stdout
    assert built_in == (REPO_ROOT / "docs" / "config.schema.json").read_text()
    markdown = pfx_in_process("schema", "--format", "markdown", "--plugin", "damped_walk.py", cwd=tmp_path).stdout
    assert "#### `kind: damped_walk`" in markdown
    missing = pfx_in_process("list", "--plugin", "nothere.py", cwd=tmp_path)
    assert one_error_line(missing) == "--plugin: plugin file not found: nothere.py"


def test_resume_refused_after_plugin_change(pfx_in_process, tmp_path):
    plugin = write_plugin(tmp_path)
    config = write_config_file(tmp_path, minimal_config())
    assert pfx_in_process("run", config, "--out", "out", cwd=tmp_path).returncode == 0
    again = pfx_in_process("run", config, "--out", "out", cwd=tmp_path)
    assert again.returncode == 0 and "up to date" in again.output
    plugin.write_text(MINIMAL.replace("a: float = 0.8", "a: float = 0.7"))
    manifest_before = (tmp_path / "out" / "manifest.json").read_text()
    changed = pfx_in_process("run", config, "--out", "out", cwd=tmp_path)
    line = one_error_line(changed)
    assert line.startswith("out: plugin damped_walk.py has changed since these results were computed (sha256 ")
    assert line.endswith("); use --fresh to recompute them or --out for another folder")
    assert (tmp_path / "out" / "manifest.json").read_text() == manifest_before
    assert pfx_in_process("run", config, "--out", "out", "--fresh", cwd=tmp_path).returncode == 0


def test_a_plugin_runs_result_folder_reruns_from_anywhere(pfx_in_process, tmp_path):
    """The folder keeps a copy of the plugin's code (plugins/, checked against the manifest's
    sha256) that its config.yaml names: rerun from another working folder, with the original
    plugin gone, it gives the same trials.csv and the same hashes; into itself, it is up to date."""
    project, elsewhere = tmp_path / "project", tmp_path / "elsewhere"
    elsewhere.mkdir()
    write_plugin(project.mkdir() or project)
    write_config_file(project, minimal_config(plugins=["damped_walk.py"]))
    assert pfx_in_process("run", "project/config.yaml", "--out", "runs/walk", cwd=tmp_path).returncode == 0
    folder = tmp_path / "runs" / "walk"
    manifest = json.loads((folder / "manifest.json").read_text())
    copy = folder / "plugins" / "damped_walk.py"
    assert copy.read_text() == MINIMAL
    assert manifest["plugins"] == [{"name": "damped_walk.py", "file": "project/damped_walk.py",
                                    "sha256": hashlib.sha256(MINIMAL.encode()).hexdigest(),
                                    "copy": "plugins/damped_walk.py"}]
    assert yaml.safe_load((folder / "config.yaml").read_text())["plugins"] == ["plugins/damped_walk.py"]
    (project / "damped_walk.py").unlink()                  # the record stands on its own

    rerun = pfx_in_process("run", folder / "config.yaml", "--out", "other", cwd=elsewhere)
    assert rerun.returncode == 0, rerun.output
    original, again = (pd.read_csv(path / "trials.csv").drop(columns="run_time_s")
                       for path in (folder, elsewhere / "other"))
    pd.testing.assert_frame_equal(original, again)
    rerun_manifest = json.loads((elsewhere / "other" / "manifest.json").read_text())
    assert (rerun_manifest["results_hash"], rerun_manifest["config_hash"]) == \
        (manifest["results_hash"], manifest["config_hash"])
    itself = pfx_in_process("run", "config.yaml", "--out", ".", cwd=folder)
    assert itself.returncode == 0 and "up to date" in itself.output, itself.output

    copy.write_text(MINIMAL.replace("a: float = 0.8", "a: float = 0.7"))     # an edited copy is refused
    line = one_error_line(pfx_in_process("run", folder / "config.yaml", "--out", "third", cwd=elsewhere))
    assert line.startswith(f"{folder / 'plugins' / 'damped_walk.py'}: this copy differs from the code the folder's "
                           "results were computed with (sha256 ")
    assert not (elsewhere / "third").exists()


# -- the examples -------------------------------------------------------------------------------


def test_stochastic_volatility_loglikelihood_spread_shrinks_with_particles():
    """The bootstrap filter's log-likelihood estimate is finite, and its spread over filter seeds
    on one data set shrinks with N (its variance is O(1/N): 16 times the particles, a quarter
    of the spread)."""
    from pfx.config.plan import build_plan
    from pfx.filters import run_filter
    from pfx.numerics.seeding import TrialStreams

    config = yaml.safe_load((EXAMPLES / "stochastic-volatility.yaml").read_text())
    config.update(trials=1, sweep={})
    plan = build_plan(config, str(EXAMPLES / "stochastic-volatility.yaml"))
    cell = plan.cells[0]
    model = cell.truth_model
    random = TrialStreams.from_seeds([2024])
    state, measurements = model.initial.sample(random), []
    for step in range(1, model.steps + 1):
        state = model.transition(state, step, random)
        measurements.append(model.simulate_measurement(state, random))
    data = np.repeat(np.stack(measurements, axis=1), 40, axis=0)      # one data set, 40 filter seeds
    spreads = {}
    for particles in (100, 1600):
        settings = cell.filter.model_copy(update={"particles": particles})
        trace = run_filter("particle", model, data, TrialStreams.from_seeds(range(40)), settings=settings,
                           prior=cell.prior)
        assert np.isfinite(trace.log_likelihood).all()
        spreads[particles] = np.std(trace.log_likelihood)
    assert spreads[1600] < 0.5 * spreads[100]


def test_examples_run(pfx_in_process, tmp_path):
    """Both examples through the command line: the stochastic-volatility filters track the
    log-variance better than its stationary spread; the bearings-only particle filter's position
    error is far below the prior's spread (sqrt(0.5^2 + 0.3^2)), and the EKF and UKF run."""
    runs = pfx_in_process.many({name: (("run", EXAMPLES / f"{name}.yaml", "--out", tmp_path / name, "--trials", "8"),
                                tmp_path) for name in ("stochastic-volatility", "bearings-only")})
    for result in runs.values():
        assert result.returncode == 0, result.output
    volatility = pd.read_csv(tmp_path / "stochastic-volatility" / "trials.csv")
    stationary_sd = 0.25 / np.sqrt(1 - 0.95**2)
    assert np.isfinite(volatility["log_likelihood"]).all()
    assert volatility[volatility["filter"] == "particle"]["rmse_position"].mean() < stationary_sd
    bearings = pd.read_csv(tmp_path / "bearings-only" / "trials.csv")
    particle = bearings[bearings["arm"] == "roughened"]["rmse_position"]
    assert particle.mean() < 0.25 * np.hypot(0.5, 0.3)
    assert set(bearings["filter"]) == {"particle", "ekf", "ukf"}
    assert np.isfinite(bearings["rmse_position"]).all()


# -- installed plugins ---------------------------------------------------------------------------


def test_entry_point_plugins(tmp_path, monkeypatch):
    """A fake installed distribution (a .dist-info folder with entry_points.txt on sys.path)
    offers a model through the group ``pfx.plugins``; `pfx list` loads it, and a config naming
    the entry point uses it."""
    from pfx.config.plan import build_plan
    from pfx.config.plugins import installed_entry_points, load_installed_plugins
    from pfx.models import MODELS

    source = MINIMAL.replace("damped_walk", "installed_walk").replace("DampedWalk", "InstalledWalk")
    (tmp_path / "pfx_test_installed_walk.py").write_text(source)
    info = tmp_path / "pfx_test_installed-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: pfx-test-installed\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[pfx.plugins]\ninstalled-walk = pfx_test_installed_walk\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "installed-walk" in installed_entry_points()
    assert "installed_walk" not in MODELS                         # nothing is loaded behind one's back
    loaded = [plugin for plugin in load_installed_plugins() if plugin.name == "installed-walk"]
    assert loaded and loaded[0].registered == ("model installed_walk",)
    assert MODELS.origin("installed_walk") == "pfx_test_installed_walk"
    config = minimal_config(plugin="installed-walk", kind="installed_walk")
    plan = build_plan(config, str(tmp_path / "config.yaml"))
    assert plan.cells[0].truth_model.kind == "installed_walk" and plan.plugins[0].sha256
    # a config that does not name the plugin does not see its model
    del config["plugins"]
    from pfx.errors import ConfigError
    with pytest.raises(ConfigError, match="unknown model kind 'installed_walk'"):
        build_plan(config, str(tmp_path / "config.yaml"))
    sys.modules.pop("pfx_test_installed_walk", None)


PROPOSAL_PLUGIN = '''from typing import Literal
import pfx

@pfx.register_proposal
class Mine(pfx.Proposal):
    """The transition, as a plugin's proposal (version {version})."""
    kind: Literal["mine"] = "mine"

    def propose(self, model, previous, step, measurement, observed, random):
        state = model.transition(previous, step, random)
        return state, 0.0 * state[..., 0]
'''


def test_a_plugin_proposal_is_recorded_and_reloads_after_an_edit(tmp_path):
    """What a plugin registered includes its proposal, and loading the edited file replaces it
    (every registry is in the one list the plugins' bookkeeping reads)."""
    from pfx.config.plugins import load_plugin
    from pfx.filters.particle.proposals import PROPOSALS

    path = tmp_path / "mine.py"
    path.write_text(PROPOSAL_PLUGIN.format(version=1))
    assert load_plugin("mine.py", tmp_path).registered == ("proposal mine",)
    path.write_text(PROPOSAL_PLUGIN.format(version=2))
    assert load_plugin("mine.py", tmp_path).registered == ("proposal mine",)
    assert "version 2" in PROPOSALS["mine"].__doc__
