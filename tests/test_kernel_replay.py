"""The two drivers of the particle filter's kernel compute the same filter when served the same draws (issue 48).

pfx's particle filter step is written once (:mod:`pfx.filters.particle.kernel`) and run by two drivers:
NumPy's :class:`~pfx.filters.particle.engine.ParticleFilter` (a Python loop over
:class:`~pfx.numerics.seeding.TrialStreams`) and JAX's :class:`~pfx.filters.particle.jax_engine.JaxParticleFilter`
(threefry :class:`~pfx.numerics.key_streams.KeyStreams`). Their generators differ, so tests/test_jax_backend.py
can only compare them in distribution. Here both draw from a replay (tests/replay_streams.py): the j-th call of
step k returns the same array on both backends, so the two drivers must agree number for number, up to
round-off. Each case runs a small cell (the feature matrix's models and filters, tests/test_filter_features.py, at 3
trials, 20 particles, at most 8 steps, ESS threshold 1: every trial resamples every step, so the NumPy driver
draws for every trial as the JAX driver does) through the NumPy driver's ``run`` and through the JAX driver's
``step`` in an eager Python loop (float64), and asserts:

* the estimates and the log-likelihood increments agree within 1e-12, relative to the value where it exceeds 1
  in magnitude (the falling body's altitude is ~3e5), absolute below; infinities equal;
* the ancestors, the resampling flags and the lost-particle counts are identical;
* both drivers asked for the same (step, method, shape) calls, and the NumPy driver took no subset of its streams.

The injection (augmented MCL) is the one stage that draws on one backend and not the other: NumPy draws only in
the trials whose injection probability is positive (a subset of its streams, whose rows the replay serves from
the full draws), JAX in every trial, keeping the draws where the probability is positive. So the call sequences
differ at the steps where no trial's probability is positive: there JAX makes the injection's two calls (the
uniforms and the prior's draws) and NumPy none; its case asserts exactly that, and that everything else agrees.

What cannot replay, and why (left out):

* resamplers ``multinomial`` and ``residual`` draw differently on the two backends by design: NumPy's multinomial
  takes the order statistics of N uniforms from N + 1 exponential spacings, JAX's N iid uniforms (a binary search
  needs no sorted points); NumPy's residual draws the residual count's spacings per trial from that trial's own
  stream, JAX N iid uniforms for every trial. :func:`test_multinomial_and_residual_draw_differently_by_design`
  pins that down, so that a change that makes them replay is noticed;
* ``move: mcmc`` with more than one Metropolis step: on JAX the steps are one ``lax.fori_loop`` whose body is
  traced once, taking new keys at every pass by folding in the pass index (``loop_pass``); a replay, which serves
  by call, serves every pass the same draws where NumPy draws anew. One step replays (the cases below);
* a model with several substeps per step (the SIR plugin): the JAX transition scans ``sample_substep`` over the
  substeps with ``random.at(index)``, a scan body traced once, so the same limitation (the JAX replay refuses
  ``at``);
* lost particles through the falling body's compiled step: at this size the bootstrap filter with the likelihood
  loses either no particle or every particle of a trial (the likelihood concentrates the cloud on one ballistic
  coefficient, and its copies leave the domain together); lost particles are replayed through the host
  transition (the mahalanobis weighting, as the feature case ``lost-transition``), the compiled step without losses;
* the ekf proposal on the range beacons: the model's ``measurement_jacobian`` is NumPy-only, so the plan refuses
  ``backend: jax`` for it; the ekf proposal is replayed on the linear model;
* ``weighting: mahalanobis`` ``form: paper`` on the range beacons: its metric is the square of the inverse of
  the cloud's 3x3 measurement covariance, of rank 2 (a planar position seen by three beacons) plus 1e-9 R, so the
  increments (~1e9) carry that inverse's condition number: they agree to ~1e-11 relative, not 1e-12. It is
  replayed on the linear model, whose 1x1 covariance is well conditioned.

On a GPU the move cases are skipped: a move's kernel is scaled by a square root of the cloud's covariance,
``V sqrt(L)`` from ``eigh`` (:func:`pfx.filters.particle.moves.square_root`), and eigenvectors are unique only
up to sign. JAX on a CPU calls LAPACK as NumPy does and gets the same signs; on a GPU cuSOLVER may choose
others, an equally valid square root (the kernels are symmetric) that turns the same draws into other moves.
On an H200 the five move cases differed from the second step on; the other cases agreed to 1e-12 there too.

The cases with an adaptive count (KLD) found the one discrepancy: the JAX driver took the uniform log-weight over
the active particles, ``-log(n)`` (:func:`pfx.filters.particle.cloud.active_uniform`), of the int32 active count,
which JAX computes in float32 even in a float64 run (increments off by up to ~6e-8); the count is now cast to
float64 first, and the cases agree to 1e-15.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import pytest
from replay_streams import JaxReplayStreams, ReplayStreams
from test_filter_features import (
    CASES,
    INJECTION,
    KLD,
    LOSING_PRIOR,
    Case,
    Run,
    _auxiliary,
    _cell,
    _measurements,
    _weighted_by,
)

from pfx.filters.particle.engine import ParticleFilter
from pfx.filters.particle.kernel import StepInputs
from pfx.filters.particle.recorders import Recording

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_plugins")

TRIALS, PARTICLES, STEPS = 3, 20, 8
TOLERANCE = 1e-12


@dataclass(frozen=True)
class Replayed:
    """One feature's cell: a feature case's model and filter (tests/test_filter_features.py) at the replay's size and ESS threshold 1, with
    ``filter`` and ``model`` overriding their keys; that case's check that the feature was reached."""

    base: str
    filter: dict = field(default_factory=dict)
    model: dict = field(default_factory=dict)
    exercised: Optional[Callable[[Run], None]] = None

    def case(self) -> Case:
        base = CASES[self.base]
        model = {**copy.deepcopy(base.model), "steps": min(base.model.get("steps", STEPS), STEPS), **self.model}
        settings = {**copy.deepcopy(base.filter), "particles": PARTICLES, "ess_threshold": 1.0, **self.filter}
        missing = tuple((trial, step) for trial, step in base.missing if step <= model["steps"])
        return Case(model, settings, missing=missing, exercised=self.exercised or base.exercised,
                    plugins=base.plugins)


MAHALANOBIS_PAPER = {"kind": "mahalanobis", "form": "paper"}


def _injected(run: Run) -> None:
    assert run.trace.injected.sum() > 0


FEATURES = {
    "resampler-systematic": Replayed("resampler-systematic-ess1"),
    "resampler-stratified": Replayed("resampler-stratified-ess1"),
    "resampler-han_lee_iv": Replayed("resampler-han_lee_iv-ess1"),
    "missing": Replayed("missing"),
    "missing-auxiliary": Replayed("missing-auxiliary"),
    "missing-ekf": Replayed("missing-ekf"),
    "missing-mcmc-one-step": Replayed("missing-mcmc", filter={"move": {"kind": "mcmc", "steps": 1}}),
    "missing-compiled-step": Replayed("missing-compiled-step"),
    "lost-transition": Replayed("lost-transition", filter={"initial": {**LOSING_PRIOR,
                                                                       "covariance": [1.0e6, 4.0e6, 100.0]}}),
    "degenerate": Replayed("degenerate"),
    "compiled-step": Replayed("compiled-step"),
    "compiled-step-rk4-substeps": Replayed("compiled-step-rk4-substeps"),
    "auxiliary": Replayed("auxiliary-ess1"),
    "auxiliary-locally_optimal": Replayed("auxiliary-locally_optimal-genealogy"),
    "auxiliary-beacons": Replayed("auxiliary-beacons-scores", exercised=_auxiliary),
    "move-regularise-gaussian": Replayed("move-regularise-gaussian"),
    "move-regularise-epanechnikov-duplicates": Replayed("move-regularise-epanechnikov-duplicates"),
    "move-regularise-scott": Replayed("move-regularise-scott"),
    "move-mcmc-one-step": Replayed("move-mcmc", filter={"move": {"kind": "mcmc", "steps": 1}}),
    "move-mcmc-scale": Replayed("move-mcmc-scale-ess1-genealogy"),
    "diffusion-gaussian": Replayed("diffusion-gaussian"),
    "diffusion-roughening": Replayed("diffusion-roughening"),
    "proposal-locally_optimal": Replayed("proposal-locally_optimal"),
    "proposal-ekf": Replayed("proposal-ekf"),
    "proposal-ukf": Replayed("proposal-ukf"),
    "proposal-ukf-beacons": Replayed("proposal-ukf-beacons"),
    "weighting-gaussian": Replayed("weighting-gaussian"),
    "weighting-euclidean": Replayed("weighting-euclidean"),
    "weighting-manhattan": Replayed("weighting-manhattan"),
    "weighting-mahalanobis-innovation": Replayed("weighting-mahalanobis-innovation"),
    "weighting-mahalanobis-paper-linear": Replayed("resampler-systematic-ess1", filter={"weighting": MAHALANOBIS_PAPER},
                                                   exercised=_weighted_by("mahalanobis-paper")),
    "kld": Replayed("kld-ess1"),
    "kld-degenerate": Replayed("degenerate-kld"),
}
INJECTION_FEATURES = {
    "injection": Replayed("injection", exercised=_injected),
    "kld-injection": Replayed("kld-injection", filter={"adaptive": KLD, "injection": INJECTION},
                              exercised=_injected),
}


# -- the two drivers on one replay each ------------------------------------------------------------------

class _SteppedParticleFilter(ParticleFilter):
    """The NumPy driver, announcing each step to its replay (as the JAX driver folds k into its keys)."""

    def step(self, cloud, inputs, random):
        random.begin(inputs.step)
        return super().step(cloud, inputs, random)


@dataclass
class Replay:
    """Both drivers' results on one cell: the NumPy trace and the JAX step outputs stacked (trials, T, ...)."""

    bound: object
    measurements: np.ndarray
    numpy_trace: object
    numpy_streams: ReplayStreams
    jax_streams: JaxReplayStreams
    estimates: np.ndarray
    increments: np.ndarray
    ancestors: np.ndarray
    resampled: np.ndarray
    lost_particles: np.ndarray
    injected: Optional[np.ndarray]


def replay(case: Case, seed: int = 0) -> Replay:
    numpy_cell = _cell(case)
    jax_cell = _cell(Case(case.model, {**case.filter, "backend": "jax"}, plugins=case.plugins))
    numpy_bound, jax_bound = numpy_cell.planned_filter.bound, jax_cell.planned_filter.bound
    assert numpy_bound.backend == "numpy" and jax_bound.backend == "jax" and jax_bound.precision == "float64"
    measurements = _measurements(numpy_cell, case.missing)
    numpy_streams = ReplayStreams(TRIALS, seed)
    trace = _SteppedParticleFilter(numpy_bound, measurements.copy(), numpy_streams, Recording(genealogy=True)).run()

    driver = jax_bound.compiled
    jax_streams = JaxReplayStreams(TRIALS, seed)
    columns = []
    with jax.enable_x64(True):
        # as traced_run: the prior's cloud (step 0's draws), then the steps
        state = jnp.asarray(jax_bound.prior.sample(jax_streams, (driver.particles,)), driver.dtype)
        cloud = driver.start(state, TRIALS)
        inputs = driver.step_inputs(measurements)
        for k in range(1, measurements.shape[1] + 1):
            jax_streams.begin(k)
            at_step = StepInputs(*(None if values is None else values[k - 1] for values in inputs))
            cloud, outputs, _ = driver.step(cloud, at_step, jax_streams)
            columns.append(jax.device_get(outputs))
        lost = np.asarray(cloud.lost_particles)

    def stacked(name):
        values = [getattr(column, name) for column in columns]
        return None if values[0] is None else np.stack([np.asarray(value) for value in values], axis=1)

    return Replay(numpy_bound, measurements, trace, numpy_streams, jax_streams, stacked("estimate"),
                  stacked("increment"), stacked("ancestors"), stacked("resampled"), lost, stacked("injected"))


def assert_close(jax_values: np.ndarray, numpy_values: np.ndarray, what: str) -> float:
    """Within TOLERANCE, relative where |value| > 1; infinities (a degenerate step's -inf) equal. The
    largest relative-or-absolute difference, for the record."""
    jax_values, numpy_values = np.asarray(jax_values, dtype=float), np.asarray(numpy_values, dtype=float)
    assert jax_values.shape == numpy_values.shape, f"{what}: shape {jax_values.shape} != {numpy_values.shape}"
    finite = np.isfinite(numpy_values)
    assert np.array_equal(np.isfinite(jax_values), finite), f"{what}: not finite at different places"
    assert np.array_equal(jax_values[~finite], numpy_values[~finite], equal_nan=True), f"{what}: infinities differ"
    difference = np.abs(jax_values[finite] - numpy_values[finite]) / np.maximum(1.0, np.abs(numpy_values[finite]))
    largest = float(difference.max(initial=0.0))
    assert largest <= TOLERANCE, f"{what}: differ by {largest:.3g} (relative where |value| > 1)"
    return largest


def assert_same_filter(result: Replay) -> None:
    trace = result.numpy_trace
    assert_close(result.estimates, trace.estimates, "estimates")
    assert_close(result.increments, trace.log_likelihood_increments, "log-likelihood increments")
    assert np.array_equal(result.ancestors, trace.ancestors), "ancestors differ"
    assert np.array_equal(result.resampled, trace.resampled), "resampled flags differ"
    assert np.array_equal(result.lost_particles, trace.lost_particles), "lost particle counts differ"
    if trace.injected is not None:
        assert np.array_equal(result.injected, trace.injected), "injected counts differ"


def _exercised(case: Case, result: Replay) -> None:
    if case.exercised is not None:
        case.exercised(Run(result.bound, result.measurements, result.numpy_trace, Recording(genealogy=True)))


@pytest.mark.parametrize("name", list(FEATURES))
def test_both_drivers_compute_the_same_filter_from_the_same_draws(name):
    if ("move" in name or "mcmc" in name) and jax.default_backend() != "cpu":
        pytest.skip("the moves' square root of the cloud's covariance comes from eigh, whose eigenvectors are "
                    "unique up to sign: on a GPU the JAX driver's (cuSOLVER's) signs differ from NumPy's (LAPACK's)")
    case = FEATURES[name].case()
    result = replay(case)
    _exercised(case, result)
    assert result.numpy_streams.calls == result.jax_streams.calls, "the drivers asked for different draws"
    assert not result.numpy_streams.subsets, "the numpy driver drew for some trials only"
    assert_same_filter(result)


def _by_step(calls: list) -> dict:
    steps: dict = {}
    for step, method, shape in calls:
        steps.setdefault(step, []).append((method, shape))
    return steps


@pytest.mark.parametrize("name", list(INJECTION_FEATURES))
def test_the_injection_replays_where_numpy_draws_only_in_the_trials_that_may_inject(name):
    """NumPy draws the injection's uniforms and prior particles only in the trials whose injection probability is
    positive, JAX in every trial: at a step where none is positive JAX makes those two calls and NumPy none; at
    the others both make them (NumPy from a subset of the rows, which the replay serves from the full draws)."""
    case = INJECTION_FEATURES[name].case()
    result = replay(case)
    _exercised(case, result)
    probe = ReplayStreams(TRIALS)
    result.bound.prior.sample(probe, (PARTICLES,))
    injection_calls = [("uniform", (PARTICLES,))] + [(method, shape) for _, method, shape in probe.calls]
    numpy_steps, jax_steps = _by_step(result.numpy_streams.calls), _by_step(result.jax_streams.calls)
    assert set(numpy_steps) == set(jax_steps)
    skipped = []
    for step in jax_steps:
        if numpy_steps[step] != jax_steps[step]:
            assert jax_steps[step] == numpy_steps[step] + injection_calls, f"step {step}: {jax_steps[step]}"
            skipped.append(step)
    subset_steps = {step for step, _ in result.numpy_streams.subsets}
    assert skipped and len(skipped) < STEPS and not subset_steps & set(skipped)
    assert_same_filter(result)


@pytest.mark.parametrize("resampler, numpy_call, jax_call", [
    ("multinomial", ("standard_exponential", (PARTICLES + 1,)), ("uniform", (PARTICLES,))),
    ("residual", ("standard_exponential", None), ("uniform", (PARTICLES,))),
])
def test_multinomial_and_residual_draw_differently_by_design(resampler, numpy_call, jax_call):
    """Step 1's resampler draws: NumPy's multinomial N + 1 exponential spacings, its residual the residual count's
    spacings per trial (a subset of one row each); JAX N iid uniforms for every trial, for both. So they cannot
    replay (module docstring)."""
    result = replay(Replayed(f"resampler-{resampler}-ess1").case())
    numpy_calls, jax_calls = _by_step(result.numpy_streams.calls)[1], _by_step(result.jax_streams.calls)[1]
    assert numpy_calls[0] == jax_calls[0]          # the transition's noise
    assert jax_calls[1:] == [jax_call]
    method, shape = numpy_call
    assert all(call[0] == method for call in numpy_calls[1:]) and numpy_calls[1:]
    if shape is not None:
        assert numpy_calls[1:] == [numpy_call] and not result.numpy_streams.subsets
    else:                 # one call per trial with a residual count, each from that trial's row alone
        rows = [subset for step, subset in result.numpy_streams.subsets if step == 1]
        assert len(rows) == len(numpy_calls) - 1 and all(len(subset) == 1 for subset in rows)
