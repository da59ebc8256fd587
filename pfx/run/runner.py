"""Run a plan: every cell, every trial, in batches; write the result folder.

Work is split into tasks of (cell, batch of trials). A batch (:func:`pfx.run.batch.run_batch`)
runs all its trials at once in the engine; an executor (:mod:`pfx.run.executors`: this process, local worker processes, or a
Dask cluster) computes the tasks. Because every trial has its own random streams, batching,
the executor and the number of workers change nothing in the results. Each finished cell is
written atomically to ``cells/`` inside the result folder, by this process alone; when every
cell is done the tables, the summary and the figures are assembled and ``cells/`` is removed.
Running again with the same config resumes from the finished cells; a folder made by a
different config is refused unless ``--fresh`` is given.

A config's plugins (:mod:`pfx.config.plugins`) are recorded in the manifest (name, file,
sha256); their code's hash is part of the results hash, so a folder computed with other plugin
code is refused, with a line naming the plugin that changed. Tasks of a config with plugins
travel as the plugins (a file plugin's code included) and the pickled arguments: a worker
process loads the plugins before it unpickles the arguments, whose model classes they define
(:func:`run_batch_with_plugins`).
"""

from __future__ import annotations

import json
import pickle
import shutil
import time
import traceback
from contextlib import nullcontext
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pandas as pd

from pfx.analysis.step_summary import merge_step_summaries, summarize_steps
from pfx.analysis.summary import summarize
from pfx.config.plan import Cell, Plan, StudyPlan
from pfx.config.plan_checks import plan_notes
from pfx.config.plugin_faults import locate, run_time_fault
from pfx.config.plugin_record import manifest_code, recorded_names
from pfx.config.plugins import PLUGIN_COPIES, LoadedPlugin, ensure_loaded
from pfx.errors import ConfigError, ModelNumericalError, PluginFault
from pfx.figures import render_figures
from pfx.folder_lock import folder_lock
from pfx.folder_state import FolderState, inspect_folder, up_to_date_note
from pfx.numerics.seeding import study_generator
from pfx.result_folder import (
    CELLS,
    FIGURES_PENDING,
    MANIFEST,
    ResultFolder,
    clear_outputs,
    read_table,
    write_csv,
    write_manifest,
    write_text,
)
from pfx.run.batch import BatchResult, run_batch
from pfx.run.executors import Executor, make_executor
from pfx.run.folder_record import drop_stale_figures, now, plugins_record, provenance, run_manifest, write_record_config
from pfx.run.interrupts import raise_if_requested
from pfx.run.memory import check_fits, default_budget, trials_per_batch
from pfx.run.progress_bar import progress_bar

OUTPUT_FILES = ("trials.csv", "steps.csv", "steps_summary.csv", "summary.csv", "particles.csv", "genealogy.csv",
                "forecasts.csv", "scene.csv", "config.yaml", "manifest.json")
# per cell in cells/; trials last (they mark the cell finished)
CELL_TABLES = ("steps", "steps_summary", "particles", "genealogy", "forecasts", "trials")
# the tables of trials' rows that a run writes whole and an extension appends to
ROW_TABLES = ("trials", "steps", "particles", "genealogy", "forecasts")


def check_folder(plan: Plan | StudyPlan, out: Path, fresh: bool, *, locked: bool = False) -> FolderState:
    """Refuse, without touching anything, a result folder this run may not write to
    (:func:`pfx.folder_state.inspect_folder`); return what it holds. ``locked``: this process
    holds the folder's lock (what it holds is settled)."""
    if not fresh:
        _check_plugin_code(plan, Path(out))
    return inspect_folder(plan, Path(out), fresh, locked=locked)


def _check_plugin_code(plan: Plan | StudyPlan, out: Path) -> None:
    """Refuse to resume or keep results computed with other code of the same plugin (the
    results hash differs too; this says why, in words)."""
    from pfx.result_folder import read_manifest

    if not (out / MANIFEST).is_file():
        return
    # A plugin is known by its recorded name (its copy's name; in older folders, its name as written).
    recorded = manifest_code(read_manifest(out))
    for plugin, name in zip(plan.plugins, recorded_names(plan.plugins)):
        if name in recorded and recorded[name] != plugin.sha256:
            raise ConfigError(f"plugin {plugin.name} has changed since these results were computed (sha256 "
                              f"{str(recorded[name])[:12]} != {plugin.sha256[:12]}); use --fresh to "
                              "recompute them or --out for another folder", file=str(out))


def run_plan(plan: Plan, out: Path, *, workers: int = 1, executor: Optional[Executor] = None,
             fresh: bool = False, report: Callable[[str], None] = lambda message: None,
             progress: bool = False, memory_budget: Optional[int] = None) -> Path:
    """Run every unfinished cell of the plan into ``out``; assemble tables and figures.

    The batches are computed by ``executor`` (see :mod:`pfx.run.executors`; the caller starts and
    closes it), or by ``workers`` local processes when none is given. What happens with a
    folder that already holds results is :mod:`pfx.result_folder`'s table: resume, extend with
    more trials, only re-render the outputs, or refuse.

    Stopped by an error or an interrupt (KeyboardInterrupt, or SIGTERM turned into one by the
    command line), it keeps every finished cell and re-raises, with a note (``__notes__``)
    saying what was kept; a run that finished no cell leaves the folder as it found it.
    """
    out = Path(out)
    if isinstance(plan, StudyPlan):
        return run_study(plan, out, fresh=fresh, report=report)
    for note in plan_notes(plan):          # what the run leaves out of what the config asks, in a line each
        report(f"{plan.file}: {note}")
    if plan.experiment.estimation is not None:
        from pfx.run.estimation import run_estimation

        return run_estimation(plan, out, fresh=fresh, report=report, progress=progress,
                              manifest_of=run_manifest, write_config=write_record_config, now=now)
    budget = memory_budget or default_budget()
    check_fits(plan, budget)
    check_folder(plan, out, fresh)                # refuse early, before making anything
    with folder_lock(out, remove_if_unused=True):  # a run that kept nothing leaves no folder it made
        # Read again: until this run held the lock, another one may have been writing the folder
        # (and may have finished it: then it is up to date).
        state = check_folder(plan, out, fresh, locked=True)
        if fresh:
            clear_outputs(out, OUTPUT_FILES)
        if state.complete and state.kept_trials == plan.experiment.trials:
            update_record(plan, out, state.manifest, report)
            return out
        own = make_executor("local", workers) if executor is None else None
        with own or nullcontext(executor) as running:        # the caller closes an executor it gave
            _run_and_assemble(plan, out, state, running, budget, progress, report)
    return out


def _run_and_assemble(plan: Plan, out: Path, state: FolderState, executor: Executor, budget: int,
                      progress: bool, report: Callable[[str], None]) -> None:
    """Run the cells the folder lacks (all trials, or only the new ones of an extension) and
    assemble the tables; on failure, keep what finished (see :func:`_keep_what_finished`)."""
    trials = plan.experiment.trials
    first = state.kept_trials              # trials 0 .. first-1 are in the tables already
    if state.done:
        report(f"{out}: resuming: {len(state.done)} of {len(plan.cells)} cells already done, skipping them")
    elif state.complete:
        report(f"{out}: extending from {first} to {trials} trials per cell (trials {first}..{trials - 1})")
    earlier_record = {name: (out / name).read_text() for name in ("config.yaml", MANIFEST)
                      if state.complete and (out / name).exists()}
    (out / CELLS).mkdir(exist_ok=True)
    manifest = run_manifest(plan, started=now())
    if first:
        manifest["extending_from"] = first
    write_record_config(plan, out)
    write_text(json.dumps(manifest, indent=2), out / MANIFEST)
    started = time.perf_counter()
    cell_times: dict[str, float] = {}
    try:
        _run_cells(plan, out, [c for c in plan.cells if c.key not in state.done], executor, budget,
                   progress, cell_times, first)
    except BaseException as error:
        error.add_note(_keep_what_finished(plan, out, earlier_record))
        raise
    try:
        _assemble(plan, out, manifest, cell_times, time.perf_counter() - started, state)
    except Exception as error:       # a plugin's figure or metric, after every trial finished
        fault = locate(error, plan.plugins) if plan.plugins else None
        if fault is None:
            raise
        raise PluginFault(f"{fault.one_line()}; every trial finished and the tables are written in {out}, "
                          "but not every figure", "".join(traceback.format_exception(error))) from error


def _keep_what_finished(plan: Plan, out: Path, earlier_record: dict[str, str]) -> str:
    """After a failed or interrupted run: keep the finished cells for a resume, or, if none
    finished, put the folder back as it was (so no later run takes it for progress). Returns
    what was kept, in words."""
    finished = len(list((out / CELLS).glob("*.trials.csv")))
    if finished:
        return (f"{finished} of {len(plan.cells)} cells finished and are kept in {out}; "
                "run the same command again to resume")
    shutil.rmtree(out / CELLS, ignore_errors=True)
    if not earlier_record:
        shutil.rmtree(out / PLUGIN_COPIES, ignore_errors=True)
    for name in ("config.yaml", MANIFEST):
        if name in earlier_record:
            write_text(earlier_record[name], out / name)
        else:
            (out / name).unlink(missing_ok=True)
    if earlier_record:
        return f"no new trial finished; {out} holds its earlier results, unchanged"
    return "no cell had finished, so nothing was kept"


def update_record(plan: Plan | StudyPlan, out: Path, manifest: dict, report: Callable[[str], None]) -> None:
    """A finished folder with the same results: bring its record (config.yaml, the manifest's
    name, description and outputs) up to the config, and render the figures it lacks (all of
    them when the run that finished it stopped while drawing them)."""
    pending = bool(manifest.get(FIGURES_PENDING))
    if manifest.get("config_hash") == plan.config_hash and not pending:
        report(up_to_date_note(out, plan.config_hash))
        return
    outputs = plan.experiment.outputs
    figures, formats, old_figures, old_formats, removed = drop_stale_figures(out, manifest, outputs)
    manifest.update(name=plan.experiment.name, description=plan.experiment.description, config_file=plan.file,
                    config_hash=plan.config_hash, figures=figures, formats=formats, **plugins_record(plan))
    write_record_config(plan, out)
    redrawn = pending or formats != old_formats
    wanted = figures if redrawn else [name for name in figures if name not in old_figures]
    _render_then_mark_drawn(out, manifest, wanted, tuple(formats))
    if pending:
        report(f"{out}: figures drawn ({', '.join(wanted) or 'none asked for'}): the run that finished "
               "the tables stopped before it had drawn them")
        return
    report(f"{out}: results up to date (same results hash {plan.results_hash}); record updated"
           + (f", figures rendered: {', '.join(wanted)}" if wanted else "")
           + (f", figures removed: {', '.join(removed)}" if removed else ""))


def _render_then_mark_drawn(out: Path, manifest: dict, figures: list[str], formats: tuple[str, ...]) -> None:
    """Write the finished manifest flagged ``figures_pending``, draw the figures, then write it
    without the flag: a run stopped while drawing leaves a folder whose rerun draws them
    (:func:`update_record`), not one whose manifest says complete with figures missing."""
    manifest[FIGURES_PENDING] = True
    write_manifest(manifest, out)
    render_figures(out, figures, formats)
    manifest.pop(FIGURES_PENDING)
    write_manifest(manifest, out)


def run_study(plan: StudyPlan, out: Path, *, fresh: bool = False,
              report: Callable[[str], None] = lambda message: None) -> Path:
    """Compute a study (:mod:`pfx.studies`) into ``out``: its tables as CSV, then its figures."""
    check_folder(plan, out, fresh)
    with folder_lock(out):
        state = check_folder(plan, out, fresh, locked=True)      # read again, now that no other run writes it
        if state.complete:
            update_record(plan, out, state.manifest, report)
            return out
        for path in [*out.glob("*.csv"), out / MANIFEST, out / "config.yaml"]:
            path.unlink(missing_ok=True)
        shutil.rmtree(out / "figures", ignore_errors=True)
        study = plan.experiment.study
        manifest = {**provenance(plan, started=now()), "study": study.kind, "units": dict(study.units)}
        write_record_config(plan, out)
        write_text(json.dumps(manifest, indent=2), out / MANIFEST)
        started = time.perf_counter()
        tables = study.tables(study_generator(plan.experiment.seed))
        for name, table in tables.items():
            write_csv(table, out / f"{name}.csv")
        manifest.update(tables=list(tables), finished=now(), complete=True,
                        wall_time_s=time.perf_counter() - started)
        _render_then_mark_drawn(out, manifest, plan.experiment.outputs.figures,
                                tuple(plan.experiment.outputs.formats))
    return out


def batch_arguments(plan: Plan, cell: Cell, trials: list[int]) -> tuple:
    """The arguments of :func:`run_batch` for some trials of a cell: everything a worker needs.

    The one place they are put together; with Dask, this tuple is what travels to a worker.
    """
    outputs = plan.experiment.outputs
    return (cell, plan.experiment.seed, trials, outputs.trace_trials, outputs.particles, plan.experiment.datasets,
            outputs.genealogy, outputs.forecasts if outputs.forecasts.requested else None)


def _run_cells(plan: Plan, out: Path, cells: list[Cell], executor: Executor, budget: int, progress: bool,
               cell_times: dict, first: int = 0) -> None:
    """Hand every batch of every cell (trials ``first`` onwards) to the executor; write each cell
    once all its batches are back."""
    experiment = plan.experiment
    trials = list(range(first, experiment.trials))
    tasks, owner, sizes, work = [], [], [], []   # per task: arguments, its cell's number, trial count, particle-steps
    expected = []                             # per cell: its number of batches
    for number, cell in enumerate(cells):
        size = trials_per_batch(cell, len(trials), budget, executor.slots, genealogy=experiment.outputs.genealogy > 0)
        batches = [trials[start:start + size] for start in range(0, len(trials), size)]
        for batch in batches:
            tasks.append(batch_arguments(plan, cell, batch))
            owner.append(number)
            sizes.append(len(batch))
            work.append(len(batch) * getattr(cell.filter, "particles", 1) * cell.filter_model.steps)
        expected.append(len(batches))
    if executor.slots > 1:
        # The largest batches first: the workers then finish together, on small ones, instead of
        # one of them running the sweep's largest batch alone at the end. (Cells are written
        # whole, whatever order their batches come back in.)
        order = sorted(range(len(tasks)), key=lambda index: -work[index])
    else:
        order = list(range(len(tasks)))
    function: Callable = run_batch
    if plan.plugins:          # workers load the plugins before the arguments, which need their classes
        function = run_batch_with_plugins
        shipped = tuple(plan.plugins)
        tasks = [(shipped, pickle.dumps(arguments, protocol=pickle.HIGHEST_PROTOCOL)) for arguments in tasks]
    returned: list[dict[int, BatchResult]] = [{} for _ in cells]
    by_tasks = executor.counts == "tasks"
    total = len(tasks) if by_tasks else sum(sizes)
    with progress_bar(progress, total, experiment.name, executor.counts) as bar:
        for position, result in executor.run(function, [tasks[index] for index in order]):
            raise_if_requested()                 # a stop signal whose exception was swallowed
            index = order[position]
            number = owner[index]
            returned[number][index] = result
            bar.advance(1 if by_tasks else sizes[index])
            if len(returned[number]) == expected[number]:
                batches = returned[number]
                _write_cell(out, cells[number], [batches[i] for i in sorted(batches)], cell_times)
                returned[number] = {}


def run_batch_with_plugins(plugins: tuple[LoadedPlugin, ...], arguments: bytes) -> BatchResult:
    """:func:`run_batch` for a config with plugins, in any process: load the plugins (a file
    plugin from its shipped code, once per process), then unpickle the arguments and run."""
    ensure_loaded(plugins)
    arguments = pickle.loads(arguments)
    try:
        return run_batch(*arguments)
    except (ModelNumericalError, ConfigError, PluginFault):
        raise                             # reported in one line already
    except Exception as error:            # from the plugins' code, or pfx's choking on what it returned
        cell = arguments[0]
        fault = run_time_fault(error, plugins, cell.filter_model)
        if fault is None:
            raise
        raise fault from None


def _write_cell(out: Path, cell: Cell, results: list[BatchResult], cell_times: dict) -> None:
    """Write one finished cell's tables to cells/ (its trials last: they mark it finished)."""
    trials = pd.concat([r.trials for r in results], ignore_index=True)
    values = {name: np.concatenate([r.step_values[name] for r in results]) for name in results[0].step_values}
    tables = {"steps": pd.concat([r.steps for r in results], ignore_index=True),
              "steps_summary": summarize_steps(values, cell.truth_model.state_names, {"cell": cell.key, **cell.labels},
                                               cell.truth_model.times()),
              "trials": trials}
    for name in ("particles", "genealogy", "forecasts"):
        kept = [getattr(r, name) for r in results if getattr(r, name) is not None]
        if kept:
            tables[name] = pd.concat(kept, ignore_index=True)
    for name in CELL_TABLES:
        if name in tables:
            write_csv(tables[name], out / CELLS / f"{cell.key}.{name}.csv")
    cell_times[cell.key] = sum(r.wall_time for r in results)


def _cell_tables(out: Path, key: str, name: str, kept: Optional[pd.DataFrame]) -> list[pd.DataFrame]:
    """One cell's rows of a table: those the folder kept from earlier trials, then the new ones."""
    frames = [kept[kept["cell"] == key]] if kept is not None and not kept.empty else []
    path = out / CELLS / f"{key}.{name}.csv"
    if path.exists():
        frames.append(read_table(path))
    return frames


def _combined(frames: list[pd.DataFrame]) -> Optional[pd.DataFrame]:
    """The frames stacked; None when there are none. Empty frames (a cell without traced
    trials) only give their columns."""
    if not frames:
        return None
    return pd.concat([f for f in frames if not f.empty] or frames[:1], ignore_index=True)


def _assemble(plan: Plan, out: Path, manifest: dict, cell_times: dict, wall_time: float,
              state: FolderState) -> None:
    """Write the folder's tables from cells/ (and, when extending, the tables it kept), the
    summary, the scene, the finished manifest and the figures; remove cells/."""
    order = [cell.key for cell in plan.cells]
    kept = {name: ResultFolder(out).optional_table(name) if state.kept_trials else None
            for name in (*ROW_TABLES, "steps_summary")}
    tables = {name: _combined([frame for key in order for frame in _cell_tables(out, key, name, kept[name])])
              for name in ROW_TABLES}
    summaries = []
    for key in order:
        parts = _cell_tables(out, key, "steps_summary", kept["steps_summary"])
        summaries.append(merge_step_summaries(*parts) if len(parts) == 2 else parts[0])
    tables["steps_summary"] = pd.concat(summaries, ignore_index=True)
    for name in (*ROW_TABLES, "steps_summary"):
        if tables[name] is not None:
            write_csv(tables[name], out / f"{name}.csv")
    write_csv(summarize(tables["trials"], plan.label_columns), out / "summary.csv")
    scene = plan.cells[0].truth_model.scene()
    if scene:
        write_csv(pd.DataFrame(scene), out / "scene.csv")
    earlier = {entry["cell"]: entry.get("wall_time_s") for entry in (state.manifest or {}).get("cells", [])}
    for entry in manifest["cells"]:
        times = [t for t in (earlier.get(entry["cell"]) if state.kept_trials else None,
                             cell_times.get(entry["cell"])) if t is not None]
        entry["wall_time_s"] = sum(times) if times else None
    manifest.pop("extending_from", None)
    if state.kept_trials:
        manifest["started"] = state.manifest.get("started", manifest["started"])
        wall_time += state.manifest.get("wall_time_s") or 0.0
    # cells/ goes before the manifest says complete: a complete folder never holds stale cells.
    shutil.rmtree(out / CELLS, ignore_errors=True)
    manifest.update(finished=now(), complete=True, wall_time_s=wall_time)
    _render_then_mark_drawn(out, manifest, plan.experiment.outputs.figures, tuple(plan.experiment.outputs.formats))
