"""Particle snapshots and forecast clouds come back in the trace, not through the requests (issue 48).

A :class:`~pfx.filters.particle.recorders.SnapshotRequest` and a
:class:`~pfx.filters.particle.forecasting.ForecastRequest` only say what to keep; each driver (numpy's
loop, jax's scan) returns the kept clouds as values of its :class:`~pfx.filters.trace.FilterTrace`:

* **the requests are frozen descriptions**: no attribute can be set, their rows are a read-only copy
  (the caller's array stays writable), and they hold nothing but what they describe;
* **one request serves any number of runs**: two runs of the same recording with the same streams
  return equal traces, each with the clouds of its own run once (a request that kept them would have
  gathered both runs' clouds);
* **the trace's clouds are the run's clouds**: with the history recorded, each snapshot of the weighted
  stage and each forecast origin's cloud are the recorded weighted cloud of their rows and step, and the
  forecast samples start from the forecast clouds' weights, on both backends.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import pfx
from pfx.filters.particle.forecasting import ForecastRequest
from pfx.filters.particle.recorders import Recording, SnapshotRequest
from pfx.filters.trace import Snapshot, WeightedCloud
from pfx.numerics.seeding import TrialStreams

STEPS, TRIALS, PARTICLES = 8, 3, 40
ROWS = [0, 2]
SNAPSHOT_STEPS = frozenset({0, 2, 5})
STAGES = frozenset({"predicted", "weighted", "resampled"})
ORIGINS, HORIZONS = frozenset({3, 6}), (1, 2, 4)        # 6 + 4 reaches past step 8: left out


def _model():
    return pfx.model("linear_gaussian", steps=STEPS, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                     process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0})


def _requests():
    snapshot = SnapshotRequest(rows=np.array(ROWS), steps=SNAPSHOT_STEPS, stages=STAGES)
    forecast = ForecastRequest(rows=np.array(ROWS), origins=ORIGINS, horizons=HORIZONS, quantiles=(0.1, 0.5, 0.9))
    return snapshot, forecast


def _run(backend: str, recording: Recording):
    model = _model()
    measurements = pfx.simulate(model, trials=TRIALS, seed=4).measurements
    bound = pfx.particle_filter(model, particles=PARTICLES, backend=backend, ess_threshold=0.5)
    return bound.planned.bound.run(measurements, TrialStreams.from_seeds([11, 12, 13]), recording)


def test_the_requests_are_frozen_descriptions():
    caller_rows = np.array(ROWS)
    snapshot = SnapshotRequest(rows=caller_rows, steps=SNAPSHOT_STEPS, stages=STAGES)
    forecast = ForecastRequest(rows=caller_rows, origins=ORIGINS, horizons=HORIZONS, quantiles=(0.5,))
    assert [f.name for f in dataclasses.fields(snapshot)] == ["rows", "steps", "stages"]
    assert [f.name for f in dataclasses.fields(forecast)] == ["rows", "origins", "horizons", "quantiles"]
    for request in (snapshot, forecast):
        with pytest.raises(dataclasses.FrozenInstanceError):
            request.rows = np.array([1])
        with pytest.raises(ValueError, match="read-only"):
            request.rows[0] = 1
        assert request.rows is not caller_rows and list(request.rows) == ROWS
    caller_rows[0] = 1                       # the caller's array is its own, and stays writable
    assert list(snapshot.rows) == ROWS and list(forecast.rows) == ROWS


def test_one_request_serves_two_runs_alike(backend):
    snapshot, forecast = _requests()
    recording = Recording(snapshot=snapshot, forecast=forecast)
    first, second = _run(backend, recording), _run(backend, recording)
    expected = [("prior", 0)] + [(stage, step) for step in sorted(SNAPSHOT_STEPS - {0})
                                 for stage in ("predicted", "weighted", "resampled")]
    for trace in (first, second):
        assert [(cloud.stage, cloud.step) for cloud in trace.snapshots] == expected
        assert all(isinstance(cloud, Snapshot) and list(cloud.rows) == ROWS for cloud in trace.snapshots)
        assert all(cloud.state.shape == (2, PARTICLES, 1) and cloud.weights.shape == (2, PARTICLES)
                   for cloud in trace.snapshots)
        assert sorted(trace.forecast_clouds) == sorted(ORIGINS)
        assert all(isinstance(cloud, WeightedCloud) and cloud.state.shape == (2, PARTICLES, 1)
                   and cloud.log_weights.shape == (2, PARTICLES) for cloud in trace.forecast_clouds.values())
        places = [(sample.origin, sample.horizon) for sample in trace.forecast_samples]
        assert places == [(3, 1), (3, 2), (3, 4), (6, 1), (6, 2)]
    for one, other in zip(first.snapshots, second.snapshots):
        np.testing.assert_array_equal(one.state, other.state)
        np.testing.assert_array_equal(one.weights, other.weights)
    assert first.forecasts.keys() == second.forecasts.keys()
    for name, values in first.forecasts.items():
        np.testing.assert_array_equal(values, second.forecasts[name], err_msg=name)


def test_the_traces_clouds_are_the_runs_weighted_clouds(backend):
    snapshot, forecast = _requests()
    trace = _run(backend, Recording(snapshot=snapshot, forecast=forecast, history=True))
    rows = np.array(ROWS)
    for cloud in trace.snapshots:
        if cloud.stage == "weighted":
            np.testing.assert_array_equal(cloud.state, trace.particles[rows, cloud.step - 1])
            np.testing.assert_allclose(np.log(cloud.weights), trace.log_weights[rows, cloud.step - 1], atol=1e-12)
    for origin, cloud in trace.forecast_clouds.items():
        np.testing.assert_array_equal(cloud.state, trace.particles[rows, origin - 1])
        np.testing.assert_array_equal(cloud.log_weights, trace.log_weights[rows, origin - 1])
    for sample in trace.forecast_samples:
        log_weights = trace.forecast_clouds[sample.origin].log_weights
        np.testing.assert_allclose(sample.weights, np.exp(log_weights), rtol=1e-12)
