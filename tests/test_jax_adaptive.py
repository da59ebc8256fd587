"""KLD-sampling (``filter.adaptive``) on the JAX backend (pfx/filters/particle/adaptive.py, run
by the kernel's resampling stage, pfx/filters/particle/kernel.py).

The backends draw from different generators, so the JAX run is checked against NumPy's in
distribution (the active counts' means, within 4 standard errors over trials), against the
Kalman filter's exact posterior, and against the rule itself (the bins' first occurrences,
exact integers; no active particle descends from an inactive one). Every seed is fixed.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import pfx
from pfx.filters.particle.adaptive import occupied_bins_by_prefix
from pfx.filters.particle.cloud import active_uniform
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_plugins")

TRIALS, STEPS, MAXIMUM = 100, 12, 1000
KLD = {"kind": "kld", "bin_size": 0.2, "min_particles": 20}


def test_occupied_bins_by_prefix_on_jax_equals_numpy_with_repeated_bins():
    """Compiled (fixed shapes: a NumPy-only rule cannot trace), for 1 to 3 components, clouds
    whose draws repeat bins many times over (coarse bins, some states copied exactly)."""
    generator = np.random.default_rng(11)
    for dimension, bin_size in ((1, 0.5), (2, [0.7, 1.5]), (3, 1.0)):
        states = generator.normal(0.0, 2.0, size=(6, 400, dimension))
        states[:, 200:] = states[:, :200][:, generator.permutation(200)]      # exact copies, reordered
        expected = occupied_bins_by_prefix(states, bin_size)
        with jax.enable_x64(True):
            occupied = jax.jit(lambda cloud, size=bin_size: occupied_bins_by_prefix(cloud, size))(jnp.asarray(states))
        np.testing.assert_array_equal(np.asarray(occupied), expected)
        assert expected[:, -1].max() < 200 < 400      # bins did repeat: the test is not vacuous


def test_active_uniform_on_jax_equals_numpy():
    """The weights of a cloud with an active count (after resampling, or a degenerate restart)."""
    counts = np.array([1, 7, 50])
    with jax.enable_x64(True):
        log_weights, weights = jax.jit(lambda n: active_uniform(n, 50))(jnp.asarray(counts))
    for computed, expected in zip((log_weights, weights), active_uniform(counts, 50)):
        np.testing.assert_array_equal(np.asarray(computed), expected)


@pytest.fixture(scope="module")
def runs():
    """One linear-Gaussian batch (x_k = 0.9 x_k-1 + w_k, z_k = x_k + v_k, unit variances) filtered
    with KLD-sampling on both backends, and the Kalman filter's exact posterior."""
    model = pfx.model("linear_gaussian", steps=STEPS, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    truth, measurements = simulate_truth(model, TrialStreams.from_seeds(range(TRIALS)))
    filtered = {backend: pfx.filter(model, measurements, particles=MAXIMUM, backend=backend, seed=3,
                                    adaptive=KLD, genealogy=True, ess_threshold=1.0)
                for backend in ("numpy", "jax")}
    kalman = pfx.filter(model, measurements, kind="kf").trace
    return filtered, kalman, truth[:, 1:]


def test_the_active_counts_agree_with_numpy_in_distribution(runs):
    filtered, _, _ = runs
    counts = {backend: result.trace.particle_counts for backend, result in filtered.items()}
    assert (counts["jax"][:, 0] == MAXIMUM).all()              # the prior's cloud: every particle
    assert (counts["jax"] >= KLD["min_particles"]).all() and (counts["jax"][:, 1:] < MAXIMUM).all()
    # per trial, the mean count over the adapted steps; then the means over trials, 4 standard errors
    per_trial = {backend: value[:, 1:].mean(axis=1) for backend, value in counts.items()}
    error = np.sqrt(sum(value.var(ddof=1) / TRIALS for value in per_trial.values()))
    assert abs(per_trial["jax"].mean() - per_trial["numpy"].mean()) < 4 * error, per_trial
    # and step by step
    for step in range(1, STEPS):
        error = np.sqrt(sum(value[:, step].var(ddof=1) / TRIALS for value in counts.values()))
        assert abs(counts["jax"][:, step].mean() - counts["numpy"][:, step].mean()) < 4 * error + 1e-9, step


def test_the_estimate_agrees_with_the_kalman_filter(runs):
    """Inactive particles (weight 0, parked on a copy of particle 0) must not count: were they
    weighted, the estimate would sit near one particle and miss the Kalman mean by about a
    posterior standard deviation. With them at weight 0, (x_pf - x_kf)^2 / P_k is the Monte
    Carlo error of a few hundred particles, ~1/ESS; and the squared error against the truth over
    P_k averages 1 within 4 standard errors."""
    filtered, kalman, truth = runs
    estimates = filtered["jax"].trace.estimates[..., 0]
    variances = kalman.covariances[..., 0, 0]
    discrepancy = (estimates - kalman.estimates[..., 0]) ** 2 / variances
    assert discrepancy.mean() < 0.05, discrepancy.mean()
    normalised = ((estimates - truth[..., 0]) ** 2 / variances).mean(axis=1)
    assert abs(normalised.mean() - 1.0) < 4 * normalised.std(ddof=1) / np.sqrt(TRIALS), normalised.mean()


def test_no_active_particle_descends_from_an_inactive_one(runs):
    """Every trial resamples at every step: the active particles of step k were drawn from the
    weighted cloud of step k-1, whose inactive particles have weight 0."""
    trace = runs[0]["jax"].trace
    counts, ancestors = trace.particle_counts, trace.ancestors
    for step in range(1, STEPS):
        active = np.arange(MAXIMUM) < counts[:, step, None]
        assert (ancestors[:, step][active] >= 0).all()
        assert (np.where(active, ancestors[:, step], -1) < counts[:, step - 1, None]).all(), step


def test_an_adaptive_config_runs_on_jax_through_the_cli(tmp_path, tiny_config_dict, pfx_in_process, write_config):
    config = tiny_config_dict()
    config["filter"].update(backend="jax", particles=300, ess_threshold=1.0,
                            adaptive={"kind": "kld", "bin_size": 0.5, "min_particles": 15})
    result = pfx_in_process("run", str(write_config(config)), "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.output
    trials = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert (trials["backend"] == "jax").all()
    assert ((trials["particles_mean"] >= 15) & (trials["particles_mean"] < 300)).all(), trials["particles_mean"]
    assert (trials["injected_mean"] == 0).all()


def test_with_kld_the_injection_replaces_only_the_active_particles_of_the_new_count(backend):
    """KLD then injection, as both engines order them: the prior draws go among the particles the
    new count keeps (ancestor -1 only below it), and every replacement counts in ``injected``.
    The likelihood of a wide measurement noise after a narrow prior keeps w_fast below w_slow
    early, so particles are injected while the counts change from step to step. (The numpy
    engine once took the count before this resampling: a prior draw could land on a particle
    the new count leaves inactive, and be counted as injected.)"""
    model = pfx.model("linear_gaussian", steps=STEPS, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(40)))
    measurements = measurements + np.where(np.arange(STEPS)[None, :, None] % 4 == 3, 6.0, 0.0)   # jumps
    trace = pfx.filter(model, measurements, particles=400, backend=backend, seed=5, adaptive=KLD,
                       injection={"kind": "augmented", "alpha_slow": 0.05, "alpha_fast": 0.5},
                       genealogy=True, ess_threshold=1.0).trace
    # ancestors[:, k]: the parents of step k's cloud, made by step k-1's resampling, which
    # injected[:, k-1] counts; particle_counts[:, k]: the count that resampling kept
    injected_at = trace.ancestors[:, 1:] == -1                              # (trials, T-1, N)
    assert trace.injected.sum() > 50 and np.unique(trace.particle_counts[:, 1:]).size > 5     # not vacuous
    active = np.arange(400) < trace.particle_counts[:, 1:, None]
    assert not (injected_at & ~active).any()
    np.testing.assert_array_equal(injected_at.sum(axis=-1), trace.injected[:, :-1])


def test_a_trial_that_did_not_resample_keeps_its_particles_as_their_own_ancestors(backend):
    """With KLD and the ESS rule at 0.5, the genealogy of a step whose trial did not resample is
    i -> i. (The jax engine once put KLD's random order on every trial, the ones that did not
    resample too: their genealogy said particles had changed places when none had.)"""
    model = pfx.model("linear_gaussian", steps=STEPS, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(20)))
    trace = pfx.filter(model, measurements, particles=200, backend=backend, seed=7, adaptive=KLD,
                       genealogy=True, ess_threshold=0.5).trace
    kept = ~trace.resampled[:, :-1]                      # ancestors[:, k] come from step k-1's resampling
    assert kept.any() and (~kept).any()                  # both kinds of step occur
    identity = np.arange(trace.ancestors.shape[-1])
    assert (trace.ancestors[:, 1:][kept] == identity).all()
    assert (trace.ancestors[:, 1:][~kept] != identity).any(axis=-1).all()
