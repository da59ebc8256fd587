"""Interrupted, resumed and concurrent runs, through real `pfx run` processes (the runs no signal
reaches: the command line in the test's process).

A sweep of ten cells (each a fraction of a second) is stopped by a signal once two cells are
finished; the folder must then hold every finished cell intact, no partial or temporary file,
and running the same command again must resume, skip the finished cells, say so, and end with
tables identical to an uninterrupted run.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, _environment

SLOW = {
    "name": "slow",
    "seed": 1,
    "trials": 4,
    "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
              "steps": 60},
    # 4000 particles: a cell lasts long enough (0.1-0.3 s) for a signal sent once two cells are
    # finished to reach the run with cells still to do; the checks (cells kept, resume, identical
    # tables) do not depend on the size
    "filter": {"particles": 4000},
    "sweep": {"filter.resampler": ["multinomial", "stratified", "systematic", "residual", "han_lee_iv"],
              "filter.ess_threshold": [1.0, 0.5]},
    "outputs": {"trace_trials": 1, "figures": []},
}
SAFETY_TIMEOUT_S = 120     # against hangs only; nothing here asserts on time


def _pfx(*args) -> list[str]:
    return [sys.executable, "-m", "pfx", *map(str, args)]


def _start(config: Path, out: Path, *extra) -> subprocess.Popen:
    return subprocess.Popen(_pfx("run", config, "--out", out, *extra), cwd=REPO_ROOT, env=_environment(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _finished_cells(out: Path) -> list[Path]:
    return sorted((out / "cells").glob("*.trials.csv")) if (out / "cells").is_dir() else []


def _wait_for(condition, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + SAFETY_TIMEOUT_S
    while not condition():
        assert process.poll() is None, f"pfx ended before the test could interrupt it: {process.communicate()}"
        assert time.monotonic() < deadline, "safety timeout"
        time.sleep(0.02)


def _trials(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "trials.csv").drop(columns="run_time_s")


@pytest.fixture(scope="module")
def config(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("interrupts") / "slow.yaml"
    path.write_text(yaml.safe_dump(SLOW))
    return path


@pytest.fixture(scope="module")
def reference(config, tmp_path_factory, pfx_in_process) -> pd.DataFrame:
    """The same sweep run without interruption (the command line in the test's process)."""
    out = tmp_path_factory.mktemp("reference") / "out"
    done = pfx_in_process("run", config, "--out", out, "--quiet")
    assert done.returncode == 0, done.stderr
    return _trials(out)


@pytest.mark.parametrize("signal_number, workers", [(signal.SIGINT, 1), (signal.SIGTERM, 2)])
def test_interrupt_keeps_finished_cells_and_resume_completes(config, reference, tmp_path, signal_number, workers):
    out = tmp_path / "out"
    process = _start(config, out, "--workers", workers)
    _wait_for(lambda: len(_finished_cells(out)) >= 2, process)
    process.send_signal(signal_number)
    _, stderr = process.communicate(timeout=SAFETY_TIMEOUT_S)

    assert process.returncode == 128 + signal_number
    assert "Traceback" not in stderr
    assert "interrupted" in stderr and "resume" in stderr
    # every finished cell is intact; nothing partial, nothing temporary, no final tables
    finished = _finished_cells(out)
    assert 2 <= len(finished) < 10
    for path in finished:
        cell = pd.read_csv(path)
        assert len(cell) == SLOW["trials"] and cell["cell"].nunique() == 1
        assert (out / "cells" / path.name.replace(".trials.", ".steps.")).is_file()
    leftovers = [p.name for p in out.rglob("*") if p.name.startswith(".tmp")]
    assert leftovers == []
    assert not (out / "trials.csv").exists()

    resumed = subprocess.run(_pfx("run", config, "--out", out), cwd=REPO_ROOT, env=_environment(),
                             capture_output=True, text=True, timeout=SAFETY_TIMEOUT_S)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{len(finished)} of 10 cells already done" in resumed.stderr
    pd.testing.assert_frame_equal(_trials(out), reference, check_exact=True)
    assert not (out / "cells").exists()


def test_killed_run_leaves_no_stale_lock(config, reference, tmp_path):
    """SIGKILL cannot be handled: the flock dies with the process, so the next run resumes."""
    out = tmp_path / "out"
    process = _start(config, out)
    _wait_for(lambda: len(_finished_cells(out)) >= 1, process)
    process.kill()
    process.communicate(timeout=SAFETY_TIMEOUT_S)
    resumed = subprocess.run(_pfx("run", config, "--out", out), cwd=REPO_ROOT, env=_environment(),
                             capture_output=True, text=True, timeout=SAFETY_TIMEOUT_S)
    assert resumed.returncode == 0, resumed.stderr
    assert "already done" in resumed.stderr
    pd.testing.assert_frame_equal(_trials(out), reference, check_exact=True)


def test_second_run_on_the_same_folder_is_refused(config, tmp_path):
    out = tmp_path / "out"
    first = _start(config, out, "--set", "filter.particles=100000")   # slow enough to be still running
    try:
        _wait_for(lambda: (out / "manifest.json").is_file(), first)
        second = subprocess.run(_pfx("run", config, "--out", out, "--set", "filter.particles=100000"),
                                cwd=REPO_ROOT, env=_environment(), capture_output=True, text=True,
                                timeout=SAFETY_TIMEOUT_S)
        assert first.poll() is None, "the first run ended too early for this test to mean anything"
        assert second.returncode == 2
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1 and "another pfx run" in lines[0] and f"pid {first.pid}" in lines[0]
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=SAFETY_TIMEOUT_S)


def test_fresh_recomputes_a_finished_folder(config, reference, tmp_path, pfx_in_process):
    """No signal here: the command line in the test's process."""
    out = tmp_path / "out"
    for arguments in ((), ("--fresh",)):
        done = pfx_in_process("run", config, "--out", out, *arguments)
        assert done.returncode == 0, done.stderr
        assert "up to date" not in done.stderr
    again = pfx_in_process("run", config, "--out", out)
    assert again.returncode == 0 and "up to date" in again.stderr
    pd.testing.assert_frame_equal(_trials(out), reference, check_exact=True)
