"""A gallery's plugin store (pfx/config/plugin_record.py): ``pfx reproduce`` keeps each plugin's
code once per content in ``<gallery>/plugins/<stem>-<sha12>.py``, named by each folder's
config.yaml by relative path, where a ``pfx run --out`` folder keeps its own copy.

The store changes paths only: the hashes stay those of the config the folder was made from, a
second reproduction keeps the record byte for byte, the folder reruns, resumes, loads and draws
its figures as before, and a stored file edited by hand is refused, in one line naming it.
"""

from __future__ import annotations

import hashlib
import json

import pandas as pd
import pytest
import yaml
from conftest import write_config_file

import pfx
from pfx.config.plan import build_plan
from pfx.config.plugins import loaded_plugins, unload_plugin
from pfx.papers.reproduce import reproduce_papers
from pfx.safe_yaml import load_config_file

pytestmark = pytest.mark.usefixtures("fresh_plugins")      # each test's plugins unloaded after it

PLUGIN = '''from typing import Literal
import pfx

@pfx.register_model
class StoredWalk(pfx.Model):
    """x_k = a x_{k-1} + w_k, z_k = x_k + v_k."""
    kind: Literal["stored_walk"] = "stored_walk"
    a: float = 0.8

    @property
    def state_names(self): return ("x",)
    @property
    def measurement_dimension(self): return 1
    def propagate(self, state, control, noise): return self.a * state + noise
    def measurement_mean(self, state): return state
'''
CHANGED = PLUGIN.replace("a: float = 0.8", "a: float = 0.7")
ENTRY = "../../plugin/stored_walk.py"       # from configs/toy/ to the project's plugin


def _config(name: str, seed: int = 3, plugin: str = ENTRY) -> dict:
    return {"name": name, "seed": seed, "plugins": [plugin], "trials": 3,
            "model": {"kind": "stored_walk", "steps": 10, "process_noise": {"variance": 1.0},
                      "measurement_noise": {"variance": 0.5},
                      "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0}},
            "filter": {"particles": 50}, "outputs": {"figures": ["error_over_time"]}}


def _project(tmp_path, experiments=("walk",), source=PLUGIN):
    """A plugin and a paper ``toy`` of configs naming it; returns the configs' folder."""
    (tmp_path / "plugin").mkdir(exist_ok=True)
    (tmp_path / "plugin" / "stored_walk.py").write_text(source)
    for seed, name in enumerate(experiments, start=3):
        write_config_file(tmp_path / "configs" / "toy", _config(name, seed), f"{name}.yaml")
    return tmp_path / "configs"


def _reproduce(configs, out, plugin_store=None) -> list[str]:
    """``pfx reproduce``, in this process; what it says. The plugins it loaded are unloaded after
    it, as a process's end with it (a later command loads an edited plugin afresh)."""
    before = {plugin.origin for plugin in loaded_plugins()}
    messages: list[str] = []
    reproduce_papers([], configs, out, fresh=True, report=messages.append, progress=False, plugin_store=plugin_store)
    for plugin in loaded_plugins():
        if plugin.origin not in before:
            unload_plugin(plugin)
    return messages


def _stored(source: str = PLUGIN) -> str:
    """The name of the stored copy of ``source``."""
    return f"stored_walk-{hashlib.sha256(source.encode()).hexdigest()[:12]}.py"


def _record(folder) -> dict:
    """A folder's files but its figures, by path: what a reproduction keeps byte for byte."""
    return {path: path.read_bytes() for path in folder.rglob("*") if path.is_file() and "figures" not in path.parts}


def test_a_gallery_folder_names_its_plugin_in_the_store_with_the_same_hashes(tmp_path, pfx_in_process):
    configs, out = _project(tmp_path), tmp_path / "results"
    _reproduce(configs, out)
    folder = out / "toy" / "walk"
    entry = f"../../plugins/{_stored()}"
    assert not (folder / "plugins").exists()
    assert yaml.safe_load((folder / "config.yaml").read_text())["plugins"] == [entry]
    assert (out / "plugins" / _stored()).read_text() == PLUGIN
    manifest = json.loads((folder / "manifest.json").read_text())
    assert [(item["sha256"], item["copy"]) for item in manifest["plugins"]] == \
        [(hashlib.sha256(PLUGIN.encode()).hexdigest(), entry)]
    # the folder's own config (the stored copy) has the hashes of the config it was made from
    plan = build_plan(load_config_file(folder / "config.yaml"), str(folder / "config.yaml"))
    assert (plan.config_hash, plan.results_hash) == (manifest["config_hash"], manifest["results_hash"])

    # and reads, resumes and draws as any folder
    assert len(pfx.load(folder).trials) == 3
    resumed = pfx_in_process("run", folder / "config.yaml", "--out", folder)
    assert resumed.returncode == 0 and "up to date" in resumed.output, resumed.output
    (folder / "figures" / "error_over_time.png").unlink()
    drawn = pfx_in_process("figures", folder)
    assert drawn.returncode == 0 and (folder / "figures" / "error_over_time.png").is_file(), drawn.output

    before = _record(out)
    messages = _reproduce(configs, out)                    # through a staging folder, compared
    assert any("the same numbers" in message for message in messages), messages
    assert _record(out) == before


def test_two_folders_with_the_same_plugin_share_one_stored_file(tmp_path):
    out = tmp_path / "results"
    _reproduce(_project(tmp_path, experiments=("walk", "walk-again")), out)
    assert [path.name for path in (out / "plugins").iterdir()] == [_stored()]
    for name in ("walk", "walk-again"):
        assert yaml.safe_load((out / "toy" / name / "config.yaml").read_text())["plugins"] == \
            [f"../../plugins/{_stored()}"]
    assert not list(out.glob("*/*/plugins"))


def test_a_gallery_inside_another_shares_its_store_and_keeps_its_files(tmp_path):
    """As results/benchmarks/ shares results/plugins/ (``make reproduce-benchmarks`` passes
    ``--plugin-store``): one stored file for both galleries, named from the inner one's folders
    by their own relative path, and neither gallery's reproduction removes what the other names."""
    out = tmp_path / "results"
    configs = _project(tmp_path)
    _reproduce(configs, out)
    _reproduce(configs, out / "benchmarks", plugin_store=out / "plugins")
    assert [path.name for path in (out / "plugins").iterdir()] == [_stored()]
    assert not (out / "benchmarks" / "plugins").exists()
    inner = out / "benchmarks" / "toy" / "walk"
    assert yaml.safe_load((inner / "config.yaml").read_text())["plugins"] == [f"../../../plugins/{_stored()}"]
    assert len(pfx.load(inner).trials) == 3
    _reproduce(_project(tmp_path, source=CHANGED), out)       # the outer gallery moves to other code
    assert sorted(path.name for path in (out / "plugins").iterdir()) == sorted([_stored(), _stored(CHANGED)])


def test_a_run_outside_a_gallery_keeps_its_own_copy_under_the_plugins_name(tmp_path, pfx_in_process):
    """Rerun from a gallery folder's config.yaml into a folder of its own, the copy travels with
    the new folder, named as the plugin is (not as the store names it), with the same hashes."""
    out = tmp_path / "results"
    _reproduce(_project(tmp_path), out)
    folder = out / "toy" / "walk"
    assert not (folder / "plugins").exists()
    rerun = pfx_in_process("run", folder / "config.yaml", "--out", tmp_path / "elsewhere" / "walk")
    assert rerun.returncode == 0, rerun.output
    own = tmp_path / "elsewhere" / "walk"
    assert (own / "plugins" / "stored_walk.py").read_text() == PLUGIN
    assert yaml.safe_load((own / "config.yaml").read_text())["plugins"] == ["plugins/stored_walk.py"]
    manifests = [json.loads((path / "manifest.json").read_text()) for path in (folder, own)]
    assert manifests[1]["plugins"][0]["copy"] == "plugins/stored_walk.py"
    assert [(m["config_hash"], m["results_hash"]) for m in manifests] == [(manifests[0]["config_hash"],
                                                                           manifests[0]["results_hash"])] * 2
    assert not (tmp_path / "elsewhere" / "plugins").exists()
    pd.testing.assert_frame_equal(*(pd.read_csv(path / "trials.csv").drop(columns="run_time_s")
                                    for path in (folder, own)))


def test_a_tampered_stored_file_is_refused_naming_it(tmp_path, pfx_in_process):
    out = tmp_path / "results"
    _reproduce(_project(tmp_path), out)
    folder = out / "toy" / "walk"
    (out / "plugins" / _stored()).write_text(CHANGED)
    result = pfx_in_process("run", folder / "config.yaml", "--out", tmp_path / "other")
    assert result.returncode == 2, result.output
    assert result.stderr.strip().splitlines() == [
        f"pfx: error: {folder / '../../plugins' / _stored()}: this copy differs from the code the folder's "
        f"results were computed with (sha256 {hashlib.sha256(CHANGED.encode()).hexdigest()[:12]} != "
        f"{hashlib.sha256(PLUGIN.encode()).hexdigest()[:12]} in manifest.json); restore it, or run an edited "
        "plugin from a config of your own"]
    assert not (tmp_path / "other").exists()


def test_a_gallery_folder_computed_with_other_plugin_code_is_not_resumed(tmp_path, pfx_in_process):
    """The plugin's code changed since the gallery's folder was computed: resuming it is refused
    in words naming the plugin (its manifest names the stored copy, by the code's digits)."""
    configs, out = _project(tmp_path), tmp_path / "results"
    _reproduce(configs, out)
    folder = out / "toy" / "walk"
    assert json.loads((folder / "manifest.json").read_text())["plugins"][0]["copy"] == f"../../plugins/{_stored()}"
    (tmp_path / "plugin" / "stored_walk.py").write_text(CHANGED)
    result = pfx_in_process("run", configs / "toy" / "walk.yaml", "--out", folder)
    assert result.returncode == 2, result.output
    assert f"plugin {ENTRY} has changed since these results were computed" in result.stderr, result.stderr


def test_a_stored_file_that_no_folder_names_any_more_is_removed(tmp_path):
    out = tmp_path / "results"
    _reproduce(_project(tmp_path), out)
    messages = _reproduce(_project(tmp_path, source=CHANGED), out)
    assert any("new numbers" in message for message in messages), messages
    assert [path.name for path in (out / "plugins").iterdir()] == [_stored(CHANGED)]
    assert any(f"removed {_stored()}" in message for message in messages), messages


def test_the_hashes_know_a_stored_copy_by_the_plugins_own_name(tmp_path):
    """A file named ``<stem>-<the first 12 digits of its own code's sha256>.py`` is a stored copy
    of ``<stem>.py``: the same hashes; other digits are part of the name (another record)."""
    for path in (tmp_path / "stored_walk.py", tmp_path / "store" / _stored(),
                 tmp_path / "store" / "stored_walk-000000000000.py"):
        path.parent.mkdir(exist_ok=True)
        path.write_text(PLUGIN)
    plans = [build_plan(_config("walk", plugin=entry), str(tmp_path / "config.yaml"))
             for entry in ("stored_walk.py", f"store/{_stored()}", "store/stored_walk-000000000000.py")]
    hashes = [(plan.config_hash, plan.results_hash) for plan in plans]
    assert hashes[0] == hashes[1] and hashes[2][0] != hashes[0][0]
