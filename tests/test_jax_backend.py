"""The JAX backend's particle filter (pfx/filters/particle/jax_engine.py): checks of what it
computes, on JAX's CPU build.

The two backends draw from different generators (NumPy's PCG64 per trial, threefry keys per
trial), so every check here is **backend-invariant**: a property of the algorithm checked
within Monte Carlo error (the offspring counts' unbiasedness, the backends' likelihood
estimates alike), or the JAX backend against itself (reruns, batching). The algorithm's checks
that hold on either backend take the ``backend`` fixture and live with their subject (the
Kalman filter's exact answers and the likelihood's unbiasedness: tests/test_kalman_convergence.py;
missing measurements: tests/test_recorded_data.py); the NumPy backend's bit-exact checks are
marked ``numpy_only``.
Statistical tolerances are 3 standard errors of the quantity compared, from the sample itself;
every seed is fixed.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import pfx
from pfx.errors import ConfigError, ModelNumericalError

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

from pfx.filters.particle.jax_resampling import JAX_RESAMPLERS, cumulative_weights  # noqa: E402
from pfx.numerics.key_streams import KeyStreams, threefry_keys  # noqa: E402
from pfx.numerics.seeding import TrialStreams  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_plugins")


def random_walk(steps: int = 30, **overrides):
    """x_k = 0.9 x_{k-1} + w_k, z_k = x_k + v_k, unit variances: the Kalman filter is exact."""
    parameters = dict(steps=steps, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    return pfx.model("linear_gaussian", **{**parameters, **overrides})


def simulated(model, trials: int, seed: int = 0):
    from pfx.models.simulation import simulate_truth

    truth, measurements = simulate_truth(model, TrialStreams.from_seeds(range(seed, seed + trials)))
    return truth[:, 1:], measurements


def test_threefry_keys_are_the_keys_jax_makes_of_the_seeds():
    seeds = [0, 1, 2**40 + 7, 2**62 + 12345]
    with jax.enable_x64(True):
        expected = np.stack([np.asarray(jax.random.key_data(jax.random.PRNGKey(seed))) for seed in seeds])
    assert (threefry_keys(seeds) == expected).all()


@pytest.mark.parametrize("precision", ["float64", "float32"])
@pytest.mark.parametrize("name", sorted(JAX_RESAMPLERS))
def test_offspring_counts_are_unbiased(name, precision):
    """E[N_j] = N w_j for every particle, over 20,000 resamplings of fixed weights (some zero:
    never chosen), within 4.5 standard errors per particle (20 particles, 10 cases); for
    han_lee_iv, kept to show its bias, E[N_j] is the exact biased mean the NumPy backend's has
    (resampling.han_lee_iv_expected_counts), as far from N w_j as it is there."""
    count, rows = 20, 20_000
    weights = np.random.default_rng(11).exponential(size=count)
    weights[[3, 4, 17]] = 0.0
    weights = (weights / weights.sum()).astype(precision)
    expected = count * weights.astype(float) / weights.astype(float).sum()
    if name == "han_lee_iv":
        from pfx.filters.particle.resampling import han_lee_iv_expected_counts

        expected = han_lee_iv_expected_counts(weights.astype(float) / weights.astype(float).sum())
    with jax.enable_x64(True):
        indices = JAX_RESAMPLERS[name](jnp.asarray(np.tile(weights, (rows, 1))), KeyStreams.from_seeds(range(rows)))
    indices = np.asarray(indices)
    counts = np.stack([np.bincount(row, minlength=count) for row in indices])
    assert (counts.sum(axis=1) == count).all()
    assert (counts[:, [3, 4, 17]] == 0).all()
    mean, standard_error = counts.mean(axis=0), counts.std(axis=0, ddof=1) / np.sqrt(rows)
    exact = standard_error == 0        # systematic may have no spread for a particle
    assert np.all(np.abs(mean - expected)[exact] < 1e-9)
    assert np.all(np.abs(mean - expected)[~exact] < 4.5 * standard_error[~exact]), (mean - expected) / standard_error


def test_cumulative_weights_stay_exact_for_a_million_float32_weights():
    """With 2^20 float32 weights, systematic resampling gives the first half of the particles
    N C_half offspring to within 1 (C summed in float64), where a float32 running sum would be
    off by more than one particle: the single-precision bias the resamplers avoid."""
    count = 2**20
    weights = np.random.default_rng(2).exponential(size=count).astype(np.float32)
    weights /= weights.sum(dtype=np.float64)
    exact_half = weights[: count // 2].astype(np.float64).sum()
    single_precision_half = np.cumsum(weights, dtype=np.float32)[count // 2 - 1]
    assert abs(count * (single_precision_half - exact_half)) > 1.0       # the test can tell
    with jax.enable_x64(True):
        cumulative = np.asarray(cumulative_weights(jnp.asarray(weights[None, :])))
        indices = np.asarray(JAX_RESAMPLERS["systematic"](jnp.asarray(weights[None, :]), KeyStreams.from_seeds([4])))
    assert cumulative.dtype == np.float64
    assert abs(cumulative[0, count // 2 - 1] - exact_half) < 1e-12
    assert abs((indices[0] < count // 2).sum() - count * exact_half) <= 1.0


def test_float32_runs_in_single_precision_and_agrees_with_float64():
    """The float64 run has the unbiasedness test's shape (tests/test_kalman_convergence.py: 10
    steps, 4000 trials of 50 particles); the tolerance is 3 standard errors at that size."""
    model = random_walk(steps=10)
    _, measurements = simulated(model, 1, seed=4)
    runs = {precision: pfx.filter(model, measurements[0], trials=4000, particles=50, backend="jax",
                                  precision=precision, seed=9).log_likelihood for precision in ("float64", "float32")}
    single, double = runs["float32"], runs["float64"]
    standard_error = np.sqrt(single.var(ddof=1) / len(single) + double.var(ddof=1) / len(double))
    assert abs(single.mean() - double.mean()) < 3 * standard_error


def test_batching_changes_nothing_and_a_rerun_is_identical():
    model = random_walk(steps=15)
    _, measurements = simulated(model, 6)
    bound = pfx.particle_filter(model, particles=64, backend="jax")
    seeds = [101, 102, 103, 104, 105, 106]
    whole = bound(measurements, seeds=seeds)
    halves = [bound(measurements[part], seeds=seeds[part]) for part in (slice(0, 3), slice(3, 6))]
    again = bound(measurements, seeds=seeds)
    assert np.array_equal(whole.estimates, again.estimates)
    assert np.array_equal(whole.log_likelihood, again.log_likelihood)
    np.testing.assert_allclose(np.concatenate([h.log_likelihood for h in halves]), whole.log_likelihood,
                               rtol=1e-12)
    np.testing.assert_allclose(np.concatenate([h.estimates for h in halves]), whole.estimates, rtol=1e-10,
                               atol=1e-12)


TRANSITION_PROPOSAL_PLUGIN = '''
from typing import Literal

import pfx


@pfx.register_proposal
class TransitionAsPlugin(pfx.Proposal):
    """The transition, as a plugin's proposal: written for NumPy (it declares no backends)."""

    kind: Literal["transition_as_plugin"] = "transition_as_plugin"

    def propose(self, model, previous, step, measurement, observed, random):
        state = model.transition(previous, step, random)
        return state, 0.0 * state[..., 0]
'''


def test_the_jax_backend_refuses_what_it_does_not_run_by_key(tmp_path):
    (tmp_path / "transition_as_plugin.py").write_text(TRANSITION_PROPOSAL_PLUGIN)
    pfx.load_plugin(str(tmp_path / "transition_as_plugin.py"))   # every built-in proposal runs on jax
    model = random_walk(steps=5)
    cases = {"proposal": {"proposal": "transition_as_plugin"},
             "backend": {"kind": "kf"}}
    for key, settings in cases.items():
        kind = settings.pop("kind", "particle")
        with pytest.raises(ConfigError) as caught:
            pfx.particle_filter(model, kind=kind, backend="jax", **settings)
        assert f"filter.{key}" in str(caught.value) and "backend: numpy" in str(caught.value), str(caught.value)
    with pytest.raises(ConfigError, match="filter.precision"):
        pfx.particle_filter(model, precision="float32")


def test_a_config_runs_its_particle_arms_on_jax_and_refuses_jax_asked_of_a_kalman_arm(tmp_path, tiny_config_dict):
    config = tiny_config_dict()
    config["filter"]["backend"] = "jax"
    config["outputs"]["figures"] = []      # figures are not what is checked, here and below
    config["arms"] = {"pf": {}, "kf": {"kind": "kf"}}
    result = pfx.run(config, out=tmp_path / "mixed")
    labels = result.trials.drop_duplicates("arm").set_index("arm")
    assert labels.loc["pf", "backend"] == "jax" and pd.isna(labels.loc["kf", "backend"])
    config["arms"]["kf"]["backend"] = "jax"
    with pytest.raises(ConfigError, match="arms.kf.backend"):
        pfx.run(config, out=tmp_path / "refused")
    config["arms"] = {"kf": {"kind": "kf"}}
    with pytest.raises(ConfigError, match="filter.backend"):
        pfx.run(config, out=tmp_path / "refused")
    assert not (tmp_path / "refused").exists()


def test_a_missing_jax_is_named_with_its_extra(monkeypatch):
    monkeypatch.setattr("pfx.filters.particle.jax_support.jax_installed", lambda: False)
    with pytest.raises(ConfigError, match=r"pip install 'pfx\[jax\]'"):
        pfx.particle_filter(random_walk(steps=5), backend="jax")


NUMPY_ONLY_PLUGIN = '''
from typing import Literal

import numpy as np
import pfx


@pfx.register_model
class NumpyOnlyWalk(pfx.Model):
    kind: Literal["numpy_only_walk"] = "numpy_only_walk"

    def presets(self):
        return {"steps": 5, "process_noise": pfx.Noise(variance=1.0), "measurement_noise": pfx.Noise(variance=1.0),
                "initial": pfx.GaussianLaw(mean=[0.0], covariance=1.0)}

    @property
    def state_names(self):
        return ("x",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        out = np.empty_like(state)
        out[..., 0] = state[..., 0] + noise[..., 0]
        return out

    def measurement_mean(self, state):
        xp = pfx.namespace(state)
        return xp.where(state > 50.0, xp.nan, state)
'''


def test_a_numpy_only_plugin_is_refused_in_one_line_saying_how(tmp_path):
    path = tmp_path / "numpy_only.py"
    path.write_text(NUMPY_ONLY_PLUGIN)
    pfx.load_plugin(str(path))
    model = pfx.model("numpy_only_walk")
    pfx.particle_filter(model, particles=10)                  # fine on numpy
    with pytest.raises(ConfigError) as caught:
        pfx.particle_filter(model, particles=10, backend="jax")
    message = str(caught.value)
    assert "\n" not in message and "propagate" in message and "pfx.namespace" in message, message


def test_a_trial_whose_particles_all_leave_the_domain_is_raised_at_its_step_after_the_scan():
    """x_k = 1e200 x_{k-1} overflows at step 2: the flag set inside the scan becomes the NumPy
    engine's error, at the same step."""
    exploding = random_walk(steps=6, transition_matrix=[[1e200]])
    with pytest.raises(ModelNumericalError, match="every particle of a trial became NaN or infinite at step 2"):
        pfx.filter(exploding, np.zeros((6, 1)), particles=10, backend="jax")
    with pytest.raises(ModelNumericalError, match="at step 2"):
        pfx.filter(exploding, np.zeros((6, 1)), particles=10)


def test_a_config_on_jax_reruns_identically_with_backend_columns(tmp_path, tiny_config_dict):
    config = tiny_config_dict()
    config["outputs"]["figures"] = []
    config["arms"] = {"jax": {"backend": "jax"}, "numpy": {"backend": "numpy"}}
    tables = []
    for run in ("first", "second"):
        pfx.run(config, out=tmp_path / run)
        tables.append(pd.read_csv(tmp_path / run / "trials.csv").drop(columns=["run_time_s", "compile_time_s"]))
    pd.testing.assert_frame_equal(tables[0], tables[1])
    assert set(tables[0]["backend"]) == {"jax", "numpy"} and set(tables[0]["precision"]) == {"float64"}


def test_a_float32_config_on_jax_writes_nees_and_nis(tmp_path, tiny_config_dict):
    """The covariances and NIS are computed in float64 whatever the precision."""
    config = tiny_config_dict()
    config["filter"]["backend"] = "jax"
    config["filter"]["precision"] = "float32"
    config["outputs"]["figures"] = []
    config["metrics"] = {"consistency": True}
    trials = pfx.run(config, out=tmp_path / "out").trials
    assert set(trials["precision"]) == {"float32"}
    assert trials[["nees_mean", "nis_mean"]].notna().all().all() and (trials["nis_mean"] > 0).all()


def _plugin_model(name: str, kind: str):
    pfx.load_plugin(str(pfx_examples() / f"{name}.py"))
    return pfx.model(kind)


def pfx_examples():
    from pathlib import Path

    return Path(__file__).resolve().parents[1] / "examples" / "plugins"


def bench_falling_body():
    """pfx bench's falling body (Simon's, Euler steps of 0.1 s) and its prior, 30 steps."""
    from pfx.bench.problem import MODEL, PRIOR

    return pfx.model(**{**MODEL, "steps": 30}), PRIOR


AGREEMENT_CASES = {     # the model and the filter's prior (None: the model's), N
    "falling_body": (bench_falling_body, 500),
    "growth": (lambda: (pfx.model("growth", steps=30), None), 200),
    "stochastic_volatility": (lambda: (_plugin_model("stochastic_volatility", "stochastic_volatility"), None), 100),
}


@pytest.mark.parametrize("case", sorted(AGREEMENT_CASES))
def test_log_likelihood_mean_and_variance_agree_with_the_numpy_backend(case):
    """Over 300 runs of each backend on one data set, the log-likelihood estimates' means agree
    within 3 standard errors of their difference, and so do their variances (the standard error
    of a sample variance from the sample's fourth central moment, (m4 - s^4) / n)."""
    build, particles = AGREEMENT_CASES[case]
    model, prior = build()
    _, measurements = simulated(model, 1, seed=21)
    runs = 300
    estimates = {backend: pfx.filter(model, measurements[0], trials=runs, particles=particles, backend=backend,
                                     prior=prior, seed=8 if backend == "jax" else 9).log_likelihood
                 for backend in ("numpy", "jax")}
    numpy_runs, jax_runs = estimates["numpy"], estimates["jax"]
    assert np.isfinite(numpy_runs).all() and np.isfinite(jax_runs).all()
    mean_error = np.sqrt(numpy_runs.var(ddof=1) / runs + jax_runs.var(ddof=1) / runs)
    assert abs(numpy_runs.mean() - jax_runs.mean()) < 3 * mean_error, (numpy_runs.mean(), jax_runs.mean(), mean_error)

    def variance_and_error(values):
        centred = values - values.mean()
        variance = centred.var(ddof=1)
        return variance, np.sqrt(max(np.mean(centred**4) - variance**2, 0.0) / len(values))

    (numpy_variance, numpy_error), (jax_variance, jax_error) = map(variance_and_error, (numpy_runs, jax_runs))
    assert abs(numpy_variance - jax_variance) < 3 * np.hypot(numpy_error, jax_error), \
        (numpy_variance, jax_variance, numpy_error, jax_error)


def test_an_extended_jax_run_equals_a_fresh_one(tmp_path, tiny_config_dict, pfx_in_process):
    """More trials extend a finished run (only the new ones run, in a batch of their own): its
    trials.csv equals a fresh run's with all of them, as on numpy."""
    config = tiny_config_dict()
    config["filter"]["backend"] = "jax"
    config["outputs"]["figures"] = []
    # 4 trials, then 4 more: both batches have the tiny config's shape, compiled once for the
    # file's other jax configs; only the fresh run of 8 compiles a program of its own
    config["trials"] = 4
    pfx.run(config, out=tmp_path / "extended")
    config["trials"] = 8
    pfx.run(config, out=tmp_path / "extended")
    pfx.run(config, out=tmp_path / "fresh")
    tables = [pd.read_csv(tmp_path / name / "trials.csv").drop(columns=["run_time_s", "compile_time_s"]) for name in ("extended", "fresh")]
    import jax

    if jax.default_backend() == "cpu":
        pd.testing.assert_frame_equal(*tables, check_exact=True)
    else:   # a GPU's reductions may take their order from the batch's shape (docs/backends.md): the last bits
        pd.testing.assert_frame_equal(*tables, check_exact=False, rtol=1e-12, atol=0.0)
    (tmp_path / "transition_as_plugin.py").write_text(TRANSITION_PROPOSAL_PLUGIN)
    refused = pfx_in_process("run", str(tmp_path / "extended" / "config.yaml"), "--set",
                             f"plugins=[{tmp_path / 'transition_as_plugin.py'}]", "--set",
                             "filter.proposal=transition_as_plugin", "--out", str(tmp_path / "refused"))
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1, refused.output
    assert "filter.proposal" in refused.stderr and "backend: numpy" in refused.stderr
    assert not (tmp_path / "refused").exists()
