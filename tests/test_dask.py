"""Sweeps on a Dask cluster: `pfx run` in this process (a real process where the test is about
one: an interrupt, an environment without the extra) and local clusters on loopback.

docs/dask.md: the same run goes to Dask distributed with identical results. A sweep of eight
cells, each split into two batches of trials on two workers (so that a cell's batches may come
back out of order), must give trials.csv, steps.csv and summary.csv identical (all but the run-time
columns) to `--executor local`, whether pfx starts the cluster (`dask-local`) or connects to
one (`dask --scheduler`); a worker process killed mid-sweep must lose nothing (Dask reruns
its tasks); an interrupted Dask run must keep its finished cells and resume; a plugin's code
reaches the workers. Without the optional extra, asking for Dask is one error line naming it.

What costs here is processes (each imports pfx, 2 to 4 s of CPU), so the tests share the
session's cluster (tests/conftest.py) wherever a cluster of their own proves nothing more, and
run `pfx` in this process wherever a subprocess proves nothing more.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import REPO_ROOT, PfxResult, _environment, tiny_config_dict, write_config_file

distributed = pytest.importorskip("distributed", reason="the Dask tests need the 'dask' extra (in '.[test]')")

CELLS = 8
SWEEP = {
    "name": "sweep",
    "seed": 11,
    # 20 trials in batches of ten on two worker threads (pfx.run.memory.trials_per_batch, for
    # any particle count up to 6,553): two batches per cell, which may come back out of order,
    # where a local run in one process makes one batch per cell
    "trials": 20,
    "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
              "steps": 40},
    # Whether two executors give identical tables does not depend on the particle count; the
    # tests that act mid-sweep need only that the sweep outlast their reaction (a poll every
    # 20 ms): they act once one or two of the 8 cells are back, and the batches still to run
    # take some 0.3 s on two workers at 1000 particles (about 50 ms each)
    "filter": {"particles": 1000},
    "sweep": {"filter.resampler": ["multinomial", "stratified", "systematic", "residual"],
              "filter.ess_threshold": [1.0, 0.5]},
    "outputs": {"trace_trials": 11, "figures": []},     # traced trials span two batches of ten
}
EXTRA_ERROR = "pfx: error: the Dask executor needs the optional extra: pip install 'pfx[dask]'"
SAFETY_TIMEOUT_S = 180     # against hangs only; nothing here asserts on time


def _pfx(*args) -> list[str]:
    return [sys.executable, "-m", "pfx", *map(str, args)]


def _run(*args, env=None) -> subprocess.CompletedProcess:
    return subprocess.run(_pfx(*args), cwd=REPO_ROOT, env=env or _environment(), capture_output=True,
                          text=True, timeout=SAFETY_TIMEOUT_S, stdin=subprocess.DEVNULL)


def _start(*args) -> subprocess.Popen:
    return subprocess.Popen(_pfx(*args), cwd=REPO_ROOT, env=_environment(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _finished_cells(out: Path) -> list[Path]:
    return sorted((out / "cells").glob("*.trials.csv")) if (out / "cells").is_dir() else []


def _wait_for(condition, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + SAFETY_TIMEOUT_S
    while not condition():
        assert process.poll() is None, f"pfx ended before the test could act: {process.communicate()}"
        assert time.monotonic() < deadline, "safety timeout"
        time.sleep(0.02)


def _in_process_acting(pfx_in_process, args: list, condition, act) -> tuple[PfxResult, object]:
    """Run ``pfx *args`` in this process (its main thread, which pfx's signal handlers need)
    while another thread calls ``act()`` as soon as ``condition()`` holds, checked every 20 ms:
    pfx's result and what ``act`` returned. Fails if pfx ended before the condition held."""
    finished = threading.Event()
    outcome: dict = {}

    def watch() -> None:
        try:
            while not finished.is_set():
                if condition():
                    outcome["acted"] = act()
                    return
                time.sleep(0.02)
        except BaseException as error:      # raised again in the test's thread
            outcome["error"] = error

    watcher = threading.Thread(target=watch, name="pfx-test-watcher", daemon=True)
    watcher.start()
    try:
        result = pfx_in_process(*args, timeout=SAFETY_TIMEOUT_S)
    finally:
        finished.set()
        watcher.join(SAFETY_TIMEOUT_S)
    if "error" in outcome:
        raise outcome["error"]
    assert "acted" in outcome, f"pfx ended before the test could act: {result}"
    return result, outcome["acted"]


def _without_time(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.drop(columns=[c for c in frame.columns if c.startswith("run_time_s")])


def assert_same_tables(out: Path, reference: Path) -> None:
    """Row for row, value for value: trials and summary (but run times), steps byte for byte."""
    for name in ("trials.csv", "summary.csv"):
        pd.testing.assert_frame_equal(_without_time(pd.read_csv(out / name)),
                                      _without_time(pd.read_csv(reference / name)), check_exact=True)
    assert (out / "steps.csv").read_bytes() == (reference / "steps.csv").read_bytes()


def _one_error_line(result) -> str:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    return lines[0]


@pytest.fixture(scope="module")
def config(tmp_path_factory) -> Path:
    return write_config_file(tmp_path_factory.mktemp("dask"), SWEEP, "sweep.yaml")


@pytest.fixture(scope="module")
def cluster(dask_cluster):
    """A Dask cluster as a user would start one: a scheduler and 2 single-threaded worker
    processes (with nannies, which restart a killed worker), on loopback: the session's
    (tests/conftest.py), with both its workers up. A test that kills a worker waits for both
    again: the nanny's restart takes a few seconds."""
    dask_cluster[1].wait_for_workers(2, timeout=SAFETY_TIMEOUT_S)
    return dask_cluster


@pytest.fixture(scope="module")
def runs(config, cluster, tmp_path_factory, pfx_in_process) -> dict[str, Path]:
    """The sweep three ways, in this process (what is compared is what the runs write; where the
    client runs changes nothing of it): locally, on a cluster pfx starts, on the test's cluster."""
    root = tmp_path_factory.mktemp("dask-runs")
    address = cluster[0].scheduler_address
    cluster[1].wait_for_workers(2, timeout=SAFETY_TIMEOUT_S)     # its description names 2 workers
    jobs = {
        "local": (["run", config, "--out", root / "local", "--executor", "local", "--workers", "1"], root),
        "dask-local": (["run", config, "--out", root / "dask-local", "--executor", "dask-local",
                        "--workers", "2"], root),
        "dask": (["run", config, "--out", root / "dask", "--executor", "dask", "--scheduler", address], root),
    }
    results = pfx_in_process.many(jobs, timeout=SAFETY_TIMEOUT_S)
    for name, result in results.items():
        assert result.returncode == 0, f"{name}: {result.output}"
    return {name: root / name for name in jobs} | {"stderr": results}


def test_dask_local_cluster_gives_identical_tables(runs):
    assert len(pd.read_csv(runs["local"] / "trials.csv")) == CELLS * SWEEP["trials"]
    assert_same_tables(runs["dask-local"], runs["local"])
    assert "local Dask cluster at tcp://127.0.0.1:" in runs["stderr"]["dask-local"].stderr


def test_dask_scheduler_gives_identical_tables(runs, cluster):
    assert_same_tables(runs["dask"], runs["local"])
    assert f"the Dask cluster at {cluster[0].scheduler_address}: 2 worker(s)" in runs["stderr"]["dask"].stderr


def test_model_error_on_a_worker_is_the_same_one_line(cluster, pfx_in_process, tmp_path):
    """A batch's exception travels back from the worker: exit 1, 'pfx: error: model ... step'."""
    overflow = {"name": "overflow", "seed": 11, "trials": 3,
                "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
                          "measurement_matrix": [[1.0, 0.0]], "steps": 5},
                "filter": {"particles": 10, "initial": {"kind": "point", "state": [1.0, 0.0]},
                           "model": {"transition_matrix": [[1e300, 0.0], [0.0, 1.0]]}}}  # inf at step 2
    config = write_config_file(tmp_path, overflow, "overflow.yaml")
    result = pfx_in_process("run", config, "--out", tmp_path / "out", "--executor", "dask", "--scheduler",
                            cluster[0].scheduler_address)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert re.search(r"^pfx: error: .*model linear_gaussian\b.*\bstep 2 of the filter",
                     result.stderr.strip().splitlines()[-1])


def _kill_mid_sweep(pfx_in_process, config, out: Path, cluster) -> tuple[PfxResult, int, bool]:
    """The sweep on the test's cluster, run in this process; SIGKILL one worker process once a
    cell is finished and while the scheduler has given that worker tasks. Returns pfx's result,
    the killed process's id and whether the sweep had ended (trials.csv written) at the kill."""
    local, client = cluster
    client.wait_for_workers(2, timeout=SAFETY_TIMEOUT_S)
    pids = client.run(os.getpid)                     # worker address -> its process id
    victim = sorted(pids)[0]

    def kill() -> bool:
        os.kill(pids[victim], signal.SIGKILL)
        return (out / "trials.csv").exists()

    result, ended = _in_process_acting(
        pfx_in_process, ["run", config, "--out", out, "--executor", "dask", "--scheduler", local.scheduler_address],
        lambda: _finished_cells(out) and client.processing(workers=[victim]).get(victim), kill)
    return result, pids[victim], ended


def test_killed_worker_loses_no_result(config, runs, cluster, pfx_in_process, tmp_path):
    """SIGKILL one worker process while it holds tasks: Dask reruns them, the sweep completes."""
    out = tmp_path / "out"
    result, killed, ended = _kill_mid_sweep(pfx_in_process, config, out, cluster)
    assert not ended, "the sweep ended before the kill"
    assert result.returncode == 0, result.stderr
    assert_same_tables(out, runs["local"])
    assert killed not in cluster[1].run(os.getpid).values()     # that process is gone indeed


@pytest.fixture
def allowed_failures(cluster):
    """Set the test cluster's scheduler's ``allowed-failures`` (Dask's limit on worker deaths
    per task) for the test, and put back what it was: ``allowed_failures(0)``."""
    client = cluster[1]

    def set_limit(limit, dask_scheduler=None) -> int:
        previous, dask_scheduler.allowed_failures = dask_scheduler.allowed_failures, limit
        return previous

    before = []
    yield lambda limit: before.append(client.run_on_scheduler(set_limit, limit))
    if before:
        client.run_on_scheduler(set_limit, before[0])


def test_workers_dying_beyond_dasks_limit_end_the_run_in_one_line_keeping_cells(
        config, cluster, allowed_failures, pfx_in_process, tmp_path):
    """With Dask's allowed-failures at 0, one worker death fails its tasks (KilledWorker):
    exit status 1, one error line, the finished cells kept for a resume. On the test's cluster,
    whose limit is put back after the test (its nanny restarts the killed worker)."""
    allowed_failures(0)
    out = tmp_path / "out"
    result, _, _ = _kill_mid_sweep(pfx_in_process, config, out, cluster)
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("pfx: error: Dask workers kept dying while running a batch: ")
    finished = len(_finished_cells(out))
    assert last.endswith(f"; {finished} of {CELLS} cells finished and are kept in {out}; "
                         "run the same command again to resume")
    assert 1 <= finished < CELLS and not (out / "trials.csv").exists()


def test_interrupted_dask_run_keeps_finished_cells_and_resumes(config, runs, cluster, pfx_in_process, tmp_path):
    """Ctrl-C (SIGINT) to a real `pfx run` process on a cluster of its own, mid-sweep; the
    same command resumes (docs/dask.md: with any executor; here on the test's cluster)."""
    out = tmp_path / "out"
    process = _start("run", config, "--out", out, "--executor", "dask-local", "--workers", "2")
    _wait_for(lambda: len(_finished_cells(out)) >= 2, process)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=SAFETY_TIMEOUT_S)

    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr and "interrupted" in stderr
    finished = _finished_cells(out)
    assert 2 <= len(finished) < CELLS
    for path in finished:                            # every kept cell is whole
        assert len(pd.read_csv(path)) == SWEEP["trials"]
    assert not (out / "trials.csv").exists()

    resumed = pfx_in_process("run", config, "--out", out, "--executor", "dask", "--scheduler",
                             cluster[0].scheduler_address)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{len(finished)} of {CELLS} cells already done" in resumed.stderr
    assert_same_tables(out, runs["local"])
    assert not (out / "cells").exists()


def test_dask_runs_plugin_models(pfx_in_process, tmp_path, cluster):
    """The minimal plugin of tests/test_plugins.py: its code reaches the cluster's worker
    processes, which never imported it, and they compute what a local run does."""
    from test_plugins import minimal_config, write_plugin

    write_plugin(tmp_path)
    config = write_config_file(tmp_path, minimal_config(trials=6, arms={"pf": {"kind": "particle"},
                                                                        "ekf": {"kind": "ekf"}}))
    local = pfx_in_process("run", config, "--out", "local", cwd=tmp_path)
    dask = pfx_in_process("run", config, "--out", "dask", "--executor", "dask", "--scheduler",
                          cluster[0].scheduler_address, cwd=tmp_path)
    assert local.returncode == 0 and dask.returncode == 0, local.output + dask.output
    columns = ["cell", "trial", "rmse_position", "log_likelihood"]
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "local" / "trials.csv")[columns],
                                  pd.read_csv(tmp_path / "dask" / "trials.csv")[columns])


@pytest.fixture
def without_dask(tmp_path) -> dict[str, str]:
    """An environment where `import distributed` fails, as where the extra is not installed."""
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "distributed.py").write_text("raise ImportError('distributed is not installed (test shim)')\n")
    env = _environment()
    env["PYTHONPATH"] = os.pathsep.join([str(shim), env["PYTHONPATH"]])
    return env


@pytest.mark.parametrize("executor", [["--executor", "dask-local"],
                                      ["--executor", "dask", "--scheduler", "tcp://127.0.0.1:8786"]])
def test_without_the_extra_dask_is_one_line_naming_it(monkeypatch, pfx_in_process, tmp_path, executor):
    """In this process, with `import distributed` failing as where the extra is not installed
    (None in sys.modules: Python's own way to make an import fail), and pfx's Dask executor
    not yet imported, as in a fresh process."""
    monkeypatch.setitem(sys.modules, "distributed", None)
    monkeypatch.delitem(sys.modules, "pfx.run.executors.dask", raising=False)
    config = write_config_file(tmp_path, tiny_config_dict(), "tiny.yaml")
    result = pfx_in_process("run", config, "--out", tmp_path / "out", *executor)
    assert _one_error_line(result) == EXTRA_ERROR
    assert not (tmp_path / "out").exists()


def test_without_the_extra_local_runs_still_work(without_dask, tmp_path):
    """A fresh process, which imports only what a local run needs: none of it may need Dask.
    (The figures left out: drawing them is matplotlib's work, whatever the executor.)"""
    config = write_config_file(tmp_path, tiny_config_dict(outputs={"trace_trials": 2, "figures": []}), "tiny.yaml")
    result = _run("run", config, "--out", tmp_path / "out", "--quiet", env=without_dask)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "trials.csv").is_file()


MISTAKES = {
    "dask without a scheduler": (["--executor", "dask"], "needs --scheduler ADDRESS"),
    "workers of a cluster": (["--executor", "dask", "--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"],
                             "--workers: a Dask cluster has its own workers"),
    "scheduler for local": (["--scheduler", "tcp://127.0.0.1:8786"], "--scheduler: only --executor dask"),
    "scheduler for dask-local": (["--executor", "dask-local", "--scheduler", "tcp://127.0.0.1:8786"],
                                 "--scheduler: dask-local starts its own scheduler"),
    "unknown executor": (["--executor", "dsk"], "--executor: unknown executor 'dsk' (did you mean 'dask'?)"),
}


@pytest.fixture(scope="module")
def mistakes(tmp_path_factory, pfx_in_process):
    """Every option mistake, through the command line in this process: name -> (result, its result folder)."""
    root = tmp_path_factory.mktemp("dask-mistakes")
    config = write_config_file(root, tiny_config_dict(), "tiny.yaml")
    results = pfx_in_process.many({name: (["run", config, "--out", root / str(index), *options], root)
                                   for index, (name, (options, _)) in enumerate(MISTAKES.items())})
    return {name: (results[name], root / str(index)) for index, name in enumerate(MISTAKES)}


@pytest.mark.parametrize("name", list(MISTAKES))
def test_executor_option_mistakes_are_one_line(mistakes, name):
    result, out = mistakes[name]
    line = _one_error_line(result)
    assert line.startswith("pfx: error: ") and MISTAKES[name][1] in line
    assert not out.exists()


def test_unreachable_scheduler_is_one_line_and_writes_nothing(pfx_in_process, tmp_path):
    import dask.config

    with socket.socket() as probe:                   # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = write_config_file(tmp_path, tiny_config_dict(), "tiny.yaml")
    # Dask's own setting (DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT for a process); default 30 s
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        result = pfx_in_process("run", config, "--out", tmp_path / "out", "--executor", "dask", "--scheduler",
                                f"tcp://127.0.0.1:{port}")
    line = _one_error_line(result)
    assert f"--scheduler: cannot connect to the Dask scheduler at tcp://127.0.0.1:{port}" in line
    assert not (tmp_path / "out").exists()


def test_workers_with_another_pfx_are_refused(pfx_in_process, tmp_path):
    """A worker whose installed pfx differs (here: package metadata of another version) would
    compute with other code: the run is refused before anything is written."""
    shim = tmp_path / "other-pfx"
    (shim / "pfx-0.0.1.dist-info").mkdir(parents=True)
    (shim / "pfx-0.0.1.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: pfx\nVersion: 0.0.1\n")
    env = _environment()
    env["PYTHONPATH"] = os.pathsep.join([str(shim), env["PYTHONPATH"]])
    with distributed.LocalCluster(n_workers=0, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                  silence_logs=logging.CRITICAL) as scheduler, \
            distributed.Client(scheduler, set_as_default=False) as client:
        # A worker started with Dask's own command, in an environment of its own.
        worker = subprocess.Popen([sys.executable, "-m", "dask", "worker", scheduler.scheduler_address,
                                   "--nthreads", "1", "--no-nanny", "--no-dashboard", "--host", "127.0.0.1"],
                                  env=env, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            client.wait_for_workers(1, timeout=SAFETY_TIMEOUT_S)
            config = write_config_file(tmp_path, tiny_config_dict(), "tiny.yaml")
            result = pfx_in_process("run", config, "--out", tmp_path / "out", "--executor", "dask",
                                    "--scheduler", scheduler.scheduler_address)
        finally:
            worker.terminate()
            worker.wait(timeout=SAFETY_TIMEOUT_S)
    line = _one_error_line(result)
    assert "has pfx 0.0.1, this client pfx 0.1.0" in line and "same pfx version" in line
    assert not (tmp_path / "out").exists()
