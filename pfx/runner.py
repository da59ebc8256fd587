"""Run a plan: every cell, every trial, in batches; write the result folder.

Work is split into tasks of (cell, batch of trials). A batch runs all its trials at once in
the engine; an executor (:mod:`pfx.executors`: this process, local worker processes, or a
Dask cluster) computes the tasks. Because every trial has its own random streams, batching,
the executor and the number of workers change nothing in the results. Each finished cell is
written atomically to ``cells/`` inside the result folder, by this process alone; when every
cell is done the tables, the summary and the figures are assembled and ``cells/`` is removed.
Running again with the same config resumes from the finished cells; a folder made by a
different config is refused unless ``--fresh`` is given.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pandas as pd
import yaml

import pfx
from pfx.config.plan import Cell, Plan, StudyPlan
from pfx.config.schema import ParticleSnapshots
from pfx.engine import SnapshotRequest, SpreadCriterion, simulate_truth
from pfx.filters import FILTERS
from pfx.errors import ConfigError
from pfx.executors import Executor, make_executor
from pfx.figures import render_figures
from pfx.memory import check_fits, default_budget, trials_per_batch
from pfx.metrics import MetricInputs, compute_metrics, normalised_squares, state_error
from pfx.seeding import TrialStreams, filter_seed, study_generator, truth_seed
from pfx.tables import summarize, write_csv, write_text

LOCK_FILE = ".pfx.lock"
OUTPUT_FILES = ("trials.csv", "steps.csv", "summary.csv", "particles.csv", "scene.csv", "config.yaml",
                "manifest.json")


@dataclass
class BatchResult:
    cell_key: str
    trials: pd.DataFrame
    steps: pd.DataFrame
    wall_time: float
    particles: Optional[pd.DataFrame] = None


def run_batch(cell: Cell, seed: int, trials: list[int], trace_trials: int,
              snapshots: Optional[ParticleSnapshots] = None) -> BatchResult:
    """Simulate the truth and run the filter for some trials of one cell; return table rows."""
    truth_seeds = [truth_seed(seed, t) for t in trials]
    filter_seeds = [filter_seed(seed, cell.stream_key, t) for t in trials]
    states, measurements = simulate_truth(cell.truth_model, TrialStreams.from_seeds(truth_seeds))
    criterion = cell.metrics.convergence
    spread = SpreadCriterion(criterion.radius, criterion.weighted) if criterion.criterion == "spread" else None
    snapshot = None
    if snapshots is not None and snapshots.steps and cell.filter.uses_particles:
        rows = np.array([i for i, t in enumerate(trials) if t < snapshots.trials], dtype=np.intp)
        if rows.size:
            steps_kept = "all" if snapshots.steps == "all" else frozenset(snapshots.steps)
            snapshot = SnapshotRequest(rows=rows, steps=steps_kept, stages=frozenset(snapshots.stages))
    options = {"snapshot": snapshot} if snapshot is not None else {}
    started = time.perf_counter()
    trace = FILTERS[cell.filter.kind](
        cell.filter_model, measurements, TrialStreams.from_seeds(filter_seeds), settings=cell.filter,
        prior=cell.prior, spread_criterion=spread, consistency=cell.metrics.consistency, **options)
    elapsed = time.perf_counter() - started
    truth = states[:, 1:]
    with np.errstate(over="ignore", invalid="ignore"):   # a diverged filter has infinite errors
        metrics = compute_metrics(MetricInputs(truth=truth, trace=trace, model=cell.truth_model,
                                               config=cell.metrics))
    model = cell.truth_model
    rows = pd.DataFrame({"cell": cell.key, **cell.labels, "trial": trials, "seed": seed,
                         "truth_seed": truth_seeds, "filter_seed": filter_seeds, "steps": model.steps,
                         **metrics, "run_time_s": elapsed / len(trials)})
    traced = [i for i, t in enumerate(trials) if t < trace_trials]
    with np.errstate(over="ignore", invalid="ignore"):
        steps = _steps_frame(cell, trials, traced, truth, trace)
    particles = _particles_frame(cell, trials, snapshot) if snapshot is not None else None
    return BatchResult(cell.key, rows, steps, elapsed, particles)


def _particles_frame(cell: Cell, trials: list[int], snapshot: SnapshotRequest) -> pd.DataFrame:
    """particles.csv rows: one per kept particle (cell, labels, trial, step, stage, particle, state, weight)."""
    names = cell.filter_model.state_names
    frames = []
    for cloud in snapshot.clouds:
        rows, n = cloud["state"].shape[:2]
        columns = {"cell": cell.key, **cell.labels,
                   "trial": np.repeat([trials[r] for r in cloud["rows"]], n),
                   "step": cloud["step"], "stage": cloud["stage"], "particle": np.tile(np.arange(n), rows)}
        for j, name in enumerate(names):
            columns[name] = cloud["state"][..., j].ravel()
        columns["weight"] = cloud["weights"].ravel()
        frames.append(pd.DataFrame(columns))
    return pd.concat(frames, ignore_index=True)


def steps_columns(cell: Cell) -> list[str]:
    """The columns of steps.csv for a cell (so that an empty table still has its header)."""
    states = cell.truth_model.state_names
    columns = ["cell", *cell.labels, "trial", "step", "time", *[f"{kind}_{name}" for name in states
                                                               for kind in ("truth", "estimate")],
               "error_distance", "ess", "resampled", "degenerate", "spread", "nees", "nis"]
    return columns + (["within_radius"] if cell.metrics.convergence.criterion == "spread" else [])


def _steps_frame(cell: Cell, trials, traced, truth, trace) -> pd.DataFrame:
    if not traced:
        return pd.DataFrame(columns=steps_columns(cell))
    model = cell.truth_model
    steps = model.steps
    position = list(model.position_components)
    frames = []
    for i in traced:
        error = trace.estimates[i][:, position] - truth[i][:, position]
        columns = {"cell": cell.key, **cell.labels, "trial": trials[i], "step": np.arange(1, steps + 1),
                   "time": model.times()}
        for j, name in enumerate(model.state_names):
            columns[f"truth_{name}"] = truth[i, :, j]
            columns[f"estimate_{name}"] = trace.estimates[i, :, j]
        columns["error_distance"] = np.sqrt(np.sum(error * error, axis=-1))
        columns["ess"] = trace.ess[i]
        columns["resampled"] = trace.resampled[i]
        columns["degenerate"] = trace.degenerate[i]
        columns["spread"] = trace.spread[i]
        columns["nees"] = (normalised_squares(state_error(truth[i], trace.estimates[i], model),
                                              trace.covariances[i])
                           if trace.covariances is not None else np.nan)
        columns["nis"] = trace.nis[i] if trace.nis is not None else np.nan
        if cell.metrics.convergence.criterion == "spread":
            columns["within_radius"] = trace.within_radius[i] if trace.within_radius is not None else np.nan
        frames.append(pd.DataFrame(columns))
    return pd.concat(frames, ignore_index=True)[steps_columns(cell)]


def _git_revision() -> Optional[str]:
    try:
        output = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(pfx.__file__).parent,
                                capture_output=True, text=True, timeout=5)
        return output.stdout.strip() or None if output.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def check_folder(plan: Plan, out: Path, fresh: bool) -> None:
    """Refuse, without touching anything, a result folder this run may not write to."""
    if out.exists() and not out.is_dir():
        raise ConfigError("result path exists and is not a folder", file=str(out))
    if fresh or not out.exists() or not [p for p in out.iterdir() if p.name != LOCK_FILE]:
        return
    manifest_path = out / "manifest.json"
    if not manifest_path.exists():
        raise ConfigError("result folder exists and was not made by pfx; choose another --out or "
                          "use --fresh", file=str(out))
    try:
        manifest = json.loads(manifest_path.read_text())
    except (OSError, ValueError):
        raise ConfigError("result folder has an unreadable manifest.json; use --fresh", file=str(out)) from None
    if manifest.get("config_hash") != plan.config_hash:
        raise ConfigError(f"result folder holds results of a different config (hash "
                          f"{manifest.get('config_hash')} != {plan.config_hash}); use --fresh to "
                          "replace them or --out for another folder", file=str(out))


def prepare_folder(plan: Plan, out: Path, fresh: bool) -> set[str]:
    """Clear the folder for --fresh; return the keys of cells already finished (for resuming)."""
    if fresh and out.exists():
        for name in OUTPUT_FILES:
            (out / name).unlink(missing_ok=True)
        shutil.rmtree(out / "cells", ignore_errors=True)
        shutil.rmtree(out / "figures", ignore_errors=True)
        return set()
    return {path.name.split(".")[0] for path in (out / "cells").glob("*.trials.csv")}


def run_plan(plan: Plan, out: Path, *, workers: int = 1, executor: Optional[Executor] = None,
             fresh: bool = False, report: Callable[[str], None] = lambda message: None,
             progress: bool = False, memory_budget: Optional[int] = None) -> Path:
    """Run every unfinished cell of the plan into ``out``; assemble tables and figures.

    The batches are computed by ``executor`` (see :mod:`pfx.executors`; the caller starts and
    closes it), or by ``workers`` local processes when none is given.

    Interrupted (KeyboardInterrupt, or SIGTERM turned into one by the command line), it stops
    the workers, keeps every finished cell and re-raises; running again resumes.
    """
    out = Path(out)
    if isinstance(plan, StudyPlan):
        return run_study(plan, out, fresh=fresh, report=report)
    budget = memory_budget or default_budget()
    check_fits(plan, budget)
    check_folder(plan, out, fresh)
    out.mkdir(parents=True, exist_ok=True)
    with folder_lock(out):
        done = prepare_folder(plan, out, fresh)
        manifest_path = out / "manifest.json"
        if not fresh and manifest_path.exists() and json.loads(manifest_path.read_text()).get("complete"):
            report(f"{out}: up to date (same config hash {plan.config_hash}); nothing to do (--fresh recomputes)")
            return out
        if done:
            report(f"{out}: resuming (same config hash {plan.config_hash}): {len(done)} of "
                   f"{len(plan.cells)} cells already done, skipping them")
        (out / "cells").mkdir(exist_ok=True)
        manifest = _manifest(plan, started=_now())
        write_text(yaml.safe_dump(plan.resolved, sort_keys=False), out / "config.yaml")
        write_text(json.dumps(manifest, indent=2), manifest_path)
        started = time.perf_counter()
        cell_times: dict[str, float] = {}
        try:
            owned = make_executor("local", workers) if executor is None else nullcontext(executor)
            with owned as running:
                _run_cells(plan, out, [c for c in plan.cells if c.key not in done], running, budget,
                           progress, cell_times)
        except KeyboardInterrupt:
            finished = len(list((out / "cells").glob("*.trials.csv")))
            report(f"{out}: interrupted; {finished} of {len(plan.cells)} cells finished and kept; "
                   "run the same command again to resume")
            raise
        _assemble(plan, out, manifest, cell_times, time.perf_counter() - started)
    return out


def run_study(plan: StudyPlan, out: Path, *, fresh: bool = False,
              report: Callable[[str], None] = lambda message: None) -> Path:
    """Compute a study (:mod:`pfx.studies`) into ``out``: its tables as CSV, then its figures."""
    check_folder(plan, out, fresh)
    out.mkdir(parents=True, exist_ok=True)
    with folder_lock(out):
        manifest_path = out / "manifest.json"
        if not fresh and manifest_path.exists() and json.loads(manifest_path.read_text()).get("complete"):
            report(f"{out}: up to date (same config hash {plan.config_hash}); nothing to do (--fresh recomputes)")
            return out
        for path in [*out.glob("*.csv"), out / "manifest.json", out / "config.yaml"]:
            path.unlink(missing_ok=True)
        shutil.rmtree(out / "figures", ignore_errors=True)
        study = plan.experiment.study
        manifest = {**_provenance(plan, started=_now()), "study": study.kind, "units": dict(study.units)}
        write_text(yaml.safe_dump(plan.resolved, sort_keys=False), out / "config.yaml")
        write_text(json.dumps(manifest, indent=2), manifest_path)
        started = time.perf_counter()
        tables = study.tables(study_generator(plan.experiment.seed))
        for name, table in tables.items():
            write_csv(table, out / f"{name}.csv")
        manifest.update(tables=list(tables), finished=_now(), complete=True,
                        wall_time_s=time.perf_counter() - started)
        write_text(json.dumps(manifest, indent=2), manifest_path)
        render_figures(out, plan.experiment.outputs.figures, tuple(plan.experiment.outputs.formats))
    return out


def batch_arguments(plan: Plan, cell: Cell, trials: list[int]) -> tuple:
    """The arguments of :func:`run_batch` for some trials of a cell: everything a worker needs.

    The one place they are put together; with Dask, this tuple is what travels to a worker.
    """
    outputs = plan.experiment.outputs
    return (cell, plan.experiment.seed, trials, outputs.trace_trials, outputs.particles)


def _run_cells(plan: Plan, out: Path, cells: list[Cell], executor: Executor, budget: int, progress: bool,
               cell_times: dict) -> None:
    """Hand every batch of every cell to the executor; write each cell once all its batches are back."""
    experiment = plan.experiment
    trials = list(range(experiment.trials))
    tasks, owner, sizes = [], [], []          # per task: its arguments, its cell's number, its trial count
    expected = []                             # per cell: its number of batches
    for number, cell in enumerate(cells):
        size = trials_per_batch(cell, len(trials), budget, executor.slots)
        batches = [trials[start:start + size] for start in range(0, len(trials), size)]
        for batch in batches:
            tasks.append(batch_arguments(plan, cell, batch))
            owner.append(number)
            sizes.append(len(batch))
        expected.append(len(batches))
    returned: list[dict[int, BatchResult]] = [{} for _ in cells]
    by_tasks = executor.counts == "tasks"
    total = len(tasks) if by_tasks else sum(sizes)
    with _progress_bar(progress, total, experiment.name, executor.counts) as live:
        task_id = live.add_task(executor.counts, total=total) if live else None
        for index, result in executor.run(run_batch, tasks):
            number = owner[index]
            returned[number][index] = result
            if live:
                live.advance(task_id, 1 if by_tasks else sizes[index])
            if len(returned[number]) == expected[number]:
                batches = returned[number]
                _write_cell(out, cells[number], [batches[i] for i in sorted(batches)], cell_times)
                returned[number] = {}


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


def _progress_bar(enabled: bool, total: int, name: str, counts: str = "trials"):
    if not enabled or total == 0:
        return nullcontext()
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                               TimeElapsedColumn, TimeRemainingColumn)

    return Progress(TextColumn(f"{name}"), BarColumn(), MofNCompleteColumn(), TextColumn(counts),
                    TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), transient=True,
                    console=Console(stderr=True))


def _write_cell(out: Path, cell: Cell, results: list[BatchResult], cell_times: dict) -> None:
    trials = pd.concat([r.trials for r in results], ignore_index=True)
    steps = pd.concat([r.steps for r in results], ignore_index=True)
    write_csv(steps, out / "cells" / f"{cell.key}.steps.csv")
    particles = [r.particles for r in results if r.particles is not None]
    if particles:
        write_csv(pd.concat(particles, ignore_index=True), out / "cells" / f"{cell.key}.particles.csv")
    write_csv(trials, out / "cells" / f"{cell.key}.trials.csv")     # last: marks the cell finished
    cell_times[cell.key] = sum(r.wall_time for r in results)


def _provenance(plan: Plan | StudyPlan, started: str) -> dict:
    """What every manifest records: the config, the software, the machine, the times."""
    return {
        "name": plan.experiment.name,
        "description": plan.experiment.description,
        "config_file": plan.file,
        "config_hash": plan.config_hash,
        "seed": plan.experiment.seed,
        "pfx_version": pfx.__version__,
        "git_revision": _git_revision(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "platform": platform.platform(),
        "started": started,
        "finished": None,
        "complete": False,
        "figures": list(plan.experiment.outputs.figures),
        "formats": list(plan.experiment.outputs.formats),
    }


def _manifest(plan: Plan, started: str) -> dict:
    model = plan.cells[0].truth_model
    return {
        **_provenance(plan, started),
        "trials": plan.experiment.trials,
        "label_columns": plan.label_columns,
        "legend_columns": plan.legend_columns,
        "units": {"time": model.time_unit, "position": model.position_unit,
                  **{f"state_{n}": u for n, u in zip(model.state_names, model.state_units)}},
        "position_states": [model.state_names[i] for i in model.position_components],
        "cells": [{"cell": c.key, **c.labels} for c in plan.cells],
    }


def _assemble(plan: Plan, out: Path, manifest: dict, cell_times: dict, wall_time: float) -> None:
    order = [cell.key for cell in plan.cells]
    trials = pd.concat([pd.read_csv(out / "cells" / f"{key}.trials.csv", keep_default_na=True)
                        for key in order], ignore_index=True)
    steps_frames = [pd.read_csv(out / "cells" / f"{key}.steps.csv") for key in order]
    steps = pd.concat([f for f in steps_frames if not f.empty] or steps_frames[:1], ignore_index=True)
    write_csv(trials, out / "trials.csv")
    write_csv(steps, out / "steps.csv")
    write_csv(summarize(trials, plan.label_columns), out / "summary.csv")
    scene = plan.cells[0].truth_model.scene()
    if scene:
        write_csv(pd.DataFrame(scene), out / "scene.csv")
    particle_files = [out / "cells" / f"{key}.particles.csv" for key in order]
    if any(path.exists() for path in particle_files):
        write_csv(pd.concat([pd.read_csv(path) for path in particle_files if path.exists()], ignore_index=True),
                  out / "particles.csv")
    for entry in manifest["cells"]:
        entry["wall_time_s"] = cell_times.get(entry["cell"])
    manifest.update(finished=_now(), complete=True, wall_time_s=wall_time)
    write_text(json.dumps(manifest, indent=2), out / "manifest.json")
    render_figures(out, plan.experiment.outputs.figures, tuple(plan.experiment.outputs.formats))
    shutil.rmtree(out / "cells", ignore_errors=True)
