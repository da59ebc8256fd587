r"""The jax backend's diagnostics: what its compiled step records besides the estimate, and how
the host turns that into the trace.

The NumPy driver calls recorders with each step's clouds, stage by stage
(:mod:`pfx.filters.particle.recorders`). The compiled step
(:mod:`pfx.filters.particle.jax_engine`) cannot call back to the host, so each diagnostic is an
output of the step instead, computed only where a static flag asks for it: each set of
:class:`Flags` is a program of its own, and a diagnostic not asked for is not in it. The step
hands :func:`step_diagnostics` its clouds at the recorders' stages
(:class:`~pfx.filters.particle.kernel.StageClouds`); after
the scan, :func:`fill_trace` turns the outputs, (T, trials, ...), into the trace's fields,
(trials, T, ...), as the recorders fill them (the kept snapshots and forecast clouds included:
the requests only describe them):

====================  ===========================  ==============================================
diagnostic            asked for by                 the step's output
====================  ===========================  ==============================================
spread, share within  the traced rows, the spread  (R,), after resampling
                      convergence criterion
standard deviations   the traced rows              (R, d), after the weight update
history               the smoothers, genealogy.csv the weighted cloud (R, N, d), its log-weights
forecast clouds       ``outputs.forecasts``        the forecast rows' weighted cloud
consistency           ``metrics.consistency``      the posterior covariance (R, d, d) after the
                                                   weight update, the NIS (R,) of the predicted
                                                   cloud with the previous weights
snapshots             ``outputs.particles``        the snapshot rows' cloud and weights at each
                                                   stage asked for; the prior's once, after the scan
====================  ===========================  ==============================================

The covariance and the NIS are the NumPy recorders' own functions, written once in the array
namespace (:func:`~pfx.filters.particle.recorders.posterior_covariance`,
:func:`~pfx.filters.particle.recorders.innovation_squared`), and computed in float64 whatever the
precision, as the trace keeps them. Snapshots keep only the request's rows, at every step (a
scan's outputs are per step); the host keeps the steps asked for, in the NumPy recorder's order
and form (:meth:`~pfx.filters.particle.recorders.SnapshotRequest.snapshot`), in
``FilterTrace.snapshots``; the forecast origins' clouds go to ``FilterTrace.forecast_clouds``.

This module is written against the array namespace (:mod:`pfx.numerics.arrays`) and imports no
JAX: the engine, which does, imports it.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from pfx.filters.particle.kernel import StageClouds
from pfx.filters.particle.recorders import innovation_squared, posterior_covariance
from pfx.filters.trace import Predictive, WeightedCloud
from pfx.numerics.angles import wrap_difference
from pfx.numerics.arrays import namespace, with_values

# the stages of a step a snapshot may keep, in the order the NumPy engine records them
STEP_STAGES = ("predicted", "weighted", "resampled")


class Flags(NamedTuple):
    """The diagnostics a run computes (static: each set of flags is its own compiled program)."""

    spread: bool
    radius: Optional[tuple]
    deviations: bool
    genealogy: bool
    history: bool
    scores: bool = False
    forecast_rows: Optional[tuple] = None
    consistency: bool = False
    snapshot_rows: Optional[tuple] = None
    snapshot_stages: tuple = ()       # "prior" and the STEP_STAGES kept at some step

    @classmethod
    def of(cls, recording, steps: int) -> "Flags":
        """The flags of a :class:`~pfx.filters.particle.recorders.Recording`, for a run of ``steps`` steps."""
        traced = recording.trace_rows is not None and len(recording.trace_rows) > 0
        criterion, snapshot = recording.spread_criterion, recording.snapshot
        stages = () if snapshot is None else _snapshot_stages(snapshot, steps)
        return cls(spread=traced or criterion is not None,
                   radius=None if criterion is None else (float(criterion.radius), bool(criterion.weighted)),
                   deviations=traced, genealogy=recording.genealogy, history=recording.history,
                   scores=recording.scores,
                   forecast_rows=None if recording.forecast is None else tuple(int(r) for r in recording.forecast.rows),
                   consistency=recording.consistency,
                   snapshot_rows=tuple(int(r) for r in snapshot.rows) if stages else None, snapshot_stages=stages)


def _snapshot_stages(request, steps: int) -> tuple:
    """The stages a snapshot request keeps at some step of a run of ``steps`` steps."""
    stages = ("prior",) if request.wants("prior", 0) else ()
    return stages + tuple(stage for stage in STEP_STAGES
                          if any(request.wants(stage, step) for step in range(1, steps + 1)))


# -- in the compiled step ------------------------------------------------------------------------

def step_diagnostics(model, flags: Flags, clouds: StageClouds, inputs) -> dict:
    """The diagnostics ``flags`` ask for at one step, by their
    :class:`~pfx.filters.particle.jax_engine.StepOutputs` field; ``inputs`` the step's
    :class:`~pfx.filters.particle.jax_engine.StepInputs`."""
    outputs: dict = {}
    if flags.spread:
        outputs["spread"] = spread(model, clouds.resampled_weights, clouds.resampled)
    if flags.radius is not None:
        outputs["within_radius"] = within_radius(model, clouds.resampled_weights, clouds.resampled, flags.radius)
    if flags.deviations:
        outputs["standard_deviations"] = standard_deviations(model, clouds.weights, clouds.predicted, clouds.estimate)
    if flags.history:            # the history the smoothers read
        outputs.update(particles=clouds.predicted, log_weights=clouds.log_weights)
    if flags.forecast_rows is not None:
        rows = np.asarray(flags.forecast_rows)
        outputs.update(forecast_particles=clouds.predicted[rows], forecast_log_weights=clouds.log_weights[rows])
    if flags.consistency:
        outputs.update(consistency(model, clouds, inputs))
    if flags.snapshot_rows is not None and set(flags.snapshot_stages) & set(STEP_STAGES):
        outputs["snapshots"] = snapshots(flags, clouds)
    return outputs


def spread(model, weights, state):
    """Weighted RMS distance of the positions from their weighted mean (after resampling)."""
    xp = namespace(state)
    positions = state[..., list(model.position_components)]
    centre = xp.einsum("rn,rnd->rd", weights, positions)[:, None, :]
    squared = xp.sum((positions - centre) ** 2, axis=-1)
    return xp.sqrt(xp.sum(weights * squared, axis=-1))


def within_radius(model, weights, state, criterion: tuple):
    """The share of particles (by weight, or by count) within the radius of the mean;
    ``criterion``: (the radius, whether by weight)."""
    xp = namespace(state)
    radius, weighted = criterion
    positions = state[..., list(model.position_components)]
    if not weighted:
        weights = xp.full_like(weights, 1.0 / weights.shape[-1])
    centre = xp.einsum("rn,rnd->rd", weights, positions)[:, None, :]
    inside = xp.sum((positions - centre) ** 2, axis=-1) <= radius ** 2
    return xp.sum(weights * inside, axis=-1)


def standard_deviations(model, weights, state, estimate):
    """Each component's weighted posterior sd before resampling (angles: wrapped deviations)."""
    xp = namespace(state)
    centred = state - estimate[:, None, :]
    angular = list(model.angular_components)
    if angular:
        centred = with_values(centred, (..., angular), wrap_difference(centred[..., angular], model.full_turn))
    return xp.sqrt(xp.einsum("rn,rnd->rd", weights, centred * centred))


def consistency(model, clouds: StageClouds, inputs) -> dict:
    """The NIS of the predicted cloud with the previous weights (NaN where z_k is missing), and
    the weighted posterior covariance before resampling, about the estimate: in float64."""
    xp = namespace(clouds.predicted)
    predicted = clouds.predicted.astype(np.float64)
    previous_weights = xp.exp(clouds.predicted_log_weights.astype(np.float64))
    nis = innovation_squared(model, inputs.measurement.astype(np.float64), predicted, previous_weights)
    covariance = posterior_covariance(clouds.weights.astype(np.float64), predicted, clouds.estimate.astype(np.float64))
    return {"nis": xp.where(inputs.observed, nis, np.nan), "covariance": covariance}


def snapshots(flags: Flags, clouds: StageClouds) -> dict:
    """The snapshot rows' (states, weights) at each step stage asked for, by stage."""
    xp = namespace(clouds.predicted)
    rows = np.asarray(flags.snapshot_rows)
    at_stage = {"predicted": lambda: (clouds.predicted[rows], xp.exp(clouds.predicted_log_weights[rows])),
                "weighted": lambda: (clouds.predicted[rows], clouds.weights[rows]),
                "resampled": lambda: (clouds.resampled[rows], clouds.resampled_weights[rows])}
    return {stage: at_stage[stage]() for stage in STEP_STAGES if stage in flags.snapshot_stages}


# -- on the host, after the scan -----------------------------------------------------------------

def by_trial(values) -> Optional[np.ndarray]:
    """A scan's output (T, R, ...) as the trace's (R, T, ...): a NumPy array of its own (JAX's
    arrays read as read-only views, and pfx writes into the trace), or None."""
    return None if values is None else np.array(np.swapaxes(np.asarray(values), 0, 1), order="C")


def fill_trace(trace, outputs, recording, observed: np.ndarray, particles: int) -> None:
    """The trace's fields that come from the diagnostics' outputs: the predictive law, the
    forecast clouds, the covariances and NIS, the snapshots. ``observed``: (R, T), whether z_k is
    there; ``particles``: N."""
    steps = observed.shape[1]
    if outputs.predictive is not None:
        trace.predictive = _predictive(outputs.predictive, observed)
    if recording.forecast is not None:          # the origins' clouds, for the host's forecasts
        trace.forecast_clouds = {
            step: WeightedCloud(np.array(outputs.forecast_particles[step - 1], dtype=float),
                                np.array(outputs.forecast_log_weights[step - 1], dtype=float))
            for step in sorted(recording.forecast.origins) if 1 <= step <= steps}
    if outputs.covariance is not None:
        trace.covariances = by_trial(outputs.covariance).astype(float)
        trace.nis = by_trial(outputs.nis).astype(float)
    if recording.snapshot is not None:
        trace.snapshots = _snapshots(recording.snapshot, outputs, steps, particles)


def _snapshots(request, outputs, steps: int, particles: int) -> list:
    """The kept clouds, as the NumPy recorder keeps them: the prior's at step 0, then each step's
    stages in their order; states and weights in float64."""
    rows = len(request.rows)
    kept_clouds = []
    if outputs.prior_snapshot is not None:
        kept_clouds.append(request.snapshot("prior", 0, np.array(outputs.prior_snapshot, dtype=float),
                                            np.full((rows, particles), 1.0 / particles)))
    kept = outputs.snapshots or {}
    for step in range(1, steps + 1):
        for stage in STEP_STAGES:
            if stage in kept and request.wants(stage, step):
                state, weights = kept[stage]
                kept_clouds.append(request.snapshot(stage, step, np.array(state[step - 1], dtype=float),
                                                    np.array(weights[step - 1], dtype=float)))
    return kept_clouds


def _predictive(outputs: dict, observed: np.ndarray) -> Predictive:
    """The trace's :class:`~pfx.filters.trace.Predictive` from the scan's outputs, (R, T, ...) in
    float64, NaN at the steps without a measurement."""
    def field(name):
        if name not in outputs:
            return None
        values = by_trial(outputs[name]).astype(float)
        mask = observed.reshape(observed.shape + (1,) * (values.ndim - 2))
        return np.where(mask, values, np.nan)

    return Predictive(mean=field("mean"), sd=field("sd"), crps=field("crps"), pit=field("pit"),
                      energy_score=field("energy_score"), log_score=field("log_score"))
