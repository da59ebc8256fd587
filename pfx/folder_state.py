"""What a run may do with a result folder that already holds results: the folder's state.

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

An estimation folder has iterations instead of trials (:func:`_estimation_contents`): a
finished one with more iterations than asked is refused, one with the same config is up to
date, an interrupted one is resumed (with more iterations than it holds, extended).

A folder with another results hash, or not made by pfx, is refused unless ``--fresh`` (the
refusal names the keys whose values differ from the folder's recorded config:
:func:`changed_keys`); one this process could not write into, before anything is written
(:func:`pfx.result_folder.check_writable`).

One run writes a folder at a time (:func:`pfx.folder_lock.folder_lock`); what a run read before
it held the lock is read again once it does (:func:`inspect_folder`'s ``locked``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import yaml

from pfx.errors import ConfigError
from pfx.folder_lock import LOCK_FILE, held_error, lock_holder
from pfx.result_folder import CELLS, MANIFEST, check_writable, read_manifest


@dataclass
class FolderState:
    """What a result folder holds for a run that may write to it."""

    manifest: Optional[dict] = None     # None: nothing there yet (or --fresh)
    kept_trials: int = 0                # trials per cell already in its tables (a finished run)
    done: set[str] = field(default_factory=set)     # cells finished in cells/ (an interrupted run)

    @property
    def complete(self) -> bool:
        return bool(self.manifest and self.manifest.get("complete"))


def up_to_date_note(out: Path, config_hash: str) -> str:
    """What a run says of a finished folder that already holds its config's results."""
    return f"{out}: up to date (same config hash {config_hash}); nothing to do (--fresh recomputes)"


def inspect_folder(plan, out: Path, fresh: bool, *, locked: bool = False) -> FolderState:
    """What ``out`` holds for this plan; refuse, without touching anything, a folder it may not
    write to (see the module docstring) or could not write to (:func:`check_writable`).

    ``locked``: this process holds the folder's lock (:func:`folder_lock`), so what it reads
    is settled. Without the lock, another run may be writing the folder at this very moment:
    what it has written so far (a config.yaml before its manifest, a temporary file) is no
    reason to refuse, so a folder that looks wrong is refused as that run's (naming it) while
    the run holds the lock, and read again once none does.
    """
    out = Path(out)
    check_writable(out)
    if locked or fresh:
        return _contents(plan, out, fresh)
    try:
        return _contents(plan, out, fresh)
    except ConfigError:
        holder = lock_holder(out)
        if holder is not None:
            raise held_error(out, holder) from None
    return _contents(plan, out, fresh)


def _contents(plan, out: Path, fresh: bool) -> FolderState:
    """:func:`inspect_folder`'s reading of the folder's files."""
    try:
        entries = [] if fresh or not out.exists() else [p for p in out.iterdir() if p.name != LOCK_FILE]
    except FileNotFoundError:          # removed since, by a run that kept nothing: as if never made
        entries = []
    if not entries:
        return FolderState()
    if not (out / MANIFEST).exists():
        raise ConfigError("result folder exists and was not made by pfx; choose another --out or "
                          "use --fresh", file=str(out))
    manifest = read_manifest(out)
    if manifest is None:
        raise ConfigError("result folder has an unreadable manifest.json; use --fresh", file=str(out))
    if manifest.get("results_hash") != plan.results_hash:
        raise ConfigError(f"result folder holds results of a different config (results hash "
                          f"{manifest.get('results_hash')} != {plan.results_hash}{_what_changed(plan, out)}); use "
                          "--fresh to replace them or --out for another folder", file=str(out))
    if not plan.cells:                       # a study: no trials
        return FolderState(manifest=manifest)
    if plan.experiment.estimation is not None:
        return _estimation_contents(plan, out, manifest)
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


def _estimation_contents(plan, out: Path, manifest: dict) -> FolderState:
    """An estimation folder with the same results hash: it has no trials, but iterations. A
    finished one holds the manifest's ``iterations`` (fewer asked would drop some: refused); an
    unfinished one is resumed, and its progress files are the estimation run's to read and check
    (:mod:`pfx.run.estimation`), before it writes anything."""
    asked, held = plan.experiment.estimation.iterations, (manifest.get("estimation") or {}).get("iterations")
    if manifest.get("complete") and isinstance(held, int) and asked < held:
        raise ConfigError(f"result folder holds {held} iterations per chain and the config asks for {asked}, which "
                          f"would drop {held - asked}; ask for {held} or more (more extend the chains), use --fresh "
                          "to recompute, or --out for another folder", file=str(out), key="estimation.iterations")
    return FolderState(manifest=manifest)


# The keys of a config that do not enter its results hash (Plan.results_hash): a change there
# keeps a folder's results, so it is never why a folder holds results of a different config.
RECORD_ONLY_KEYS = ("name", "description", "trials", "outputs.figures", "outputs.formats", "estimation.iterations")
# How many changed keys the refusal names; the rest are counted.
CHANGED_KEYS_SHOWN = 5


def _what_changed(plan, out: Path) -> str:
    """``; keys that differ from its record: seed, filter.particles``: the dotted keys whose
    values differ between the config the folder recorded (its ``config.yaml``) and the plan's,
    the first :data:`CHANGED_KEYS_SHOWN` of them; empty where the folder has no readable record."""
    try:
        recorded = yaml.safe_load((out / "config.yaml").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return ""
    if not isinstance(recorded, dict):
        return ""
    keys = changed_keys(recorded, plan.resolved, out)
    if not keys:
        return ("; its config.yaml differs in no key that sets the numbers: its plugins' code, its data files' "
                "contents or the version of pfx that ran it differ")
    shown = ", ".join(keys[:CHANGED_KEYS_SHOWN])
    more = f" and {len(keys) - CHANGED_KEYS_SHOWN} more" if len(keys) > CHANGED_KEYS_SHOWN else ""
    return f"; keys that differ from its record: {shown}{more}"


def changed_keys(recorded: dict, resolved: dict, folder: Path) -> list[str]:
    """The dotted keys (``model.mu``, ``estimation.parameters.model.mu.start``) whose values
    differ between a folder's recorded config and a resolved one, in the resolved config's
    order, then the keys only the record has. A list is one value. The record names its data
    files relative to the folder (:func:`pfx.run.folder_record.write_record_config`), so those
    are compared as the files they reach; the plugins (the record names its copies) and the
    keys that keep the results (:data:`RECORD_ONLY_KEYS`) are left out."""
    old, new = _leaves(recorded), _leaves(resolved)
    for key in old.keys() | new.keys():
        if key.startswith("data.") and isinstance(old.get(key), str) and isinstance(new.get(key), str):
            old[key] = os.path.realpath(Path(folder) / old[key])
            new[key] = os.path.realpath(new[key])
    keys = list(new) + [key for key in old if key not in new]
    return [key for key in keys if old.get(key, _ABSENT) != new.get(key, _ABSENT)
            and key not in RECORD_ONLY_KEYS and key != "plugins" and not key.startswith("plugins.")]


_ABSENT = object()


def _leaves(value, prefix: str = "") -> dict:
    """A nested mapping as ``{dotted key: value}``; lists, numbers, text and empty mappings are leaves."""
    if not isinstance(value, dict) or not value:
        return {prefix: value}
    leaves = {}
    for key, item in value.items():
        leaves.update(_leaves(item, f"{prefix}.{key}" if prefix else str(key)))
    return leaves
