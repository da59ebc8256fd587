"""``pfx reproduce``: run every paper's configs into ``results/<paper>/<experiment>/``.

Each paper has a folder ``configs/papers/<short-name>/`` of ordinary configs (the short names
and their documents: ``docs/papers/<short-name>.md``) and a ``paper.yaml`` holding the
document's own numbers; reproducing a paper is running its configs, copying ``paper.yaml``
beside the results, and rewriting the gallery ``results/README.md`` (:mod:`pfx.papers.gallery`).

``results/`` is committed, so a fresh reproduction is computed beside a finished folder and
compared with it (:mod:`pfx.papers.record`): where the numbers agree, the committed tables and
manifest stay as they are, and a fresh clone's ``make reproduce-papers`` leaves ``git status``
clean; where they differ, the new results replace the old and the report says what moved. Before
that comparison, a report that keeps small tables of files the repository leaves out
(:data:`pfx.papers.base.KEPT_TABLES`) writes them into the new folder, so they are part of the record.

The folders of a gallery keep their plugins' code in one store, ``<out>/plugins/`` unless
``--plugin-store`` names another (``make reproduce-benchmarks`` names ``results/plugins/``, so
that the papers' and the benchmarks' galleries share one), once per content, rather than a copy
in each folder (:mod:`pfx.config.plugin_record`): each folder a reproduction writes has its
copies moved there (:func:`pfx.run.folder_record.store_plugin_copies`), and a stored file that no
folder below the store's parent names any more is removed (:func:`prune_plugin_store`).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Callable, Optional

import yaml

from pfx.config.plan import build_plan
from pfx.config.plugins import PLUGIN_COPIES
from pfx.errors import ConfigError
from pfx.papers.base import KEPT_TABLES
from pfx.papers.gallery import write_gallery
from pfx.papers.record import settle, staging_folder
from pfx.registry import closest_name
from pfx.result_folder import ResultFolder, check_writable, read_manifest, write_text
from pfx.run.folder_record import store_plugin_copies
from pfx.run.runner import check_folder, run_plan
from pfx.safe_yaml import load_config_file

PAPER_FILE = "paper.yaml"      # the document's own numbers, not an experiment


def paper_configs(configs_dir: Path) -> dict[str, list[Path]]:
    """Paper short name -> its experiment config files: the folder's, sorted, then the ones
    its ``paper.yaml`` names under ``also_run`` (configs kept elsewhere, e.g. an example whose
    results the section shows, or one that needs a plugin), in that order."""
    if not configs_dir.is_dir():
        return {}
    found = {folder.name: sorted(p for p in folder.glob("*.yaml") if p.name != PAPER_FILE) + _also_run(folder)
             for folder in sorted(configs_dir.iterdir()) if folder.is_dir()}
    return {paper: files for paper, files in found.items() if files}


def _also_run(folder: Path) -> list[Path]:
    """The configs ``folder/paper.yaml`` lists under ``also_run`` (paths relative to the folder)."""
    numbers = folder / PAPER_FILE
    if not numbers.exists():
        return []
    listed = (load_config_file(numbers) or {}).get("also_run") or []
    if not isinstance(listed, list):
        raise ConfigError("also_run must be a list of config files (relative to this folder)",
                          file=str(numbers), key="also_run")
    paths = []
    for index, name in enumerate(listed):
        path = folder / str(name)
        if not (isinstance(name, str) and path.suffix == ".yaml" and path.is_file()):
            raise ConfigError(f"no config file {name!r} (paths are relative to {folder})",
                              file=str(numbers), key=f"also_run[{index}]")
        paths.append(path)
    return paths


def reproduce_papers(papers: list[str], configs_dir: Path, out: Path, *, fresh: bool,
                     report: Callable[[str], None], progress: bool, plugin_store: Optional[Path] = None) -> None:
    store = plugin_store if plugin_store is not None else out / PLUGIN_COPIES
    available = paper_configs(configs_dir)
    for paper in papers:
        if paper not in available:
            hint = closest_name(paper, available)
            raise ConfigError(f"no configs for paper {paper!r}" + (f" (did you mean {hint!r}?)" if hint else ""),
                              file=str(configs_dir))
    chosen = papers or list(available)
    if not chosen:
        report(f"no paper configs under {configs_dir}/ yet: nothing to reproduce")
        return
    # Validate everything before running anything.
    plans = [(paper, build_plan(load_config_file(path), str(path)))
             for paper in chosen for path in available[paper]]
    numbers = {paper: load_config_file(configs_dir / paper / PAPER_FILE)
               for paper in chosen if (configs_dir / paper / PAPER_FILE).exists()}
    # And every folder before writing any: the gallery's, then each experiment's.
    check_writable(out, "results folder")
    for paper, plan in plans:
        check_folder(plan, out / paper / plan.experiment.name, fresh)
    for paper, plan in plans:
        started = time.perf_counter()
        target = out / paper / plan.experiment.name
        outcome = _reproduce(paper, plan, target, store, fresh=fresh, report=report, progress=progress)
        report(f"{paper}/{plan.experiment.name}: {time.perf_counter() - started:.1f} s -> {target}{outcome}")
    removed = prune_plugin_store(store)
    if removed:
        report(f"{store}: removed {', '.join(removed)}, which no result folder names any more")
    for paper, document in numbers.items():
        write_text(yaml.safe_dump(document, sort_keys=False, allow_unicode=True), out / paper / PAPER_FILE)
    report(f"gallery: {write_gallery(out)}")


def finished_manifest_or_none(folder: Path):
    """The manifest of a finished result folder, or None."""
    manifest = read_manifest(folder) if folder.is_dir() else None
    return manifest if manifest and manifest.get("complete") else None


def write_kept_tables(paper: str, experiment: str, folder: Path) -> None:
    """Write the small tables ``paper``'s report keeps of ``experiment``'s folder (its
    :data:`~pfx.papers.base.KEPT_TABLES` entry; nothing for a paper that has none)."""
    if paper in KEPT_TABLES:
        KEPT_TABLES[paper](experiment, folder)


def _reproduce(paper: str, plan, target: Path, store: Path, *, fresh: bool, report: Callable[[str], None],
               progress: bool) -> str:
    """Run one experiment of ``paper`` into ``target``, its plugins' code kept in the gallery's
    ``store``; a fresh run over a finished folder goes through a staging folder (beside the target,
    so that it names the store by the same relative path) and keeps the committed record where the
    numbers agree. Returns what happened to the record, in words (empty when there was none to compare with)."""
    if not (fresh and finished_manifest_or_none(target)):
        run_plan(plan, target, fresh=fresh, report=report, progress=progress)
        store_plugin_copies(target, store)
        write_kept_tables(paper, plan.experiment.name, target)
        return ""
    staging = staging_folder(target)
    shutil.rmtree(staging, ignore_errors=True)      # a reproduction stopped before it settled
    run_plan(plan, staging, fresh=True, report=report, progress=progress)
    store_plugin_copies(staging, store)
    write_kept_tables(paper, plan.experiment.name, staging)
    difference = settle(target, staging)
    if difference is None:
        return " (the same numbers as the folder held: its tables and manifest kept)"
    return f" (new numbers: {difference})"


def prune_plugin_store(store: Path) -> list[str]:
    """Remove from a plugin store the files that no result folder below the store's parent names
    in its ``config.yaml`` any more (the code of results since recomputed with a changed plugin),
    so that the store holds the code of the galleries' results and nothing else. Returns the
    names removed."""
    if not store.is_dir():
        return []
    named = set()
    for config in store.parent.rglob("config.yaml"):
        entries = ResultFolder(config.parent).config.get("plugins")
        if isinstance(entries, list):
            named.update((config.parent / entry).resolve() for entry in entries if isinstance(entry, str))
    unused = sorted(path for path in store.glob("*.py") if path.resolve() not in named)
    for path in unused:
        path.unlink()
    return [path.name for path in unused]
