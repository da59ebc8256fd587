"""One task of a run: some trials of one cell, all at once.

:func:`run_batch` simulates the truth of each trial from its own stream, runs the cell's filter
on all of them in one call, and returns the batch's table rows: one row per trial
(trials.csv), the full per-step traces of the traced trials (steps.csv), the kept particle
clouds (particles.csv) and every trial's per-step values (for steps_summary.csv). It is what an
executor sends to a worker, so it depends on nothing but its arguments. What the filter keeps
(the particle clouds, the forecasts) it returns in its trace; the requests only say what to keep.

With recorded data (``cell.data``, :mod:`pfx.config.data`) nothing is simulated: every trial
filters the recorded measurements (trials replicate the filter's randomness), and the truth is
the recorded one, or none: the columns that need it are then empty.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Optional

import numpy as np
import pandas as pd

from pfx.analysis.genealogy import distinct_ancestor_counts
from pfx.analysis.metrics import MetricInputs, compute_metrics, error_distance, normalised_squares, state_error
from pfx.analysis.step_summary import step_values
from pfx.config.forecasts import ForecastOutputs, origin_steps
from pfx.config.plan import Cell
from pfx.config.schema import ParticleSnapshots
from pfx.filters.particle.forecasting import ForecastRequest
from pfx.filters.particle.recorders import SnapshotRequest, SpreadCriterion
from pfx.filters.trace import Snapshot
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, filter_seed, truth_seed


@dataclass
class BatchResult:
    cell_key: str
    trials: pd.DataFrame
    steps: pd.DataFrame
    wall_time: float
    particles: Optional[pd.DataFrame] = None
    step_values: Optional[dict] = None        # every trial's per-step values (pfx.analysis.step_summary)
    genealogy: Optional[pd.DataFrame] = None  # genealogy.csv rows (outputs.genealogy)
    forecasts: Optional[pd.DataFrame] = None  # forecasts.csv rows (outputs.forecasts)


def run_batch(cell: Cell, seed: int, trials: list[int], trace_trials: int,
              snapshots: Optional[ParticleSnapshots] = None, datasets: Optional[int] = None,
              genealogy_trials: int = 0, forecasts: Optional[ForecastOutputs] = None) -> BatchResult:
    """Simulate the truth and run the filter for some trials of one cell; return table rows."""
    truth_seeds = [truth_seed(seed, t, datasets) for t in trials]
    filter_seeds = [filter_seed(seed, cell.stream_key, t) for t in trials]
    truth, measurements, observed = _truth_and_measurements(cell, truth_seeds)
    criterion = cell.metrics.convergence
    spread = SpreadCriterion(criterion.radius, criterion.weighted) if criterion.criterion == "spread" else None
    snapshot = None
    if snapshots is not None and snapshots.steps and cell.filter.uses_particles:
        rows = np.array([i for i, t in enumerate(trials) if t < snapshots.trials], dtype=np.intp)
        if rows.size:
            steps_kept = "all" if snapshots.steps == "all" else frozenset(snapshots.steps)
            snapshot = SnapshotRequest(rows=rows, steps=steps_kept, stages=frozenset(snapshots.stages))
    options = {"snapshot": snapshot} if snapshot is not None else {}
    traced = [i for i, t in enumerate(trials) if t < trace_trials]
    if cell.planned_filter.takes_trace_rows:      # costly per-step diagnostics for these rows only
        options["trace_rows"] = np.array(traced, dtype=np.intp)
    written = [i for i, t in enumerate(trials) if t < genealogy_trials] if cell.filter.uses_particles else []
    if written:                                    # genealogy.csv: each particle's ancestor, state and weight
        options.update(genealogy=True, history=True)
    if cell.metrics.scores and cell.planned_filter.computes_scores:     # the predictive distribution's scores
        options["scores"] = True
    forecast = _forecast_request(cell, trials, forecasts)
    if forecast is not None:
        options["forecast"] = forecast
    started = time.perf_counter()
    trace = cell.planned_filter.run(
        cell.filter_model, measurements, TrialStreams.from_seeds(filter_seeds), settings=cell.filter,
        prior=cell.prior, spread_criterion=spread, consistency=cell.metrics.consistency, **options)
    elapsed = time.perf_counter() - started
    with np.errstate(over="ignore", invalid="ignore"):   # a diverged filter has infinite errors
        metrics = compute_metrics(MetricInputs(truth=truth, trace=trace, model=cell.truth_model,
                                               config=cell.metrics, observed=observed))
    model = cell.truth_model
    # the time a trial's run took; on the jax backend its program's compilation apart (a config on
    # jax gets the column: docs/output-files.md), each trial its share of the batch's
    timings = {"run_time_s": (elapsed - trace.compile_time_s) / len(trials)}
    if "backend" in cell.labels:
        timings["compile_time_s"] = trace.compile_time_s / len(trials)
    rows = pd.DataFrame({"cell": cell.key, **cell.labels, "trial": trials, "seed": seed,
                         "truth_seed": truth_seeds, "filter_seed": filter_seeds, "steps": model.steps,
                         **metrics, **timings})
    with np.errstate(over="ignore", invalid="ignore"):
        steps = _steps_frame(cell, trials, traced, truth, trace, measurements, genealogy_trials)
    particles = _particles_frame(cell, trials, trace.snapshots) if snapshot is not None else None
    genealogy = _genealogy_frame(cell, trials, written, trace) if written else None
    forecast_rows = _forecasts_frame(cell, trials, trace.forecasts) if forecast is not None else None
    return BatchResult(cell.key, rows, steps, elapsed, particles, step_values(truth, trace, model), genealogy,
                       forecast_rows)


def _forecast_request(cell: Cell, trials: list[int], forecasts: Optional[ForecastOutputs]):
    """What to forecast in this batch (outputs.forecasts): its first trials' clouds at the
    origins, for a particle filter; None when nothing is asked of it."""
    if forecasts is None or not forecasts.requested or not cell.filter.uses_particles:
        return None
    rows = np.array([i for i, t in enumerate(trials) if t < forecasts.trials], dtype=np.intp)
    if not rows.size:
        return None
    return ForecastRequest(rows=rows, origins=origin_steps(forecasts, np.asarray(cell.truth_model.times(), dtype=float)),
                           horizons=tuple(forecasts.horizons), quantiles=tuple(forecasts.quantiles))


def _forecasts_frame(cell: Cell, trials: list[int], columns: Optional[dict]) -> Optional[pd.DataFrame]:
    """forecasts.csv rows: one per (trial, origin, horizon), the cell's labels first."""
    if not columns:
        return None
    times = np.asarray(cell.truth_model.times(), dtype=float)
    frame = {"cell": cell.key, **cell.labels, "trial": np.asarray(trials)[columns["row"]],
             "origin_step": columns["origin"], "origin_time": times[columns["origin"] - 1],
             "horizon": columns["horizon"], "step": columns["step"], "time": times[columns["step"] - 1]}
    frame.update({name: values for name, values in columns.items() if name not in ("row", "origin", "horizon", "step")})
    return pd.DataFrame(frame).sort_values(["trial", "origin_step", "horizon"], kind="stable", ignore_index=True)


def _predictive_columns(model, predictive, row: int) -> dict:
    """One trial's steps.csv columns of the predictive law and its scores (empty where the
    filter kind computes none)."""
    names = model.measurement_names
    columns = {}
    for j, name in enumerate(names):
        for column, field in PREDICTIVE_COLUMNS.items():
            columns[f"{column}_{name}"] = getattr(predictive, field)[row, :, j] if predictive is not None else np.nan
    if len(names) > 1:
        energy = None if predictive is None else predictive.energy_score
        columns["energy_score"] = energy[row] if energy is not None else np.nan
    log_score = None if predictive is None else predictive.log_score
    columns["log_score"] = log_score[row] if log_score is not None else np.nan
    return columns


def _genealogy_frame(cell: Cell, trials: list[int], rows: list[int], trace) -> pd.DataFrame:
    """genealogy.csv rows: one per (trial, step, particle): its ancestor at the step before, its
    weight and state at this step (the weighted cloud, before resampling)."""
    names = cell.filter_model.state_names
    frames = []
    for i in rows:
        steps, count = trace.ancestors.shape[1:]
        columns = {"cell": cell.key, **cell.labels, "trial": trials[i], "step": np.repeat(np.arange(1, steps + 1), count),
                   "particle": np.tile(np.arange(count), steps), "ancestor": trace.ancestors[i].ravel(),
                   "weight": np.exp(trace.log_weights[i]).ravel()}
        for j, name in enumerate(names):
            columns[name] = trace.particles[i, ..., j].ravel()
        frames.append(pd.DataFrame(columns))
    return pd.concat(frames, ignore_index=True)


def _truth_and_measurements(cell: Cell, truth_seeds: list[int]):
    """(truth at steps 1..T or None, measurements, observed mask or None), all (trials, T, ...):
    simulated from each trial's truth stream, or the recorded data repeated for every trial."""
    if cell.data is None:
        states, measurements = simulate_truth(cell.truth_model, TrialStreams.from_seeds(truth_seeds))
        return states[:, 1:], measurements, None
    trials = len(truth_seeds)

    def repeated(array):
        return None if array is None else np.repeat(array[None], trials, axis=0)

    return repeated(cell.data.truth), repeated(cell.data.measurements), repeated(cell.data.observed)


def _particles_frame(cell: Cell, trials: list[int], snapshots: list[Snapshot]) -> pd.DataFrame:
    """particles.csv rows: one per kept particle (cell, labels, trial, step, stage, particle, state,
    weight), from the trace's kept clouds (``FilterTrace.snapshots``)."""
    names = cell.filter_model.state_names
    frames = []
    for cloud in snapshots:
        rows, n = cloud.state.shape[:2]
        columns = {"cell": cell.key, **cell.labels,
                   "trial": np.repeat([trials[r] for r in cloud.rows], n),
                   "step": cloud.step, "stage": cloud.stage, "particle": np.tile(np.arange(n), rows)}
        for j, name in enumerate(names):
            columns[name] = cloud.state[..., j].ravel()
        columns["weight"] = cloud.weights.ravel()
        frames.append(pd.DataFrame(columns))
    return pd.concat(frames, ignore_index=True)


def smoother_labels(cell: Cell) -> list[str]:
    """The labels of the cell's smoothers (``filter.smoothers``), in their order."""
    return [smoother.label for smoother in getattr(cell.filter, "smoothers", None) or ()]


def records_genealogy(cell: Cell, genealogy_trials: int = 0) -> bool:
    """Whether the cell's filter records each particle's ancestor: for a genealogy smoother, or for
    genealogy.csv (``outputs.genealogy``)."""
    smoothers = getattr(cell.filter, "smoothers", None) or ()
    return cell.filter.uses_particles and (genealogy_trials > 0 or any(s.needs_genealogy for s in smoothers))


def steps_columns(cell: Cell, genealogy_trials: int = 0) -> list[str]:
    """The columns of steps.csv for a cell (so that an empty table still has its header)."""
    states = cell.truth_model.state_names
    columns = ["cell", *cell.labels, "trial", "step", "time", *[f"{kind}_{name}" for name in states
                                                               for kind in ("truth", "estimate", "sd")],
               "error_distance", "ess", "resampled", "degenerate", "spread", "nees", "nis", "particles"]
    columns += ["within_radius"] if cell.metrics.convergence.criterion == "spread" else []
    for label in smoother_labels(cell):            # each smoother's mean and sd beside the filter's
        columns += [f"smoothed_{label}_{name}" for name in states] + [f"smoothed_sd_{label}_{name}" for name in states]
    columns += ["distinct_ancestors"] if records_genealogy(cell, genealogy_trials) else []
    columns += ["log_likelihood_increment"]             # added after the others: appended
    measurements = cell.truth_model.measurement_names
    columns += [f"measurement_{name}" for name in measurements]
    if cell.metrics.scores:                             # metrics.scores: the predictive law and its scores
        columns += [f"{quantity}_{name}" for name in measurements for quantity in PREDICTIVE_COLUMNS]
        columns += ["energy_score"] if len(measurements) > 1 else []
        columns += ["log_score"]
    return columns


# steps.csv's columns per measurement component with metrics.scores, and the Predictive field of each
PREDICTIVE_COLUMNS = {"predictive_mean": "mean", "predictive_sd": "sd", "crps": "crps", "pit": "pit"}


def _steps_frame(cell: Cell, trials, traced, truth, trace, measurements, genealogy_trials: int = 0) -> pd.DataFrame:
    if not traced:
        return pd.DataFrame(columns=steps_columns(cell, genealogy_trials))
    model = cell.truth_model
    steps = model.steps
    deviations = trace.posterior_standard_deviations()
    if truth is None:                      # recorded data without the truth: those columns stay empty
        truth = np.full(trace.estimates.shape, np.nan)
    frames = []
    for i in traced:
        columns = {"cell": cell.key, **cell.labels, "trial": trials[i], "step": np.arange(1, steps + 1),
                   "time": model.times()}
        for j, name in enumerate(model.state_names):
            columns[f"truth_{name}"] = truth[i, :, j]
            columns[f"estimate_{name}"] = trace.estimates[i, :, j]
            columns[f"sd_{name}"] = deviations[i, :, j] if deviations is not None else np.nan
        columns["error_distance"] = error_distance(truth[i], trace.estimates[i], model)
        columns["ess"] = trace.ess[i]
        columns["resampled"] = trace.resampled[i]
        columns["degenerate"] = trace.degenerate[i]
        columns["spread"] = trace.spread[i]
        columns["nees"] = (normalised_squares(state_error(truth[i], trace.estimates[i], model),
                                              trace.covariances[i])
                           if trace.covariances is not None else np.nan)
        columns["nis"] = trace.nis[i] if trace.nis is not None else np.nan
        counts = getattr(trace, "particle_counts", None)
        columns["particles"] = counts[i] if counts is not None else np.nan
        if cell.metrics.convergence.criterion == "spread":
            columns["within_radius"] = trace.within_radius[i] if trace.within_radius is not None else np.nan
        for label, smoothed in trace.smoothed.items():
            for j, name in enumerate(model.state_names):
                columns[f"smoothed_{label}_{name}"] = smoothed.means[i, :, j]
                columns[f"smoothed_sd_{label}_{name}"] = smoothed.standard_deviations[i, :, j]
        if trace.ancestors is not None:
            columns["distinct_ancestors"] = distinct_ancestor_counts(trace.ancestors[i])
        increments = trace.log_likelihood_increments
        columns["log_likelihood_increment"] = increments[i] if increments is not None else np.nan
        for j, name in enumerate(model.measurement_names):
            columns[f"measurement_{name}"] = measurements[i, :, j]
        if cell.metrics.scores:
            columns.update(_predictive_columns(model, trace.predictive, i))
        frames.append(pd.DataFrame(columns))
    return pd.concat(frames, ignore_index=True)[steps_columns(cell, genealogy_trials)]
