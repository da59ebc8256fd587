"""Recorded data (``data:``, pfx/config/data.py and data_files.py, docs/recorded-data.md).

* the Nile example: pfx's Kalman log-likelihood against statsmodels' (the same wide prior to
  rounding; the exact diffuse initialisation to what the finite prior variance allows), the
  published maximum-likelihood variances as the maximum of pfx's likelihood, and the particle
  filter's estimate within its standard error;
* missing measurements: predict-only steps in every filter kind;
* the data pipeline: a run on recorded data of a simulated trial gives that trial's numbers;
  without the truth the truth columns are empty; every trial traced; the posterior sd columns;
* bad data: one line naming the file, line and column; exit status 2; nothing written.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, tiny_config_dict, write_config_file

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.filters import FILTERS
from pfx.filters.base import run_filter
from pfx.models import MODELS
from pfx.numerics.seeding import TrialStreams, truth_seed

NILE_CONFIG = REPO_ROOT / "configs" / "examples" / "nile.yaml"
NILE_DATA = REPO_ROOT / "examples" / "data" / "nile.csv"
MEASUREMENT_VARIANCE, LEVEL_VARIANCE = 15099.0, 1469.1      # Durbin & Koopman (2012), section 2.10.3


def nile_flow() -> np.ndarray:
    return pd.read_csv(NILE_DATA)["z1"].to_numpy(dtype=float)


def local_level(measurement=MEASUREMENT_VARIANCE, level=LEVEL_VARIANCE, prior_variance=1e7, steps=100):
    model = MODELS["linear_gaussian"](
        transition_matrix=[[1.0]], measurement_matrix=[[1.0]], names=["level"], steps=steps,
        process_noise={"variance": level}, measurement_noise={"variance": measurement},
        initial={"kind": "gaussian", "mean": [0.0], "covariance": prior_variance})
    return model


def kalman_log_likelihood(model, measurements: np.ndarray) -> float:
    settings = build_settings("kf")
    trace = run_filter("kf", model, measurements[None, :, None], TrialStreams.from_seeds([0]),
                       settings=settings, prior=model.initial)
    return float(trace.log_likelihood[0])


def build_settings(kind: str, **values):
    from pfx.config.schema import config_schema

    return config_schema().FilterConfig(kind=kind, **values)


def first_term(y1: float, prior_variance: float, measurement=MEASUREMENT_VARIANCE, level=LEVEL_VARIANCE) -> float:
    """log N(y_1; 0, P0 + q + r): the first observation's term, which a diffuse likelihood leaves out."""
    variance = prior_variance + level + measurement
    return -0.5 * (math.log(2 * math.pi * variance) + y1 * y1 / variance)


# -- the Nile -------------------------------------------------------------------------------------

def test_nile_data_is_the_published_series():
    data = pd.read_csv(NILE_DATA)
    assert list(data.columns) == ["time", "z1"]
    assert data["time"].tolist() == list(range(1871, 1971))
    flow = data["z1"].to_numpy()
    assert flow[:5].tolist() == [1120, 1160, 963, 1210, 1160] and flow[-3:].tolist() == [718, 714, 740]
    assert flow.sum() == 91935                           # R: sum(Nile)


def test_nile_kalman_log_likelihood_matches_statsmodels():
    statsmodels = pytest.importorskip("statsmodels.api")
    y = nile_flow()
    # 1. The same prior: statsmodels' state at t = 1 before its observation is N(0, P0 + q).
    prior_variance = 1e7
    ours = kalman_log_likelihood(local_level(prior_variance=prior_variance), y)
    known = statsmodels.tsa.UnobservedComponents(y, "local level")
    known.ssm.initialize_known(np.array([0.0]), np.array([[prior_variance + LEVEL_VARIANCE]]))
    known.loglikelihood_burn = 0
    reference = known.smooth([MEASUREMENT_VARIANCE, LEVEL_VARIANCE]).llf
    assert ours == pytest.approx(reference, rel=1e-12, abs=1e-9)

    # 2. The exact diffuse initialisation (Durbin & Koopman's likelihood): the wide prior's
    # log-likelihood is log p(y_1) + log p(y_2..n | y_1); the diffuse one is the second term
    # less 0.5 log(2 pi) (it counts n, not n - 1, in its constant). The finite P0 moves the
    # level's posterior after y_1 by a relative r / P0: the gap shrinks like 1 / P0.
    exact = statsmodels.tsa.UnobservedComponents(y, "local level", use_exact_diffuse=True)
    diffuse = exact.smooth([MEASUREMENT_VARIANCE, LEVEL_VARIANCE]).llf
    for prior_variance, tolerance in ((1e7, 2e-2), (1e12, 1e-6)):
        total = kalman_log_likelihood(local_level(prior_variance=prior_variance), y)
        ours_diffuse = total - first_term(y[0], prior_variance) - 0.5 * math.log(2 * math.pi)
        assert abs(ours_diffuse - diffuse) < tolerance, (prior_variance, ours_diffuse, diffuse)


def test_published_variances_maximise_the_likelihood():
    """Durbin & Koopman's maximum-likelihood variances: pfx's Kalman log-likelihood is lower
    10 % away in every direction (the likelihood is flat near its maximum: the published values
    are within optimiser tolerance of it, about 1e-4 in log-likelihood)."""
    y = nile_flow()
    best = kalman_log_likelihood(local_level(prior_variance=1e12), y)
    for factor_r, factor_q in ((1.1, 1.0), (0.9, 1.0), (1.0, 1.1), (1.0, 0.9)):
        other = kalman_log_likelihood(local_level(MEASUREMENT_VARIANCE * factor_r, LEVEL_VARIANCE * factor_q,
                                                  prior_variance=1e12), y)
        assert other < best - 1e-3


def test_nile_example_particle_filter_within_its_standard_error(pfx_in_process, tmp_path):
    """The shipped config, through the command line (fewer trials): the particle filter's
    log-likelihood estimate. Its log is biased low by about var/2 (it is the likelihood that is
    unbiased; the log of it is asymptotically normal with mean log L - sigma^2/2, Berard, Del
    Moral & Doucet 2014), so mean + var/2 must lie within 4 standard errors of the Kalman value."""
    result = pfx_in_process("run", NILE_CONFIG, "--out", tmp_path / "nile", "--trials", "30")
    assert result.returncode == 0, result.stderr
    trials = pd.read_csv(tmp_path / "nile" / "trials.csv")
    kalman = trials.loc[trials["arm"] == "KF", "log_likelihood"]
    assert kalman.nunique() == 1                       # the same measurements in every trial
    particle = trials.loc[trials["arm"] == "PF", "log_likelihood"].to_numpy()
    spread = particle.std(ddof=1)
    standard_error = math.sqrt(spread ** 2 / len(particle) + spread ** 4 / (2 * (len(particle) - 1)))
    assert abs(particle.mean() + spread ** 2 / 2 - kalman.iloc[0]) < 4 * standard_error
    # no truth: the columns that need it are there and empty; the others are filled
    for column in ("rmse_level", "rmse_position", "error_distance_mean", "error_distance_final", "nees_mean"):
        assert trials[column].isna().all(), column
    assert trials["nis_mean"].notna().sum() == 30 and trials.loc[trials["arm"] == "PF", "ess_mean"].notna().all()
    steps = pd.read_csv(tmp_path / "nile" / "steps.csv")
    assert sorted(steps["trial"].unique()) == list(range(30))      # every trial traced by default
    assert steps["time"].iloc[0] == 1871 and steps["time"].iloc[99] == 1970
    assert steps["truth_level"].isna().all() and steps["error_distance"].isna().all()
    # the Kalman sd: sqrt(P); the particle filter's, weighted, agrees to its Monte Carlo error
    kf_sd = steps.loc[(steps["arm"] == "KF") & (steps["trial"] == 0), "sd_level"].to_numpy()
    assert kf_sd[0] == pytest.approx(math.sqrt(1 / (1 / (1e7 + LEVEL_VARIANCE) + 1 / MEASUREMENT_VARIANCE)))
    pf = steps[steps["arm"] == "PF"].pivot(index="trial", columns="step", values="sd_level").to_numpy()
    late = slice(10, None)                               # past the prior's influence
    mean, error = pf[:, late].mean(axis=0), pf[:, late].std(axis=0, ddof=1) / math.sqrt(len(pf))
    assert np.all(np.abs(mean - kf_sd[late]) < 5 * error + 0.01 * kf_sd[late])   # 1 %: O(1/ESS) bias


# -- missing measurements ---------------------------------------------------------------------------

MISSING = (2, 5, 6)           # 0-based steps without a measurement


def missing_setup(trials=1, steps=10):
    model = local_level(measurement=1.0, level=0.5, prior_variance=2.0, steps=steps)
    random = TrialStreams.from_seeds([3])
    from pfx.models.simulation import simulate_truth

    _, measurements = simulate_truth(model, random)
    measurements = np.repeat(measurements, trials, axis=0)
    with_gaps = measurements.copy()
    with_gaps[:, list(MISSING)] = np.nan
    return model, measurements, with_gaps


def reference_kalman(model, measurements: np.ndarray, skip) -> tuple[np.ndarray, np.ndarray, float]:
    """A scalar Kalman filter written out here, skipping the updates at ``skip``."""
    q = model.process_noise.covariance()[0, 0]
    r = model.measurement_noise.covariance()[0, 0]
    mean, variance, log_likelihood = 0.0, 2.0, 0.0
    means, variances = [], []
    for k, z in enumerate(measurements):
        variance += q
        if k not in skip:
            s = variance + r
            log_likelihood += -0.5 * (math.log(2 * math.pi * s) + (z - mean) ** 2 / s)
            gain = variance / s
            mean, variance = mean + gain * (z - mean), (1 - gain) * variance
        means.append(mean)
        variances.append(variance)
    return np.array(means), np.array(variances), log_likelihood


@pytest.mark.parametrize("kind", ["kf", "ekf", "ukf"])
def test_gaussian_filters_skip_the_update_where_the_measurement_is_missing(kind):
    model, _, with_gaps = missing_setup()
    settings = build_settings(kind, **({"unscented": {"alpha": 1.0}} if kind == "ukf" else {}))
    trace = run_filter(kind, model, with_gaps, TrialStreams.from_seeds([0]), settings=settings, prior=model.initial)
    means, variances, log_likelihood = reference_kalman(model, with_gaps[0, :, 0], MISSING)
    assert trace.estimates[0, :, 0] == pytest.approx(means, rel=1e-10)
    assert trace.posterior_standard_deviations()[0, :, 0] == pytest.approx(np.sqrt(variances), rel=1e-10)
    assert trace.log_likelihood[0] == pytest.approx(log_likelihood, rel=1e-12)
    assert np.isnan(trace.nis[0, list(MISSING)]).all() and np.isfinite(np.delete(trace.nis[0], MISSING)).all()


@pytest.mark.parametrize("kind", ["kf", "ukf"])
def test_some_trials_missing_a_measurement_others_not(kind):
    """Trial 0 misses steps 2, 5 and 6; trial 1 has them: each equals its own run."""
    model, measurements, with_gaps = missing_setup(trials=2)
    mixed = measurements.copy()
    mixed[0] = with_gaps[0]
    settings = build_settings(kind)
    run = lambda data: run_filter(kind, model, data, TrialStreams.from_seeds(list(range(len(data)))),  # noqa: E731
                                  settings=settings, prior=model.initial)
    both, alone_gaps, alone_full = run(mixed), run(with_gaps[:1]), run(measurements[:1])
    assert both.estimates[0] == pytest.approx(alone_gaps.estimates[0], rel=1e-12)
    assert both.estimates[1] == pytest.approx(alone_full.estimates[0], rel=1e-12)
    assert both.log_likelihood == pytest.approx([alone_gaps.log_likelihood[0], alone_full.log_likelihood[0]])


def test_histogram_filter_skips_the_update_where_the_measurement_is_missing():
    model, _, with_gaps = missing_setup()
    settings = build_settings("histogram", grid={"low": [-15.0], "high": [15.0], "cells": 3000})
    trace = run_filter("histogram", model, with_gaps, TrialStreams.from_seeds([0]), settings=settings,
                       prior=model.initial)
    means, variances, log_likelihood = reference_kalman(model, with_gaps[0, :, 0], MISSING)
    # a fine grid over +-15 sd: the grid's error (cell width^2 / 12 in the variance) is ~1e-5
    assert trace.estimates[0, :, 0] == pytest.approx(means, abs=1e-3)
    assert trace.posterior_standard_deviations()[0, :, 0] == pytest.approx(np.sqrt(variances), rel=1e-3)
    assert trace.log_likelihood[0] == pytest.approx(log_likelihood, abs=1e-3)
    assert np.isnan(trace.nis[0, list(MISSING)]).all()


@pytest.mark.parametrize("kind", ["particle", "sis"])
def test_particle_filters_skip_the_weight_update_where_the_measurement_is_missing(kind, backend):
    trials, particles = 200, 500
    model, _, with_gaps = missing_setup(trials=trials)
    settings = build_settings(kind, particles=particles, ess_threshold=0.5, backend=backend)
    trace = run_filter(kind, model, with_gaps, TrialStreams.from_seeds(list(range(trials))), settings=settings,
                       prior=model.initial, trace_rows=np.arange(trials))
    # weights untouched at a missing step: the ESS is the previous step's, or N (uniform weights)
    # where the previous step resampled
    for step in MISSING:
        kept = ~trace.resampled[:, step - 1]
        assert trace.ess[kept, step] == pytest.approx(trace.ess[kept, step - 1], rel=1e-12)
        assert trace.ess[~kept, step] == pytest.approx(particles, rel=1e-12)
    # the predict-only step 5 (0-based) follows a missing one too: it kept its weights (so the
    # first check above ran on every trial there)
    assert (~trace.resampled[:, 5]).all()
    assert np.isnan(trace.nis[:, list(MISSING)]).all() if trace.nis is not None else True
    # the likelihood estimate stays unbiased (mean of log + var/2, see the Nile test) ...
    _, _, exact = reference_kalman(model, with_gaps[0, :, 0], MISSING)
    estimates = trace.log_likelihood
    spread = estimates.std(ddof=1)
    error = math.sqrt(spread ** 2 / trials + spread ** 4 / (2 * (trials - 1)))
    assert abs(estimates.mean() + spread ** 2 / 2 - exact) < 4 * error
    # ... and the posterior sd (weighted, before resampling) matches the Kalman filter's
    _, variances, _ = reference_kalman(model, with_gaps[0, :, 0], MISSING)
    deviations = trace.standard_deviations[:, :, 0]
    mean, sem = deviations.mean(axis=0), deviations.std(axis=0, ddof=1) / math.sqrt(trials)
    if kind == "particle":          # SIS degenerates: its sd says so, it need not match
        assert np.all(np.abs(mean - np.sqrt(variances)) < 5 * sem + 0.02 * np.sqrt(variances))


def test_missing_measurement_steps_add_nothing_and_the_genealogy_is_kept(backend):
    """Step 3 missing in every trial, step 6 in trial 1 only: their increments are exactly 0, the
    others finite and non-zero; the increments sum to the log-likelihood; the genealogy runs over
    every step (ESS rule at 1: every step resamples, missing or not)."""
    from pfx.models.simulation import simulate_truth

    model = pfx.model("linear_gaussian", steps=8, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(3)))
    measurements[:, 2] = np.nan
    measurements[1, 5] = np.nan
    result = pfx.filter(model, measurements, particles=32, backend=backend, genealogy=True, ess_threshold=1.0)
    increments = result.trace.log_likelihood_increments
    assert (increments[:, 2] == 0).all() and increments[1, 5] == 0
    assert np.isfinite(increments).all() and (increments[0, 5] != 0)
    np.testing.assert_allclose(increments.sum(axis=1), result.log_likelihood)
    assert result.ancestors.shape == (3, 8, 32)
    assert (result.ancestors[:, 0] == np.arange(32)).all()          # step 1 descends from the prior
    assert result.trace.resampled.all()


def test_particle_sd_is_recorded_for_the_traced_rows_only():
    model, measurements, _ = missing_setup(trials=4)
    settings = build_settings("particle", particles=100)
    planned = FILTERS["particle"].plan(model, settings, model.initial)
    trace = planned.run(model, measurements, TrialStreams.from_seeds([0, 1, 2, 3]), settings=settings,
                        prior=model.initial, trace_rows=np.array([1, 3]))
    assert np.isfinite(trace.standard_deviations[[1, 3]]).all()
    assert np.isnan(trace.standard_deviations[[0, 2]]).all()


# -- the pipeline -----------------------------------------------------------------------------------

SIMULATED = {
    "name": "simulated", "seed": 11, "trials": 1,
    "model": {"kind": "linear_gaussian", "steps": 12, "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
              "measurement_matrix": [[1.0, 0.0]], "names": ["position", "velocity"],
              "process_noise": {"variance": [0.05, 0.05]}, "measurement_noise": {"variance": 1.0},
              "initial": {"kind": "gaussian", "mean": [0.0, 1.0], "covariance": [1.0, 0.1]}},
    "filter": {"kind": "kf"},
    "metrics": {"convergence": {"criterion": "truth", "radius": 1.0, "hold": 2}},
    "outputs": {"figures": []},
}


def write_simulated_trial(folder: Path) -> None:
    """measurements.csv and truth.csv of trial 0 of SIMULATED, as pfx simulates it."""
    from pfx.models.simulation import simulate_truth

    model = MODELS["linear_gaussian"](**SIMULATED["model"])
    states, measurements = simulate_truth(model, TrialStreams.from_seeds([truth_seed(SIMULATED["seed"], 0)]))
    steps = np.arange(1, 13)
    pd.DataFrame({"step": steps, "z1": measurements[0, :, 0]}).to_csv(folder / "measurements.csv", index=False,
                                                                      float_format="%.17g")
    pd.DataFrame({"step": steps, "velocity": states[0, 1:, 1], "position": states[0, 1:, 0]}).to_csv(
        folder / "truth.csv", index=False, float_format="%.17g")


def test_recorded_trial_gives_the_simulated_trials_numbers(pfx_in_process, tmp_path):
    write_simulated_trial(tmp_path)
    simulated = write_config_file(tmp_path, SIMULATED, "simulated.yaml")
    recorded = write_config_file(tmp_path, {**SIMULATED, "name": "recorded", "trials": 3,
                                            "model": {k: v for k, v in SIMULATED["model"].items() if k != "steps"},
                                            "data": {"measurements": "measurements.csv", "truth": "truth.csv"}},
                                 "recorded.yaml")
    results = pfx_in_process.many({"simulated": (("run", simulated, "--out", tmp_path / "sim"), tmp_path),
                            "recorded": (("run", recorded, "--out", tmp_path / "rec"), tmp_path)})
    for result in results.values():
        assert result.returncode == 0, result.stderr
    simulated_trials = pd.read_csv(tmp_path / "sim" / "trials.csv")
    recorded_trials = pd.read_csv(tmp_path / "rec" / "trials.csv")
    assert len(recorded_trials) == 3
    for column in ("rmse_position", "rmse_velocity", "error_distance_mean", "convergence_step", "nees_mean",
                   "nis_mean", "log_likelihood", "steps"):
        assert recorded_trials[column].to_numpy() == pytest.approx(simulated_trials[column].iloc[0], rel=1e-12), column
    steps = pd.read_csv(tmp_path / "rec" / "steps.csv")
    assert sorted(steps["trial"].unique()) == [0, 1, 2]                      # trace_trials: every trial
    simulated_steps = pd.read_csv(tmp_path / "sim" / "steps.csv")
    for column in ("truth_position", "estimate_velocity", "sd_position", "sd_velocity", "nees", "time"):
        assert steps.loc[steps["trial"] == 0, column].to_numpy() == pytest.approx(simulated_steps[column].to_numpy())
    config = yaml.safe_load((tmp_path / "rec" / "config.yaml").read_text())
    # the folder's record names the file relative to the folder, which its paths are read from
    named = Path(config["data"]["measurements"])
    assert not named.is_absolute() and config["outputs"]["trace_trials"] == 10_000
    assert ((tmp_path / "rec") / named).resolve().read_bytes() == (tmp_path / named.name).read_bytes()


def plan_for(folder: Path, measurements: str, truth=None, controls=None, **model_changes):
    (folder / "measurements.csv").write_text(measurements)
    data = {"measurements": "measurements.csv"}
    if truth is not None:
        (folder / "truth.csv").write_text(truth)
        data["truth"] = "truth.csv"
    if controls is not None:
        (folder / "controls.csv").write_text(controls)
        data["controls"] = "controls.csv"
    model = {k: v for k, v in tiny_config_dict()["model"].items() if k != "steps"}
    model.update(model_changes)
    config = tiny_config_dict(model=model, data=data)
    path = write_config_file(folder, config)
    return build_plan(yaml.safe_load(path.read_text()), str(path))


def test_steps_times_and_controls_from_the_files(tmp_path):
    plan = plan_for(tmp_path, "time,z1\n0.5,1.0\n1.0,\n1.5,2.0\n")
    cell = plan.cells[0]
    assert cell.truth_model.steps == 3 and cell.truth_model.dt == 0.5
    assert cell.truth_model.times().tolist() == [0.5, 1.0, 1.5]
    assert cell.data.observed.tolist() == [True, False, True]
    plan = plan_for(tmp_path, "step,z1\n1,1.0\n2,2.0\n", controls="step,u\n1,0.5\n2,-0.5\n",
                    control_matrix=[[1.0]])
    assert plan.cells[0].truth_model.control(2).tolist() == [-0.5]
    assert plan.cells[0].truth_model.times().tolist() == [1.0, 2.0]       # a step column: dt x step


def test_data_changes_the_cell_key_not_the_filter_stream(tmp_path):
    first = plan_for(tmp_path, "step,z1\n1,1.0\n2,2.0\n").cells[0]
    second = plan_for(tmp_path, "step,z1\n1,1.0\n2,2.5\n").cells[0]
    assert first.key != second.key and first.filter_key == second.filter_key


# -- bad data: one line, file, line and column -------------------------------------------------------

BAD_DATA = {
    "empty file": ("", None, "measurements.csv: the file is empty"),
    "no rows": ("step,z1\n", None, "measurements.csv:1: the file has a header but no rows"),
    "first column": ("year,z1\n1,2\n", None, "measurements.csv:1: column 1: the first column must be `step` or `time`"),
    "missing step": ("step,z1\n1,1\n2,2\n4,4\n", None, "measurements.csv:4: column step: step 3 is missing"),
    "duplicate step": ("step,z1\n1,1\n2,2\n2,3\n", None, "measurements.csv:4: column step: step 2 appears twice (lines 3 and 4)"),
    "step not from 1": ("step,z1\n0,1\n1,2\n", None, "measurements.csv:2: column step: steps must run 1, 2, ..., T"),
    "duplicate time": ("time,z1\n1,1\n1,2\n", None, "measurements.csv:3: column time: time 1 appears twice"),
    "decreasing time": ("time,z1\n2,1\n1,2\n", None, "measurements.csv:3: column time: times must increase"),
    "non-numeric": ("step,z1\n1,1\n2,abc\n", None, "measurements.csv:3: column z1: 'abc' is not a number"),
    "nan text": ("step,z1\n1,nan\n", None, "measurements.csv:2: column z1: 'nan' is not a finite number"),
    "ragged row": ("step,z1\n1,1\n2,2,3\n", None, "measurements.csv:3: 3 cells, the header has 2 columns"),
    "column count": ("step,z1,z2\n1,1,2\n", None,
                     "measurements.csv:1: column z2: found z1, z2 after `step`, expected the 1 measurement"),
    "unknown column": ("step,flow\n1,1\n", None, "measurements.csv:1: column flow: found flow after `step`, expected"),
    "partial row": ("step,z1,z2\n1,1,\n", None, "measurements.csv:2: column z2: a partly blank measurement"),
    "truth shorter": ("step,z1\n1,1\n2,2\n", "step,x1\n1,0\n",
                      "truth.csv:2: column step: 1 rows, the measurements (measurements.csv) 2: the file ends before step 2"),
    "truth longer": ("step,z1\n1,1\n", "step,x1\n1,0\n2,0\n",
                     "truth.csv:3: column step: 2 rows, the measurements (measurements.csv) 1: step 2 has no measurement row"),
    "truth blank": ("step,z1\n1,1\n", "step,x1\n1,\n", "truth.csv:2: column x1: a blank cell"),
    "truth names": ("step,z1\n1,1\n", "step,level\n1,0\n", "truth.csv:1: column level: found level after `step`, expected the 1 state"),
    "truth time vs step": ("step,z1\n1,1\n", "time,x1\n1,0\n", "truth.csv:1: column 1: the first column is `time`"),
}


@pytest.mark.parametrize("case", list(BAD_DATA))
def test_bad_data_is_one_line_naming_file_line_and_column(tmp_path, case):
    measurements, truth, expected = BAD_DATA[case]
    changes = {"measurement_matrix": [[1.0], [1.0]],
               "measurement_noise": {"variance": [1.0, 1.0]}} if case == "partial row" else {}
    with pytest.raises(ConfigError) as caught:
        plan_for(tmp_path, measurements, truth, **changes)
    message = str(caught.value).replace(f"{tmp_path}/", "")       # the files as given: relative
    assert "\n" not in message
    assert message.startswith(expected), message


def test_config_level_refusals(tmp_path):
    cases = {
        "steps disagree": ({"steps": 5}, "step,z1\n1,1\n2,2\n", None, "model.steps: 5 disagrees with the 2 rows"),
        "dt disagrees": ({"dt": 2.0}, "time,z1\n1,1\n2,2\n", None, "model.dt: 2.0 disagrees with the spacing 1"),
        "irregular times": ({}, "time,z1\n1,1\n2,2\n4,3\n", None,
                            "measurements.csv:4: column time: irregular times (2 since the previous row, 1 between the first two)"),
        "no such file": ({}, None, None, "data.measurements: no such file"),
        "controls without matrix": ({}, "step,z1\n1,1\n", "step,u\n1,1\n",
                                    "controls.csv:1: 1 control column(s) for model linear_gaussian: control_matrix and "
                                    "controls go together"),
        "controls too wide": ({"control_matrix": [[1.0]]}, "step,z1\n1,1\n", "step,u,v\n1,1,2\n",
                              "controls.csv:1: 2 control column(s) for model linear_gaussian: each control vector "
                              "needs 1 value(s)"),
    }
    for name, (model, measurements, controls, expected) in cases.items():
        if measurements is None:
            (tmp_path / "measurements.csv").unlink(missing_ok=True)
            config = tiny_config_dict(data={"measurements": "measurements.csv"})
            path = write_config_file(tmp_path, config)
            with pytest.raises(ConfigError) as caught:
                build_plan(yaml.safe_load(path.read_text()), str(path))
        else:
            with pytest.raises(ConfigError) as caught:
                plan_for(tmp_path, measurements, controls=controls, **model)
        assert expected in str(caught.value).replace(f"{tmp_path}/", ""), (name, str(caught.value))


def test_bad_data_through_the_command_line(pfx_in_process, tmp_path):
    """Exit status 2, one line on stderr, no traceback, nothing written."""
    (tmp_path / "measurements.csv").write_text("step,z1\n1,1\n2,abc\n")
    path = write_config_file(tmp_path, tiny_config_dict(
        model={k: v for k, v in tiny_config_dict()["model"].items() if k != "steps"},
        data={"measurements": "measurements.csv"}))
    result = pfx_in_process("run", path.name, "--out", "out", cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip() == "pfx: error: measurements.csv:3: column z1: 'abc' is not a number " \
                                    "(leave a missing value blank)"
    assert "Traceback" not in result.output and not (tmp_path / "out").exists()


def test_a_result_folder_with_recorded_controls_reruns(pfx_in_process, tmp_path):
    """config.yaml records data.controls by its path, not copied into model.controls as well
    (which the rerun refused: "controls are given twice")."""
    config = {"name": "controls", "seed": 1, "trials": 2,
              "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                        "control_matrix": [[1.0]], "process_noise": {"variance": 0.1},
                        "measurement_noise": {"variance": 0.1},
                        "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0}},
              "filter": {"particles": 20}, "data": {"measurements": "z.csv", "controls": "u.csv"},
              "outputs": {"figures": []}}
    (tmp_path / "z.csv").write_text("step,z1\n1,0.1\n2,0.3\n3,0.2\n")
    (tmp_path / "u.csv").write_text("step,u1\n1,0.1\n2,0.1\n3,0.1\n")
    first = pfx_in_process("run", write_config_file(tmp_path, config), "--out", tmp_path / "first", cwd=tmp_path)
    assert first.returncode == 0, first.output
    record = yaml.safe_load((tmp_path / "first" / "config.yaml").read_text())
    assert "controls" not in record["model"] and record["data"]["controls"] == "../u.csv"    # from the folder
    again = pfx_in_process("run", tmp_path / "first" / "config.yaml", "--out", tmp_path / "again", cwd=tmp_path)
    assert again.returncode == 0, again.output
    columns = ["trial", "log_likelihood", "rmse_x"]
    first_trials, again_trials = (pd.read_csv(tmp_path / name / "trials.csv") for name in ("first", "again"))
    pd.testing.assert_frame_equal(first_trials[[c for c in columns if c in first_trials]],
                                  again_trials[[c for c in columns if c in again_trials]])


def test_the_log_likelihood_spread_figure_treats_recorded_data_as_one_dataset(pfx_in_process, tmp_path):
    """Every trial of a data run filters the same measurements: the spread of the log-likelihood
    estimate is pooled over all of a cell's trials (each has its own truth_seed, which told
    datasets apart and left no dataset run twice: the figure drew nothing)."""
    from pfx.analysis.estimator_spread import within_dataset_spread
    from pfx.result_folder import ResultFolder

    config = yaml.safe_load(NILE_CONFIG.read_text())
    config.update(trials=8, outputs={"figures": ["log_likelihood_spread_vs_particles"]},
                  filter={"kind": "particle", "particles": 50})
    config["data"]["measurements"] = str(NILE_DATA)
    config.pop("arms", None)
    config["sweep"] = {"filter.particles": [50, 200]}
    result = pfx_in_process("run", write_config_file(tmp_path, config), "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 0, result.output
    folder = ResultFolder(tmp_path / "out")
    assert folder.recorded_data and folder.trials.groupby("n_particles")["truth_seed"].nunique().eq(8).all()
    spread = within_dataset_spread(folder.trials, folder.label_columns, one_dataset=True)
    for particles, cell in folder.trials.groupby("n_particles"):
        row = spread[spread["n_particles"] == particles].iloc[0]
        assert row["datasets"] == 1 and row["degrees_of_freedom"] == 7
        assert row["variance"] == pytest.approx(np.var(cell["log_likelihood"], ddof=1), rel=1e-12)
    assert (tmp_path / "out" / "figures" / "log_likelihood_spread_vs_particles.png").exists()
