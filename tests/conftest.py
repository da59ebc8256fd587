"""Shared fixtures: run the real ``pfx`` command line, and write small valid configs.

* ``run_pfx(*args, cwd=..., timeout=...)`` runs ``python -m pfx ARGS`` in a subprocess and
  returns a :class:`PfxResult` (``returncode, stdout, stderr = result`` also works).
  ``run_pfx.many({key: (args, cwd)})`` runs several invocations concurrently (one per CPU):
  each is still a separate, real subprocess, the suite just waits less.
* ``tiny_config_dict()`` is a fresh dict of a tiny, fast, valid experiment (1-D linear-Gaussian
  model, 5 steps, 20 particles, 4 trials); ``write_config(data, name)`` writes a dict (as YAML),
  text or bytes into ``tmp_path``; ``tiny_config`` is the tiny config written to a file.
"""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Iterator, NamedTuple, Optional

import pytest
import yaml

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TIMEOUT_S = 180      # a safety net against hangs, not a timing assertion

TINY_CONFIG: dict[str, Any] = {
    "name": "tiny",
    "description": "a tiny experiment for the tests",
    "seed": 7,
    "trials": 4,
    "model": {
        "kind": "linear_gaussian",
        "steps": 5,
        "transition_matrix": [[1.0]],
        "measurement_matrix": [[1.0]],
    },
    "filter": {"particles": 20, "resampler": "systematic"},
    "outputs": {"trace_trials": 2},
}


class PfxResult(NamedTuple):
    returncode: int
    stdout: str
    stderr: str

    @property
    def output(self) -> str:
        return self.stdout + self.stderr


def _environment() -> dict[str, str]:
    env = dict(os.environ)
    env["CI"] = "1"                          # no progress bar
    # The suite runs several CLI processes side by side: one BLAS thread each avoids
    # oversubscribing the CPUs (results must not depend on it).
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(variable, "1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


class PfxRunner:
    """Callable that runs the real CLI as a subprocess (see the module docstring)."""

    def __init__(self, default_cwd: Path):
        self.default_cwd = Path(default_cwd)

    def __call__(self, *args: Any, cwd: Optional[Path] = None, timeout: float = DEFAULT_TIMEOUT_S) -> PfxResult:
        completed = subprocess.run(
            [sys.executable, "-m", "pfx", *[str(a) for a in args]],
            cwd=str(cwd or self.default_cwd), env=_environment(), capture_output=True, text=True,
            timeout=timeout, stdin=subprocess.DEVNULL)
        return PfxResult(completed.returncode, completed.stdout, completed.stderr)

    def many(self, jobs: dict[Any, tuple], timeout: float = DEFAULT_TIMEOUT_S) -> dict[Any, PfxResult]:
        """Run ``{key: (args, cwd)}`` concurrently; return ``{key: PfxResult}``."""
        workers = max(1, min(len(jobs), os.cpu_count() or 1))
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {key: pool.submit(self, *args, cwd=cwd, timeout=timeout)
                       for key, (args, cwd) in jobs.items()}
            return {key: future.result() for key, future in futures.items()}


@pytest.fixture(scope="session")
def run_pfx(tmp_path_factory) -> PfxRunner:
    """Run ``python -m pfx``; the default working folder is an empty temporary folder."""
    return PfxRunner(tmp_path_factory.mktemp("pfx-cwd"))


def tiny_config_dict(**changes: Any) -> dict:
    """A fresh copy of the tiny config, with top-level keys replaced by ``changes``."""
    data = copy.deepcopy(TINY_CONFIG)
    data.update(copy.deepcopy(changes))
    return data


@pytest.fixture(name="tiny_config_dict")
def tiny_config_dict_fixture():
    return tiny_config_dict


def write_config_file(folder: Path, data: Any, name: str = "config.yaml") -> Path:
    """Write a dict (as YAML), a str or bytes to ``folder/name``; return the path."""
    path = Path(folder) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, bytes):
        path.write_bytes(data)
    elif isinstance(data, str):
        path.write_text(data, encoding="utf-8")
    else:
        path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


@pytest.fixture
def write_config(tmp_path):
    """``write_config(data, name='config.yaml')`` writes into ``tmp_path``."""
    def write(data: Any, name: str = "config.yaml") -> Path:
        return write_config_file(tmp_path, data, name)
    return write


@pytest.fixture
def tiny_config(tmp_path) -> Path:
    """The tiny valid config, written to ``tmp_path/tiny.yaml``."""
    return write_config_file(tmp_path, tiny_config_dict(), "tiny.yaml")


def csv_fields(text: str) -> Iterator[str]:
    """Every comma-separated field of a CSV text (the tests' files hold no quoted commas)."""
    for line in text.splitlines():
        yield from line.split(",")
