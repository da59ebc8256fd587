"""The result folder's state: what a run may do with a folder that already holds results.

A folder belongs to the results its ``manifest.json`` describes. Its ``results_hash`` covers
what the numbers depend on (cells, seed, traced trials; see
:attr:`pfx.config.plan.Plan.results_hash`), so a run of a config that differs only in its
name, description, figures or trial count keeps the results:

=====================================  ==========================================================
folder                                 a run with the same results hash
=====================================  ==========================================================
empty or missing                       runs everything
finished, same trials                  up to date; rewrites the record and renders figures if
                                       the outputs asked for changed
finished, fewer trials than asked      extends it: runs only the new trials (each trial has its
                                       own random streams), then merges
finished, more trials than asked       refused (the extra trials would be dropped)
interrupted (``cells/`` kept)          resumes the same run; another trial count is refused
=====================================  ==========================================================

A folder with another results hash, or not made by pfx, is refused unless ``--fresh``.
Everything here only reads or refuses, apart from :func:`clear_outputs` and :func:`folder_lock`.
"""

from __future__ import annotations

import json
import os
import shutil
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from pfx.errors import ConfigError

LOCK_FILE = ".pfx.lock"
MANIFEST = "manifest.json"
CELLS = "cells"


@dataclass
class FolderState:
    """What a result folder holds for a run that may write to it."""

    manifest: Optional[dict] = None     # None: nothing there yet (or --fresh)
    kept_trials: int = 0                # trials per cell already in its tables (a finished run)
    done: set[str] = field(default_factory=set)     # cells finished in cells/ (an interrupted run)

    @property
    def complete(self) -> bool:
        return bool(self.manifest and self.manifest.get("complete"))


def read_manifest(out: Path) -> Optional[dict]:
    """The folder's manifest, or None if it has none or it is unreadable."""
    try:
        manifest = json.loads((Path(out) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def finished_manifest(out: Path, *, needs: tuple[str, ...] = ()) -> dict:
    """The manifest of a finished result folder (that also holds the files ``needs``); else
    a ConfigError naming the folder: the one check that commands reading a folder use."""
    manifest = read_manifest(out)
    missing = [name for name in needs if not (Path(out) / name).is_file()]
    if manifest is None or manifest.get("complete") is not True or missing:
        wanted = " and ".join(["a complete manifest.json", *missing])
        raise ConfigError(f"not a finished pfx result folder (no {wanted})", file=str(out))
    return manifest


def record_figures(out: Path, names: list[str]) -> None:
    """Add figures to a finished folder's record (manifest and config.yaml), so that ``pfx
    figures`` renders them again and a rerun of the config keeps or drops them knowingly."""
    import yaml

    from pfx.config.plan import canonical_hash
    from pfx.tables import write_text

    manifest = read_manifest(out)
    new = [name for name in names if name not in manifest.get("figures", [])]
    if not new:
        return
    manifest["figures"] = [*manifest.get("figures", []), *new]
    config_path = Path(out) / "config.yaml"
    if config_path.is_file():
        config = yaml.safe_load(config_path.read_text())
        config.setdefault("outputs", {})["figures"] = manifest["figures"]
        write_text(yaml.safe_dump(config, sort_keys=False), config_path)
        manifest["config_hash"] = canonical_hash(config)
    write_text(json.dumps(manifest, indent=2), Path(out) / MANIFEST)


def inspect_folder(plan, out: Path, fresh: bool) -> FolderState:
    """What ``out`` holds for this plan; refuse, without touching anything, a folder it may not
    write to (see the module docstring)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError("result path exists and is not a folder", file=str(out))
    if fresh or not out.exists() or not [p for p in out.iterdir() if p.name != LOCK_FILE]:
        return FolderState()
    if not (out / MANIFEST).exists():
        raise ConfigError("result folder exists and was not made by pfx; choose another --out or "
                          "use --fresh", file=str(out))
    manifest = read_manifest(out)
    if manifest is None:
        raise ConfigError("result folder has an unreadable manifest.json; use --fresh", file=str(out))
    if manifest.get("results_hash") != plan.results_hash:
        raise ConfigError(f"result folder holds results of a different config (results hash "
                          f"{manifest.get('results_hash')} != {plan.results_hash}); use --fresh to "
                          "replace them or --out for another folder", file=str(out))
    if not plan.cells:                       # a study: no trials
        return FolderState(manifest=manifest)
    asked, held = plan.experiment.trials, int(manifest.get("trials", 0))
    if manifest.get("complete"):
        if asked < held:
            raise ConfigError(f"result folder holds {held} trials per cell and the config asks for {asked}, "
                              f"which would drop {held - asked}; ask for {held} or more (more extend the "
                              "run), use --fresh to recompute, or --out for another folder", file=str(out))
        return FolderState(manifest=manifest, kept_trials=held)
    if asked != held:
        raise ConfigError(f"result folder holds an interrupted run of {held} trials per cell; finish it "
                          f"first (--trials {held}), or use --fresh", file=str(out))
    done = {path.name.split(".")[0] for path in (out / CELLS).glob("*.trials.csv")}
    return FolderState(manifest=manifest, kept_trials=int(manifest.get("extending_from", 0)), done=done)


def clear_outputs(out: Path, names) -> None:
    """Remove pfx's own outputs from a folder (--fresh): the named files, cells/ and figures/."""
    for name in names:
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / CELLS, ignore_errors=True)
    shutil.rmtree(out / "figures", ignore_errors=True)


@contextmanager
def folder_lock(out: Path):
    """Hold an exclusive lock on the result folder; a second run on it is refused.

    The lock (``.pfx.lock``, flock) dies with its process, so a killed run leaves no stale lock.
    """
    try:
        import fcntl
    except ImportError:          # no flock on this platform: run unlocked
        yield
        return
    handle = open(out / LOCK_FILE, "a+")
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.seek(0)
            holder = handle.read().strip() or "?"
            raise ConfigError(f"another pfx run (pid {holder}) is writing to this result folder; "
                              "wait for it or choose another --out", file=str(out)) from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        yield
    finally:
        handle.close()
