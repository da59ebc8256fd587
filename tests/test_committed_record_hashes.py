"""Every committed result folder is what its own config.yaml asks for today.

A folder's manifest keeps the results hash of the config it ran (pfx.config.plan.Plan.results_hash:
every setting that decides its numbers). A change to pfx that moves that hash for a config whose
numbers did not change (a new optional key recorded as null, say) would make every committed
folder look like another config's results: `make reproduce-papers` would rerun it, and a user's
folder would refuse its own config. So each committed folder's config.yaml, planned today, must
give the hash in its manifest.

The plans are built in one fresh process (each folder's plugins are copies of the examples' files
under their own names, which a worker that loaded the examples' files would refuse as taken).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import REPO_ROOT

FOLDERS = sorted(manifest.parent for manifest in (REPO_ROOT / "results").glob("**/manifest.json")
                 if "results_hash" in json.loads(manifest.read_text()))

PLAN_ALL = """
import json, sys
from pfx.config.plan import build_plan
from pfx.config.plugins import loaded_plugins, unload_plugin
from pfx.safe_yaml import load_config_file
hashes = {}
for folder in sys.argv[1:]:
    config = folder + "/config.yaml"
    hashes[folder] = build_plan(load_config_file(config), config).results_hash
    for plugin in loaded_plugins():      # the next folder's copy of a plugin registers the same names
        unload_plugin(plugin)
print(json.dumps(hashes))
"""


@pytest.fixture(scope="module")
def planned() -> dict[str, str]:
    folders = [str(folder) for folder in FOLDERS
               if "backend: jax" not in (folder / "config.yaml").read_text() or _has_jax()]
    result = subprocess.run([sys.executable, "-c", PLAN_ALL, *folders], capture_output=True, text=True,
                            cwd=REPO_ROOT, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


def _has_jax() -> bool:
    import importlib.util

    return importlib.util.find_spec("jax") is not None


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda folder: str(folder.relative_to(REPO_ROOT / "results")))
def test_a_committed_folders_config_gives_its_results_hash(folder, planned):
    if str(folder) not in planned:
        pytest.skip("a jax folder, and jax is not installed")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert planned[str(folder)] == manifest["results_hash"]
