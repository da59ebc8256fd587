"""The pilot behind ``particles: auto``: a PMMH cell's particle count, measured or read back.

A cell whose ``particles`` is ``auto`` gets its N in the run's read-and-check phase
(:mod:`pfx.run.estimation`): read back from the folder's ``estimation/<cell>.particle_count.csv``
when a resumed or extended run finds one (checked by replaying the rule on its rows), else
measured by the rule of :mod:`pfx.estimation.particle_count` at ``estimation.particle_count.at``
(the chains' start by default), which may refuse before anything is written. The write phase
then keeps the measured rows at once (so that no later run measures again), says each choice in
a line with what the chains will cost at it (:func:`cost_text`: their wall time projected from
the run's own filter runs at that N, so that a run that will take an hour says so before it
starts), and the tables end with particle_count.csv. While it measures, the pilot shows its
progress bar (:mod:`pfx.run.progress_bar`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from pfx.config.estimation import AUTO
from pfx.config.estimation_tables import CELL, PARTICLE_COUNT
from pfx.config.plan import Cell, Plan
from pfx.errors import ConfigError
from pfx.estimation.likelihood_spread import Spread, log_likelihood_spread
from pfx.estimation.particle_count import ParticleChoice, choose_particle_count, effective_sd, ladder
from pfx.estimation.pmmh import Chains
from pfx.estimation.target import EstimationTarget
from pfx.folder_state import FolderState
from pfx.numerics.seeding import restart_seed
from pfx.result_folder import write_csv
from pfx.run.estimation_progress import damaged, pilot_file, read_pilot
from pfx.run.progress_bar import progress_bar


def is_auto(plan: Plan, cell: Cell) -> bool:
    return plan.experiment.estimation.method == "pmmh" and cell.filter.uses_particles and cell.filter.particles == AUTO


def particle_count(plan: Plan, target: EstimationTarget, out: Path, state: FolderState,
                   before, progress: bool = False) -> tuple[ParticleChoice, bool]:
    """The cell's particle count and whether this run measured it: read back from the folder's
    progress (a resumed or extended run; checked, as every progress file is), the count found
    before the lock, or the pilot's (:mod:`pfx.estimation.particle_count`), writing nothing;
    ``progress``: the pilot shows its bar (:func:`_with_bar`)."""
    path = pilot_file(out, target.cell)
    if state.manifest is not None and path.is_file():
        return _read_back_pilot(plan, target, path), False
    if state.complete:
        raise damaged(path, "is missing, and the folder's manifest.json records a finished run")
    if before is not None and before.pilot is not None:
        return before.pilot, before.pilot_measured
    settings = plan.experiment.estimation.pilot
    point, point_text = _pilot_point(plan, target)

    def spread_at(particles: int):
        return log_likelihood_spread(target, point, particles, settings.runs, plan.experiment.seed)

    name = f"{plan.experiment.name}: particles: auto"
    with progress_bar(progress, sum(ladder(settings)), name, counted=False) as bar:
        return choose_particle_count(_with_bar(spread_at, settings, bar, name), settings,
                                     key=_particles_key(plan, target.cell), point_text=point_text, file=plan.file), True


def _with_bar(spread_at: Callable[[int], Spread], settings, bar, name: str) -> Callable[[int], Spread]:
    """``spread_at``, advancing the pilot's bar. Its work is weighed in particles, which a rung's
    time grows with: the bar starts at the ladder's every rung up to the cap, and once a rung is
    at or below the target, the one N left to measure is about as large as it (rule step 2)."""
    done = 0

    def measure(particles: int) -> Spread:
        nonlocal done
        bar.describe(f"{name}, N = {particles}")
        row = spread_at(particles)
        done += particles
        bar.advance(particles)
        if effective_sd(row) <= settings.target_sd:
            bar.resize(done + particles)
        return row

    return measure


def _read_back_pilot(plan: Plan, target: EstimationTarget, path: Path) -> ParticleChoice:
    """The pilot file's choice, if replaying the rule on its rows measures exactly them and
    chooses the same count (else it was changed by something else: refused)."""
    rows, chosen = read_pilot(path)
    remaining = list(rows)

    def recorded(particles: int):
        if not remaining or remaining[0].particles != particles:
            raise damaged(path, f"does not hold the particle counts the rule measures ({particles} next)")
        return remaining.pop(0)

    try:
        choice = choose_particle_count(recorded, plan.experiment.estimation.pilot, key="", point_text="")
    except ConfigError as error:
        if error.file == str(path):
            raise
        raise damaged(path, "its rows end above the target sd, where the rule chooses nothing") from None
    if remaining or choice.particles != chosen:
        raise damaged(path, f"marks {chosen} particles chosen, and the rule on its rows chooses {choice.particles}")
    return choice


def _pilot_point(plan: Plan, target: EstimationTarget) -> tuple[np.ndarray, str]:
    """Where the pilot measures (``particle_count.at``), and it in words: the given point, or the
    chains' start (the per-parameter median of their starts where they differ: the median
    commutes with the monotone transforms). Starts the model refuses are refused as PMMH's
    iteration 0 refuses them (:meth:`EstimationTarget.check_starts`)."""
    at = plan.experiment.estimation.pilot.at
    if isinstance(at, dict):
        point, origin, key = np.array([at[path] for path in target.paths]), "estimation.particle_count.at", "at"
    else:
        starts = target.starting_values(plan.experiment.seed, target.cell.stream_key)
        refused = np.array([target.model_at(row) is None for row in starts])
        try:
            target.check_starts(starts, np.where(refused, -np.inf, 0.0))
        except ConfigError as error:
            raise error.located(file=plan.file) from None
        common = bool((starts == starts[0]).all())
        point, key = np.median(starts, axis=0), "at"
        origin = "the chains' start" if common else "the median of the chains' starts"
    text = ", ".join(f"{name}={value:.6g}" for name, value in zip(target.columns, point)) + f" ({origin})"
    if target.model_at(point) is None:
        raise ConfigError(f"the pilot of particles: auto measures at {text}, where the model refuses the parameters; "
                          "give estimation.particle_count.at a point the model accepts", file=plan.file,
                          key=f"estimation.particle_count.{key}")
    return point, text


def _particles_key(plan: Plan, cell: Cell) -> str:
    """The key that made the cell's particles auto: its arm's, or the filter section's."""
    arm = plan.experiment.arms.get(cell.labels["arm"])
    return f"arms.{cell.labels['arm']}.particles" if arm is not None and "particles" in arm.model_fields_set \
        else "filter.particles"


# -- after the warm-up: measured again where the chains have gone ---------------------------------------

def after_warm_up_applies(plan: Plan, item) -> bool:
    """Whether the cell's count is measured again after the warm-up (``after_warm_up``, and a
    warm-up to measure after)."""
    estimation = plan.experiment.estimation
    return item.pilot is not None and estimation.pilot.after_warm_up and estimation.warm_up >= 1


def read_back_after_warm_up(plan: Plan, item, out: Path) -> EstimationTarget:
    """For a run resumed or extended past the warm-up: the count measured after it, read back
    (its file must be there), and the cell's problem at that count."""
    path = pilot_file(out, item.cell, "after_warm_up")
    if not path.is_file():
        raise damaged(path, f"is missing, and the chains are past their warm-up of {plan.experiment.estimation.warm_up} "
                            "iterations, after which particles: auto measured again")
    item.after_warm_up = _read_back_pilot(plan, item.target, path)
    return item.target.with_particles(item.after_warm_up.particles)


def measure_after_warm_up(plan: Plan, item, chains: Chains, out: Path, report: Callable[[str], None]
                          ) -> EstimationTarget:
    """At the end of the warm-up: the pilot again, at the median of the chains' positions over
    the warm-up's second half (where the posterior is, as far as the warm-up found it), and each
    chain's current estimate computed again at the new count, from a stream of its own
    (:func:`pfx.numerics.seeding.restart_seed`). The chains after the warm-up are then plain
    PMMH chains at that count, started where the warm-up left them (the warm-up's draws are not
    the posterior's, whatever their count). Returns the cell's problem at the new count."""
    estimation, target = plan.experiment.estimation, item.target
    path = pilot_file(out, item.cell, "after_warm_up")
    if path.is_file():                      # a run stopped between the measurement and the next iteration
        item.after_warm_up, how = _read_back_pilot(plan, target, path), f"read back from {path.name}"
    else:
        second_half = np.stack(chains.history[estimation.warm_up // 2 + 1:estimation.warm_up + 1])   # (k, C, p)
        point = np.median(second_half.reshape(-1, target.dimension), axis=0)
        text = (", ".join(f"{name}={value:.6g}" for name, value in zip(target.columns, point))
                + " (the median of the chains over the warm-up's second half)")

        def spread_at(particles: int):
            return log_likelihood_spread(target, point, particles, estimation.pilot.runs, plan.experiment.seed)

        item.after_warm_up = choose_particle_count(spread_at, estimation.pilot, key=_particles_key(plan, item.cell),
                                                   point_text=text, file=plan.file)
        write_csv(item.after_warm_up.table(), path)
        how = f"measured at {text}"
    best = item.after_warm_up.chosen
    moved = target.with_particles(best.particles)
    seeds = [restart_seed(plan.experiment.seed, item.cell.stream_key, chain) for chain in range(len(chains.values))]
    started = time.perf_counter()
    chains.log_likelihood = moved.log_likelihoods(chains.values, seeds)
    timed = ("their estimates computed again", time.perf_counter() - started)     # one iteration's filter runs
    report(f"{out}: cell {item.cell.key}: particles auto after the warm-up -> {best.particles} (sd of the "
           f"log-likelihood {best.sd:.3g}, target {estimation.pilot.target_sd:g}; {how})"
           + cost_text(item.after_warm_up, target, estimation.iterations - estimation.warm_up, " after the warm-up",
                       timed))
    report("  " + _ladder_text(item.after_warm_up))
    return moved


def _ladder_text(choice: ParticleChoice) -> str:
    return ", ".join(f"N={row.particles}: sd {row.sd:.3g}" + ("" if row.finite == row.runs else
                     f" ({row.runs - row.finite} of {row.runs} runs -inf)") for row in choice.rows)


def pilot_record(work: list) -> dict:
    """The manifest's ``particle_count``: each auto cell's particle count, the one its posterior
    draws used (after the warm-up's measurement, where there was one; none: nothing)."""
    chosen = {item.cell.key: (item.after_warm_up or item.pilot).particles for item in work if item.pilot is not None}
    return {"particle_count": chosen} if chosen else {}


def keep_pilots(out: Path, work: list, report: Callable[[str], None]) -> None:
    """The write phase's first step for the cells with ``particles: auto``: the pilot files of
    the counts measured by this run (kept at once, so that no later run measures again), and each
    choice said in a line, with the ladder measured."""
    for item in work:
        if item.pilot is None:
            continue
        if item.pilot_measured:
            write_csv(item.pilot.table(), pilot_file(out, item.cell))
        estimation, best = item.target.estimation, item.pilot.chosen
        how = "measured" if item.pilot_measured else f"read back from {pilot_file(out, item.cell).name}"
        left = estimation.iterations - item.first + 1
        # the starts, computed by this run at the chosen N, are one iteration's filter runs, timed
        timed = ("their starts", item.seconds) if item.started and item.after_warm_up is None else None
        cost = cost_text(item.after_warm_up or item.pilot, item.target, left, "" if item.first == 1 else " left", timed)
        again = item.after_warm_up is None and estimation.pilot.after_warm_up and item.first <= estimation.warm_up + 1
        if cost and again:
            cost += "; N is measured again after the warm-up"
        report(f"{out}: cell {item.cell.key}: particles auto -> {best.particles} (sd of the log-likelihood "
               f"{best.sd:.3g}, target {estimation.pilot.target_sd:g}; {how}){cost}")
        report("  " + _ladder_text(item.pilot))


# -- what the chains will cost ---------------------------------------------------------------------------

def cost_text(choice: ParticleChoice, target: EstimationTarget, iterations: int, which: str = "",
              timed: tuple[str, float] | None = None) -> str:
    """What the chains will cost at the chosen N, said before they run: "; the 4 chains x 2000
    iterations will take about 58 min at 0.43 s per filter run (...)", or "" when no iteration is
    left. Each iteration makes one filter run per chain (C; fewer where a proposal leaves the
    prior), run as the chains' starts were: in one batch where the target is batched, else one
    by one. So the time per iteration is measured where it can be:

    * ``timed``: what this run timed of C filter runs at that N, as an iteration makes them
      (the starts, or after the warm-up each chain's estimate computed again), and its seconds:
      an iteration costs that;
    * else (a resumed or extended run, whose starts were computed before) the pilot's R runs at
      N, t seconds: a run costs t / R. Run one by one, that is what an iteration's run costs; in
      one batch, a call's fixed cost is shared by R rows in the pilot and C in the chains, so
      the projection is a lower bound ("at least");
    * on jax the pilot's and the starts' times are mostly compiling (a program for each shape),
      so no time is projected.
    """
    if iterations <= 0:
        return ""
    if target.cell.filter.backend == "jax":
        return ("; on jax the pilot's times are mostly compiling (a program for each N), so they do not tell what "
                "the chains will take: their progress bar measures it")
    chains, best = target.estimation.chains, choice.chosen
    if timed is not None:
        what, seconds = timed
        per_run, bound = seconds / chains, "about"
        source = f"{what}, {chains} filter runs at N = {best.particles}, took {seconds:.2g} s"
    else:
        per_run, bound = best.seconds / best.runs, "at least" if target.batched else "about"
        source = f"the pilot's {best.runs} runs at N = {best.particles} took {best.seconds:.2g} s"
        if target.batched:
            source += f" in one batch, whose fixed cost the chains' batches of {chains} share among fewer runs"
    return (f"; the {chains} chains x {iterations} iterations{which} will take {bound} "
            f"{duration_text(per_run * chains * iterations)} at {per_run:.2g} s per filter run ({source})")


def duration_text(seconds: float) -> str:
    """A wall time in words, to two significant figures: 45 s, 58 min, 2.5 h."""
    if seconds < 60:
        return f"{seconds:.2g} s"
    if seconds < 3600:
        return f"{seconds / 60:.2g} min"
    return f"{seconds / 3600:.2g} h" if seconds < 100 * 3600 else f"{seconds / 3600:.0f} h"


def write_particle_count(plan: Plan, out: Path, work: list) -> None:
    """particle_count.csv: every auto cell's pilot rows, the cell's columns and the stage first."""
    frames = []
    for item in work:
        for stage, choice in (("before_chains", item.pilot), ("after_warm_up", item.after_warm_up)):
            if choice is not None:
                rows = choice.table()
                frames.append(pd.concat([pd.DataFrame({CELL: item.cell.key, **item.cell.labels, "stage": stage},
                                                      index=rows.index), rows], axis=1))
    if frames:
        table = pd.concat(frames, ignore_index=True)
        write_csv(table[[CELL, *plan.label_columns, "stage", *PARTICLE_COUNT.own]], out / PARTICLE_COUNT.file)
