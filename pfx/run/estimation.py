"""Running a parameter-estimation experiment (a config with ``estimation:``) into its folder.

Every cell runs the method (:mod:`pfx.estimation.pmmh`, :mod:`pfx.estimation.if2`) on its
dataset. Progress is kept as it goes, in ``estimation/<cell>.csv`` (every chain's rows, or
every IF2 iteration's estimates, with ``estimation/<cell>.swarm.npy``, IF2's particle swarm):
an interrupted run resumes from them, and a finished one asked for more ``iterations`` extends
its chains (each iteration's random numbers depend only on its chain and its index, so either
way the numbers are those of one uninterrupted run). Then the tables: chains.csv,
posterior.csv, priors.csv (PMMH); if2.csv, maximum_likelihood.csv (IF2); and the figures.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from pfx.config.plan import Cell, Plan
from pfx.errors import ConfigError
from pfx.estimation.if2 import IteratedFiltering
from pfx.estimation.pmmh import Chains, ParticleMarginalMetropolisHastings
from pfx.estimation.summary import posterior_summary, prior_grid
from pfx.estimation.target import EstimationTarget, dataset
from pfx.folder_lock import folder_lock
from pfx.result_folder import MANIFEST, read_table, write_bytes, write_csv, write_text

PROGRESS = "estimation"
CHECKPOINT_SECONDS = 10.0
DEFAULT_FIGURES = {"pmmh": ["chain_traces", "posterior_marginals", "posterior_pairs"], "if2": ["if2_convergence"]}
TABLES = ("chains.csv", "posterior.csv", "priors.csv", "if2.csv", "maximum_likelihood.csv")


def figures_of(plan: Plan) -> list[str]:
    outputs = plan.experiment.outputs
    if "figures" in outputs.model_fields_set:
        return list(outputs.figures)
    return DEFAULT_FIGURES[plan.experiment.estimation.method]


def run_estimation(plan: Plan, out: Path, *, fresh: bool, report: Callable[[str], None], progress: bool,
                   manifest_of: Callable, write_config: Callable, now: Callable) -> Path:
    """Run (or resume, or extend) every cell's estimation into ``out``; tables and figures."""
    from pfx.result_folder import inspect_folder

    inspect_folder(plan, out, fresh)              # refuse a folder of other results, early
    with folder_lock(out, remove_if_unused=True):
        inspect_folder(plan, out, fresh, locked=True)
        if fresh:
            for name in TABLES:
                (out / name).unlink(missing_ok=True)
            for path in (out / PROGRESS).glob("*") if (out / PROGRESS).is_dir() else []:
                path.unlink()
        (out / PROGRESS).mkdir(exist_ok=True)
        estimation = plan.experiment.estimation
        manifest = {**manifest_of(plan, now()), "estimation": {"method": estimation.method,
                                                               "iterations": estimation.iterations,
                                                               "chains": estimation.chains}}
        manifest["figures"] = figures_of(plan)
        manifest.pop("trials", None)
        earlier = _earlier_times(out, fresh)
        write_config(plan, out)
        write_text(json.dumps(manifest, indent=2), out / MANIFEST)
        cell_times, batched = {}, {}
        for cell in plan.cells:
            cell_started = time.perf_counter()
            target = EstimationTarget(cell, estimation, dataset(cell, plan.experiment.seed))
            batched[cell.key] = target.batched
            run = _run_pmmh if estimation.method == "pmmh" else _run_if2
            run(plan, target, out, report)
            cell_times[cell.key] = time.perf_counter() - cell_started
        _assemble(plan, out)
        # Times add up over the runs that made the folder (a resumed or extended run's own time
        # plus the earlier ones'), as a filter run's do.
        cell_times = {key: round(value + earlier.get(key, 0.0), 3) for key, value in cell_times.items()}
        manifest.update(finished=now(), complete=True, wall_time_s=round(sum(cell_times.values()), 3),
                        cell_wall_time_s=cell_times, batched=batched)
        write_text(json.dumps(manifest, indent=2), out / MANIFEST)
    from pfx.figures.registry import render_figures

    render_figures(out, manifest["figures"], tuple(plan.experiment.outputs.formats))
    return out


def _earlier_times(out: Path, fresh: bool) -> dict:
    """The cells' wall times of the runs that made the folder so far: the finished manifest's
    (a run stopped before its end records none, and its time is lost)."""
    from pfx.result_folder import read_manifest

    manifest = None if fresh else read_manifest(out)
    return dict((manifest or {}).get("cell_wall_time_s") or {}) if (manifest or {}).get("complete") else {}


def _progress_file(out: Path, cell: Cell) -> Path:
    return out / PROGRESS / f"{cell.key}.csv"


def _kept(out: Path, cell: Cell, iterations: int) -> pd.DataFrame:
    """A cell's rows kept from an earlier run (empty if none); refuses to drop iterations."""
    path = _progress_file(out, cell)
    if not path.is_file():
        return pd.DataFrame()
    rows = read_table(path)
    if not rows.empty and rows["iteration"].max() > iterations:
        raise ConfigError(f"{out} holds {rows['iteration'].max()} iterations of cell {cell.key}; asking for "
                          f"{iterations} would drop some (ask for at least as many, or use --fresh)",
                          file=str(out), key="estimation.iterations")
    return rows


def _run_pmmh(plan: Plan, target: EstimationTarget, out: Path, report: Callable[[str], None]) -> None:
    estimation, cell, columns = target.estimation, target.cell, target.columns
    sampler = ParticleMarginalMetropolisHastings(target, plan.experiment.seed, cell.stream_key)
    kept = _kept(out, cell, estimation.iterations)
    frames = [kept] if not kept.empty else []
    if kept.empty:
        chains = sampler.start()
        frames.append(_chain_rows(chains, 0, np.zeros(estimation.chains, dtype=bool), columns, estimation.warm_up))
        first = 1
    else:
        kept = kept.sort_values(["iteration", "chain"])
        last = kept[kept["iteration"] == kept["iteration"].max()]
        chains = Chains(values=last[columns].to_numpy(dtype=float), log_likelihood=last["log_likelihood"].to_numpy(float),
                        log_prior=last["log_prior"].to_numpy(float),
                        history=[rows[columns].to_numpy(dtype=float) for _, rows in kept.groupby("iteration", sort=True)])
        first = int(last["iteration"].iloc[0]) + 1
        if first <= estimation.iterations:
            report(f"{out}: cell {cell.key}: continuing the chains from iteration {first}")
    saved = time.perf_counter()
    for iteration in range(first, estimation.iterations + 1):
        accepted = sampler.iterate(chains, iteration)
        frames.append(_chain_rows(chains, iteration, accepted, columns, estimation.warm_up))
        if time.perf_counter() - saved > CHECKPOINT_SECONDS or iteration == estimation.iterations:
            frames = [pd.concat(frames, ignore_index=True)]
            write_csv(frames[0], _progress_file(out, cell))
            saved = time.perf_counter()


def _chain_rows(chains: Chains, iteration: int, accepted: np.ndarray, columns: list[str], warm_up: int) -> pd.DataFrame:
    count = len(chains.values)
    return pd.DataFrame({"chain": np.arange(count), "iteration": iteration, "warm_up": iteration <= warm_up,
                         **{name: chains.values[:, j] for j, name in enumerate(columns)},
                         "log_likelihood": chains.log_likelihood, "log_prior": chains.log_prior,
                         "accepted": accepted})


def _run_if2(plan: Plan, target: EstimationTarget, out: Path, report: Callable[[str], None]) -> None:
    estimation, cell, columns = target.estimation, target.cell, target.columns
    method = IteratedFiltering(target, plan.experiment.seed, cell.stream_key)
    kept = _kept(out, cell, estimation.iterations)
    swarm_file = out / PROGRESS / f"{cell.key}.swarm.npy"
    if kept.empty or not swarm_file.is_file():
        swarm = method.start()
        frames = [_if2_rows(method.estimates(swarm), 0, np.full(method.replicates, np.nan), columns)]
        first = 1
    else:
        import io

        swarm = np.load(io.BytesIO(swarm_file.read_bytes()))
        frames = [kept]
        first = int(kept["iteration"].max()) + 1
        if first <= estimation.iterations:
            report(f"{out}: cell {cell.key}: continuing IF2 from iteration {first}")
    for iteration in range(first, estimation.iterations + 1):
        swarm, log_likelihood = method.iterate(swarm, iteration)
        frames.append(_if2_rows(method.estimates(swarm), iteration, log_likelihood, columns))
        _save_swarm(swarm, swarm_file)
        write_csv(pd.concat(frames, ignore_index=True), _progress_file(out, cell))
    if first > estimation.iterations:
        write_csv(pd.concat(frames, ignore_index=True), _progress_file(out, cell))


def _save_swarm(swarm: np.ndarray, path: Path) -> None:
    import io

    buffer = io.BytesIO()
    np.save(buffer, swarm)
    write_bytes(buffer.getvalue(), path)


def _if2_rows(estimates: np.ndarray, iteration: int, log_likelihood: np.ndarray, columns: list[str]) -> pd.DataFrame:
    return pd.DataFrame({"replicate": np.arange(len(estimates)), "iteration": iteration,
                         **{name: estimates[:, j] for j, name in enumerate(columns)},
                         "log_likelihood": log_likelihood})


def _assemble(plan: Plan, out: Path) -> None:
    """The tables of every cell, from the progress files (labels first, as in trials.csv)."""
    estimation = plan.experiment.estimation
    columns = estimation.columns
    frames, summaries, finals = [], [], []
    for cell in plan.cells:
        rows = read_table(_progress_file(out, cell))
        rows = rows[rows["iteration"] <= estimation.iterations]
        labelled = pd.concat([pd.DataFrame({"cell": cell.key, **cell.labels}, index=rows.index), rows], axis=1)
        frames.append(labelled)
        if estimation.method == "pmmh":
            summary = posterior_summary(rows, columns, estimation.warm_up)
            summaries.append(pd.concat([pd.DataFrame({"cell": cell.key, **cell.labels}, index=summary.index),
                                        summary], axis=1))
        else:
            method = IteratedFiltering(EstimationTarget(cell, estimation, dataset(cell, plan.experiment.seed)),
                                       plan.experiment.seed, cell.stream_key)
            last = rows[rows["iteration"] == rows["iteration"].max()].sort_values("replicate")
            estimates = last[columns].to_numpy(dtype=float)
            log_likelihood, standard_error = method.evaluate(estimates)
            final = pd.DataFrame({"cell": cell.key, **cell.labels, "replicate": last["replicate"].to_numpy(),
                                  **{name: estimates[:, j] for j, name in enumerate(columns)},
                                  "log_likelihood": log_likelihood, "log_likelihood_se": standard_error})
            finals.append(final)
    table = pd.concat(frames, ignore_index=True)
    if estimation.method == "pmmh":
        write_csv(table, out / "chains.csv")
        write_csv(pd.concat(summaries, ignore_index=True), out / "posterior.csv")
        draws = table[~table["warm_up"].astype(bool)]
        write_csv(prior_grid(estimation, draws), out / "priors.csv")
    else:
        write_csv(table, out / "if2.csv")
        write_csv(pd.concat(finals, ignore_index=True), out / "maximum_likelihood.csv")
