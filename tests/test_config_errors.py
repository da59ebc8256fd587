"""Every class of config error, through the real command line, driven by a corpus of files.

The corpus is ``tests/malformed_configs/``: one malformed config per file (``NN-short-name.yaml``),
each starting with

    # expect: <key path, or -> [@line:column] | <reason fragment> [| <reason fragment> ...]

and, for a known pfx defect, a second line ``# xfail: <reason>`` (the case is then a strict xfail).
Entries that cannot carry a comment (empty and binary files) and entries the test creates itself
(a missing file, a directory, a path through a regular file, a Unix socket, a file over the size
limit) are described in ``malformed_configs/EXPECTATIONS.yaml``.

Each entry is given to ``pfx validate`` and, for a representative subset, to
``pfx run good.yaml ENTRY --out out`` (a valid config first: nothing may run, since every config
is checked first). The contract (docs/configuration.md#reading-and-validation): exit status 2, stderr exactly one line
``pfx: error: <file>[:line:col]: [<key path>: ]<reason>``, no traceback, no pydantic internals,
nothing written, no code executed (YAML python tags), alias bombs refused before expansion.

A module fixture runs every invocation through the command line's entry point in the test's
process (``pfx_in_process``: a subprocess per entry would cost two seconds of CPU each and
prove nothing more); each test checks its own. A few of them (THROUGH_A_PROCESS) also run as
real ``python -m pfx`` processes, which must give the same exit status, stdout and stderr.
"""

from __future__ import annotations

import re
import shutil
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import pytest
import yaml
from conftest import tiny_config_dict, write_config_file

CORPUS = Path(__file__).resolve().parent / "malformed_configs"
GOOD = "good.yaml"          # a valid config given before the bad one to `pfx run`
PREFIX = "pfx: error: "
MAX_FILE_BYTES = 10 * 1024 * 1024

# `pfx run --out out` on these too (by short name: the part after 'NN-'): one per family of checks
RUN_SUBSET = {
    "yaml-bad-indentation", "python-object-apply-tag", "alias-bomb", "unknown-key-filter",
    "covariance-not-positive-definite", "sweep-bad-value", "diffusion-std-wrong-length",
}


@dataclass
class Entry:
    id: str                             # corpus name without its extension
    target: str                         # what is passed on the command line (relative to the case folder)
    key: Optional[str]                  # key path the message must name (None: no key)
    reason: tuple[str, ...]             # substrings of the reason (case-insensitive)
    location: Optional[str] = None      # 'line:col' the message must carry after the file name
    make: Optional[str] = None          # created by the test instead of copied from the corpus
    xfail: Optional[str] = None
    extra_args: tuple[str, ...] = ()
    content: Optional[str] = None       # for the command-line cases: YAML text of the config

    @property
    def short(self) -> str:
        return re.sub(r"^\d+-", "", self.id)


def _parse_expect(name: str, head: str) -> tuple[Optional[str], Optional[str], tuple[str, ...]]:
    match = re.match(r"# expect: (?P<key>.+?)(?: @(?P<location>\d+:\d+))? \|(?P<reasons>.*)$", head)
    assert match, f"{name}: first line must be '# expect: KEY [@L:C] | reason [| ...]', got {head!r}"
    reasons = tuple(r.strip() for r in match["reasons"].split("|") if r.strip())
    assert reasons, f"{name}: no reason fragment"
    key = None if match["key"] == "-" else match["key"]
    return key, match["location"], reasons


def load_corpus() -> list[Entry]:
    """Every corpus entry with its expectation; fails loudly on an entry without one."""
    table = yaml.safe_load((CORPUS / "EXPECTATIONS.yaml").read_text())
    entries = []
    for path in sorted(CORPUS.iterdir()):
        if not re.match(r"\d\d-", path.name):
            continue
        lines = path.read_bytes().decode("latin-1").splitlines()
        if path.name in table:
            spec = table.pop(path.name)
            entries.append(Entry(path.stem, path.name, spec.get("key"), tuple(spec["reason"]),
                                 xfail=spec.get("xfail")))
            continue
        key, location, reasons = _parse_expect(path.name, lines[0] if lines else "")
        xfail = lines[1][len("# xfail: "):] if len(lines) > 1 and lines[1].startswith("# xfail: ") else None
        entries.append(Entry(path.stem, path.name, key, reasons, location, xfail=xfail))
    for name, spec in table.items():                 # the entries the test creates
        assert "make" in spec, f"EXPECTATIONS.yaml: {name} is neither in the corpus nor made by the test"
        entries.append(Entry(name.split("/")[0].rsplit(".", 1)[0], name, spec.get("key"),
                             tuple(spec["reason"]), make=spec["make"], xfail=spec.get("xfail")))
    return entries


def _tiny_yaml() -> str:
    return yaml.safe_dump(tiny_config_dict(), sort_keys=False)


# Command-line mistakes: not config files, so not in the corpus.
COMMAND_LINE = [
    Entry("set-without-equals", "exp.yaml", None, ("--set", "key.path=value"),
          extra_args=("--set", "filter.particles"), content=_tiny_yaml()),
    Entry("set-unknown-key", "exp.yaml", "--set filter.particels=50",
          ("unknown key filter.particels", "did you mean filter.particles"),
          extra_args=("--set", "filter.particels=50"), content=_tiny_yaml()),
]
RUN_SUBSET.add("set-unknown-key")

ENTRIES = load_corpus() + COMMAND_LINE
MODES = [(entry, mode) for entry in ENTRIES
         for mode in (("validate", "run") if entry.short in RUN_SUBSET else ("validate",))]


def _make(folder: Path, entry: Entry) -> None:
    target = folder / entry.target
    if entry.make == "missing":
        return
    if entry.make == "directory":
        target.mkdir()
        (target / "config.yaml").write_text(_tiny_yaml())
    elif entry.make == "through-a-file":
        target.parent.write_text(_tiny_yaml())          # config.yaml is a file: config.yaml/x cannot exist
    elif entry.make == "socket":
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            server.bind(str(target))                    # the socket file stays after close
        finally:
            server.close()
    elif entry.make == "large":
        text = _tiny_yaml() + "# padding\n" * (MAX_FILE_BYTES // 10 + 1)
        target.write_text(text)
        assert target.stat().st_size > MAX_FILE_BYTES
    else:
        raise AssertionError(f"unknown make: {entry.make}")


def _prepare(folder: Path, entry: Entry, mode: str) -> None:
    folder.mkdir(parents=True)
    if entry.make:
        _make(folder, entry)
    elif entry.content is not None:
        write_config_file(folder, entry.content, entry.target)
    else:
        shutil.copyfile(CORPUS / entry.target, folder / entry.target)
    if mode == "run" and not entry.extra_args:
        write_config_file(folder, tiny_config_dict(name="good"), GOOD)


def _arguments(entry: Entry, mode: str) -> list[str]:
    if mode == "validate":
        return ["validate", entry.target, *entry.extra_args]
    configs = [entry.target] if entry.extra_args else [GOOD, entry.target]
    return ["run", *configs, "--out", "out", *entry.extra_args]


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _run_every(cases, root: Path, runner) -> dict:
    """Run each (entry, mode) once in a folder of its own under ``root``;
    {(id, mode): (folder, files before, result)}."""
    jobs, before = {}, {}
    for index, (entry, mode) in enumerate(cases):
        folder = root / f"{index:03d}-{mode}"           # short: a socket path must stay < 108 bytes
        _prepare(folder, entry, mode)
        before[(entry.id, mode)] = (folder, _listing(folder))
        jobs[(entry.id, mode)] = (_arguments(entry, mode), folder)
    results = runner.many(jobs, timeout=120)    # a safety net (alias bomb, socket), not a timing check
    return {key: (*before[key], results[key]) for key in jobs}


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory, pfx_in_process):
    """Every (entry, mode), through the command line in this process."""
    return _run_every(MODES, tmp_path_factory.mktemp("config-errors"), pfx_in_process)


# Through real processes as well: a YAML error, a python tag (no code runs), an alias bomb (refused
# before it can take the process's memory), a --set mistake on the command line.
THROUGH_A_PROCESS = [("01-yaml-bad-indentation", "validate"), ("13-python-object-apply-tag", "run"),
                     ("16-alias-bomb", "run"), ("set-unknown-key", "run")]


@pytest.fixture(scope="module")
def processes(tmp_path_factory, run_pfx):
    """THROUGH_A_PROCESS, as real ``python -m pfx`` processes started concurrently."""
    cases = [(entry, mode) for entry, mode in MODES if (entry.id, mode) in THROUGH_A_PROCESS]
    return _run_every(cases, tmp_path_factory.mktemp("config-errors-processes"), run_pfx)


def test_corpus_is_complete():
    """The corpus holds >= 50 malformed files (not counting the entries the test makes), every
    expectation names a reason, and the run subset names existing entries."""
    stored = [e for e in ENTRIES if not e.make and e.content is None]
    assert len(stored) >= 50, len(stored)
    assert len({e.id for e in ENTRIES}) == len(ENTRIES), "duplicate corpus ids"
    shorts = {e.short for e in ENTRIES}
    assert RUN_SUBSET <= shorts, RUN_SUBSET - shorts
    assert set(THROUGH_A_PROCESS) <= {(entry.id, mode) for entry, mode in MODES}


PARAMS = [pytest.param(entry, mode, id=f"{entry.id}-{mode}",
                       marks=[pytest.mark.xfail(reason=entry.xfail, strict=True)] if entry.xfail else [])
          for entry, mode in MODES]


@pytest.mark.parametrize("entry, mode", PARAMS)
def test_config_error_is_one_clear_line(entry: Entry, mode: str, outcomes):
    """Exit 2; stderr is one 'pfx: error: FILE[:L:C]: [KEY: ]REASON' line naming the file, the key
    path and the reason; no traceback or pydantic text; nothing written; no code executed."""
    folder, files_before, result = outcomes[(entry.id, mode)]
    assert "Traceback" not in result.output, result.output
    assert result.returncode == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got:\n{result.stderr}"
    line = lines[0]
    assert line.startswith(PREFIX), line
    message = line[len(PREFIX):]
    assert message.startswith(entry.target + ":"), f"the message must start with the file name: {line}"
    if entry.location:
        assert message.startswith(f"{entry.target}:{entry.location}: "), \
            f"expected position {entry.location}: {line}"
    if entry.key:
        assert f": {entry.key}: " in message, f"key path {entry.key!r} not named: {line}"
    for fragment in entry.reason:
        assert fragment.lower() in message.lower(), f"reason lacks {fragment!r}: {line}"
    assert message.rstrip().rsplit(": ", 1)[-1].strip(), f"no reason: {line}"
    for internal in ("pydantic", "[type=", "validation error for"):
        assert internal not in message, f"internal text {internal!r} leaked: {line}"
    assert not re.search(r"\b[A-Z]\w*(Error|Exception)\b", message), f"a Python exception leaked: {line}"
    assert _listing(folder) == files_before, "the command wrote something"
    assert not (folder / "pwned.txt").exists(), "a YAML tag ran code"
    if mode == "run":
        assert result.stdout == ""
        assert not (folder / "out").exists()


@pytest.mark.parametrize("key", THROUGH_A_PROCESS, ids="-".join)
def test_a_real_process_gives_what_the_in_process_command_line_gave(key, processes, outcomes):
    """The exit status is the process's own, and nothing else differs: stdout, stderr, the files."""
    folder, files_before, result = processes[key]
    assert (result.returncode, result.stdout, result.stderr) == outcomes[key][2]
    assert result.returncode == 2
    assert _listing(folder) == files_before
