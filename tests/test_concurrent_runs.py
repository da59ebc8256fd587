"""Several runs of the same config into the same new folder at once (issue 23, item 4).

Whatever the interleaving, exactly one run computes; every other one either is refused in one
line naming the folder and the run that holds it (exit status 2), or takes the folder after the
first one finished and finds it up to date (exit status 0). No run deletes a folder another one
is using, and the finished folder is the one a single run writes.

The stress test starts several ``pfx run`` processes together, over several rounds; the
deterministic tests make the two interleavings that broke the lock happen every time, with
two runs in two threads of this process (``flock`` locks belong to an open file, so two opens
of the lock file in one process exclude each other as two processes do):

* a run refused while another is starting must not remove the folder the other has locked;
* a run that locks a lock file its holder removed (folder and all, because it kept nothing)
  after the lock file was opened must start again on a new folder, not write into nothing.
"""

from __future__ import annotations

import importlib
import subprocess
import sys
import threading
from pathlib import Path

import pandas as pd
import yaml
from conftest import REPO_ROOT, _environment, tiny_config_dict

from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.run.runner import run_plan

# the module itself, to replace a function in it (``pfx.run`` is also the API's run function)
runner = importlib.import_module("pfx.run.runner")

RUNS_AT_ONCE = 6
ROUNDS = 2            # each round starts RUNS_AT_ONCE processes (about 2 s of imports each); the
                      # deterministic tests below make the interleavings that once broke the lock every time
TIMEOUT_S = 120        # against hangs only


def _config(folder: Path) -> Path:
    """The tiny particle-filter config (a run lasts a fraction of a second after its imports)."""
    path = folder / "config.yaml"
    path.write_text(yaml.safe_dump(tiny_config_dict(outputs={"trace_trials": 2, "figures": []}), sort_keys=False))
    return path


def _trials(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "trials.csv").drop(columns="run_time_s")


def _start(config: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pfx", "run", str(config), "--out", str(out)], cwd=REPO_ROOT,
                            env=_environment(), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def test_runs_started_together_on_one_folder(tmp_path, pfx_in_process):
    config = _config(tmp_path)
    # the reference, a single run, needs no process of its own: the command line in this process
    clean = pfx_in_process("run", config, "--out", tmp_path / "clean", cwd=REPO_ROOT)
    assert clean.returncode == 0, clean.stderr
    reference = _trials(tmp_path / "clean")
    for round_number in range(ROUNDS):
        out = tmp_path / f"round-{round_number}" / "out"
        processes = [_start(config, out) for _ in range(RUNS_AT_ONCE)]
        outcomes = []
        for process in processes:
            stdout, stderr = process.communicate(timeout=TIMEOUT_S)
            outcomes.append((process.pid, process.returncode, stdout, stderr))
        for pid, status, stdout, stderr in outcomes:
            where = f"round {round_number}, pid {pid}: exit {status}\n{stderr}"
            assert "Traceback" not in stdout + stderr, where
            assert status in (0, 2), where
            if status == 2:
                [line] = stderr.splitlines()
                assert line.startswith(f"pfx: error: {out}: another pfx run (pid "), where
        computed = [pid for pid, status, _, stderr in outcomes if status == 0 and "up to date" not in stderr]
        assert len(computed) == 1, f"round {round_number}: runs {computed} computed, exactly one should"
        pd.testing.assert_frame_equal(_trials(out), reference, check_exact=True)
        assert sorted(path.name for path in out.iterdir()) == sorted(path.name for path in (tmp_path / "clean").iterdir())


# -- two runs in two threads, interleaved the same way every time --------------------------------

WAIT_S = 60            # a step that never comes fails the test instead of hanging it


def _plan(folder: Path):
    return build_plan(tiny_config_dict(outputs={"trace_trials": 2, "figures": []}), str(folder / "config.yaml"))


def _in_thread(name: str, function) -> tuple[threading.Thread, dict]:
    """Start ``function`` in a thread called ``name``; the dict gets its "result" or "error"."""
    outcome: dict = {}

    def target():
        try:
            outcome["result"] = function()
        except BaseException as error:     # noqa: BLE001 - the test reads it
            outcome["error"] = error
        finally:
            outcome["done"] = True
    thread = threading.Thread(target=target, name=name)
    thread.start()
    return thread, outcome


def _wait(event: threading.Event) -> None:
    assert event.wait(WAIT_S), "the other run never reached its step"


def _reference(tmp_path: Path) -> pd.DataFrame:
    run_plan(_plan(tmp_path), tmp_path / "clean")
    return _trials(tmp_path / "clean")


def test_a_refused_run_leaves_the_folder_of_the_run_that_holds_it(tmp_path, monkeypatch):
    """B finds no folder, A makes and locks it, B's mkdir and lock come after: B is refused and
    must not remove the folder (as a run that kept nothing does with a folder it made), which
    A is about to write."""
    reference = _reference(tmp_path)
    out = tmp_path / "out"
    b_before_mkdir, a_locked, b_done = threading.Event(), threading.Event(), threading.Event()
    real_mkdir, real_run = Path.mkdir, runner._run_and_assemble
    paused = set()

    def mkdir(self, *args, **kwargs):
        if threading.current_thread().name == "B" and "B" not in paused:
            paused.add("B")
            b_before_mkdir.set()
            _wait(a_locked)
        return real_mkdir(self, *args, **kwargs)

    def run_and_assemble(*args, **kwargs):
        if threading.current_thread().name == "A":
            a_locked.set()
            _wait(b_done)
        return real_run(*args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    monkeypatch.setattr(runner, "_run_and_assemble", run_and_assemble)
    thread_b, b = _in_thread("B", lambda: run_plan(_plan(tmp_path), out))
    _wait(b_before_mkdir)
    thread_a, a = _in_thread("A", lambda: run_plan(_plan(tmp_path), out))
    _wait(a_locked)
    thread_b.join(WAIT_S)
    b_done.set()
    thread_a.join(WAIT_S)
    assert a.get("done") and b.get("done")
    assert isinstance(b.get("error"), ConfigError) and "another pfx run" in str(b["error"]), b
    assert "error" not in a, a["error"]
    pd.testing.assert_frame_equal(_trials(out), reference, check_exact=True)


def test_a_run_that_locks_a_removed_lock_file_starts_again(tmp_path, monkeypatch):
    """B opens the lock file while A holds it; A fails having kept nothing and removes the
    folder it made; B's lock then succeeds on the removed file: B must make the folder again
    and run, not write into a folder that no longer exists."""
    import fcntl

    reference = _reference(tmp_path)
    out = tmp_path / "out"
    a_locked, b_at_lock, a_done = threading.Event(), threading.Event(), threading.Event()
    real_flock, real_run = fcntl.flock, runner._run_and_assemble
    paused = set()

    def flock(descriptor, operation):
        if threading.current_thread().name == "B" and "B" not in paused:
            paused.add("B")
            b_at_lock.set()
            _wait(a_done)
        return real_flock(descriptor, operation)

    def run_and_assemble(*args, **kwargs):
        if threading.current_thread().name == "A":
            a_locked.set()
            _wait(b_at_lock)
            raise RuntimeError("A fails before any cell finishes")
        return real_run(*args, **kwargs)

    monkeypatch.setattr(fcntl, "flock", flock)
    monkeypatch.setattr(runner, "_run_and_assemble", run_and_assemble)
    thread_a, a = _in_thread("A", lambda: run_plan(_plan(tmp_path), out))
    _wait(a_locked)
    thread_b, b = _in_thread("B", lambda: run_plan(_plan(tmp_path), out))
    thread_a.join(WAIT_S)
    a_done.set()
    thread_b.join(WAIT_S)
    assert a.get("done") and b.get("done")
    assert isinstance(a.get("error"), RuntimeError), a
    assert "error" not in b, repr(b["error"])
    pd.testing.assert_frame_equal(_trials(out), reference, check_exact=True)
