"""Diagnostics of the particle filter: what a run records besides its estimates.

A :class:`Recorder` is attached to the engine (:class:`pfx.filters.particle.engine.ParticleFilter`)
and called after each stage of a step ("prior", "predicted", "weighted", "resampled"); it reads
the cloud and fills its part of the trace, and never changes the cloud or draws a random number.
So the engine's loop holds the algorithm and nothing else, and a diagnostic that is not asked
for costs nothing.

* :class:`SpreadRecorder`: the weighted RMS distance of the positions from their mean (steps.csv's
  ``spread``) and, for the spread convergence criterion, the share within a radius;
* :class:`StandardDeviationRecorder`: the posterior standard deviation of each component;
* :class:`ConsistencyRecorder`: the weighted posterior covariance and the NIS (for NEES and NIS);
* :class:`SnapshotRecorder`: the particle clouds a :class:`SnapshotRequest` asks for;
* :class:`ForecastRecorder`: the weighted clouds a forecast request
  (:class:`~pfx.filters.particle.forecasting.ForecastRequest`) forecasts from.

A request is a description only (frozen: rows, steps, stages; rows, origins, horizons): what a
run keeps comes back as values in its trace (``FilterTrace.snapshots``, a list of
:class:`~pfx.filters.trace.Snapshot`; ``FilterTrace.forecast_clouds``, origin step ->
:class:`~pfx.filters.trace.WeightedCloud`), so one request may serve any number of runs.

What the jax backend computes alike is written here once: the posterior covariance and the NIS
(:func:`posterior_covariance`, :func:`innovation_squared`) in the array namespace
(:mod:`pfx.numerics.arrays`), and which clouds a snapshot request keeps, in what form
(:meth:`SnapshotRequest.wants`, :meth:`SnapshotRequest.snapshot`);
:mod:`pfx.filters.particle.jax_diagnostics` calls them inside and after its compiled scan.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from pfx.filters.particle.cloud import active_uniform, weighted_mean
from pfx.filters.trace import Snapshot, WeightedCloud
from pfx.numerics.angles import wrap_difference
from pfx.numerics.arrays import namespace
from pfx.numerics.quadratic_forms import normalised_squares


@dataclass(frozen=True, eq=False)
class SnapshotRequest:
    """Which particle clouds to keep: trials (rows of the batch), steps, stages. A description
    only: the kept clouds come back in the run's trace (``FilterTrace.snapshots``).

    Stages: ``prior`` (step 0), ``predicted`` (after the transition, with the previous
    weights), ``weighted`` (after the weight update, before resampling) and ``resampled``
    (after resampling and diffusion). Each kept cloud is a :class:`~pfx.filters.trace.Snapshot`
    of the request's rows: state (len(rows), N, d) and weights (len(rows), N).
    """

    rows: np.ndarray
    steps: object                 # a collection of steps, or "all"
    stages: frozenset

    def __post_init__(self):
        object.__setattr__(self, "rows", read_only_rows(self.rows))

    def wants(self, stage: str, step: int) -> bool:
        """Whether the cloud of ``stage`` at ``step`` is kept (the prior's whenever step 0 is asked for)."""
        return (stage in self.stages or stage == "prior") and (self.steps == "all" or step in self.steps)

    def snapshot(self, stage: str, step: int, state: np.ndarray, weights: np.ndarray) -> Snapshot:
        """The kept cloud of the request's rows: ``state`` (len(rows), N, d) and ``weights``
        (len(rows), N), of those rows already and arrays of their own (kept as given)."""
        return Snapshot(stage=stage, step=step, rows=self.rows, state=state, weights=weights)


def read_only_rows(rows) -> np.ndarray:
    """A request's rows of the batch: a read-only index array of its own (the caller's stays writable)."""
    rows = np.array(rows, dtype=np.intp)
    rows.flags.writeable = False
    return rows


@dataclass
class SpreadCriterion:
    """Record, per step, the share of particles within ``radius`` of the particle mean."""

    radius: float
    weighted: bool


class Recorder:
    """A diagnostic attached to :class:`ParticleFilter`: after each stage ("prior",
    "predicted", "weighted", "resampled") it may read the filter's cloud and fill its part of
    the trace. Recorders never change the cloud or draw random numbers."""

    def record(self, stage: str, step: int, run) -> None:
        raise NotImplementedError


class SpreadRecorder(Recorder):
    """After each step: the weighted RMS distance of the positions from their mean (``spread``,
    a column of steps.csv: for the traced ``rows`` only, None: every row) and, for the spread
    convergence criterion, the share within its radius (every row)."""

    def __init__(self, model, criterion: Optional[SpreadCriterion], rows: Optional[np.ndarray] = None):
        position = list(model.position_components)
        if position == list(range(position[0], position[-1] + 1)):
            position = slice(position[0], position[-1] + 1)      # a view of the state, not a copy per step
        self.position, self.criterion = position, criterion
        self.rows = slice(None) if rows is None else np.asarray(rows, dtype=np.intp)

    def record(self, stage: str, step: int, run) -> None:
        if stage != "resampled":
            return
        if self.criterion is not None and run.trace.within_radius is None:
            run.trace.within_radius = np.empty((run.trials, run.steps))
        # (a diverging cloud has infinite spread: the run's np.errstate lets it be)
        run.trace.spread[self.rows, step - 1] = _spread(run.weights[self.rows], run.state[self.rows][..., self.position])
        if self.criterion is not None:
            run.trace.within_radius[:, step - 1] = _share_within(run.weights, run.state[..., self.position],
                                                                 self.criterion, run.active)


class StandardDeviationRecorder(Recorder):
    """The posterior standard deviation of each state component, weighted, before resampling
    (at the estimate's stage), for some rows of the batch (the traced trials; None: all); the others stay NaN.

    An angular component's deviations are taken from the circular mean, wrapped into half a
    turn either side, as its errors are.
    """

    def __init__(self, model, rows: Optional[np.ndarray]):
        self.rows = slice(None) if rows is None else np.asarray(rows, dtype=np.intp)   # None: every row
        self.angular = list(model.angular_components)
        self.full_turn = model.full_turn

    def record(self, stage: str, step: int, run) -> None:
        trace, t = run.trace, step - 1
        if stage == "prior":
            trace.standard_deviations = np.full((run.trials, run.steps, run.state.shape[-1]), np.nan)
        elif stage == "weighted":
            with np.errstate(over="ignore", invalid="ignore"):    # a diverging cloud: infinite spread
                centred = run.state[self.rows] - trace.estimates[self.rows, t, None, :]
                if self.angular:
                    centred[..., self.angular] = wrap_difference(centred[..., self.angular], self.full_turn)
                variances = np.einsum("rn,rnd->rd", run.weights[self.rows], centred * centred)
                trace.standard_deviations[self.rows, t] = np.sqrt(variances)


class ConsistencyRecorder(Recorder):
    """NEES and NIS for particle filters: the NIS of the predicted cloud, and the weighted
    posterior covariance (before resampling)."""

    def __init__(self, model):
        self.model = model

    def record(self, stage: str, step: int, run) -> None:
        trace, t = run.trace, step - 1
        if stage == "prior":
            dimension = run.state.shape[-1]
            trace.covariances = np.empty((run.trials, run.steps, dimension, dimension))
            trace.nis = np.empty((run.trials, run.steps))
        elif stage == "predicted":
            trace.nis[:, t] = innovation_squared(self.model, run.measurements[:, t], run.state, run.weights)
        elif stage == "weighted":
            trace.covariances[:, t] = posterior_covariance(run.weights, run.state, trace.estimates[:, t])


class SnapshotRecorder(Recorder):
    """Keeps the particle clouds a :class:`SnapshotRequest` asks for, in ``trace.snapshots``."""

    def __init__(self, request: SnapshotRequest):
        self.request = request

    def record(self, stage: str, step: int, run) -> None:
        if stage == "prior":
            run.trace.snapshots = []
        if self.request.wants(stage, step):
            rows = self.request.rows         # an index array: the rows are copies
            run.trace.snapshots.append(self.request.snapshot(stage, step, run.state[rows], run.weights[rows]))


def innovation_squared(model, measurement, state, weights):
    """NIS of the predicted cloud: nu' S^-1 nu, nu = z - E_w[h(x)], S = Cov_w(h(x)) + R; NaN where
    S cannot be inverted reliably (:mod:`pfx.numerics.quadratic_forms`). ``measurement`` (trials,
    m), ``state`` (trials, N, d) and ``weights`` (trials, N): NumPy or JAX arrays."""
    xp = namespace(state, weights)
    with np.errstate(over="ignore", invalid="ignore"):
        predicted = model.measurement_mean(state)
        mean = xp.einsum("rn,rnm->rm", weights, predicted)
        centred = predicted - mean[:, None, :]
        innovation_covariance = xp.einsum("rn,rnm,rnk->rmk", weights, centred, centred) \
            + model.measurement_noise.covariance()
        return normalised_squares(measurement - mean, innovation_covariance)


def posterior_covariance(weights, state, estimate):
    """The weighted covariance of the cloud about the estimate, (trials, N), (trials, N, d),
    (trials, d) -> (trials, d, d): NumPy or JAX arrays. The deviations from the estimate are
    taken as they are, an angular component's too (the standard deviations wrap theirs)."""
    centred = state - estimate[:, None, :]
    return namespace(state, weights).einsum("rn,rnd,rne->rde", weights, centred, centred)


def _spread(weights: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Weighted RMS distance of the particles' positions from their weighted mean."""
    centre = weighted_mean(weights, positions)[:, None, :]
    squared = np.sum((positions - centre) ** 2, axis=-1)
    return np.sqrt(np.einsum("rn,rn->r", weights, squared))


def _share_within(weights: np.ndarray, positions: np.ndarray, criterion: SpreadCriterion,
                  active: Optional[np.ndarray] = None) -> np.ndarray:
    """Share of particles (by weight, or by count: of the active ones) within the radius of the
    (matching) mean."""
    if not criterion.weighted:
        weights = np.full_like(weights, 1.0 / weights.shape[-1]) if active is None \
            else active_uniform(active, weights.shape[-1])[1]
    centre = weighted_mean(weights, positions)[:, None, :]
    inside = np.sum((positions - centre) ** 2, axis=-1) <= criterion.radius ** 2
    return np.sum(weights * inside, axis=-1)


class GenealogyRecorder(Recorder):
    """Each step's ancestor indices: ``trace.ancestors[r, k-1, i]`` is the particle of step k-1
    (of its weighted cloud, before resampling) from which particle i of step k descends, -1 for
    a particle injected from the prior. A step whose trial did not resample has i -> i.

    The engine notes the ancestors whenever it resamples (at the end of step k-1, or in the
    auxiliary filter's first stage at step k); this recorder copies them once step k's particles
    are proposed, and starts the next step from i -> i. Memory: T N integers per trial, only when
    asked for (``Recording.genealogy``).
    """

    def record(self, stage: str, step: int, run) -> None:
        if stage == "prior":
            dtype = np.int32 if run.particles < 2**31 else np.int64
            run.trace.ancestors = np.empty((run.trials, run.steps, run.particles), dtype=dtype)
        elif stage == "predicted":
            run.trace.ancestors[:, step - 1] = run.ancestors
            run.ancestors[:] = np.arange(run.particles)


@dataclass(frozen=True)
class Recording:
    """Which diagnostics a run records besides its estimates, ESS and log-likelihood.

    ``spread_criterion``: the share of particles within a radius (the spread convergence
    criterion), every trial. ``consistency``: the weighted posterior covariance and the NIS (NEES,
    NIS). ``snapshot``: particle clouds to keep. ``trace_rows``: the rows of the batch whose
    per-step spread and posterior standard deviations steps.csv shows (None: none, as in ``pfx
    bench``, whose timings are the filter's). ``genealogy``: each step's ancestor indices
    (``FilterTrace.ancestors``, (trials, T, N): memory T N per trial). ``scores``: the one-step-ahead
    predictive distribution of the measurement and its proper scores (``FilterTrace.predictive``,
    :mod:`pfx.filters.particle.predictive`; one measurement draw per particle and step, from
    streams apart from the filter's). ``snapshot`` and ``forecast`` name what to keep, and the
    trace holds it: ``FilterTrace.snapshots``, and the weighted clouds to forecast from,
    ``FilterTrace.forecast_clouds`` (a :class:`~pfx.filters.particle.forecasting.ForecastRequest`).
    """

    spread_criterion: Optional[SpreadCriterion] = None
    consistency: bool = False
    snapshot: Optional[SnapshotRequest] = None
    trace_rows: Optional[np.ndarray] = None
    genealogy: bool = False
    history: bool = False
    scores: bool = False
    forecast: Optional[object] = None       # a ForecastRequest (pfx.filters.particle.forecasting)


class ForecastRecorder(Recorder):
    """Keeps the weighted clouds (before resampling) a forecast request asks for: its rows, at
    its origin steps, in ``trace.forecast_clouds`` (:mod:`pfx.filters.particle.forecasting`
    forecasts from them after the run)."""

    def __init__(self, request):
        self.request = request

    def record(self, stage: str, step: int, run) -> None:
        if stage == "prior":
            run.trace.forecast_clouds = {}
        elif stage == "weighted" and step in self.request.origins:
            rows = self.request.rows
            run.trace.forecast_clouds[step] = WeightedCloud(np.array(run.state[rows], dtype=float),
                                                            np.array(run.log_weights[rows], dtype=float))


class HistoryRecorder(Recorder):
    """Each step's weighted cloud before resampling: the states and normalised log-weights the
    particle smoothers (:mod:`pfx.filters.particle.smoothing`) run on. Memory: T N (d + 1)
    numbers per trial, only when asked for (``Recording.history``)."""

    def record(self, stage: str, step: int, run) -> None:
        if stage == "prior":
            run.trace.particles = np.empty((run.trials, run.steps) + run.state.shape[1:])
            run.trace.log_weights = np.empty((run.trials, run.steps, run.particles))
        elif stage == "weighted":
            run.trace.particles[:, step - 1] = run.state
            run.trace.log_weights[:, step - 1] = run.log_weights


def recorders_for(model, recording: Recording) -> list[Recorder]:
    """The recorders a :class:`~pfx.filters.particle.bound.Recording` asks for, in their order
    (the predictive scores' recorder, :mod:`pfx.filters.particle.predictive`, is the engine's to add)."""
    recorders: list[Recorder] = []
    rows = recording.trace_rows
    traced = rows is not None and len(rows) > 0
    if traced or recording.spread_criterion is not None:   # steps.csv's spread; the spread convergence criterion
        recorders.append(SpreadRecorder(model, recording.spread_criterion,
                                        None if recording.spread_criterion is not None else rows))
    if traced:
        recorders.append(StandardDeviationRecorder(model, rows))
    if recording.consistency:
        recorders.append(ConsistencyRecorder(model))
    if recording.snapshot is not None:
        recorders.append(SnapshotRecorder(recording.snapshot))
    if recording.genealogy:
        recorders.append(GenealogyRecorder())
    if recording.history:
        recorders.append(HistoryRecorder())
    if recording.forecast is not None:
        recorders.append(ForecastRecorder(recording.forecast))
    return recorders
