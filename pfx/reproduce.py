"""``pfx reproduce``: run every paper's configs into ``results/<paper>/<experiment>/``.

Each paper has a folder ``configs/papers/<short-name>/`` of ordinary configs (see
``../shared/papers/README.md`` for the short names); reproducing a paper is running them.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from pfx.config.plan import build_plan
from pfx.config.yaml_loading import load_config_file
from pfx.errors import ConfigError
from pfx.registry import closest_name
from pfx.runner import run_plan


def paper_configs(configs_dir: Path) -> dict[str, list[Path]]:
    """Paper short name -> its config files, sorted."""
    if not configs_dir.is_dir():
        return {}
    return {folder.name: sorted(folder.glob("*.yaml"))
            for folder in sorted(configs_dir.iterdir()) if folder.is_dir() and any(folder.glob("*.yaml"))}


def reproduce_papers(papers: list[str], configs_dir: Path, out: Path, *, fresh: bool,
                     report: Callable[[str], None], progress: bool) -> None:
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
    for paper, plan in plans:
        started = time.perf_counter()
        target = out / paper / plan.experiment.name
        run_plan(plan, target, fresh=fresh, report=report, progress=progress)
        report(f"{paper}/{plan.experiment.name}: {time.perf_counter() - started:.1f} s -> {target}")
