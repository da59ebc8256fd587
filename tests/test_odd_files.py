"""Files a config names that are not ordinary data files (issue 23: nothing a user writes can crash pfx).

A path in a config may name a device (``/dev/zero`` never ends), a named pipe (opening it waits
for a writer, forever), a folder or a socket: each is refused before it is opened, in one line
naming the config's key, with exit status 2 and nothing written (:mod:`pfx.user_files`). The
size limit holds whatever size a file reports (``/proc`` files report 0). Times whose
differences overflow are refused naming the data file, its line and the column, with no numpy
warning on stderr.

Every command that meets an odd file runs in a real process with a timeout, so that a pipe that
blocks fails the test instead of hanging the suite.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, tiny_config_dict, write_config_file

from pfx.config.plan import build_plan
from pfx.errors import ConfigError

TIMEOUT_S = 60          # a blocked read fails the test (subprocess.TimeoutExpired) after this long


def data_config(folder: Path, measurements: str) -> Path:
    """The tiny config filtering the recorded measurements at ``measurements``."""
    model = {key: value for key, value in tiny_config_dict()["model"].items() if key != "steps"}
    return write_config_file(folder, tiny_config_dict(model=model, data={"measurements": measurements}))


def make_odd_file(kind: str, folder: Path) -> str:
    """Create a file of this kind in ``folder`` (the working folder); return its path as a config gives it."""
    if kind == "device":
        return "/dev/zero"
    if kind == "pipe":
        os.mkfifo(folder / "pipe")
        return "pipe"
    if kind == "directory":
        (folder / "folder").mkdir()
        return "folder"
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind("socket")                   # relative: a socket's path must stay under 108 bytes
    server.close()                          # the socket file stays
    return "socket"


ODD_FILES = {
    "device": "/dev/zero is a device, not a regular file",
    "pipe": "pipe is a named pipe (FIFO), not a regular file",
    "directory": "folder is a directory, not a file",
    "socket": "socket is a socket, not a regular file",
}


@pytest.mark.parametrize("kind", list(ODD_FILES))
def test_a_data_file_that_is_not_a_regular_file_is_refused_at_once(run_pfx, tmp_path, monkeypatch, kind):
    monkeypatch.chdir(tmp_path)
    path = data_config(tmp_path, make_odd_file(kind, tmp_path))
    result = run_pfx("run", path.name, "--out", "out", cwd=tmp_path, timeout=TIMEOUT_S)
    assert result.returncode == 2, result.output
    assert result.stderr.splitlines() == [f"pfx: error: config.yaml: data.measurements: {ODD_FILES[kind]}"]
    assert "Traceback" not in result.output and not (tmp_path / "out").exists()


def test_a_symbolic_link_is_judged_by_the_file_it_names(run_pfx, tmp_path):
    """A link to a regular file is read; a link to a pipe is refused as the pipe is."""
    (tmp_path / "flow.csv").write_text("step,z1\n1,1.0\n2,2.0\n")
    (tmp_path / "link.csv").symlink_to("flow.csv")
    os.mkfifo(tmp_path / "pipe")
    (tmp_path / "pipe-link.csv").symlink_to("pipe")
    path = data_config(tmp_path, "link.csv")
    assert build_plan(yaml.safe_load(path.read_text()), str(path)).cells[0].truth_model.steps == 2
    path = data_config(tmp_path, "pipe-link.csv")
    result = run_pfx("validate", path.name, cwd=tmp_path, timeout=TIMEOUT_S)
    assert result.returncode == 2, result.output
    assert result.stderr.splitlines() == [
        "pfx: error: config.yaml: data.measurements: pipe-link.csv is a named pipe (FIFO), not a regular file"]


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="needs Linux's /proc")
def test_the_size_limit_holds_for_a_file_that_reports_no_size(tmp_path, monkeypatch):
    """/proc files report a size of 0 and hold more: the limit counts the bytes read."""
    import pfx.config.data_files

    assert os.stat("/proc/self/status").st_size == 0
    monkeypatch.setattr(pfx.config.data_files, "MAX_FILE_BYTES", 64)
    path = data_config(tmp_path, "/proc/self/status")
    with pytest.raises(ConfigError) as caught:
        build_plan(yaml.safe_load(path.read_text()), str(path))
    assert str(caught.value) == f"{path}: data.measurements: /proc/self/status is larger than 64 bytes"


def test_times_whose_spacing_overflows_name_the_data_file_line_and_column(pfx_in_process, tmp_path):
    """Finite times whose difference is not a float: the data file's line, not model.dt, and
    no numpy RuntimeWarning on stderr."""
    (tmp_path / "measurements.csv").write_text("time,z1\n-1.7e308,1\n1.7e308,2\n")
    path = data_config(tmp_path, "measurements.csv")
    result = pfx_in_process("run", path.name, "--out", "out", cwd=tmp_path, timeout=TIMEOUT_S)
    assert result.returncode == 2, result.output
    assert result.stderr.splitlines() == [
        "pfx: error: measurements.csv:3: column time: the time since the previous row (1.7e+308 - -1.7e+308) "
        "is too large to be represented as a number: use smaller times (e.g. measured from the first)"]
    assert not (tmp_path / "out").exists()


def test_a_map_file_that_is_a_pipe_is_refused_at_once(run_pfx, tmp_path):
    """sonar_mcl's model.map_file is read like a data file: a pipe does not block the command."""
    raw = yaml.safe_load((REPO_ROOT / "configs" / "examples" / "sonar-mcl.yaml").read_text())
    del raw["model"]["walls"]
    raw["model"]["map_file"] = "pipe"
    os.mkfifo(tmp_path / "pipe")
    path = write_config_file(tmp_path, raw)
    result = run_pfx("validate", path.name, cwd=tmp_path, timeout=TIMEOUT_S)
    assert result.returncode == 2, result.output
    [line] = result.stderr.splitlines()
    assert line.startswith("pfx: error: config.yaml: model.map_file: ") and \
        "map file 'pipe' is a named pipe (FIFO), not a regular file" in line, line


def test_a_plugin_file_that_is_a_pipe_is_refused_at_once(run_pfx, tmp_path):
    """A config's plugin file is read like a data file: a pipe does not block the command."""
    os.mkfifo(tmp_path / "walk.py")
    write_config_file(tmp_path, tiny_config_dict(plugins=["walk.py"]))
    result = run_pfx("validate", "config.yaml", cwd=tmp_path, timeout=TIMEOUT_S)
    assert result.returncode == 2, result.output
    assert result.stderr.splitlines() == [
        "pfx: error: config.yaml: plugins[0]: plugin file walk.py is a named pipe (FIFO), not a regular file"]
