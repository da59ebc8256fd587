"""Numerical extremes: the smallest filters, the most extreme noise, weights that all underflow,
and models that produce NaN or infinity (no NaN ever reaches a CSV: docs/output-files.md#the-result-folder).

Two layers:

* the engine, driven directly (as in ``test_numerics.py``) where a case needs a measurement or a
  model that no config can express: every weight underflowing for every resampler and for SIS
  at N = 1, 2, 50; a model that returns NaN or inf at a given step;
* the command line (``pfx run``, its entry point in the test's process, by a module fixture) on tiny
  configs: N = 1, N = 2 and T = 1 for every resampler and SIS on every model; measurement and
  process noise variances of 1e-12 and 1e12 under every weighting; a prior so far from the truth
  that every likelihood is zero; filters and truths that overflow.

After every successful run the result folder is checked (:func:`check_result_folder`): no ``nan``
anywhere in a CSV, empty fields only where docs/output-files.md documents them, and every figure the
manifest lists exists as a PNG.
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

import pfx
from pfx.analysis.summary import MINIMUM_VALUES
from pfx.errors import ModelNumericalError
from pfx.filters.particle.diffusion import NoDiffusion, Roughening
from pfx.laws.initial import GaussianLaw
from pfx.models.base import bind_law
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams

RESAMPLER_NAMES = ["multinomial", "stratified", "systematic", "residual", "han_lee_iv"]
# empty = never converged; NEES/NIS not recorded (particle filters without metrics.consistency)
EMPTY_IN_TRIALS = {"convergence_step", "error_at_convergence", "nees_mean", "nees_invalid_steps", "nis_mean",
                   "nis_invalid_steps", "grid_lost_mass", "move_acceptance"}
SPREAD_STATISTICS = {"std", "sem"}                               # empty when n < 2
INTERVAL_STATISTICS = {"ci95_low", "ci95_high"}                  # empty when n < MINIMUM_VALUES (6)
CENTRAL_STATISTICS = {"mean", "median"}                          # empty when n == 0


# -- the result-folder contract --------------------------------------------------------------------

def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def check_result_folder(folder: Path) -> dict[str, list[dict[str, str]]]:
    """Assert the folder is a finished result with no NaN and only documented empty fields;
    return its tables as lists of rows."""
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["complete"] is True
    tables = {}
    for name in ("trials", "steps", "summary"):
        path = folder / f"{name}.csv"
        text = path.read_text()
        assert "nan" not in text.lower(), f"{path} holds a NaN"
        tables[name] = _rows(path)
        assert tables[name], f"{path} has no rows"
    for row in tables["trials"]:
        for column, value in row.items():
            if value == "":
                assert column in EMPTY_IN_TRIALS, f"trials.csv: empty {column}: {row}"
                if column in ("convergence_step", "error_at_convergence"):
                    assert row["converged"] == "False", f"trials.csv: empty {column} but converged: {row}"
    for row in tables["steps"]:
        empty = [column for column, value in row.items() if value == "" and column not in ("nees", "nis")]
        assert not empty, f"steps.csv: empty {empty}: {row}"
    for row in tables["summary"]:
        for column, value in row.items():
            if value != "":
                continue
            if column in ("log_mean_likelihood", "log_mean_likelihood_se"):
                # pomp's logmeanexp counts a -inf as a zero likelihood; its jackknife needs two nonzero ones
                assert int(row["log_likelihood_n"]) < (2 if column.endswith("_se") else 1), f"summary.csv: empty {column}"
                continue
            metric, _, statistic = column.rpartition("_")
            if statistic in ("low", "high"):
                metric, _, statistic = metric.rpartition("_")[0], None, f"ci95_{statistic}"
            assert f"{metric}_n" in row, f"summary.csv: empty non-statistic column {column}"
            n = int(row[f"{metric}_n"])
            allowed = ((statistic in SPREAD_STATISTICS and n < 2) or (statistic in INTERVAL_STATISTICS and n < MINIMUM_VALUES)
                       or (statistic in CENTRAL_STATISTICS and n == 0))
            assert allowed, f"summary.csv: empty {column} with {metric}_n = {n}"
    figures = [f"{name}.{fmt}" for name in manifest["figures"] for fmt in manifest["formats"]]
    assert figures, "the manifest lists no figure"
    for name in figures:
        path = folder / "figures" / name
        assert path.is_file(), f"figure {name} missing"
        if name.endswith(".png"):
            assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{name} is not a PNG"
    return tables


def _floats(rows, column) -> np.ndarray:
    return np.array([float(row[column]) for row in rows])


# -- the engine, driven directly ------------------------------------------------------------------------

def _linear(cls=LinearGaussian, steps: int = 4, **fields) -> LinearGaussian:
    return cls(transition_matrix=[[1.0]], measurement_matrix=[[1.0]], steps=steps, **fields)


def _filter(model, measurements, *, particles, resampler="systematic", threshold=1.0, diffusion=None,
            prior=None, seed=0):
    prior = prior if prior is not None else bind_law(model.default_prior(), model.state_dimension, "initial")
    trials = measurements.shape[0]
    return pfx.particle_filter(model, prior=prior, particles=particles, resampler=resampler, ess_threshold=threshold, diffusion=diffusion or NoDiffusion())(measurements, seeds=range(seed, seed + trials), traced=True).trace                    # every trial traced: its spread recorded


FILTERS = [(name, 1.0) for name in RESAMPLER_NAMES] + [("systematic", 0.0)]     # threshold 0 = SIS
FILTER_IDS = RESAMPLER_NAMES + ["sis"]


@pytest.mark.parametrize("far", ["uniform-noise", "gaussian-noise-overflow"])
@pytest.mark.parametrize("particles", [1, 2, 50])
@pytest.mark.parametrize("resampler, threshold", FILTERS, ids=FILTER_IDS)
def test_engine_every_weight_underflows(resampler, threshold, particles, far):
    """Measurements far out of the particle cloud at every step: with uniform noise every
    likelihood is exactly 0; with gaussian noise and z = 1e200 the squared innovation overflows,
    log-likelihood -inf. Every step of every trial is degenerate, the weights are reset to
    uniform (ESS = N), estimates and spread stay finite, log p(z) is -inf, never NaN."""
    noise = {"family": "uniform", "variance": 1e-6} if far == "uniform-noise" else {"variance": 1.0}
    model = _linear(measurement_noise=noise)
    measurements = np.full((3, 4, 1), 1e6 if far == "uniform-noise" else 1e200)
    trace = _filter(model, measurements, particles=particles, resampler=resampler, threshold=threshold,
                    diffusion=Roughening(factor=0.2))
    assert trace.degenerate.all()
    np.testing.assert_allclose(trace.ess, particles, rtol=1e-12)
    assert np.isfinite(trace.estimates).all() and np.isfinite(trace.spread).all()
    assert np.all(trace.log_likelihood == -np.inf)
    assert trace.resampled.any() == (threshold > 0)


@pytest.mark.parametrize("particles", [1, 2])
@pytest.mark.parametrize("resampler, threshold", FILTERS, ids=FILTER_IDS)
def test_engine_one_or_two_particles_one_step(resampler, threshold, particles):
    """N = 1 and N = 2 for T = 1 on simulated measurements: ESS lies in [1, N] (exactly 1 for
    N = 1), estimates are finite, the log-likelihood is finite, nothing is degenerate."""
    model = _linear(steps=1)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([10, 11, 12]))
    trace = _filter(model, measurements, particles=particles, resampler=resampler, threshold=threshold)
    assert trace.estimates.shape == (3, 1, 1)
    assert np.isfinite(trace.estimates).all() and np.isfinite(trace.log_likelihood).all()
    assert np.all((trace.ess >= 1 - 1e-12) & (trace.ess <= particles + 1e-12))
    if particles == 1:
        np.testing.assert_array_equal(trace.ess, 1.0)
    assert not trace.degenerate.any()


class _Faulty(LinearGaussian):
    """A linear model that returns ``value`` from ``where`` (transition or likelihood) at step ``at``
    (the engine numbers steps 1..T; the likelihood's step is counted by its calls)."""

    def configure(self, where: str, value: float, at: int) -> "_Faulty":
        self._fault = (where, value, at)
        self._likelihood_calls = 0
        return self

    def transition(self, state, step, random):
        moved = super().transition(state, step, random)
        where, value, at = self._fault
        return np.full_like(moved, value) if where == "transition" and step == at else moved

    def log_likelihood(self, measurement, state):
        self._likelihood_calls += 1
        result = super().log_likelihood(measurement, state)
        where, value, at = self._fault
        return np.full_like(result, value) if where == "likelihood" and self._likelihood_calls == at else result


@pytest.mark.parametrize("at", [1, 3])
@pytest.mark.parametrize("where, value", [("transition", math.nan), ("transition", math.inf),
                                          ("transition", -math.inf), ("likelihood", math.nan),
                                          ("likelihood", math.inf)])
def test_engine_model_nan_or_inf_is_a_clear_error(where, value, at):
    """A model returning NaN or +-inf (every particle's state, or the log-likelihood) at step k
    stops the filter with ModelNumericalError: one line naming the model kind and step k."""
    model = _linear(_Faulty, steps=4).configure(where, value, at)
    with pytest.raises(ModelNumericalError) as raised:
        _filter(model, np.zeros((2, 4, 1)), particles=20)
    message = str(raised.value)
    assert "\n" not in message
    assert "linear_gaussian" in message
    assert re.search(rf"\bstep {at}\b", message), message


@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_engine_truth_nan_or_inf_is_a_clear_error(value):
    """A truth that becomes NaN or inf at step 2 is a one-line error naming the model and step 2."""
    model = _linear(_Faulty, steps=4).configure("transition", value, 2)
    with pytest.raises(ModelNumericalError, match=r"linear_gaussian.*step 2\b.*truth") as raised:
        simulate_truth(model, TrialStreams.from_seeds([0, 1]))
    assert "\n" not in str(raised.value)


@pytest.mark.parametrize("variance", [1e-12, 1e12])
def test_engine_tiny_and_huge_noise(variance):
    """Process and measurement variance 1e-12 or 1e12 (gaussian): finite estimates, ESS in
    [1, N], finite log-likelihood, no degenerate step (log-domain weights never underflow here)."""
    model = _linear(steps=5, process_noise={"variance": variance}, measurement_noise={"variance": variance},
                    initial=GaussianLaw(mean=[0.0], covariance=variance))
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([1, 2, 3]))
    trace = _filter(model, measurements, particles=40)
    assert np.isfinite(trace.estimates).all() and np.isfinite(trace.log_likelihood).all()
    assert np.all((trace.ess >= 1 - 1e-9) & (trace.ess <= 40 + 1e-9))
    assert not trace.degenerate.any()


# -- the command line ---------------------------------------------------------------------------------------

ARMS_BY_RESAMPLER = {**{name: {"resampler": name} for name in RESAMPLER_NAMES}, "sis": {"kind": "sis"}}
MODELS = {
    "linear_gaussian": {"kind": "linear_gaussian", "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
                        "measurement_matrix": [[1.0, 0.0]]},
    "range_beacons": {"kind": "range_beacons", "beacons": [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]},
    "falling_body": {"kind": "falling_body", "substeps": 2},
}
FALLING_BODY_PRIOR = {"kind": "gaussian", "mean": [3.0e5, -2.0e4, 1.0e-3], "covariance": [1.0e6, 4.0e6, 1.0e-7]}
WEIGHTING_ARMS = {"gaussian": {"weighting": "gaussian"}, "euclidean": {"weighting": "euclidean"},
                  "manhattan": {"weighting": "manhattan"},
                  "mahalanobis-paper": {"weighting": {"kind": "mahalanobis", "form": "paper"}},
                  "mahalanobis-innovation": {"weighting": {"kind": "mahalanobis", "form": "innovation"}}}
TRIALS = 3


def _config(name: str, model: dict, **sections: Any) -> dict:
    return {"name": name, "seed": 11, "trials": TRIALS, "model": model, **sections}


def _small_grid(kind: str) -> dict:
    """Every resampler and SIS, N in {1, 2}, T in {1, 3}: 24 cells."""
    return _config(f"small-{kind}", dict(MODELS[kind]),
                   filter={"particles": 2, "diffusion": {"kind": "roughening", "factor": 0.2}},
                   arms=ARMS_BY_RESAMPLER,
                   sweep={"filter.particles": [1, 2], "model.steps": [1, 3]},
                   outputs={"trace_trials": 2})


def _noise_grid(kind: str) -> dict:
    """Measurement and process variances of 1e-12 and 1e12 (falling body: tiny process noise
    only, see below), under every weighting for the linear model."""
    model = {**MODELS[kind], "steps": 4}
    sweep = {"model.measurement_noise.variance": [1e-12, 1e12],
             "model.process_noise.variance": [1e-12] if kind == "falling_body" else [1e-12, 1e12]}
    filter_ = {"particles": 30, "ess_threshold": 0.5}
    if kind == "falling_body":
        filter_["initial"] = FALLING_BODY_PRIOR
    return _config(f"noise-{kind}", model, filter=filter_, sweep=sweep,
                   arms=WEIGHTING_ARMS if kind == "linear_gaussian" else {},
                   metrics={"convergence": {"criterion": "spread", "radius": 1.0, "fraction": 0.9}})


# The prior sits at 1000 while the truth starts at 0 and the uniform measurement noise has
# half-width sqrt(3e-6): every likelihood is exactly zero at every step.
UNDERFLOW = _config(
    "underflow",
    {"kind": "linear_gaussian", "steps": 4, "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
     "process_noise": {"variance": 1e-6}, "measurement_noise": {"family": "uniform", "variance": 1e-6},
     "initial": {"kind": "point", "state": [0.0]}},
    filter={"particles": 50, "initial": {"kind": "gaussian", "mean": [1000.0], "covariance": 1.0}},
    arms={name: arm for name, arm in ARMS_BY_RESAMPLER.items()},
    outputs={"trace_trials": 1})

SUCCESSES = {
    **{f"small-{kind}": _small_grid(kind) for kind in MODELS},
    **{f"noise-{kind}": _noise_grid(kind) for kind in MODELS},
    "underflow": UNDERFLOW,
}

# Configs a model error must stop: (config, regex the error line must match)
FAILURES = {
    # the filter assumes x' = 1e300 x: every particle overflows to inf at step 2
    "filter-overflow": (_config("filter-overflow", {**MODELS["linear_gaussian"], "steps": 5},
                                filter={"particles": 10, "initial": {"kind": "point", "state": [1.0, 0.0]},
                                        "model": {"transition_matrix": [[1e300, 0.0], [0.0, 1.0]]}}),
                        r"model linear_gaussian\b.*\bstep 2 of the filter"),
    # a negative ballistic coefficient makes the drag blow up in finite time
    "filter-nan-falling-body": (_config("filter-nan", {**MODELS["falling_body"], "steps": 10},
                                        filter={"particles": 10,
                                                "initial": {"kind": "point", "state": [3.0e5, -2.0e4, -10.0]}}),
                                r"model falling_body\b.*\bstep \d+ of the filter"),
    # process noise of variance 1e12 sends the true falling body out of its domain at step 2
    "truth-overflow-falling-body": (_config("truth-overflow",
                                            {**MODELS["falling_body"], "steps": 4, "process_noise": {"variance": 1e12}},
                                            filter={"particles": 10, "initial": FALLING_BODY_PRIOR}),
                                    r"model falling_body\b.*\bstep 2 of the truth"),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, pfx_in_process):
    """Run every CLI case once; {name: (result folder, PfxResult)}."""
    root = tmp_path_factory.mktemp("extremes")
    jobs, folders = {}, {}
    for name, config in {**SUCCESSES, **{k: v[0] for k, v in FAILURES.items()}}.items():
        folder = root / name
        folder.mkdir()
        (folder / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        jobs[name] = (["run", "config.yaml", "--out", "out", "--quiet"], folder)
        folders[name] = folder / "out"
    results = pfx_in_process.many(jobs)
    return {name: (folders[name], results[name]) for name in jobs}


def _successful(runs, name) -> dict[str, list[dict[str, str]]]:
    folder, result = runs[name]
    assert "Traceback" not in result.output, result.output
    assert result.returncode == 0, result.output
    return check_result_folder(folder)


@pytest.mark.parametrize("kind", list(MODELS))
def test_cli_one_or_two_particles_and_one_step(kind, runs):
    """N = 1, 2 and T = 1, 3 for every resampler and SIS run to completion on every model: all
    24 cells x trials present, ESS in [1, N] (exactly 1 when N = 1), SIS never resamples,
    every trial of T = 1 has one traced step; no NaN, figures written."""
    tables = _successful(runs, f"small-{kind}")
    trials = tables["trials"]
    assert len(trials) == len(ARMS_BY_RESAMPLER) * 2 * 2 * TRIALS
    assert {(r["n_particles"], r["steps"]) for r in trials} == {("1", "1"), ("1", "3"), ("2", "1"), ("2", "3")}
    ess, n = _floats(trials, "ess_mean"), _floats(trials, "n_particles")
    assert np.all((ess >= 1 - 1e-9) & (ess <= n + 1e-9))
    np.testing.assert_allclose(ess[n == 1], 1.0)
    assert all(r["resample_count"] == "0" for r in trials if r["arm"] == "sis")
    assert all(r["resample_count"] == r["steps"] for r in trials if r["arm"] != "sis")
    for column in ("rmse_position", "error_distance_mean", "error_distance_final", "log_likelihood"):
        assert np.isfinite(_floats(trials, column)).all(), column
    one_step = [r for r in tables["steps"] if r["model_steps"] == "1"]
    assert one_step and {r["step"] for r in one_step} == {"1"}


@pytest.mark.parametrize("kind", list(MODELS))
def test_cli_tiny_and_huge_noise_variances(kind, runs):
    """Noise variances of 1e-12 and 1e12 (under every weighting for the linear model) run to
    completion with finite RMSE, error distances, ESS and log-likelihood; no NaN, figures written."""
    tables = _successful(runs, f"noise-{kind}")
    trials = tables["trials"]
    variances = {(r["model_measurement_noise_variance"], r["model_process_noise_variance"]) for r in trials}
    assert len(variances) == (2 if kind == "falling_body" else 4)
    if kind == "linear_gaussian":
        assert {r["arm"] for r in trials} == set(WEIGHTING_ARMS)
    for column in ("rmse_position", "error_distance_mean", "error_distance_final", "ess_mean", "log_likelihood"):
        assert np.isfinite(_floats(trials, column)).all(), column
    assert np.all(_floats(trials, "degenerate_steps") == 0)


def test_cli_every_weight_underflows(runs):
    """A prior 1000 away from the truth under uniform noise of half-width 0.0017: every step of
    every trial is degenerate (degenerate_steps = T), the weights are reset to uniform (ESS = N),
    the run completes for every resampler and SIS, log_likelihood is -inf (not NaN) and the
    summary counts no finite log-likelihood; steps.csv flags every step degenerate."""
    tables = _successful(runs, "underflow")
    trials = tables["trials"]
    assert {r["arm"] for r in trials} == set(ARMS_BY_RESAMPLER)
    assert all(r["degenerate_steps"] == r["steps"] == "4" for r in trials)
    np.testing.assert_allclose(_floats(trials, "ess_mean"), 50.0, rtol=1e-9)
    assert all(r["log_likelihood"] == "-inf" for r in trials)
    assert all(r["log_likelihood_n"] == "0" for r in tables["summary"])
    assert tables["steps"] and all(r["degenerate"] == "True" for r in tables["steps"])


@pytest.mark.parametrize("name", list(FAILURES))
def test_cli_model_error_names_model_and_step(name, runs):
    """A model that yields NaN or inf stops the run with exit 1 and, as the last line on stderr,
    'pfx: error: model KIND ... step K of the filter|truth'; no traceback, no NaN in any CSV."""
    folder, result = runs[name]
    assert "Traceback" not in result.output, result.output
    assert result.returncode == 1, result.output
    last = result.stderr.splitlines()[-1]
    assert last.startswith("pfx: error: "), result.stderr
    assert re.search(FAILURES[name][1], last), last
    for path in folder.rglob("*.csv"):
        assert "nan" not in path.read_text().lower(), path


@pytest.mark.parametrize("name", list(FAILURES))
def test_cli_model_error_is_one_line(name, runs):
    """The model error is the only line on stderr (no numpy warnings)."""
    _, result = runs[name]
    assert len(result.stderr.splitlines()) == 1, result.stderr
