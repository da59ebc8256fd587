"""Every committed result folder is what its own config.yaml asks for today.

A folder's manifest keeps the results hash of the config it ran (pfx.config.plan.Plan.results_hash:
every setting that decides its numbers). A change to pfx that moves that hash for a config whose
numbers did not change (a new optional key recorded as null, say) would make every committed
folder look like another config's results: `make reproduce-papers` would rerun it, and a user's
folder would refuse its own config. So each committed folder's config.yaml, planned today, must
give the hash in its manifest.
"""

from __future__ import annotations

import json

import pytest
from conftest import REPO_ROOT

from pfx.config.plan import build_plan
from pfx.config.plugins import loaded_plugins, unload_plugin
from pfx.safe_yaml import load_config_file

FOLDERS = sorted(manifest.parent for manifest in (REPO_ROOT / "results").glob("**/manifest.json")
                 if "results_hash" in json.loads(manifest.read_text()))

pytestmark = pytest.mark.usefixtures("fresh_plugins")


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda folder: str(folder.relative_to(REPO_ROOT / "results")))
def test_a_committed_folders_config_gives_its_results_hash(folder):
    config = folder / "config.yaml"
    if "backend: jax" in config.read_text():
        pytest.importorskip("jax")
    manifest = json.loads((folder / "manifest.json").read_text())
    # as a fresh process plans it: a plugin an earlier module of this worker left loaded (the same
    # model's file from examples/, not the folder's copy) would otherwise clash with the copy's names
    for plugin in loaded_plugins():
        unload_plugin(plugin)
    assert build_plan(load_config_file(config), str(config)).results_hash == manifest["results_hash"]
