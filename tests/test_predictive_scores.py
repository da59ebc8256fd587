"""Proper scores of the one-step-ahead predictive distribution (pfx/numerics/proper_scores.py,
pfx/filters/particle/predictive.py, the Gaussian filters' exact scores, ``metrics.scores``).

The sample forms are checked against brute-force double sums on small samples (exact, to
rounding) and against the Gaussian closed forms (within Monte Carlo error: 4 standard errors of
the mean over independent rows, from the sample itself). The filters are checked against the
Kalman filter's exact predictive law on a linear-Gaussian model, and the PIT against uniformity.
Every seed is fixed.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

import pfx
from pfx.numerics.proper_scores import (
    energy_shifts,
    gaussian_crps,
    gaussian_pit,
    sample_crps,
    sample_energy_score,
    sample_pit,
)

pytestmark = pytest.mark.usefixtures("fresh_plugins")


def brute_force_crps(draws, weights, value):
    """sum_i w_i |z_i - y| - 1/(2 (1 - sum w^2)) sum_{i != j} w_i w_j |z_i - z_j|, by the double sum."""
    first = np.sum(weights * np.abs(draws - value))
    pairs = np.abs(draws[:, None] - draws[None, :]) * weights[:, None] * weights[None, :]
    return first - 0.5 * pairs.sum() / (1.0 - np.sum(weights ** 2))


def test_sample_crps_is_the_fair_double_sum():
    generator = np.random.default_rng(1)
    draws = generator.normal(size=(5, 40))
    draws[0, :10] = draws[0, 10:20]                       # ties change nothing
    weights = generator.random((5, 40))
    weights /= weights.sum(axis=1, keepdims=True)
    values = generator.normal(size=5)
    expected = [brute_force_crps(draws[r], weights[r], values[r]) for r in range(5)]
    assert np.allclose(sample_crps(draws, weights, values), expected, rtol=1e-12, atol=1e-12)


def test_sample_crps_is_unbiased_for_the_gaussian_crps():
    """Equal weights, draws from N(mu, sigma^2): the fair estimator's mean over 400 independent
    rows equals the exact CRPS within 4 standard errors (for mu, sigma and y chosen apart)."""
    generator = np.random.default_rng(2)
    rows, count = 400, 50
    for mean, sd, value in ((0.0, 1.0, 0.3), (3.0, 0.5, 1.0), (-2.0, 4.0, 7.0)):
        draws = generator.normal(mean, sd, size=(rows, count))
        weights = np.full((rows, count), 1.0 / count)
        estimates = sample_crps(draws, weights, np.full(rows, value))
        exact = gaussian_crps(mean, sd, value)
        standard_error = estimates.std(ddof=1) / np.sqrt(rows)
        assert abs(estimates.mean() - exact) < 4 * standard_error, (mean, sd, value, estimates.mean(), exact)


def test_energy_score_of_a_scalar_with_every_pair_is_the_crps():
    """With N - 1 <= ENERGY_SHIFTS every pair i != j is counted: the energy score of a scalar
    measurement is then its fair CRPS, to rounding."""
    generator = np.random.default_rng(3)
    draws = generator.normal(size=(4, 12, 1))
    weights = generator.random((4, 12))
    weights /= weights.sum(axis=1, keepdims=True)
    values = generator.normal(size=(4, 1))
    assert list(energy_shifts(12)) == list(range(1, 12))
    assert np.allclose(sample_energy_score(draws, weights, values), sample_crps(draws[..., 0], weights, values[:, 0]),
                       rtol=1e-12)


def test_energy_score_with_spread_shifts_estimates_the_double_sum():
    """For N beyond the shifts, the pairs (i, i + s) of the spread offsets estimate the full
    double sum: over 200 rows of iid 2-d Gaussian draws, the mean difference from the brute-force
    energy score is within 4 standard errors."""
    generator = np.random.default_rng(4)
    rows, count = 200, 120
    draws = generator.normal(size=(rows, count, 2))
    weights = np.full((rows, count), 1.0 / count)
    values = generator.normal(size=(rows, 2))
    approximate = sample_energy_score(draws, weights, values)
    exact = []
    for r in range(rows):
        first = np.mean(np.linalg.norm(draws[r] - values[r], axis=1))
        pairs = np.linalg.norm(draws[r][:, None] - draws[r][None, :], axis=-1)
        exact.append(first - 0.5 * pairs.sum() / (count * (count - 1)))
    difference = approximate - np.array(exact)
    assert abs(difference.mean()) < 4 * difference.std(ddof=1) / np.sqrt(rows)
    assert len(energy_shifts(count)) == 16


def test_randomised_pit_spreads_the_ties():
    """A discrete predictive sample: the PIT of a value tied with draws is the mass below plus
    V times the tied mass; of a value above every draw, 1."""
    draws = np.array([[0.0, 1.0, 1.0, 2.0]])
    weights = np.full((1, 4), 0.25)
    assert sample_pit(draws, weights, np.array([1.0]), np.array([0.5]))[0] == pytest.approx(0.25 + 0.5 * 0.5)
    assert sample_pit(draws, weights, np.array([5.0]), np.array([0.3]))[0] == pytest.approx(1.0)
    assert gaussian_pit(0.0, 2.0, 0.0) == pytest.approx(0.5)
    assert gaussian_pit(1.0, 2.0, 1.0 + 2.0 * 1.959963984540054) == pytest.approx(0.975)


# a small linear-Gaussian config with a Kalman and a particle arm (tests add metrics and outputs)
SMALL_CONFIG = """
name: scores
seed: 3
trials: 4
model:
  kind: linear_gaussian
  transition_matrix: [[0.9]]
  measurement_matrix: [[1.0]]
  steps: 12
  process_noise: {variance: 1.0}
  measurement_noise: {variance: 1.0}
  initial: {kind: gaussian, mean: [0.0], covariance: 1.0}
filter: {particles: 200}
arms:
  kf: {kind: kf}
  pf: {}
"""


def random_walk(steps: int = 40, **overrides):
    """x_k = 0.9 x_{k-1} + w_k, z_k = x_k + v_k, unit variances: the Kalman filter is exact."""
    parameters = dict(steps=steps, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    return pfx.model("linear_gaussian", **{**parameters, **overrides})


def simulated(model, trials: int, seed: int = 0):
    return pfx.simulate(model, trials=trials, seed=seed).measurements


def test_particle_scores_match_the_kalman_filters_exact_scores(backend):
    """On a linear-Gaussian model the exact predictive law of z_k is N(H m, H P H' + R): the
    Kalman filter's CRPS and log score are exact. The particle filter's, averaged per trial over
    the steps, match them: the paired difference over 100 trials (each its own data) is within 4
    standard errors plus 2/N. (A particle approximation of the predictive law scores worse than
    the exact law by O(1/N): for the log score E[-log p-hat] - (-log p) ~ Var(p-hat / p) / 2 =
    c / (2N), with c = N * sum w^2 of order 1 to 4 here; about 0.0008 at N = 2000, as measured.)"""
    model = random_walk()
    measurements = simulated(model, 100)
    exact = pfx.filter(model, measurements, kind="kf", scores=True).predictive
    particle = pfx.filter(model, measurements, particles=2000, backend=backend, seed=3, scores=True).predictive
    for name in ("crps", "log_score"):
        exact_values = getattr(exact, name).reshape(100, -1).mean(axis=1)
        particle_values = getattr(particle, name).reshape(100, -1).mean(axis=1)
        difference = particle_values - exact_values
        standard_error = difference.std(ddof=1) / np.sqrt(len(difference))
        assert abs(difference.mean()) < 4 * standard_error + 2.0 / 2000, \
            (name, difference.mean(), standard_error)
    # the predictive moments are the Kalman filter's H m and sqrt(S)
    assert np.allclose(particle.mean.mean(), exact.mean.mean(), atol=0.02)
    assert abs(np.median(particle.sd / exact.sd) - 1.0) < 0.02


def test_pit_is_uniform_when_the_model_is_right_and_not_when_it_is_wrong(backend):
    """The PITs of a well-specified filter are iid uniform over the steps and trials: a
    Kolmogorov-Smirnov test at 1 % does not reject. A filter that assumes a measurement variance
    9 times too small (over-confident) gets a U-shaped PIT, and the test rejects; one that assumes
    it 9 times too large, a hump, rejected too."""
    model = random_walk(steps=30)
    measurements = simulated(model, 40, seed=11)
    right = pfx.filter(model, measurements, particles=1000, backend=backend, seed=5, scores=True).predictive.pit
    assert stats.kstest(right.ravel(), "uniform").pvalue > 0.01
    for variance, shape in ((1.0 / 9.0, "U"), (9.0, "hump")):
        assumed = random_walk(steps=30, measurement_noise={"variance": variance})
        wrong = pfx.filter(assumed, measurements, particles=1000, backend=backend, seed=5, scores=True).predictive.pit
        assert stats.kstest(wrong.ravel(), "uniform").pvalue < 0.01, shape
        tails = np.mean((wrong < 0.1) | (wrong > 0.9))
        assert (tails > 0.2) if shape == "U" else (tails < 0.2), (shape, tails)


def test_scores_leave_the_filters_numbers_as_they_were():
    """The score draws come from streams apart from the filter's: with and without scores, the
    estimates and the log-likelihood are the same to the bit."""
    model = random_walk(steps=20)
    measurements = simulated(model, 5)
    plain = pfx.filter(model, measurements, particles=300, seed=2)
    scored = pfx.filter(model, measurements, particles=300, seed=2, scores=True)
    assert np.array_equal(plain.estimates, scored.estimates)
    assert np.array_equal(plain.log_likelihood, scored.log_likelihood)
    assert plain.predictive is None and scored.predictive.crps.shape == (5, 20, 1)


def test_missing_measurements_score_nothing():
    model = random_walk(steps=10)
    measurements = simulated(model, 2)
    measurements[0, 3] = np.nan
    for kind, options in (("particle", {"particles": 200}), ("kf", {})):
        predictive = pfx.filter(model, measurements, kind=kind, seed=1, scores=True, **options).predictive
        for name in ("mean", "sd", "crps", "pit"):
            values = getattr(predictive, name)
            assert np.isnan(values[0, 3]).all() and np.isfinite(values[1]).all(), (kind, name)
        assert np.isnan(predictive.log_score[0, 3]) and np.isfinite(predictive.log_score[0, 4])


def test_a_bivariate_measurement_has_an_energy_score():
    model = pfx.model("linear_gaussian", steps=15, transition_matrix=[[1.0, 1.0], [0.0, 1.0]],
                      measurement_matrix=[[1.0, 0.0], [0.0, 1.0]], process_noise={"variance": [0.1, 0.1]},
                      measurement_noise={"variance": [1.0, 0.5]},
                      initial={"kind": "gaussian", "mean": [0.0, 1.0], "covariance": [1.0, 0.1]})
    measurements = simulated(model, 3)
    predictive = pfx.filter(model, measurements, particles=500, seed=1, scores=True).predictive
    assert predictive.energy_score.shape == (3, 15) and np.isfinite(predictive.energy_score).all()
    # the energy score of a vector is at least the larger of its components' CRPS, to Monte Carlo error
    assert (predictive.energy_score.mean() > predictive.crps.mean(axis=(0, 1)).max())


def test_config_writes_the_score_columns(tmp_path):
    """``metrics.scores``: steps.csv's predictive columns and trials.csv's means, for a particle
    and a Kalman arm; the measurements are in steps.csv whether or not scores are asked for."""
    config = tmp_path / "scores.yaml"
    config.write_text(SMALL_CONFIG + "metrics: {scores: true}\noutputs: {figures: [], trace_trials: 2}\n")
    out = tmp_path / "out"
    pfx.run(config, out=out)
    trials = pd.read_csv(out / "trials.csv")
    steps = pd.read_csv(out / "steps.csv")
    assert {"crps_z1", "log_score"} <= set(trials.columns)
    assert trials[["crps_z1", "log_score"]].notna().all().all()
    for column in ("measurement_z1", "predictive_mean_z1", "predictive_sd_z1", "crps_z1", "pit_z1", "log_score"):
        assert steps[column].notna().all(), column
    simulation = pfx.simulate(pfx.model("linear_gaussian", transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                                        steps=12, process_noise={"variance": 1.0},
                                        measurement_noise={"variance": 1.0},
                                        initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0}),
                              trials=2, seed=3)
    first = steps[(steps["arm"] == "pf") & (steps["trial"] == 0)]["measurement_z1"].to_numpy()
    assert np.allclose(first, simulation.measurements[0, :, 0])


# -- forecasts (pfx/filters/particle/forecasting.py, outputs.forecasts) -------------------------

def forecasts_of(model, measurements, backend: str, origin: int, horizons, particles: int = 2000):
    """The particle filter's forecasts from step ``origin`` of every trial, as forecast_table's columns."""
    from pfx.filters.particle.forecasting import ForecastRequest
    from pfx.numerics.seeding import TrialStreams

    bound = pfx.particle_filter(model, particles=particles, backend=backend)
    request = ForecastRequest(rows=np.arange(len(measurements)), origins=frozenset({origin}),
                              horizons=tuple(horizons), quantiles=(0.1, 0.5, 0.9))
    trace = bound.planned.run(model, measurements, TrialStreams.from_seeds(range(100, 100 + len(measurements))),
                              settings=bound.settings, prior=bound.prior, forecast=request)
    return trace.forecasts


def test_forecast_mean_and_variance_are_the_exact_k_step_moments(backend):
    """From the Kalman filter's posterior N(m_k, P_k) at the origin, the exact h-step forecast of
    x_{k+h} is N(a^h m_k, a^{2h} P_k + q sum_{j<h} a^{2j}). The particle filter's forecast mean,
    per trial, differs from a^h m_k by Monte Carlo error only: the mean difference over 100
    trials (each its own data) is within 4 standard errors; its forecast variance over the exact
    one averages 1 within 4 standard errors plus the O(1/N) of a weighted sample."""
    model = random_walk(steps=30)
    measurements = simulated(model, 100, seed=21)
    origin, horizons = 20, (1, 5)
    kalman = pfx.filter(model, measurements, kind="kf").trace
    mean, variance = kalman.estimates[:, origin - 1, 0], kalman.covariances[:, origin - 1, 0, 0]
    table = pd.DataFrame(forecasts_of(model, measurements, backend, origin, horizons))
    for horizon in horizons:
        rows = table[table["horizon"] == horizon].sort_values("row")
        exact_mean = 0.9 ** horizon * mean
        exact_variance = 0.81 ** horizon * variance + sum(0.81 ** j for j in range(horizon))
        difference = rows["state_mean_x1"].to_numpy() - exact_mean
        assert abs(difference.mean()) < 4 * difference.std(ddof=1) / np.sqrt(len(difference)), horizon
        ratio = rows["state_sd_x1"].to_numpy() ** 2 / exact_variance
        assert abs(ratio.mean() - 1.0) < 4 * ratio.std(ddof=1) / np.sqrt(len(ratio)) + 2.0 / 2000, horizon
        # the measurement's forecast adds the measurement variance 1
        spread = rows["measurement_sd_z1"].to_numpy() ** 2
        assert abs(np.mean(spread / (exact_variance + 1.0)) - 1.0) < 0.05, horizon


def test_forecasts_leave_the_filter_as_it_was_and_skip_horizons_past_the_record():
    model = random_walk(steps=12)
    measurements = simulated(model, 3)
    table = forecasts_of(model, measurements, "numpy", origin=10, horizons=(1, 2, 5), particles=300)
    assert sorted(set(table["horizon"].tolist())) == [1, 2]          # 10 + 5 is past step 12
    assert np.isfinite(table["crps_z1"]).all() and ((table["pit_z1"] >= 0) & (table["pit_z1"] <= 1)).all()
    quantiles = [c for c in table if c.startswith("state_q")]
    assert quantiles == ["state_q10_x1", "state_q50_x1", "state_q90_x1"]
    assert (table["state_q10_x1"] <= table["state_q50_x1"]).all() and (table["state_q50_x1"] <= table["state_q90_x1"]).all()


FORECAST_CONFIG = SMALL_CONFIG + """outputs:
  figures: []
  forecasts: {horizons: [1, 3], origins: ORIGINS, trials: 2}
"""


def test_config_writes_forecasts_csv_for_the_particle_cells(tmp_path):
    config = tmp_path / "forecasts.yaml"
    config.write_text(FORECAST_CONFIG.replace("ORIGINS", "[4, 8]"))
    pfx.run(config, out=tmp_path / "out")
    table = pd.read_csv(tmp_path / "out" / "forecasts.csv")
    assert set(table["arm"]) == {"pf"} and sorted(set(table["trial"])) == [0, 1]
    assert sorted(set(zip(table["origin_time"], table["horizon"]))) == [(4.0, 1), (4.0, 3), (8.0, 1), (8.0, 3)]
    assert (table["time"] == table["origin_time"] + table["horizon"]).all()


@pytest.mark.parametrize("origins, key", [("[4.5]", "outputs.forecasts.origins[0]"), ("sometimes", "outputs.forecasts.origins")])
def test_an_origin_that_is_no_step_is_refused_by_key(tmp_path, origins, key):
    from typer.testing import CliRunner

    from pfx.cli import app

    config = tmp_path / "forecasts.yaml"
    config.write_text(FORECAST_CONFIG.replace("ORIGINS", origins))
    result = CliRunner().invoke(app, ["run", str(config), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and key in result.output and "Traceback" not in result.output
    assert not (tmp_path / "out").exists()
