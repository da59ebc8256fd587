"""A model's compiled step (``Model.compiled_step``) is its transition and likelihood, to rounding.

* The falling body's fused loop gives ``propagate`` and ``log_likelihood``'s values (relative
  1e-12: only the compiled ``exp`` differs from NumPy's, in the last bit) for every variant,
  integrator and unit system, with and without process noise.
* The engine uses it for the bootstrap filter with the ``gaussian`` weighting, draws the noise
  as ``transition`` does, and so gives the filter of the NumPy path: estimates and
  log-likelihoods equal to rounding, the random streams left in the same state.
* Where it does not apply (a non-Gaussian range noise, another weighting, a guided proposal),
  the engine does not call it; a model without one (every plugin) is unchanged.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from pfx.bench.problem import CONFIG
from pfx.config.plan import build_plan
from pfx.models.falling_body import FallingBody
from pfx.numerics.seeding import TrialStreams


def _cell(model_changes=None, filter_changes=None, particles=200, trials=3):
    raw = copy.deepcopy(CONFIG)
    raw["model"].update(model_changes or {})
    raw["filter"].update(filter_changes or {})
    raw["filter"]["particles"] = particles
    raw["trials"] = trials
    return build_plan(raw, "<test>").cells[0]


VARIANTS = [
    {},                                                                      # simon, Euler, 1 sub-step, noise
    {"integrator": "rk4", "substeps": 4},
    {"variant": "jud", "integrator": "rk4", "substeps": 8, "dt": 1.0,
     "process_noise": {"family": "gaussian", "variance": 0.0}},             # no noise: zeros, no draws
    {"units": "si", "integrator": "rk4", "substeps": 2},
]


@pytest.mark.parametrize("changes", VARIANTS)
def test_the_fused_loop_is_propagate_and_log_likelihood(changes):
    cell = _cell(changes)
    model = cell.filter_model
    random = TrialStreams.from_seeds([1, 2, 3])
    state = cell.prior.sample(random, (200,))
    noise = model.process_noise.sample(random, (200,))
    measurement = np.array([[1.2e5], [9.0e4], [np.nan]])                   # a missing measurement too
    step = model.compiled_step()
    assert step is not None
    new_state, log_likelihood = step(state, None, noise, measurement)
    expected = model.propagate(state, None, noise)
    np.testing.assert_allclose(new_state, expected, rtol=1e-12, atol=0)
    expected_log_likelihood = model.log_likelihood(measurement[:, None, :], expected)
    np.testing.assert_allclose(log_likelihood[:2], expected_log_likelihood[:2], rtol=1e-12, atol=1e-12)
    assert np.isnan(log_likelihood[2]).all()


def test_no_compiled_step_for_a_non_gaussian_range_noise():
    cell = _cell({"measurement_noise": {"family": "laplace", "variance": 1.0e4}})
    assert cell.filter_model.compiled_step() is None


def _run(cell, measurements, seeds):
    streams = TrialStreams.from_seeds(seeds)
    trace = cell.planned_filter.run(cell.filter_model, measurements, streams, settings=cell.filter,
                                    prior=cell.prior, spread_criterion=None)
    return trace, streams


@pytest.mark.parametrize("filter_changes", [{}, {"ess_threshold": 0.5, "resampler": "stratified"}])
def test_the_engine_gives_the_numpy_paths_filter(monkeypatch, filter_changes):
    from pfx.bench.problem import make_case

    case = make_case(300, 4)
    cell = _cell(filter_changes=filter_changes, particles=300, trials=4)
    calls = []
    original = FallingBody.compiled_step

    def counted(self):
        step = original(self)
        return lambda *arguments: calls.append(1) or step(*arguments)

    monkeypatch.setattr(FallingBody, "compiled_step", counted)
    fused, fused_streams = _run(cell, case.measurements, case.filter_seeds)
    assert len(calls) == case.measurements.shape[1]            # once per step, for the whole batch
    monkeypatch.setattr(FallingBody, "compiled_step", lambda self: None)
    plain, plain_streams = _run(cell, case.measurements, case.filter_seeds)
    np.testing.assert_allclose(fused.estimates, plain.estimates, rtol=1e-9)
    np.testing.assert_allclose(fused.log_likelihood, plain.log_likelihood, rtol=1e-9)
    np.testing.assert_array_equal(fused.resampled, plain.resampled)
    for ours, theirs in zip(fused_streams.generators, plain_streams.generators):
        assert ours.bit_generator.state == theirs.bit_generator.state


@pytest.mark.parametrize("filter_changes", [{"weighting": {"kind": "euclidean"}}, {"proposal": "ekf"},
                                            {"auxiliary": True}])
def test_the_engine_skips_it_where_it_does_not_apply(monkeypatch, filter_changes):
    from pfx.bench.problem import make_case

    case = make_case(50, 2)
    cell = _cell(filter_changes=filter_changes, particles=50, trials=2)
    monkeypatch.setattr(FallingBody, "compiled_step", lambda self: pytest.fail("compiled_step was asked for"))
    trace, _ = _run(cell, case.measurements, case.filter_seeds)
    assert np.isfinite(trace.estimates).all()
