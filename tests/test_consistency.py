"""NEES and NIS are never negative or made of rounding: a covariance that cannot be inverted
reliably gives an empty value, left out of the means and counted (pfx/numerics/quadratic_forms.py,
pfx/analysis/metrics.py ``consistency``, steps_summary.csv's ``nees_n``).

The collapsed cloud is the case seen in the wild (NEES of -6.5e23 from a 500-particle cloud
whose weight sat on about one particle): weights spread over many orders of magnitude make the
weighted covariance nearly of rank one, and rounding makes it indefinite.
"""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib
import numpy as np
import pandas as pd
import pytest
from conftest import tiny_config_dict

from pfx.analysis.metrics import MetricInputs, MetricsConfig, consistency_metrics
from pfx.config.plan import build_plan
from pfx.figures.traces import nees_over_time
from pfx.numerics.quadratic_forms import SMALLEST_CORRELATION_EIGENVALUE, normalised_squares, reliably_invertible
from pfx.result_folder import ResultFolder
from pfx.run.runner import run_plan

matplotlib.use("Agg")

SCALES = np.array([100.0, 100.0, 10.0, 10.0, 0.1])      # metres, metres, m/s, m/s, rad/s: units far apart


def _collapsed_clouds(count: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(errors, weighted covariances) of ``count`` 500-particle clouds whose log-weights spread
    over 20 to 80 nats: the weight sits on one particle or a few."""
    random = np.random.default_rng(seed)
    errors, covariances = [], []
    for _ in range(count):
        particles = random.normal(size=(500, 5)) * SCALES
        log_weights = random.normal(size=500) * random.uniform(20, 80)
        weights = np.exp(log_weights - log_weights.max())
        weights /= weights.sum()
        centred = particles - weights @ particles
        covariances.append(np.einsum("n,nd,ne->de", weights, centred, centred))
        errors.append(random.normal(size=5) * SCALES)
    return np.array(errors), np.array(covariances)


def test_a_collapsed_cloud_has_no_nees_rather_than_a_wrong_one():
    errors, covariances = _collapsed_clouds(400)
    values = normalised_squares(errors, covariances)
    reliable = reliably_invertible(covariances)
    # Before the test existed, 22 of these 400 came out negative one cloud at a time (down to
    # -1.4e42), and a batch holding one exactly singular matrix went through the pseudo-inverse
    # whole: a value depended on its neighbours. Now each is what it is, alone or in a batch.
    one_at_a_time = np.array([normalised_squares(error, covariance) for error, covariance in zip(errors, covariances)])
    np.testing.assert_array_equal(values, one_at_a_time)
    assert not (values < 0).any()
    assert np.array_equal(np.isnan(values), ~reliable)
    assert 0 < reliable.sum() < len(reliable)          # the case has both kinds
    # Where kept, the value is the one a backward-stable Cholesky solve of the scaled problem
    # gives, to the accuracy the module docstring promises (relative error below d N sqrt(eps)).
    scale = np.sqrt(np.diagonal(covariances[reliable], axis1=-2, axis2=-1))
    correlation = covariances[reliable] / (scale[:, :, None] * scale[:, None, :])
    factor = np.linalg.cholesky(0.5 * (correlation + np.swapaxes(correlation, -1, -2)))
    whitened = np.linalg.solve(factor, (errors[reliable] / scale)[..., None])[..., 0]
    np.testing.assert_allclose(values[reliable], np.sum(whitened ** 2, axis=-1),
                               rtol=5 * 500 * SMALLEST_CORRELATION_EIGENVALUE)


def test_units_far_apart_do_not_make_a_covariance_unreliable():
    """The test looks at the correlation matrix: a well-conditioned one in units 1e8 apart keeps
    its exact NEES; a truly singular one (two particles span a line) has none."""
    correlation = np.array([[1.0, 0.5, 0.0], [0.5, 1.0, 0.3], [0.0, 0.3, 1.0]])
    scale = np.array([1e4, 1.0, 1e-4])
    covariance = correlation * np.outer(scale, scale)
    error = np.array([2e4, -1.0, 3e-4])
    expected = (error / scale) @ np.linalg.solve(correlation, error / scale)
    assert normalised_squares(error, covariance) == pytest.approx(expected, rel=1e-12)
    line = np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert np.isnan(normalised_squares(error, line))
    assert np.isnan(normalised_squares(error, np.zeros((3, 3))))
    assert np.isnan(normalised_squares(error, np.full((3, 3), np.inf)))


def _inputs(errors: np.ndarray, covariances: np.ndarray, nis: np.ndarray, observed=None) -> MetricInputs:
    trials, steps, dimension = errors.shape
    model = SimpleNamespace(angular_components=(), full_turn=2 * np.pi)
    trace = SimpleNamespace(estimates=errors, covariances=covariances, nis=nis)
    return MetricInputs(truth=np.zeros_like(errors), trace=trace, model=model, config=MetricsConfig(),
                        observed=observed)


def test_the_means_are_over_the_valid_steps_and_the_others_are_counted():
    errors = np.tile(np.array([1.0, 2.0]), (2, 4, 1))                  # 2 trials, 4 steps, d = 2
    covariances = np.tile(np.eye(2), (2, 4, 1, 1))
    covariances[0, 1] = [[1.0, 1.0], [1.0, 1.0]]                         # singular
    covariances[0, 3] = [[1.0, 1.0], [1.0, 1.0 - 1e-13]]                 # indefinite by rounding
    nis = np.array([[1.0, np.nan, 3.0, 5.0], [2.0, 2.0, 2.0, 2.0]])     # trial 0, step 2: S not invertible
    columns = consistency_metrics(_inputs(errors, covariances, nis))
    np.testing.assert_array_equal(columns["nees_mean"], [5.0, 5.0])      # 1 + 4 at the valid steps
    np.testing.assert_array_equal(columns["nees_invalid_steps"], [2.0, 0.0])
    np.testing.assert_array_equal(columns["nis_mean"], [3.0, 2.0])
    np.testing.assert_array_equal(columns["nis_invalid_steps"], [1.0, 0.0])
    # A step without a measurement has no NIS by design: neither averaged nor counted.
    observed = np.array([[True, True, False, True], [True, True, True, True]])
    nis[0, 2] = np.nan
    columns = consistency_metrics(_inputs(errors, covariances, nis, observed))
    np.testing.assert_array_equal(columns["nis_mean"], [3.0, 2.0])
    np.testing.assert_array_equal(columns["nis_invalid_steps"], [1.0, 0.0])
    # Every step invalid: an empty mean, every step counted.
    covariances[1] = 0.0
    columns = consistency_metrics(_inputs(errors, covariances, nis))
    assert np.isnan(columns["nees_mean"][1]) and columns["nees_invalid_steps"][1] == 4


@pytest.fixture(scope="module")
def collapsed_run(tmp_path_factory):
    """Sequential importance sampling (never resampling) of a 2-D state with a precise sensor:
    within a few steps every trial's weight sits on one particle or a few."""
    model = {"kind": "linear_gaussian", "steps": 30, "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
             "measurement_matrix": [[1.0, 0.0]], "names": ["position", "velocity"], "position": [0],
             "measurement_noise": {"variance": 0.01}}
    config = tiny_config_dict(name="collapsed", model=model, trials=6, filter={"particles": 50, "kind": "sis"},
                              metrics={"consistency": True}, outputs={"trace_trials": 6, "figures": []})
    return run_plan(build_plan(config, "collapsed.yaml"), tmp_path_factory.mktemp("collapsed") / "run")


def test_a_collapsed_run_writes_no_negative_nees_and_counts_what_it_left_out(collapsed_run):
    trials = pd.read_csv(collapsed_run / "trials.csv")
    steps = pd.read_csv(collapsed_run / "steps.csv")
    summary = pd.read_csv(collapsed_run / "steps_summary.csv")
    assert (trials["nees_invalid_steps"] > 0).all()
    assert not (trials["nees_mean"] < 0).any() and not (steps["nees"] < 0).any()
    # Every trial is traced: steps.csv's empty NEES are the steps trials.csv counts.
    left_out = steps.groupby("trial")["nees"].apply(lambda values: values.isna().sum())
    np.testing.assert_array_equal(left_out.to_numpy(), trials["nees_invalid_steps"].to_numpy())
    valid_mean = steps.groupby("trial")["nees"].mean()          # pandas skips the empty ones
    np.testing.assert_allclose(valid_mean.to_numpy(), trials["nees_mean"].to_numpy(), rtol=1e-12)
    # steps_summary.csv: nees_n counts the trials with a NEES at each step, the mean is over them.
    np.testing.assert_array_equal(summary["nees_n"], steps.groupby("step")["nees"].count())
    np.testing.assert_allclose(summary["nees_mean"], steps.groupby("step")["nees"].mean(), rtol=1e-12)
    assert (trials["nis_invalid_steps"] == 0).all()            # S = Cov + R: R keeps it invertible


def test_the_nees_figure_says_what_it_left_out(collapsed_run):
    figure = nees_over_time(ResultFolder(collapsed_run))
    steps = pd.read_csv(collapsed_run / "steps.csv")
    title = figure._suptitle.get_text()
    assert (f"left out: {int(steps['nees'].isna().sum())} of {len(steps)} (trial, step) values whose "
            "covariance could not be inverted reliably") in title
