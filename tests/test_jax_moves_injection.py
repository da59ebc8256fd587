"""The moves after resampling (``filter.move``: regularise, mcmc) and particle injection
(``filter.injection``: augmented MCL) on the jax backend, against the NumPy backend and the
Kalman filter.

The two backends draw from different generators, so their runs agree in distribution: means
over trials within 4 standard errors (fixed seeds). What is deterministic is checked exactly:
the regularisation kernel's displacement is h eps D' with D D' the unbiased weighted covariance,
the kernel draws eps regenerated from the same streams; a trial that did not resample injects
nothing; a prior draw has ancestor -1.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import tiny_config_dict

import pfx
from pfx.filters.particle.injection import AugmentedMCL, injection_probability, observed_averages
from pfx.filters.particle.moves import MoveContext, Regularisation, unbiased_weighted_covariance
from pfx.models.simulation import simulate_truth
from pfx.models.sonar_mcl import FreeSpaceLaw, SonarMCL
from pfx.numerics.seeding import TrialStreams

pytest.importorskip("jax")

SQUARE = [[0.0, 0.0, 100.0, 0.0], [100.0, 0.0, 100.0, 100.0], [100.0, 100.0, 0.0, 100.0], [0.0, 100.0, 0.0, 0.0]]
KIDNAP_STEP, TRIALS = 7, 40
INJECTION = {"kind": "augmented", "alpha_slow": 0.1, "alpha_fast": 0.5}


# -- injection: the kidnapped robot ------------------------------------------------------------

@pytest.fixture(scope="module")
def kidnapped():
    """The kidnapped robot in a square arena (tests/test_adaptive.py's), carried at step 7:
    {(backend, ESS threshold): (filter result, settings)} for 40 trials of 200 particles."""
    model = SonarMCL(walls=SQUARE, route=["move 20", "turn 90", "move 20", "turn 90"] * 3,
                     initial={"kind": "point", "state": [30.0, 30.0, 0.0]},
                     kidnap={"step": KIDNAP_STEP, "to": [80.0, 70.0, 180.0]}, measurement_noise={"variance": 25.0})
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(TRIALS)))
    runs = {}
    for backend in ("numpy", "jax"):
        for threshold in (1.0, 0.5):
            run = pfx.particle_filter(model, prior=FreeSpaceLaw(walls=SQUARE), particles=200, resampler="systematic",
                                      ess_threshold=threshold, injection=INJECTION, backend=backend)
            runs[backend, threshold] = run(measurements, seeds=list(range(100, 100 + TRIALS)), genealogy=True)
    return runs


@pytest.mark.parametrize("threshold", [1.0, 0.5])
def test_the_jax_backend_injects_after_the_kidnap_and_none_before(kidnapped, threshold):
    injected = kidnapped["jax", threshold].trace.injected
    assert injected.shape == (TRIALS, 12) and injected.dtype == np.int64
    assert (injected[:, :KIDNAP_STEP - 1] == 0).all()
    assert (injected[:, KIDNAP_STEP - 1:].sum(axis=1) > 0).mean() > 0.9


@pytest.mark.parametrize("threshold", [1.0, 0.5])
def test_the_injected_counts_agree_with_numpy_in_distribution(kidnapped, threshold):
    totals = {backend: kidnapped[backend, threshold].trace.injected.sum(axis=1).astype(float)
              for backend in ("numpy", "jax")}
    standard_error = math.sqrt(sum(total.var(ddof=1) / TRIALS for total in totals.values()))
    assert totals["jax"].mean() > 0
    assert abs(totals["jax"].mean() - totals["numpy"].mean()) < 4 * standard_error


def test_a_prior_draw_has_no_ancestor_on_either_backend(kidnapped):
    for backend in ("numpy", "jax"):
        result = kidnapped[backend, 1.0]
        orphans = (result.ancestors[:, 1:] == -1).sum(axis=-1)      # step k + 1's particles, made at step k
        np.testing.assert_array_equal(orphans, result.trace.injected[:, :-1])
        assert orphans.sum() > 0, backend


def test_only_the_trials_that_resample_inject_and_at_the_stated_rate(kidnapped):
    """ESS threshold 0.5: the probability p_k = max(0, 1 - w_fast / w_slow) of each trial and step,
    replayed from the recorded log-normalisers L_k by the injection module's functions; a trial
    that did not resample injects nothing (also where p_k > 0), and one that did replaces
    N p_k particles in expectation (binomial standard error)."""
    result = kidnapped["jax", 0.5]
    trace, settings = result.trace, AugmentedMCL(**INJECTION)
    slow = fast = np.full(TRIALS, -np.inf)
    probability = np.empty_like(trace.log_likelihood_increments)
    with np.errstate(divide="ignore"):
        for step in range(probability.shape[1]):
            slow, fast = observed_averages(settings, slow, fast, trace.log_likelihood_increments[:, step])
            probability[:, step] = injection_probability(slow, fast)
    kept = ~trace.resampled
    assert (kept & (probability > 0.05)).sum() >= 5            # the case is met, at several steps
    assert (trace.injected[kept] == 0).all()
    drawn = trace.resampled & (probability > 0)
    expected = 200 * probability[drawn]
    standard_error = math.sqrt(np.sum(expected * (1.0 - probability[drawn])))
    assert abs(trace.injected[drawn].sum() - expected.sum()) < 4 * standard_error


# -- regularise: the kernel, exactly, and against the Kalman filter ----------------------------

def _clouds(particles: int = 4000):
    """Three trials' weighted clouds in 2-D: a correlated one, one collapsed onto the line
    x2 = 2 x1 (a singular covariance) and one on a single point (a zero covariance)."""
    generator = np.random.default_rng(8)
    first = generator.normal(size=(particles, 2)) @ np.array([[1.0, 0.0], [0.6, 0.5]])
    line = generator.normal(size=(particles, 1)) * np.array([1.0, 2.0])
    point = np.full((particles, 2), 3.0)
    cloud = np.stack([first, line, point])
    weights = generator.exponential(size=(3, particles))
    weights /= weights.sum(axis=1, keepdims=True)
    return cloud, weights


def _kernel_displacements(move, cloud, weights, seeds, backend):
    """(the move's displacements (R, N, d) of ``cloud`` resampled in place, the kernel's draws
    regenerated from the same streams), on ``backend``; on jax, traced as the compiled step traces it."""
    import jax
    import jax.numpy as jnp

    from pfx.numerics.key_streams import KeyStreams

    trials, count, dimension = cloud.shape
    indices = np.broadcast_to(np.arange(count), (trials, count))
    if backend == "numpy":
        context = MoveContext(model=None, step=1, resampled=cloud, cloud=cloud, weights=weights, measurement=None,
                              parents=None, indices=indices, log_weights=np.log(weights))
        moved = move.apply(context, TrialStreams.from_seeds(seeds))[0]
        return moved - cloud, move.draw_kernel(TrialStreams.from_seeds(seeds), count, dimension)

    def moved_by(arrays):
        context = MoveContext(model=None, step=1, resampled=arrays[0], cloud=arrays[0], weights=arrays[1],
                              measurement=None, parents=None, indices=arrays[2], log_weights=jnp.log(arrays[1]))
        return move.apply(context, KeyStreams.from_seeds(seeds))[0]

    with jax.enable_x64(True):
        moved = np.asarray(jax.jit(moved_by)((jnp.asarray(cloud), jnp.asarray(weights), jnp.asarray(indices))))
        draws = np.asarray(move.draw_kernel(KeyStreams.from_seeds(seeds), count, dimension))
    return moved - cloud, draws


@pytest.mark.parametrize("kernel", ["gaussian", "epanechnikov"])
def test_the_regularisation_kernel_moves_by_h_eps_d_on_both_backends(kernel):
    """The move's displacement is h eps D' with eps the kernel's draws (regenerated from the same
    streams) and D D' the unbiased weighted covariance before resampling: recovered by least
    squares, D D' matches to 1e-9, also where the covariance is singular (the jax path clips the
    round-off eigenvalues as numpy does: no NaN, nothing raised) or zero (no move). Hence the
    cloud's spread grows by h^2 c_K Sigma (c_K the kernel's variance: 1, or 1/(d + 4))."""
    cloud, weights = _clouds()
    trials, count, dimension = cloud.shape
    move = Regularisation(kernel=kernel, bandwidth=0.5, bandwidth_scale=2.0)      # h = 1
    covariance = unbiased_weighted_covariance(weights, cloud, np.ones_like(weights, dtype=bool))
    variance = 1.0 if kernel == "gaussian" else 1.0 / (dimension + 4)
    for backend in ("numpy", "jax"):
        displacement, draws = _kernel_displacements(move, cloud, weights, [21, 22, 23], backend)
        assert np.isfinite(displacement).all(), backend
        np.testing.assert_allclose(displacement[2], 0.0, atol=1e-12)    # a zero covariance (to round-off): no move
        for trial in range(2):
            factor, *_ = np.linalg.lstsq(draws[trial], displacement[trial], rcond=None)
            np.testing.assert_allclose(draws[trial] @ factor, displacement[trial], atol=1e-9)
            np.testing.assert_allclose(factor.T @ factor, covariance[trial], rtol=1e-9, atol=1e-9)
            # the spread added: E|h D eps|^2 = h^2 c_K tr(Sigma), within 4 standard errors
            squared = np.sum(displacement[trial] ** 2, axis=-1)
            expected = variance * np.trace(covariance[trial])
            assert abs(squared.mean() - expected) < 4 * squared.std(ddof=1) / math.sqrt(count), backend
        along = displacement[1] @ np.array([2.0, -1.0])                 # normal to the line x2 = 2 x1
        np.testing.assert_allclose(along, 0.0, atol=1e-9)


def _linear_model():
    return pfx.model("linear_gaussian", steps=25, transition_matrix=[[0.9, 0.2], [0.0, 0.8]],
                     measurement_matrix=[[1.0, 0.0]], process_noise={"variance": [0.5, 0.5]},
                     measurement_noise={"variance": 1.0},
                     initial={"kind": "gaussian", "mean": [0.0, 0.0], "covariance": 1.0})


@pytest.fixture(scope="module")
def kalman():
    """60 trials' own measurements, the Kalman filter's means and its last posterior sds."""
    model = _linear_model()
    simulation = pfx.simulate(model, trials=60, seed=4)
    exact = pfx.filter(model, simulation.measurements, kind="kf", consistency=True)
    return model, simulation.measurements, exact.estimates, np.sqrt(np.diagonal(exact.trace.covariances[0, -1]))


@pytest.mark.parametrize("move", [{"kind": "regularise"}, {"kind": "mcmc", "steps": 2}], ids=["regularise", "mcmc"])
def test_a_moved_filter_matches_the_kalman_mean_on_both_backends(kalman, move):
    """Mean over trials of each trial's mean error against the Kalman filter within 4 standard
    errors, and its RMS a small part of the posterior sd, on both backends; with mcmc, the mean
    acceptance rates of the two backends within 4 standard errors."""
    model, measurements, exact, posterior_sd = kalman
    acceptance = {}
    for backend in ("numpy", "jax"):
        result = pfx.filter(model, measurements, particles=300, backend=backend, seed=5, move=move, ess_threshold=0.5)
        error = result.estimates - exact
        per_trial = error.mean(axis=1)
        standard_error = per_trial.std(ddof=1, axis=0) / math.sqrt(len(per_trial))
        assert (np.abs(per_trial.mean(axis=0)) < 4 * standard_error).all(), (backend, per_trial.mean(axis=0))
        assert (np.sqrt(np.mean(error ** 2, axis=(0, 1))) < 0.25 * posterior_sd).all(), backend
        acceptance[backend] = result.trace.move_acceptance
    if move["kind"] == "mcmc":
        assert np.isfinite(acceptance["jax"]).all() and ((acceptance["jax"] > 0) & (acceptance["jax"] < 1)).all()
        standard_error = math.sqrt(sum(rates.var(ddof=1) / len(rates) for rates in acceptance.values()))
        assert abs(acceptance["jax"].mean() - acceptance["numpy"].mean()) < 4 * standard_error
    else:
        assert acceptance["jax"] is None and acceptance["numpy"] is None


# -- the command line ------------------------------------------------------------------------

def test_a_config_with_the_moves_and_injection_runs_on_jax_from_the_command_line(pfx_in_process, tmp_path):
    """The moved arms run the Kalman tests' filters (_linear_model, 60 trials of 300 particles,
    ESS threshold 0.5, mcmc with 2 steps; untraced, no spread criterion): the programs compiled
    there serve here. What is checked (the arms run on jax, their columns) does not depend on the size."""
    model = _linear_model()
    config = tiny_config_dict(trials=60, outputs={"figures": [], "trace_trials": 0},
                              metrics={"convergence": {"criterion": "truth"}})
    config["model"] = {"kind": "linear_gaussian", "steps": model.steps,
                       "transition_matrix": [[0.9, 0.2], [0.0, 0.8]], "measurement_matrix": [[1.0, 0.0]],
                       "process_noise": {"variance": [0.5, 0.5]}, "measurement_noise": {"variance": 1.0},
                       "initial": {"kind": "gaussian", "mean": [0.0, 0.0], "covariance": 1.0}}
    config["filter"].update(backend="jax", particles=300, ess_threshold=0.5)
    config["arms"] = {"regularised": {"move": {"kind": "regularise"}}, "mcmc": {"move": {"kind": "mcmc", "steps": 2}},
                      "augmented": {"injection": INJECTION}}
    path = tmp_path / "moved.yaml"
    path.write_text(yaml.safe_dump(config))
    code, out, err = pfx_in_process("run", path, "--out", tmp_path / "out")
    assert code == 0, out + err
    trials = pd.read_csv(tmp_path / "out" / "trials.csv").set_index("arm")
    assert set(trials.index) == {"regularised", "mcmc", "augmented"} and (trials["backend"] == "jax").all()
    assert len(trials) == 3 * 60 and trials["rmse_x1"].notna().all()
    assert (trials.loc["augmented", "injected_mean"] >= 0).all()
    acceptance = trials.loc["mcmc", "move_acceptance"]
    assert ((acceptance > 0) & (acceptance < 1)).all()
