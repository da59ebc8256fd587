"""Running a parameter-estimation experiment (a config with ``estimation:``) into its folder.

Every cell runs the method (:mod:`pfx.estimation.pmmh`, :mod:`pfx.estimation.if2`) on its
dataset. Progress is kept as it goes, in ``estimation/<cell>.csv`` (every chain's rows, or
every IF2 iteration's estimates, with ``estimation/<cell>.swarm.npy``, IF2's particle swarm;
:mod:`pfx.run.estimation_progress`; on the jax backend the iterations run in compiled blocks,
:mod:`pfx.estimation.compiled_pmmh` and :mod:`pfx.estimation.compiled_if2`): an interrupted run resumes from them, and a finished one
asked for more ``iterations`` extends its chains (each iteration's random numbers depend only on
its chain and its index, so either way the numbers are those of one uninterrupted run). Then the
tables: chains.csv, posterior.csv, priors.csv, and likelihood_spread.csv where a flagged cell's
spread was measured (PMMH); if2.csv, maximum_likelihood.csv (IF2); forecasts.csv where
``outputs.forecasts`` asks (PMMH); and the figures. A finished folder whose chains already hold
the iterations asked, run with a config that differs in what only reads them (forecasts, figures,
the name), runs nothing again: :func:`pfx.run.estimation_outputs.update_outputs` makes those outputs.

A run does in two phases what it does to a folder. First it reads and checks everything it
will build on, writing nothing: each cell's progress files (refused if damaged), the iterations
they hold against those asked (never fewer), the particle count of a PMMH cell with ``particles:
auto`` (read back from ``estimation/<cell>.particle_count.csv``, or measured by the pilot of
:mod:`pfx.estimation.particle_count`, which may refuse), and the starts of the cells without
progress (the model must accept each chain's start and the data have a likelihood above zero there). Any of
these refused, the folder is as it was. Only then does it write. Stopped (Ctrl-C, SIGTERM, an
error), it keeps what it computed: PMMH's rows are saved every :data:`CHECKPOINT_SECONDS` and at
the stop, IF2's after every pass; the same command resumes. While the iterations run, one
progress bar (:mod:`pfx.run.progress_bar`) counts them over all cells, as each is reported (on
jax, a compiled block's when it ends); it changes nothing the run computes or writes.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np
import pandas as pd

from pfx.analysis.estimation_flags import if2_advice, pmmh_advice, replicate_flags
from pfx.config.estimation_tables import CHAINS, IF2, LIKELIHOOD_SPREAD, MAXIMUM_LIKELIHOOD, PARTICLE_COUNT
from pfx.config.plan import Cell, Plan
from pfx.config.plugins import PLUGIN_COPIES
from pfx.config.profile_settings import profile_as_if2
from pfx.errors import ConfigError
from pfx.estimation.if2 import IteratedFiltering
from pfx.estimation.particle_count import ParticleChoice
from pfx.estimation.pmmh import Chains, ParticleMarginalMetropolisHastings
from pfx.estimation.profile import PROFILE_INTERVAL_FILE, profile_line, profile_tables
from pfx.estimation.summary import posterior_summary, prior_grid, spread_at_posterior_mean
from pfx.estimation.target import EstimationTarget, dataset
from pfx.folder_lock import folder_lock
from pfx.folder_state import FolderState, inspect_folder, up_to_date_note
from pfx.result_folder import (
    ESTIMATION_TABLES,
    MANIFEST,
    clear_outputs,
    write_bytes,
    write_csv,
    write_text,
)
from pfx.run.estimation_outputs import posterior_forecast_table, update_outputs
from pfx.run.estimation_progress import (
    PROGRESS,
    damaged,
    progress_file,
    read_rows,
    read_swarm,
    save_swarm,
    swarm_file,
)
from pfx.run.interrupts import raise_if_requested
from pfx.run.particle_count_pilot import (
    after_warm_up_applies,
    is_auto,
    keep_pilots,
    measure_after_warm_up,
    particle_count,
    pilot_record,
    read_back_after_warm_up,
    write_particle_count,
)
from pfx.run.progress_bar import NO_BAR, progress_bar

CHECKPOINT_SECONDS = 10.0
# every table a run may write; likelihood_spread.csv only where a flagged cell's spread was measured,
# particle_count.csv only where a cell's particles are `auto`, forecasts.csv only with outputs.forecasts
TABLES = (*(f"{name}.csv" for names in ESTIMATION_TABLES.values() for name in names), LIKELIHOOD_SPREAD.file,
          PARTICLE_COUNT.file, "forecasts.csv")
RECORD = ("config.yaml", MANIFEST)


@dataclass
class CellWork:
    """One cell's estimation as a run takes it up: its rows so far (from the progress file, or
    the starts), the state they end in, and the first iteration still to run."""

    cell: Cell
    target: EstimationTarget
    rows: pd.DataFrame
    state: Union[Chains, np.ndarray]    # PMMH's chains, or IF2's swarm, after the last row's iteration
    first: int
    started: bool                       # the rows are the starts, computed by this run (nothing kept)
    seconds: float = 0.0                # time spent computing the starts
    note: str = ""                      # what the run says when it takes the cell up
    pilot: Optional[ParticleChoice] = None      # `particles: auto`: the particle count chosen, and how
    pilot_measured: bool = False                # measured by this run (else read from the folder)
    after_warm_up: Optional[ParticleChoice] = None  # `auto` measured again after the warm-up


def run_estimation(plan: Plan, out: Path, *, fresh: bool, report: Callable[[str], None], progress: bool,
                   manifest_of: Callable, write_config: Callable, now: Callable) -> Path:
    """Run (or resume, or extend) every cell's estimation into ``out``; tables and figures
    (module docstring: everything that may be refused is refused before anything is written)."""
    state = inspect_folder(plan, out, fresh)      # refuse a folder of other results, early
    if state.complete and state.manifest.get("config_hash") == plan.config_hash:
        # As a finished filter run: nothing to recompute (IF2's final evaluations included).
        report(up_to_date_note(out, plan.config_hash))
        return out
    work = _prepare(plan, out, state, {}, progress)      # and damaged progress, dropped iterations, bad starts
    with folder_lock(out, remove_if_unused=True):
        # Read again: until this run held the lock, another one may have been writing the folder.
        state = inspect_folder(plan, out, fresh, locked=True)
        work = _prepare(plan, out, state, {item.cell.key: item for item in work}, progress)
        if state.complete and all(item.first > plan.experiment.estimation.iterations for item in work):
            # every chain holds the iterations asked: only what reads them (forecasts.csv, figures) is made
            update_outputs(plan, out, work, state.manifest, report, write_config)
            return out
        earlier_record = {} if fresh else {name: (out / name).read_bytes() for name in RECORD if (out / name).is_file()}
        if fresh:
            clear_outputs(out, TABLES + RECORD)
            shutil.rmtree(out / PROGRESS, ignore_errors=True)
        (out / PROGRESS).mkdir(exist_ok=True)
        estimation = plan.experiment.estimation
        manifest = {**manifest_of(plan, now()), "estimation": {"method": estimation.method,
                                                               "iterations": estimation.iterations,
                                                               "chains": estimation.chains}}
        manifest["figures"] = list(plan.experiment.outputs.figures)    # the method's, by default (pfx.config.plan)
        manifest.update(pilot_record(work))       # nothing without `particles: auto`
        manifest.pop("trials", None)
        earlier = {} if fresh else dict((state.manifest or {}).get("cell_wall_time_s") or {})
        write_config(plan, out)
        write_text(json.dumps(manifest, indent=2), out / MANIFEST)
        keep_pilots(out, work, report)
        cell_times: dict[str, float] = {}
        # one bar for every cell's iterations left (each cell's first is 1, or where its progress ends)
        left = sum(max(0, estimation.iterations - item.first + 1) for item in work)
        try:
            with progress_bar(progress, left, plan.experiment.name, "iterations") as bar:
                for item in work:
                    if item.note:
                        report(f"{out}: cell {item.cell.key}: {item.note}")
                    if len(work) > 1:
                        bar.describe(_bar_name(plan, item))
                    started = time.perf_counter()
                    try:
                        item.rows = (_run_pmmh if estimation.method == "pmmh" else _run_if2)(item, plan, out, report,
                                                                                            bar)
                    finally:
                        cell_times[item.cell.key] = item.seconds + time.perf_counter() - started
            _assemble(plan, out, work, report)
            write_particle_count(plan, out, work)
        except BaseException as error:
            kept = _keep_what_ran(out, manifest, _summed(cell_times, earlier), earlier_record)
            if isinstance(error, ConfigError) and not error.file:     # found while running (IF2's random walk)
                located = error.located(file=plan.file)
                located.add_note(kept)
                raise located from None
            error.add_note(kept)
            raise
        manifest.update(finished=now(), complete=True, batched={item.cell.key: item.target.batched for item in work},
                        **pilot_record(work))      # the counts the posterior draws used
        # Times add up over the runs that made the folder (a resumed or extended run's own time
        # plus the earlier ones', an interrupted run's included), as a filter run's do.
        cell_times = _summed(cell_times, earlier)
        manifest.update(wall_time_s=round(sum(cell_times.values()), 3), cell_wall_time_s=cell_times)
        write_text(json.dumps(manifest, indent=2), out / MANIFEST)
    from pfx.figures.registry import render_figures

    render_figures(out, manifest["figures"], tuple(plan.experiment.outputs.formats))
    return out


def _summed(times: dict[str, float], earlier: dict[str, float]) -> dict[str, float]:
    return {key: round(value + earlier.get(key, 0.0), 3) for key, value in times.items()}


def _keep_what_ran(out: Path, manifest: dict, cell_times: dict, earlier_record: dict[str, bytes]) -> str:
    """After a stopped or failed run: with progress kept, the manifest records the time spent
    (an unfinished manifest: the same command resumes); without, the folder is put back as the
    run found it (so that no later run takes it for progress). Returns what was kept, in words."""
    if any((out / PROGRESS).glob("*.csv")):
        write_text(json.dumps({**manifest, "cell_wall_time_s": cell_times}, indent=2), out / MANIFEST)
        return f"the chains so far are kept in {out / PROGRESS}; run the same command again to resume"
    for name in RECORD:
        if name in earlier_record:
            write_bytes(earlier_record[name], out / name)
        else:
            (out / name).unlink(missing_ok=True)
    if not earlier_record:
        shutil.rmtree(out / PLUGIN_COPIES, ignore_errors=True)
    if not any((out / PROGRESS).iterdir()):
        (out / PROGRESS).rmdir()
    return f"{out} holds its earlier results, unchanged" if earlier_record else "no iteration finished, so nothing was kept"


# -- what a run takes up: the rows kept, or the starts -------------------------------------------------

def _prepare(plan: Plan, out: Path, state: FolderState, earlier: dict[str, CellWork],
             progress: bool = False) -> list[CellWork]:
    """Every cell's work, read and checked (module docstring), writing nothing. ``state``: what
    the folder holds (nothing, with --fresh); ``earlier``: the work found before the lock, whose
    computed starts are reused (they do not depend on the folder); ``progress``: a pilot of
    ``particles: auto`` shows its bar."""
    estimation, work = plan.experiment.estimation, []
    # A finished run's progress files hold every iteration its manifest records, no fewer.
    finished = (state.manifest or {}).get("estimation", {}).get("iterations") if state.complete else None
    for cell in plan.cells:
        before = earlier.get(cell.key)
        # a profile runs as IF2 (its grid values x starts the replicates): pfx.config.profile_settings
        target = before.target if before else EstimationTarget(cell, profile_as_if2(estimation),
                                                               dataset(cell, plan.experiment.seed))
        pilot, measured = (particle_count(plan, target, out, state, before, progress) if is_auto(plan, cell)
                           else (None, False))
        if pilot is not None:
            target = target.with_particles(pilot.particles)
        item = None
        if state.manifest is not None:
            item = (_resumed_pmmh if estimation.method == "pmmh" else _resumed_if2)(plan, target, out)
        if item is None and finished is not None:
            raise damaged(progress_file(out, cell), "is missing, and the folder's manifest.json records a finished run")
        if item is None:
            same = before is not None and before.target.cell.filter.particles == target.cell.filter.particles
            item = before if same and before.started else _started(plan, target)
        item.pilot, item.pilot_measured = pilot, measured
        if after_warm_up_applies(plan, item) and item.first > estimation.warm_up + 1:
            item.target = read_back_after_warm_up(plan, item, out)
        held = int(item.rows["iteration"].iloc[-1])
        if finished is not None and held != finished:
            raise damaged(progress_file(out, cell), f"holds iterations 0 to {held}, and the folder's manifest.json "
                                                    f"records a finished run of {finished}", len(item.rows) + 2)
        if held > estimation.iterations:
            raise ConfigError(f"{out} holds {held} iterations of cell {cell.key}; asking for {estimation.iterations} "
                              "would drop some (ask for at least as many, or use --fresh)", file=str(out),
                              key="estimation.iterations")
        work.append(item)
    return work


def _started(plan: Plan, target: EstimationTarget) -> CellWork:
    """A cell's iteration 0, its starts checked (a ConfigError naming the chain, the parameters
    and the config's key otherwise)."""
    started = time.perf_counter()
    try:
        if plan.experiment.estimation.method == "pmmh":
            chains = _sampler(plan, target).start()
            state, rows = chains, _chain_rows(chains, 0, np.zeros(len(chains.values), dtype=bool), target)
        else:
            method = _iterated_filtering(plan, target)
            state = method.start()
            rows = _if2_rows(method.estimates(state), 0, np.full(method.replicates, np.nan), target)
    except ConfigError as error:
        raise error.located(file=plan.file) from None
    return CellWork(target.cell, target, rows, state, first=1, started=True, seconds=time.perf_counter() - started)


def _resumed_pmmh(plan: Plan, target: EstimationTarget, out: Path) -> CellWork | None:
    """The chains as the folder's progress file left them (None if it has none)."""
    path = progress_file(out, target.cell)
    if not path.is_file():
        return None
    estimation, columns = target.estimation, target.columns
    rows = read_rows(path, "pmmh", columns, estimation.chains, estimation.warm_up)
    values = rows[columns].to_numpy(dtype=float).reshape(-1, estimation.chains, len(columns))
    last = rows.iloc[-estimation.chains:]
    chains = Chains(values=values[-1].copy(), log_likelihood=last["log_likelihood"].to_numpy(float),
                    log_prior=last["log_prior"].to_numpy(float), history=list(values))
    first = len(values)
    note = f"continuing the chains from iteration {first}" if first <= estimation.iterations else ""
    return CellWork(target.cell, target, rows, chains, first, started=False, note=note)


def _resumed_if2(plan: Plan, target: EstimationTarget, out: Path) -> CellWork | None:
    """IF2's estimates and swarm as the folder's progress files left them (None if there are
    none, or only a first pass whose swarm was never saved). The estimates of a pass are its
    swarm's means, so the swarm file must give those of the table's last pass; or those of the
    pass before, when a run stopped after writing the table and before the swarm (the last pass
    is then computed again, to the same numbers)."""
    path, swarm_path = progress_file(out, target.cell), swarm_file(out, target.cell)
    if not path.is_file():
        return None
    columns, method = target.columns, _iterated_filtering(plan, target)
    rows = read_rows(path, "if2", columns, method.replicates)
    estimates = rows[columns].to_numpy(dtype=float).reshape(-1, method.replicates, len(columns))
    last = len(estimates) - 1
    if not swarm_path.is_file():
        if last <= 1:
            return None
        raise damaged(swarm_path, f"is missing, and {path.name} holds {last} passes")
    swarm = read_swarm(swarm_path, (method.replicates, method.particles, len(columns)))
    means = method.estimates(swarm)
    if np.array_equal(means, estimates[last]):
        first, note = last + 1, f"continuing IF2 from iteration {last + 1}"
    elif np.array_equal(means, estimates[last - 1]):
        rows = rows[rows["iteration"] < last]
        first, note = last, f"continuing IF2 from iteration {last} (computed again: a stopped run saved its estimates, " \
                            "not its swarm)"
    else:
        raise damaged(swarm_path, f"holds a swarm whose means are not the estimates of iteration {last} in {path.name}")
    if first > target.estimation.iterations:
        note = ""
    return CellWork(target.cell, target, rows, swarm, first, started=False, note=note)


def _sampler(plan: Plan, target: EstimationTarget):
    """The cell's PMMH: iteration by iteration on numpy, compiled blocks of iterations on jax
    (:class:`~pfx.estimation.compiled_pmmh.CompiledChains`, imported only then: it needs the jax extra)."""
    sampler = ParticleMarginalMetropolisHastings(target, plan.experiment.seed, target.cell.stream_key)
    if target.cell.filter.backend != "jax":
        return sampler
    from pfx.estimation.compiled_pmmh import CompiledChains

    return CompiledChains(sampler)


def _iterated_filtering(plan: Plan, target: EstimationTarget) -> IteratedFiltering:
    return IteratedFiltering(target, plan.experiment.seed, target.cell.stream_key)


# -- running the iterations -----------------------------------------------------------------------------

def _run_pmmh(item: CellWork, plan: Plan, out: Path, report: Callable[[str], None], bar=NO_BAR) -> pd.DataFrame:
    """The cell's remaining iterations; its rows saved every CHECKPOINT_SECONDS, at the end, and
    when the run stops (all complete iterations: a stopped run keeps its work). ``bar`` counts
    the iterations as they are reported (on jax, a compiled block's at its end)."""
    estimation, target, chains = plan.experiment.estimation, item.target, item.state
    sampler = _sampler(plan, target)
    frames, unsaved, saved = [item.rows], item.started, time.perf_counter()

    def record(iteration: int, accepted: np.ndarray) -> None:
        nonlocal frames, unsaved, saved
        frames.append(_chain_rows(chains, iteration, accepted, target))
        bar.advance()
        unsaved = True
        if time.perf_counter() - saved > CHECKPOINT_SECONDS:
            frames = [pd.concat(frames, ignore_index=True)]
            write_csv(frames[0], progress_file(out, item.cell))
            unsaved, saved = False, time.perf_counter()
        raise_if_requested()           # a stop whose exception a finaliser swallowed

    try:
        iteration = item.first
        while iteration <= estimation.iterations:
            if iteration == estimation.warm_up + 1 and after_warm_up_applies(plan, item):
                bar.describe(f"{_bar_name(plan, item)}: particles: auto, measuring again")
                item.target = measure_after_warm_up(plan, item, chains, out, report)
                bar.describe(_bar_name(plan, item))
                sampler = _sampler(plan, item.target)
            # a block ends at the warm-up's end too (where `particles: auto` may measure again)
            last = min(iteration + sampler.block_size - 1, estimation.iterations,
                       estimation.warm_up if iteration <= estimation.warm_up else estimation.iterations)
            sampler.run(chains, iteration, last, record)
            iteration = last + 1
    finally:
        if unsaved:
            frames = [pd.concat(frames, ignore_index=True)]
            write_csv(frames[0], progress_file(out, item.cell))
    return frames[0]


def _bar_name(plan: Plan, item: CellWork) -> str:
    """What the iterations' bar says it counts: the experiment, and the cell where there are several."""
    return plan.experiment.name if len(plan.cells) == 1 else f"{plan.experiment.name}, cell {item.cell.key}"


def _chain_rows(chains: Chains, iteration: int, accepted: np.ndarray, target: EstimationTarget) -> pd.DataFrame:
    columns, count = target.columns, len(chains.values)
    rows = pd.DataFrame({"chain": np.arange(count), "iteration": iteration,
                         "warm_up": iteration <= target.estimation.warm_up,
                         **{name: chains.values[:, j] for j, name in enumerate(columns)},
                         "log_likelihood": chains.log_likelihood, "log_prior": chains.log_prior,
                         "accepted": accepted})
    return rows[CHAINS.progress_columns(columns)]


def _run_if2(item: CellWork, plan: Plan, out: Path, report: Callable[[str], None], bar=NO_BAR) -> pd.DataFrame:
    """The cell's remaining passes, each saved as it ends: the table, then the swarm (a run
    stopped between the two leaves the table a pass ahead, which the next run computes again);
    ``bar`` counts them."""
    estimation, target, rows = plan.experiment.estimation, item.target, item.rows
    method = _iterated_filtering(plan, target)

    def record(iteration: int, swarm: np.ndarray, log_likelihood: np.ndarray) -> None:
        nonlocal rows
        rows = pd.concat([rows, _if2_rows(method.estimates(swarm), iteration, log_likelihood, target)],
                         ignore_index=True)
        write_csv(rows, progress_file(out, item.cell))
        save_swarm(swarm, swarm_file(out, item.cell))
        bar.advance()
        raise_if_requested()

    # pass by pass on numpy; compiled blocks of passes on jax (imported only then: it needs the jax extra)
    runner = method
    if target.cell.filter.backend == "jax":
        from pfx.estimation.compiled_if2 import CompiledSwarm

        runner = CompiledSwarm(method)
    runner.run(item.state, item.first, estimation.iterations, record)
    return rows


def _if2_rows(estimates: np.ndarray, iteration: int, log_likelihood: np.ndarray, target: EstimationTarget
              ) -> pd.DataFrame:
    columns = target.columns
    rows = pd.DataFrame({"replicate": np.arange(len(estimates)), "iteration": iteration,
                         **{name: estimates[:, j] for j, name in enumerate(columns)},
                         "log_likelihood": log_likelihood})
    return rows[IF2.progress_columns(columns)]


# -- the tables ---------------------------------------------------------------------------------------------

def _assemble(plan: Plan, out: Path, work: list[CellWork], report: Callable[[str], None]) -> None:
    """The tables of every cell, from its rows (labels first, as in trials.csv)."""
    estimation = plan.experiment.estimation
    columns, labels = estimation.columns, plan.label_columns
    frames, summaries, finals, spreads = [], [], [], []
    for item in work:
        cell = item.cell
        rows = item.rows[item.rows["iteration"] <= estimation.iterations]
        labelled = pd.concat([pd.DataFrame({"cell": cell.key, **cell.labels}, index=rows.index), rows], axis=1)
        frames.append(labelled)
        if estimation.method == "pmmh":
            summary = posterior_summary(rows, columns, estimation.warm_up)
            if (summary["acceptance_rate"] == 0).all():
                report(f"{out}: cell {cell.key}: no chain accepted a proposal after the warm-up, so each chain's "
                       "posterior draws are one point, repeated (posterior.csv: acceptance_rate 0); try a smaller "
                       "proposal_sd, adapt, a longer warm-up or more particles")
            # flagged chains: the likelihood's spread measured where it may be the cause, and what to try
            spread = spread_at_posterior_mean(item.target, summary, plan.experiment.seed)
            if spread is not None:
                spreads.append(pd.concat([pd.DataFrame({"cell": cell.key, **cell.labels}, index=spread.index), spread],
                                         axis=1)[LIKELIHOOD_SPREAD.columns(labels, columns)])
            advice = pmmh_advice(summary, estimation.iterations, None if spread is None else spread.iloc[0],
                                 chosen_by_pilot=item.pilot is not None, chains=rows, adapt=estimation.adapt,
                                 adapt_after=estimation.adapt_after)
            if advice:
                report(f"{out}: cell {cell.key}: {advice}")
            summaries.append(pd.concat([pd.DataFrame({"cell": cell.key, **cell.labels}, index=summary.index),
                                        summary], axis=1))
        else:
            last = rows[rows["iteration"] == rows["iteration"].max()].sort_values("replicate")
            estimates = last[columns].to_numpy(dtype=float)
            log_likelihood, standard_error = _iterated_filtering(plan, item.target).evaluate(estimates)
            final = pd.DataFrame({"cell": cell.key, **cell.labels, "replicate": last["replicate"].to_numpy(),
                                  **{name: estimates[:, j] for j, name in enumerate(columns)},
                                  "log_likelihood": log_likelihood, "log_likelihood_se": standard_error,
                                  "flag": replicate_flags(log_likelihood, standard_error, len(columns))})
            finals.append(final[MAXIMUM_LIKELIHOOD.columns(labels, columns)])
            # (a profile's replicates at other grid values lie below the best by design: no advice)
            advice = if2_advice(final["flag"], len(columns)) if estimation.method == "if2" else ""
            if advice and np.isfinite(log_likelihood).any():      # none finite: the line below says it
                report(f"{out}: cell {cell.key}: {advice}")
            if not np.isfinite(log_likelihood).any():
                report(f"{out}: cell {cell.key}: every replicate's likelihood is zero at its final estimate "
                       "(log_likelihood -inf in maximum_likelihood.csv): no particle explained some measurement; "
                       "try other starts, a smaller random_walk_sd, more particles, or a wider measurement noise")
    table = pd.concat(frames, ignore_index=True)
    if estimation.method == "pmmh":
        write_csv(table[CHAINS.columns(labels, columns)], out / "chains.csv")
        write_csv(pd.concat(summaries, ignore_index=True), out / "posterior.csv")
        draws = table[~table["warm_up"].astype(bool)]
        write_csv(prior_grid(estimation, draws), out / "priors.csv")
        forecasts = plan.experiment.outputs.forecasts
        if forecasts.requested:            # from posterior draws, each with its own filter
            write_csv(posterior_forecast_table(plan, work, forecasts, out, report), out / "forecasts.csv")
        if spreads:
            write_csv(pd.concat(spreads, ignore_index=True), out / LIKELIHOOD_SPREAD.file)
        else:                   # an extended run whose chains are no longer flagged: no stale measurement
            (out / LIKELIHOOD_SPREAD.file).unlink(missing_ok=True)
    else:
        write_csv(table[IF2.columns(labels, columns)], out / "if2.csv")
        write_csv(pd.concat(finals, ignore_index=True), out / "maximum_likelihood.csv")
        if estimation.method == "profile":        # the grid's estimates, and MCAP's interval (pfx.estimation.profile)
            for name, frame in profile_tables(pd.concat(finals, ignore_index=True), estimation, labels).items():
                write_csv(frame, out / name)
                if name == PROFILE_INTERVAL_FILE:
                    for row in frame.itertuples(index=False):
                        report(f"{out}: cell {row.cell}: {profile_line(row)}")
