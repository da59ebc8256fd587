"""A result folder's record of how it was made: ``config.yaml`` (the config as it ran, its data
files named relative to the folder, its plugins' code copied beside it) and the provenance every
``manifest.json`` starts with (the config's hashes, the software, the machine, the times).

:mod:`pfx.run.runner` writes them for a filter run or a study, :mod:`pfx.run.estimation` for an
estimation run (handed these functions), so every kind of folder records the same things.
``pfx reproduce`` then moves the plugin copies of each folder it writes into its gallery's store
(:func:`store_plugin_copies`; :mod:`pfx.config.plugin_record` says why and how they are named).
"""

from __future__ import annotations

import hashlib
import os
import platform
import shutil
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple, Optional

import numpy as np
import yaml

import pfx
from pfx.config.plan import Plan, StudyPlan
from pfx.config.plugin_record import copied_entries, copy_paths, is_own_copy, stored_name
from pfx.config.plugins import PLUGIN_COPIES
from pfx.config.time_units import time_unit
from pfx.result_folder import read_manifest, write_bytes, write_manifest, write_text


def git_revision() -> Optional[str]:
    try:
        output = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(pfx.__file__).parent,
                                capture_output=True, text=True, timeout=5)
        return output.stdout.strip() or None if output.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def write_record_config(plan: Plan | StudyPlan, out: Path) -> None:
    """The folder's ``config.yaml``, the config as it ran, and beside it in ``plugins/`` a copy of
    each plugin file's code (the very bytes that ran, whose sha256 the manifest records), which
    its ``plugins:`` list names: the folder reruns from anywhere, on its own."""
    resolved = plan.resolved
    if resolved.get("data"):
        resolved = {**resolved, "data": {key: path if path is None else _recorded_path(path, out)
                                         for key, path in resolved["data"].items()}}
    if plan.plugins:
        for plugin, copy in zip(plan.plugins, copy_paths(plan.plugins)):
            if copy is not None:
                (out / PLUGIN_COPIES).mkdir(exist_ok=True)
                write_bytes(plugin.source, out / copy)
        resolved = {**resolved, "plugins": copied_entries(plan.plugins)}
    write_text(yaml.safe_dump(resolved, sort_keys=False), out / "config.yaml")


def store_plugin_copies(folder: Path, store: Path) -> None:
    """Move the copies a result folder keeps of its plugin files (``plugins/<name>``) into its
    gallery's ``store``, once per content (``<stem>-<sha12>.py``), and name them there, relative to
    the folder, in its ``config.yaml`` and its manifest's ``copy`` entries: what ``pfx reproduce``
    does with each folder it writes. Only the paths change, never a hash
    (:func:`pfx.config.plugin_record.recorded_names`); a folder without copies of its own is left as it is."""
    folder = Path(folder)
    config_file = folder / "config.yaml"
    config = yaml.safe_load(config_file.read_text(encoding="utf-8")) if config_file.is_file() else None
    entries = config.get("plugins") if isinstance(config, dict) else None
    moved: dict[str, str] = {}
    for entry in entries or []:
        if not (isinstance(entry, str) and is_own_copy(entry)):
            continue
        source = (folder / entry).read_bytes()
        stored = Path(store) / stored_name(Path(entry).name, hashlib.sha256(source).hexdigest())
        if not (stored.is_file() and stored.read_bytes() == source):
            stored.parent.mkdir(parents=True, exist_ok=True)
            write_bytes(source, stored)
        moved[entry] = Path(os.path.relpath(os.path.abspath(stored), os.path.abspath(folder))).as_posix()
    if not moved:
        return
    manifest = read_manifest(folder)
    write_text(yaml.safe_dump({**config, "plugins": [moved.get(entry, entry) for entry in entries]},
                              sort_keys=False), config_file)
    if manifest:
        for record in manifest.get("plugins", []):
            if isinstance(record, dict) and record.get("copy") in moved:
                record["copy"] = moved[record["copy"]]
        write_manifest(manifest, folder)
    shutil.rmtree(folder / PLUGIN_COPIES)


def _recorded_path(path: str, out: Path) -> str:
    """A data file's path as the folder's config.yaml records it: relative to the folder (a
    config's paths are read relative to its own folder), so that a repository holding both, cloned
    anywhere, keeps the same record; absolute where the two share no folder but the root."""
    folder = Path(out).resolve()
    if os.path.commonpath([os.path.abspath(path), str(folder)]) == folder.anchor:
        return str(path)
    return Path(os.path.relpath(path, folder)).as_posix()


def provenance(plan: Plan | StudyPlan, started: str) -> dict:
    """What every manifest records: the config, the software, the machine, the times."""
    return {
        "name": plan.experiment.name,
        "description": plan.experiment.description,
        "config_file": plan.file,
        "config_hash": plan.config_hash,
        "results_hash": plan.results_hash,
        "seed": plan.experiment.seed,
        "pfx_version": pfx.__version__,
        "git_revision": git_revision(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "platform": platform.platform(),
        "started": started,
        "finished": None,
        "complete": False,
        "figures": list(plan.experiment.outputs.figures),
        "formats": list(plan.experiment.outputs.formats),
        **plugins_record(plan),
    }


def plugins_record(plan: Plan | StudyPlan) -> dict:
    """The manifest's ``plugins`` (nothing for a config without plugins): each plugin's name as
    written, its file, its code's sha256 and, for a file plugin, its copy as config.yaml names it."""
    if not plan.plugins:
        return {}
    return {"plugins": [plugin.record(copy) for plugin, copy in zip(plan.plugins, copy_paths(plan.plugins))]}


class FigureChange(NamedTuple):
    """The figures and formats a config asks for, those a folder's manifest had, and the
    figures dropped."""

    figures: list
    formats: list
    old_figures: list
    old_formats: list
    removed: list


def drop_stale_figures(out: Path, manifest: dict, outputs) -> FigureChange:
    """Before a finished folder's record is brought up to a config that changed only its outputs:
    delete the figure files the config no longer asks for (a figure dropped, or a format; a
    GIF animation stays)."""
    figures, formats = list(outputs.figures), list(outputs.formats)
    old_figures, old_formats = manifest.get("figures", []), manifest.get("formats", ["png"])
    removed = [name for name in old_figures if name not in figures]
    for path in (out / "figures").glob("*") if (out / "figures").is_dir() else []:
        name, extension = path.stem, path.suffix.lstrip(".")
        if name in removed or (name in figures and extension not in formats and extension != "gif"):
            path.unlink()
    return FigureChange(figures, formats, old_figures, old_formats, removed)


def run_manifest(plan: Plan, started: str) -> dict:
    """A filter run's manifest as it starts. Its ``units`` are the model's, but the time's: the
    config's ``time_unit`` where it sets one (:func:`pfx.config.time_units.time_unit`)."""
    model = plan.cells[0].truth_model
    return {
        **provenance(plan, started),
        "trials": plan.experiment.trials,
        "label_columns": plan.label_columns,
        "legend_columns": plan.legend_columns,
        "units": {"time": time_unit(plan.resolved, model), "position": model.position_unit,
                  **{f"state_{n}": u for n, u in zip(model.state_names, model.state_units)}},
        "position_states": [model.state_names[i] for i in model.position_components],
        "angular_states": [model.state_names[i] for i in model.angular_components],
        "full_turn": model.full_turn,
        "cells": [{"cell": c.key, **c.labels, **_auxiliary_mark(c)} for c in plan.cells],
        # every trial filters the same recorded measurements: one dataset (figures need to know)
        **({"recorded_data": True} if plan.cells[0].data is not None else {}),
    }


def _auxiliary_mark(cell) -> dict:
    """``auxiliary: true`` for a cell of the auxiliary particle filter, whose ESS (that of its
    second-stage weights) figures must name; its labels say so only when the setting is swept."""
    auxiliary = cell.filter.uses_particles and getattr(cell.filter, "auxiliary", False)
    return {"auxiliary": True} if auxiliary and "auxiliary" not in cell.labels else {}
