"""The particle filter's feature matrix: one small run per feature, each checked to reach its feature.

Each case of the matrix below builds a small plan from a config dict (3 trials, at most 40 particles, at
most 12 steps: the file runs in seconds) and runs its cell's bound particle filter on the numpy backend:
every resampler at ESS thresholds 0, 0.5 and 1; missing measurements, lost particles, substeps, a model's
fused numba step; the auxiliary filter, each move, KLD, injection, each proposal and each weighting;
scores, forecasts, the genealogy and each smoother. Each case checks that its feature was exercised (a
resampling at ESS threshold 0.5, lost particles, an injection, ...): a case that silently stopped reaching
its feature would prove nothing, and the matrix covers every registered component
(:func:`test_the_matrix_covers_every_registered_component`).

The matrix guarded the kernel refactor (issue 48), when a frozen copy of the old NumPy engine was run beside
pfx on every case, bit for bit. Its cases now serve tests/test_kernel_replay.py, which runs both drivers of
the one kernel on the same draws.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
import pytest
from conftest import REPO_ROOT

from pfx.config.plan import build_plan
from pfx.errors import ModelNumericalError
from pfx.filters.particle.forecasting import ForecastRequest
from pfx.filters.particle.moves import MOVES
from pfx.filters.particle.proposals import PROPOSALS
from pfx.filters.particle.recorders import Recording, SnapshotRequest, SpreadCriterion
from pfx.filters.particle.resampling import RESAMPLERS
from pfx.filters.particle.weighting import WEIGHTINGS
from pfx.filters.smoothers import SMOOTHERS
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, filter_seed, truth_seed

# the SIR plugin's model integrates substeps and has an accumulating component
pytestmark = pytest.mark.usefixtures("fresh_plugins")

SEED, TRIALS = 5, 3
PARTICLES = 40
STEPS = 12
SIR_PLUGIN = str(REPO_ROOT / "examples" / "plugins" / "sir.py")
STAGES = frozenset({"prior", "predicted", "weighted", "resampled"})

# -- models ------------------------------------------------------------------------------------------------

LINEAR = {"kind": "linear_gaussian", "steps": STEPS, "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
          "measurement_matrix": [[1.0, 0.0]]}
# three range measurements of a planar position: a nonlinear measurement for the guided proposals
BEACONS = {"kind": "range_beacons", "steps": 10, "beacons": [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]}
# pfx bench's falling body: the bootstrap filter with the likelihood takes its fused compiled step
FALLING_BODY = {"kind": "falling_body", "variant": "simon", "integrator": "euler", "substeps": 1, "dt": 0.1,
                "steps": STEPS, "process_noise": {"family": "gaussian", "variance": [100.0, 100.0, 1.0e-12]}}
FALLING_BODY_PRIOR = {"kind": "gaussian", "mean": [3.0e5, -2.0e4, 1.0e-3], "covariance": [1.0e6, 4.0e6, 1.0e-7]}
# a ballistic coefficient of either sign (sd 3.2): the drag equation blows up (or its Euler step
# goes unstable) for some particles, which leave the model's domain (lost particles)
LOSING_FALLING_BODY = {"kind": "falling_body", "steps": STEPS}
LOSING_PRIOR = {"kind": "gaussian", "mean": [3.0e5, -2.0e4, 0.0], "covariance": [1.0e6, 4.0e6, 10.0]}
# uniform measurement noise far from the filter's prior: every likelihood is exactly 0 (degenerate steps)
UNDERFLOWING = {"kind": "linear_gaussian", "steps": 6, "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                "process_noise": {"variance": 1e-6}, "measurement_noise": {"family": "uniform", "variance": 1e-6},
                "initial": {"kind": "point", "state": [0.0]}}
UNDERFLOWING_PRIOR = {"kind": "gaussian", "mean": [1000.0], "covariance": 1.0}
SIR = {"kind": "sir", "steps": 10, "substeps": 4, "population": 2000.0}

# measurements made missing (NaN) in the missing-measurement cases, (trial or None: every trial, step)
MISSING_STEPS = ((0, 3), (0, 4), (None, 6), (1, 9), (2, STEPS))


# -- the cases ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Case:
    """One run of the matrix: a config's model and filter, the recording, the measurements made
    missing, and ``exercised(run)``, which asserts that the case reached its feature."""

    model: dict
    filter: dict
    recording: Callable[[], Recording] = Recording
    missing: tuple = ()
    exercised: Optional[Callable[["Run"], None]] = None
    plugins: tuple = ()


@dataclass
class Run:
    """pfx's run of a case (what ``exercised`` looks at)."""

    bound: Any
    measurements: np.ndarray
    trace: Any
    recording: Recording


def _filter(**settings) -> dict:
    return {"particles": PARTICLES, "resampler": "systematic", "ess_threshold": 0.5, **settings}


def _resampled_as_the_threshold_says(threshold: float) -> Callable[[Run], None]:
    def check(run: Run) -> None:
        resampled = run.trace.resampled
        if threshold == 0.0:
            assert not resampled.any()
        elif threshold >= 1.0:
            assert resampled.all()
        else:
            assert resampled.any() and not resampled.all()
    return check


def _all(*checks: Callable[[Run], None]) -> Callable[[Run], None]:
    def check(run: Run) -> None:
        for one in checks:
            one(run)
    return check


def _some_resampled(run: Run) -> None:
    assert run.trace.resampled.any()


def _missing_steps_add_nothing(run: Run) -> None:
    missing = np.isnan(run.measurements).any(axis=-1)
    assert missing.any() and missing.all(axis=0).any()       # some trials' steps, and one step of every trial
    assert (run.trace.log_likelihood_increments[missing] == 0.0).all()
    assert (run.trace.log_likelihood_increments[~missing] != 0.0).all()


def _lost(run: Run) -> None:
    assert run.trace.lost_particles.sum() > 0


def _compiled(run: Run) -> None:
    assert run.bound.uses_compiled_step and run.bound.model.compiled_step() is not None


def _not_compiled(run: Run) -> None:
    assert not run.bound.uses_compiled_step


def _degenerate(run: Run) -> None:
    assert run.trace.degenerate.any()


def _auxiliary(run: Run) -> None:
    assert run.bound.auxiliary is not None and run.trace.resampled.any()


def _guided(kind: str) -> Callable[[Run], None]:
    def check(run: Run) -> None:
        assert run.bound.proposal is not None and run.bound.proposal.settings.kind == kind
    return check


def _bootstrap(run: Run) -> None:
    assert run.bound.proposal is None


def _weighted_by(label: str) -> Callable[[Run], None]:
    def check(run: Run) -> None:
        assert run.bound.weighting.label() == label
    return check


def _moved(kind: str) -> Callable[[Run], None]:
    """A move acts on every resampled trial: it ran if some trial resampled; mcmc reports its acceptance."""
    def check(run: Run) -> None:
        assert run.bound.move is not None and run.bound.move.kind == kind and run.trace.resampled.any()
        if kind == "mcmc":
            acceptance = run.trace.move_acceptance
            assert np.isfinite(acceptance).any() and ((acceptance[np.isfinite(acceptance)] > 0.0).all())
        else:
            assert run.trace.move_acceptance is None
    return check


def _count_changed(run: Run) -> None:
    assert (run.trace.particle_counts < run.bound.particles).any()


def _injected(run: Run) -> None:
    assert run.trace.injected.sum() > 0


def _injected_have_no_ancestor(run: Run) -> None:
    assert (run.trace.ancestors == -1).any()


def _genealogy(run: Run) -> None:
    ancestors = run.trace.ancestors
    assert ancestors is not None and (ancestors != np.arange(ancestors.shape[-1])).any()


def _history(run: Run) -> None:
    assert run.trace.particles is not None and run.trace.log_weights is not None


def _consistency(run: Run) -> None:
    assert run.trace.covariances is not None and np.isfinite(run.trace.nis).any()


def _scores(run: Run) -> None:
    predictive = run.trace.predictive
    assert predictive is not None and np.isfinite(predictive.crps).any()


def _scores_without_log_score(run: Run) -> None:
    assert run.trace.predictive is not None and run.trace.predictive.log_score is None


def _energy_score(run: Run) -> None:
    assert run.trace.predictive.energy_score is not None


def _forecasts(run: Run) -> None:
    forecasts = run.trace.forecasts
    assert forecasts and len(forecasts["row"]) > 0 and run.trace.forecast_samples and run.trace.forecast_clouds


def _snapshots(run: Run) -> None:
    assert {cloud.stage for cloud in run.trace.snapshots} == STAGES


def _traced(run: Run) -> None:
    trace = run.trace
    assert np.isfinite(trace.spread[:2]).all() and np.isfinite(trace.standard_deviations[:2]).all()
    assert trace.within_radius is not None


def _smoothed(*labels: str) -> Callable[[Run], None]:
    def check(run: Run) -> None:
        assert list(run.trace.smoothed) == list(labels)
    return check


def _substeps(run: Run) -> None:
    model = run.bound.model
    assert model.propagations_per_step == 4 and tuple(model.accumulating_components) == (3,)


def _forecast_request() -> ForecastRequest:
    # horizon 5 from step 8 reaches past the last step (12): left out
    return ForecastRequest(rows=np.array([0, 2]), origins=frozenset({3, 8}), horizons=(1, 2, 5),
                           quantiles=(0.1, 0.5, 0.9))


def _snapshot_request() -> SnapshotRequest:
    return SnapshotRequest(rows=np.array([0, 2]), steps=frozenset({0, 1, 5, STEPS}), stages=STAGES)


def _every_recorder() -> Recording:
    return Recording(spread_criterion=SpreadCriterion(radius=2.0, weighted=False), consistency=True,
                     snapshot=SnapshotRequest(rows=np.array([1]), steps="all", stages=STAGES),
                     trace_rows=np.array([0, 1]), genealogy=True, history=True, scores=True,
                     forecast=_forecast_request())


def _recording(**fields) -> Callable[[], Recording]:
    return lambda: Recording(**fields)


THRESHOLDS = (0.0, 0.5, 1.0)
RESAMPLING_CASES = {
    f"resampler-{name}-ess{threshold:g}": Case(
        LINEAR, _filter(resampler=name, ess_threshold=threshold),
        exercised=_resampled_as_the_threshold_says(threshold))
    for name in RESAMPLERS.visible() for threshold in THRESHOLDS}

MISSING = dict(missing=MISSING_STEPS)
KLD = {"kind": "kld", "bin_size": 2.0, "epsilon": 0.3, "min_particles": 5}
INJECTION = {"kind": "augmented", "alpha_slow": 0.05, "alpha_fast": 0.9}
CASES: dict[str, Case] = {
    **RESAMPLING_CASES,
    "sis": Case(LINEAR, _filter(kind="sis"), exercised=_resampled_as_the_threshold_says(0.0)),
    "diffusion-gaussian": Case(LINEAR, _filter(diffusion={"kind": "gaussian", "std": [0.1, 0.05]}),
                               exercised=_some_resampled),
    "diffusion-roughening": Case(LINEAR, _filter(diffusion={"kind": "roughening", "factor": 0.3}),
                                 exercised=_some_resampled),
    "degenerate": Case(UNDERFLOWING, _filter(initial=UNDERFLOWING_PRIOR), exercised=_degenerate),
    "degenerate-kld": Case(UNDERFLOWING, _filter(initial=UNDERFLOWING_PRIOR, adaptive=KLD, ess_threshold=1.0),
                           exercised=_degenerate),
    # missing measurements: predict-only steps, in the stages that look at the measurement
    "missing": Case(LINEAR, _filter(), **MISSING, exercised=_all(_missing_steps_add_nothing, _some_resampled)),
    "missing-auxiliary": Case(LINEAR, _filter(auxiliary=True), **MISSING,
                              exercised=_all(_missing_steps_add_nothing, _auxiliary)),
    "missing-ekf": Case(LINEAR, _filter(proposal="ekf"), **MISSING,
                        exercised=_all(_missing_steps_add_nothing, _guided("ekf"))),
    "missing-mcmc": Case(LINEAR, _filter(move={"kind": "mcmc", "steps": 2}), **MISSING,
                         exercised=_all(_missing_steps_add_nothing, _moved("mcmc"))),
    "missing-kld-injection": Case(LINEAR, _filter(adaptive=KLD, injection=INJECTION, ess_threshold=1.0), **MISSING,
                                  exercised=_all(_missing_steps_add_nothing, _count_changed, _injected)),
    "missing-compiled-step": Case(FALLING_BODY, _filter(initial=FALLING_BODY_PRIOR), **MISSING,
                                  exercised=_all(_missing_steps_add_nothing, _compiled)),
    "missing-every-recorder": Case(LINEAR, _filter(), **MISSING, recording=_every_recorder,
                                   exercised=_all(_missing_steps_add_nothing, _scores, _forecasts, _consistency)),
    # particles leaving the model's domain: parked at weight zero and counted
    "lost-compiled-step": Case(LOSING_FALLING_BODY, _filter(initial=LOSING_PRIOR), exercised=_all(_lost, _compiled)),
    "lost-transition": Case(LOSING_FALLING_BODY, _filter(initial=LOSING_PRIOR,
                                                         weighting={"kind": "mahalanobis", "form": "innovation"}),
                            exercised=_all(_lost, _not_compiled)),
    "lost-every-recorder": Case(LOSING_FALLING_BODY, _filter(initial=LOSING_PRIOR), recording=_every_recorder,
                                exercised=_all(_lost, _scores, _genealogy, _consistency)),
    # the model's transition: substeps with an accumulating component (a plugin), the fused compiled step
    "substeps-sir-plugin": Case(SIR, _filter(), plugins=(SIR_PLUGIN,), exercised=_all(_substeps, _not_compiled)),
    "compiled-step": Case(FALLING_BODY, _filter(initial=FALLING_BODY_PRIOR, ess_threshold=1.0), exercised=_compiled),
    "compiled-step-rk4-substeps": Case({**FALLING_BODY, "integrator": "rk4", "substeps": 4},
                                       _filter(initial=FALLING_BODY_PRIOR), exercised=_compiled),
    # the auxiliary filter: its first stage resamples
    "auxiliary-ess0.5": Case(LINEAR, _filter(auxiliary=True), exercised=_auxiliary),
    "auxiliary-ess1": Case(LINEAR, _filter(auxiliary=True, ess_threshold=1.0), exercised=_auxiliary),
    "auxiliary-locally_optimal-genealogy": Case(LINEAR, _filter(auxiliary=True, proposal="locally_optimal"),
                                                recording=_recording(genealogy=True),
                                                exercised=_all(_auxiliary, _genealogy)),
    "auxiliary-beacons-scores": Case(BEACONS, _filter(auxiliary=True), recording=_recording(scores=True),
                                     exercised=_all(_auxiliary, _scores, _energy_score)),
    # moves after resampling
    "move-regularise-gaussian": Case(LINEAR, _filter(move="regularise"), exercised=_moved("regularise")),
    "move-regularise-epanechnikov-duplicates": Case(
        LINEAR, _filter(move={"kind": "regularise", "kernel": "epanechnikov", "jitter": "duplicates"},
                        ess_threshold=1.0), exercised=_moved("regularise")),
    "move-regularise-scott": Case(LINEAR, _filter(move={"kind": "regularise", "bandwidth": "scott",
                                                        "bandwidth_scale": 0.5}), exercised=_moved("regularise")),
    "move-mcmc": Case(LINEAR, _filter(move={"kind": "mcmc", "steps": 2}), exercised=_moved("mcmc")),
    "move-mcmc-scale-ess1-genealogy": Case(LINEAR, _filter(move={"kind": "mcmc", "scale": 0.5}, ess_threshold=1.0),
                                           recording=_recording(genealogy=True),
                                           exercised=_all(_moved("mcmc"), _genealogy)),
    # the adaptive count (KLD-sampling) and injection (augmented MCL)
    "kld-ess1": Case(LINEAR, _filter(adaptive=KLD, ess_threshold=1.0), exercised=_count_changed),
    "kld-ess0.5-genealogy": Case(LINEAR, _filter(adaptive=KLD), recording=_recording(genealogy=True),
                                 exercised=_all(_count_changed, _genealogy)),
    "kld-spread": Case(LINEAR, _filter(adaptive=KLD, ess_threshold=1.0), recording=lambda: Recording(
        spread_criterion=SpreadCriterion(radius=2.0, weighted=False), trace_rows=np.array([0, 1])),
        exercised=_all(_count_changed, _traced)),
    "injection": Case(LINEAR, _filter(injection=INJECTION, ess_threshold=1.0), exercised=_injected),
    "injection-ess0.5-genealogy": Case(LINEAR, _filter(injection=INJECTION), recording=_recording(genealogy=True),
                                       exercised=_all(_injected, _injected_have_no_ancestor)),
    "kld-injection": Case(LINEAR, _filter(adaptive=KLD, injection=INJECTION, ess_threshold=1.0),
                          exercised=_all(_count_changed, _injected)),
    # proposals (every registered kind, where it applies) and weightings (every registered kind)
    "proposal-bootstrap": Case(LINEAR, _filter(proposal="bootstrap"), exercised=_bootstrap),
    "proposal-locally_optimal": Case(LINEAR, _filter(proposal="locally_optimal"), exercised=_guided("locally_optimal")),
    "proposal-ekf": Case(LINEAR, _filter(proposal="ekf"), exercised=_guided("ekf")),
    "proposal-ukf": Case(LINEAR, _filter(proposal={"kind": "ukf", "alpha": 1.0}), exercised=_guided("ukf")),
    "proposal-ekf-beacons": Case(BEACONS, _filter(proposal="ekf"), exercised=_guided("ekf")),
    "proposal-ukf-beacons": Case(BEACONS, _filter(proposal={"kind": "ukf", "alpha": 0.5, "kappa": 1.0}),
                                 exercised=_guided("ukf")),
    "weighting-gaussian": Case(BEACONS, _filter(weighting="gaussian"), exercised=_weighted_by("gaussian")),
    "weighting-euclidean": Case(BEACONS, _filter(weighting="euclidean"), exercised=_weighted_by("euclidean")),
    "weighting-manhattan": Case(BEACONS, _filter(weighting={"kind": "manhattan", "scale": 2.0}),
                                exercised=_weighted_by("manhattan")),
    "weighting-mahalanobis-paper": Case(BEACONS, _filter(weighting={"kind": "mahalanobis", "form": "paper"}),
                                        exercised=_weighted_by("mahalanobis-paper")),
    "weighting-mahalanobis-innovation": Case(BEACONS, _filter(weighting={"kind": "mahalanobis", "form": "innovation"}),
                                             exercised=_weighted_by("mahalanobis-innovation")),
    # what a run records: scores, forecasts, the genealogy, the history, NEES/NIS, snapshots, the traced rows
    "scores": Case(LINEAR, _filter(), recording=_recording(scores=True), exercised=_scores),
    "scores-euclidean": Case(BEACONS, _filter(weighting="euclidean"), recording=_recording(scores=True),
                             exercised=_all(_scores, _scores_without_log_score, _energy_score)),
    "scores-ekf": Case(LINEAR, _filter(proposal="ekf"), recording=_recording(scores=True), exercised=_scores),
    "forecasts": Case(LINEAR, _filter(), recording=lambda: Recording(forecast=_forecast_request()),
                      exercised=_forecasts),
    "genealogy": Case(LINEAR, _filter(), recording=_recording(genealogy=True), exercised=_genealogy),
    "history": Case(LINEAR, _filter(), recording=_recording(history=True), exercised=_history),
    "consistency": Case(LINEAR, _filter(), recording=_recording(consistency=True), exercised=_consistency),
    "snapshots": Case(LINEAR, _filter(), recording=lambda: Recording(snapshot=_snapshot_request()),
                      exercised=_snapshots),
    "traced-spread-weighted": Case(LINEAR, _filter(), recording=lambda: Recording(
        spread_criterion=SpreadCriterion(radius=2.0, weighted=True), trace_rows=np.array([0, 1])), exercised=_traced),
    "every-recorder": Case(LINEAR, _filter(), recording=_every_recorder,
                           exercised=_all(_scores, _forecasts, _genealogy, _history, _consistency, _snapshots,
                                          _traced)),
    # smoothers, after the filter, on its recorded history and from its streams
    "smoother-ffbs": Case(LINEAR, _filter(smoothers=[{"kind": "ffbs", "trajectories": 15}]),
                          exercised=_smoothed("ffbs")),
    "smoother-ffbs_rejection": Case(LINEAR, _filter(smoothers=[{"kind": "ffbs_rejection", "trajectories": 15,
                                                                "rounds": 2}]), exercised=_smoothed("ffbs_rejection")),
    "smoother-fixed_lag": Case(LINEAR, _filter(smoothers=[{"kind": "fixed_lag", "lag": 3}]),
                               exercised=_smoothed("fixed_lag")),
    "smoother-genealogy": Case(LINEAR, _filter(smoothers=[{"kind": "genealogy"}]), exercised=_smoothed("genealogy")),
    "smoother-ffbs-both-forms-sis": Case(
        LINEAR, _filter(kind="sis", smoothers=[{"kind": "ffbs", "trajectories": 10},
                                               {"kind": "ffbs_rejection", "trajectories": 10}]),
        exercised=_all(_smoothed("ffbs", "ffbs_rejection"), _resampled_as_the_threshold_says(0.0))),
    "smoother-every-kind-with-forecasts": Case(
        LINEAR, _filter(smoothers=[{"kind": "ffbs", "trajectories": 10}, {"kind": "ffbs_rejection", "trajectories": 10},
                                   {"kind": "fixed_lag", "lag": 2}, {"kind": "genealogy"}]),
        recording=lambda: Recording(forecast=_forecast_request()),
        exercised=_all(_smoothed("ffbs", "ffbs_rejection", "fixed_lag", "genealogy"), _forecasts)),
}


# -- running a case ------------------------------------------------------------------------------------------

def _cell(case: Case):
    raw = {"name": "features", "seed": SEED, "trials": TRIALS, "model": copy.deepcopy(case.model),
           "filter": copy.deepcopy(case.filter)}
    if case.plugins:
        raw["plugins"] = list(case.plugins)
    return build_plan(raw, "features.yaml").cells[0]


def _measurements(cell, missing: tuple) -> np.ndarray:
    """The trials' simulated measurements, as ``pfx.run.batch.run_batch`` simulates them; ``missing``
    (trial or None, step) made NaN, as recorded data with blank rows arrives."""
    _, measurements = simulate_truth(cell.truth_model, TrialStreams.from_seeds(
        [truth_seed(SEED, trial, None) for trial in range(TRIALS)]))
    for trial, step in missing:
        measurements[slice(None) if trial is None else trial, step - 1] = np.nan
    return measurements


def _filter_streams(cell) -> TrialStreams:
    return TrialStreams.from_seeds([filter_seed(SEED, cell.stream_key, trial) for trial in range(TRIALS)])


def run(case: Case) -> Run:
    cell = _cell(case)
    bound = cell.planned_filter.bound
    assert bound.backend == "numpy" and bound.compiled is None
    measurements = _measurements(cell, case.missing)
    recording = case.recording()
    return Run(bound, measurements, bound.run(measurements.copy(), _filter_streams(cell), recording), recording)


@pytest.mark.parametrize("name", list(CASES))
def test_each_case_reaches_its_feature(name):
    case = CASES[name]
    case.exercised(run(case))


def test_a_trial_that_loses_every_particle_stops_the_run_at_its_step():
    case = Case(LOSING_FALLING_BODY, _filter(initial={**LOSING_PRIOR, "covariance": [1.0e6, 4.0e6, 1.0]}))
    cell = _cell(case)
    with pytest.raises(ModelNumericalError, match=r"model falling_body: every particle of a trial became NaN or "
                                                  r"infinite at step \d+ of the filter"):
        cell.planned_filter.bound.run(_measurements(cell, ()), _filter_streams(cell))


@dataclass
class _Used:
    resamplers: set = field(default_factory=set)
    moves: set = field(default_factory=set)
    proposals: set = field(default_factory=set)
    weightings: set = field(default_factory=set)
    smoothers: set = field(default_factory=set)


def _kind(value, default: str) -> str:
    return default if value is None else value if isinstance(value, str) else value["kind"]


def test_the_matrix_covers_every_registered_component():
    """A resampler, move, proposal, weighting or particle smoother registered in pfx without a case
    here fails this test: add its case to the matrix."""
    assert all(case.exercised is not None for case in CASES.values())      # each case proves it reached its feature
    used = _Used()
    for case in CASES.values():
        settings = case.filter
        used.resamplers.add(settings.get("resampler", "systematic"))
        used.moves.add(_kind(settings.get("move"), "none"))
        used.proposals.add(_kind(settings.get("proposal"), "bootstrap"))
        used.weightings.add(_kind(settings.get("weighting"), "gaussian"))
        used.smoothers.update(smoother["kind"] for smoother in settings.get("smoothers", ()))
    particle_smoothers = {name for name, smoother in SMOOTHERS.visible().items() if "particle" in smoother.filter_kinds}
    assert used.resamplers == set(RESAMPLERS.visible())
    assert used.moves == set(MOVES.visible())
    assert used.proposals == set(PROPOSALS.visible())
    assert used.weightings == set(WEIGHTINGS.visible())
    assert used.smoothers == particle_smoothers
