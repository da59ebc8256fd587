"""Result folders pfx cannot write (issue 23: nothing a user writes can crash pfx).

An ``--out`` under a regular file, in a read-only folder, or an existing read-only result
folder is refused before anything is written: one line naming the folder and what is wrong,
exit status 2 (:func:`pfx.result_folder.check_writable`, run by every command that writes:
``pfx run``, ``pfx figures``, ``pfx compare``, ``pfx reproduce``).

Root ignores permission bits, and this suite often runs as root (CI, containers). A test of a
read-only folder then runs pfx as root without the capability that overrides them
(CAP_DAC_OVERRIDE, dropped from the child's bounding set before it executes the interpreter),
so that the modes bind it as they bind any user. Not as the user ``nobody``: the interpreter
may live where only root can reach it (a pyenv under /root). Run by another user, the tests
run pfx as that user.
"""

from __future__ import annotations

import ctypes
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import PfxResult, _environment

TIMEOUT_S = 120         # against hangs only
FAST = {                # one Kalman-filter cell: a run lasts about a second, mostly imports
    "name": "fast",
    "seed": 3,
    "trials": 2,
    "model": {"kind": "linear_gaussian", "steps": 5, "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]]},
    "filter": {"kind": "kf"},
    "outputs": {"figures": []},
}
PR_CAPBSET_DROP, CAP_DAC_OVERRIDE = 24, 1       # <linux/prctl.h>, <linux/capability.h>
# Loaded here, in the parent: a forked child of a threaded process should only call into it.
_LIBC = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith("linux") else None


def _without_permission_override() -> None:        # in the child, before it executes the interpreter
    if _LIBC.prctl(PR_CAPBSET_DROP, CAP_DAC_OVERRIDE, 0, 0, 0) != 0:
        error = ctypes.get_errno()
        raise OSError(error, f"prctl(PR_CAPBSET_DROP, CAP_DAC_OVERRIDE): {os.strerror(error)}")


def run_bound_by_modes(folder: Path, *args) -> PfxResult:
    """``python -m pfx ARGS`` in ``folder``, bound by the permission bits even when this process is root."""
    as_root = os.geteuid() == 0
    if as_root and _LIBC is None:
        pytest.skip("dropping root's permission override needs Linux")
    completed = subprocess.run([sys.executable, "-m", "pfx", *map(str, args)], cwd=folder, env=_environment(),
                               capture_output=True, text=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL,
                               preexec_fn=_without_permission_override if as_root else None)
    return PfxResult(completed.returncode, completed.stdout, completed.stderr)


def write_config(folder: Path, config: dict = FAST) -> Path:
    path = folder / "config.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def read_only(path: Path) -> None:
    """Make a folder and everything in it read-only (folders stay enterable)."""
    for item in [path, *path.rglob("*")]:
        item.chmod(item.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def assert_refused(result: PfxResult, line: str) -> None:
    assert result.returncode == 2, result.output
    assert result.stderr.splitlines() == [f"pfx: error: {line}"]
    assert "Traceback" not in result.output


def test_a_result_folder_under_a_regular_file_is_refused(pfx_in_process, tmp_path):
    write_config(tmp_path)
    (tmp_path / "notes.txt").write_text("not a folder\n")
    result = pfx_in_process("run", "config.yaml", "--out", "notes.txt/out", cwd=tmp_path, timeout=TIMEOUT_S)
    assert_refused(result, "notes.txt/out: cannot create the result folder: notes.txt is a file, not a folder")
    assert (tmp_path / "notes.txt").read_text() == "not a folder\n"


def test_a_result_folder_in_a_read_only_folder_is_refused(tmp_path):
    write_config(tmp_path)
    (tmp_path / "locked").mkdir()
    read_only(tmp_path / "locked")
    result = run_bound_by_modes(tmp_path, "run", "config.yaml", "--out", "locked/runs/fast")
    assert_refused(result, "locked/runs/fast: cannot create the result folder: locked is not writable "
                           "(permission denied); choose another folder")
    assert not any((tmp_path / "locked").iterdir())


def test_a_read_only_result_folder_is_refused(tmp_path):
    write_config(tmp_path)
    (tmp_path / "out").mkdir()
    read_only(tmp_path / "out")
    result = run_bound_by_modes(tmp_path, "run", "config.yaml", "--out", "out")
    assert_refused(result, "out: result folder is not writable (permission denied); choose another folder")
    assert not any((tmp_path / "out").iterdir())


def test_figures_into_a_read_only_folder_are_refused(tmp_path):
    """`pfx figures` re-renders into figures/: a read-only one is refused before drawing."""
    write_config(tmp_path, {**FAST, "outputs": {"figures": ["state_error_over_time"]}})
    made = run_bound_by_modes(tmp_path, "run", "config.yaml", "--out", "out")
    assert made.returncode == 0, made.output
    before = sorted((path.name, path.stat().st_mtime_ns) for path in (tmp_path / "out").rglob("*"))
    read_only(tmp_path / "out")
    result = run_bound_by_modes(tmp_path, "figures", "out")
    assert_refused(result, "out/figures: figures folder is not writable (permission denied); choose another folder")
    assert sorted((path.name, path.stat().st_mtime_ns) for path in (tmp_path / "out").rglob("*")) == before


def test_reproduce_into_a_path_under_a_regular_file_is_refused(pfx_in_process, tmp_path):
    (tmp_path / "papers" / "some-paper").mkdir(parents=True)
    write_config(tmp_path / "papers" / "some-paper")
    (tmp_path / "notes.txt").write_text("not a folder\n")
    result = pfx_in_process("reproduce", "--configs", "papers", "--out", "notes.txt/results", cwd=tmp_path,
                     timeout=TIMEOUT_S)
    assert_refused(result, "notes.txt/results: cannot create the results folder: notes.txt is a file, not a folder")


def test_a_folder_the_checks_pass_but_the_system_refuses_is_one_error(tmp_path, monkeypatch):
    """Root on a read-only file system: the permission checks may pass and the first mkdir still
    fail; the run then ends in the same kind of one-line error, not an OSError."""
    import errno

    from pfx.config.plan import build_plan
    from pfx.errors import ConfigError
    from pfx.run.runner import run_plan

    plan = build_plan(dict(FAST), str(write_config(tmp_path)))

    def read_only_file_system(path, *args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    monkeypatch.setattr(os, "access", lambda *args, **kwargs: True)
    monkeypatch.setattr(os, "mkdir", read_only_file_system)
    with pytest.raises(ConfigError) as caught:
        run_plan(plan, tmp_path / "out")
    assert str(caught.value) == f"{tmp_path / 'out'}: cannot create the result folder: Read-only file system"
