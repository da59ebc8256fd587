"""The jax backend records NEES/NIS and particle snapshots as the numpy backend does
(pfx/filters/particle/jax_diagnostics.py).

* **Consistency, in distribution.** On a linear-Gaussian model (d = m = 2), the same data filtered
  on both backends at N = 1000: per trial, the mean NEES and NIS agree between the backends
  within 4 standard errors of their paired differences, and each backend's agrees with the
  Kalman filter's exact expectation (NEES d, NIS m) within 4 standard errors over the trials.
* **Consistency, number for number.** With ESS threshold 0 (never resample) the recorded
  covariance is the weighted covariance of the recorded weighted cloud about the estimate, and
  the NIS that of the recorded predicted cloud with the previous step's weights, both
  recomputed on the host from first principles; NaN where the measurement is missing, as on
  numpy. The snapshots the same run returns (``trace.snapshots``) hold those clouds and weights.
* **particles.csv.** A config with ``outputs.particles`` on jax runs through the command line
  and writes the rows and columns the same config writes on numpy.
* **pfx.filter.** ``consistency=True`` on jax returns the NIS and the covariances.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import write_config_file

import pfx
from pfx.filters.particle.recorders import SnapshotRequest
from pfx.filters.trace import Snapshot
from pfx.numerics.quadratic_forms import normalised_squares
from pfx.numerics.seeding import TrialStreams

pytest.importorskip("jax")

TRANSITION = [[0.9, 0.2], [0.0, 0.8]]
MEASUREMENT = [[1.0, 0.0], [0.5, 1.0]]
STEPS = 10
TRIALS, PARTICLES = 300, 1000          # the statistical comparison
ALL_STAGES = frozenset({"predicted", "weighted", "resampled"})


def linear_gaussian():
    return pfx.model("linear_gaussian", steps=STEPS, transition_matrix=TRANSITION, measurement_matrix=MEASUREMENT,
                     process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0})


@pytest.fixture(scope="module")
def consistency_runs() -> dict:
    """Per trial, the mean NEES and NIS over the steps on each backend, the same data; and the
    jax result itself."""
    model = linear_gaussian()
    simulation = pfx.simulate(model, seed=11, trials=TRIALS)
    truth = simulation.states[:, 1:]
    runs = {}
    for backend in ("numpy", "jax"):
        result = pfx.filter(model, simulation.measurements, particles=PARTICLES, backend=backend,
                            consistency=True, seed=4)
        nees = normalised_squares(truth - result.estimates, result.trace.covariances)
        runs[backend] = {"nees": nees.mean(axis=1), "nis": result.trace.nis.mean(axis=1), "result": result}
    return runs


def standard_error(values: np.ndarray) -> float:
    return float(values.std(ddof=1) / np.sqrt(len(values)))


@pytest.mark.parametrize("statistic", ["nees", "nis"])
def test_the_backends_agree_on_nees_and_nis_within_monte_carlo_error(consistency_runs, statistic):
    difference = consistency_runs["numpy"][statistic] - consistency_runs["jax"][statistic]
    assert abs(difference.mean()) <= 4 * standard_error(difference), (difference.mean(), standard_error(difference))


@pytest.mark.parametrize("statistic,expected", [("nees", 2.0), ("nis", 2.0)])
def test_each_backend_has_the_kalman_filters_expected_nees_and_nis(consistency_runs, backend, statistic, expected):
    """The Kalman filter is the exact posterior here: NEES ~ chi2(d), NIS ~ chi2(m) at each step."""
    per_trial = consistency_runs[backend][statistic]
    assert abs(per_trial.mean() - expected) <= 4 * standard_error(per_trial), (per_trial.mean(), standard_error(per_trial))


def test_pfx_filter_on_jax_returns_the_nis_and_covariances(consistency_runs):
    trace = consistency_runs["jax"]["result"].trace
    assert trace.nis.shape == (TRIALS, STEPS) and trace.nis.dtype == np.float64 and np.isfinite(trace.nis).all()
    covariances = trace.covariances
    assert covariances.shape == (TRIALS, STEPS, 2, 2) and covariances.dtype == np.float64
    np.testing.assert_allclose(covariances, np.swapaxes(covariances, -1, -2), rtol=1e-12)
    assert (np.linalg.eigvalsh(covariances) > 0).all()
    assert trace.covariances.flags.writeable and trace.nis.flags.writeable


# -- number for number, never resampling ------------------------------------------------------------

MISSING_STEP = 4        # 1-based: every trial's measurement is missing there


@pytest.fixture(scope="module")
def never_resampling():
    """A jax run at ESS threshold 0 recording the consistency, the weighted clouds (the history)
    and snapshots of one row at every stage; 3 trials x 64 particles."""
    model = linear_gaussian()
    measurements = pfx.simulate(model, seed=2, trials=3).measurements
    measurements[:, MISSING_STEP - 1] = np.nan
    bound = pfx.particle_filter(model, particles=64, backend="jax", ess_threshold=0.0)
    snapshot = SnapshotRequest(rows=np.array([1]), steps="all", stages=ALL_STAGES)
    trace = bound.planned.run(model, measurements, TrialStreams.from_seeds([5, 6, 7]), settings=bound.settings,
                              prior=bound.prior, consistency=True, history=True, snapshot=snapshot)
    return model, measurements, trace, snapshot


def test_the_covariance_is_that_of_the_recorded_weighted_cloud(never_resampling):
    _, _, trace, _ = never_resampling
    assert not trace.resampled.any()
    weights = np.exp(trace.log_weights)
    centred = trace.particles - trace.estimates[:, :, None, :]
    expected = np.einsum("rtn,rtnd,rtne->rtde", weights, centred, centred)
    np.testing.assert_allclose(trace.covariances, expected, rtol=1e-10, atol=1e-14)


def test_the_nis_is_that_of_the_predicted_cloud_with_the_previous_weights(never_resampling):
    model, measurements, trace, _ = never_resampling
    H, R = np.array(MEASUREMENT), model.measurement_noise.covariance()
    particles = trace.particles.shape[2]
    previous = np.concatenate([np.full(trace.log_weights[:, :1].shape, 1.0 / particles),
                               np.exp(trace.log_weights[:, :-1])], axis=1)      # (trials, T, N)
    predicted = trace.particles @ H.T                # never resampled: the predicted cloud is the weighted one
    mean = np.einsum("rtn,rtnm->rtm", previous, predicted)
    centred = predicted - mean[:, :, None, :]
    innovation_covariance = np.einsum("rtn,rtnm,rtnk->rtmk", previous, centred, centred) + R
    innovation = measurements - mean
    expected = np.einsum("rtm,rtm->rt", innovation, np.linalg.solve(innovation_covariance, innovation[..., None])[..., 0])
    missing = MISSING_STEP - 1
    assert np.isnan(trace.nis[:, missing]).all() and np.isfinite(np.delete(trace.nis, missing, axis=1)).all()
    np.testing.assert_allclose(trace.nis, expected, rtol=1e-9)       # NaN where expected is NaN


def test_the_snapshots_hold_the_clouds_of_their_stages(never_resampling):
    _, _, trace, snapshot = never_resampling
    clouds = {(cloud.stage, cloud.step): cloud for cloud in trace.snapshots}
    order = [(cloud.stage, cloud.step) for cloud in trace.snapshots]
    assert order == [("prior", 0)] + [(stage, step) for step in range(1, STEPS + 1)
                                      for stage in ("predicted", "weighted", "resampled")]
    assert all(isinstance(cloud, Snapshot) and list(cloud.rows) == [1] for cloud in trace.snapshots)
    np.testing.assert_array_equal(clouds[("prior", 0)].weights, np.full((1, 64), 1 / 64))
    weights = np.exp(trace.log_weights[1])
    for step in range(1, STEPS + 1):
        weighted = clouds[("weighted", step)]
        assert weighted.state.shape == (1, 64, 2) and weighted.state.dtype == np.float64
        np.testing.assert_array_equal(weighted.state[0], trace.particles[1, step - 1])
        np.testing.assert_allclose(weighted.weights[0], weights[step - 1], rtol=1e-12)
        previous = weights[step - 2] if step > 1 else np.full(64, 1 / 64)
        np.testing.assert_allclose(clouds[("predicted", step)].weights[0], previous, rtol=1e-12)
        np.testing.assert_array_equal(clouds[("predicted", step)].state, weighted.state)
        np.testing.assert_array_equal(clouds[("resampled", step)].state, weighted.state)


# -- particles.csv through the command line -----------------------------------------------------------

def test_a_jax_config_writes_the_particles_csv_numpy_writes(tmp_path, tiny_config_dict, pfx_in_process):
    tables = {}
    for backend in ("numpy", "jax"):
        config = tiny_config_dict()
        config["filter"]["backend"] = backend
        config["outputs"]["particles"] = {"steps": [0, 2, 5], "trials": 2,
                                          "stages": ["predicted", "weighted", "resampled"]}
        path = write_config_file(tmp_path / backend, config)
        result = pfx_in_process("run", path, "--out", tmp_path / backend / "out")
        assert result.returncode == 0, result.stderr
        tables[backend] = pd.read_csv(tmp_path / backend / "out" / "particles.csv")
    on_jax, on_numpy = tables["jax"], tables["numpy"]
    # a config that runs a cell on jax has backend and precision columns in its tables (docs/backends.md)
    assert set(on_jax["backend"]) == {"jax"} and set(on_jax["precision"]) == {"float64"}
    assert list(on_jax.drop(columns=["backend", "precision"]).columns) == list(on_numpy.columns)
    assert len(on_jax) == len(on_numpy) == 2 * 20 * (1 + 2 * 3)
    keys = ["trial", "step", "stage", "particle"]
    pd.testing.assert_frame_equal(on_jax[keys], on_numpy[keys])
    np.testing.assert_allclose(on_jax.groupby(["trial", "step", "stage"])["weight"].sum(), 1.0, rtol=1e-12)
