"""Guided proposals and the auxiliary particle filter (pfx/filters/particle/proposals.py, auxiliary.py).

On a linear-Gaussian model the locally optimal proposal p(x_k | x_k-1, z_k) is known in closed
form, and the EKF and UKF (alpha = 1) proposals are exact there, so:

* the weight update of the locally optimal proposal, log p(z | x) + log p(x | x_prev) - log q,
  is log N(z; H f(x_prev), H Q H' + R), whatever x was drawn (to round-off), so a cloud with one
  common x_prev keeps equal weights (ESS = N); EKF and UKF draw the same particles;
* the posterior means agree with the Kalman filter's: the mean over n independent runs (one data
  set) of (x_hat - m_KF) / sqrt(P_KF) lies within 4 standard errors (the sample standard
  deviation / sqrt(n)) of 0; the self-normalised estimate's O(1/N) bias is below one standard
  error for N >= n;
* the likelihood estimate is unbiased, E[L_hat] = p(z_1:T): by the CLT for log L_hat (Bérard,
  Del Moral & Doucet 2014), l = log L_hat - log p is close to N(-s^2/2, s^2), so
  mean(l) + var(l)/2 must lie within 4 standard errors of 0, with
  se^2 = s^2/n + s^4/(2 (n - 1)) (the variances of a normal sample's mean and of half its
  variance); the runs keep s^2 below 1, where the normal approximation holds;
* with an informative sensor (R = Q/50), the locally optimal proposal's log-likelihood variance is
  far below the bootstrap's: a one-sided F-test rejects "bootstrap variance <= 10 x locally
  optimal variance" at level 0.001;
* the auxiliary filter that never resamples (ess_threshold 0) is exactly the plain filter: the
  first-stage normaliser and the second stage's division by p(z | mu) cancel (leaving the first
  out, the classic bug, would break this and the unbiasedness), increment by increment;
* a missing measurement is a predict-only step that adds nothing.

The checks against the Kalman filter, the auxiliary filter's and the missing measurement's run on
both backends (the ``backend`` fixture); the proposals' jax-only checks are in
tests/test_jax_proposals.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import tiny_config_dict
from scipy import stats

from pfx.config.plan import build_plan
from pfx.config.schema import config_schema
from pfx.errors import ConfigError
from pfx.filters import run_filter
from pfx.filters.particle.proposals import PROPOSALS
from pfx.laws.initial import GaussianLaw
from pfx.laws.noise import Noise
from pfx.models.base import bind_law
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.simulation import simulate_truth
from pfx.numerics.log_weights import normalise_weights
from pfx.numerics.seeding import TrialStreams

RUNS = 200            # independent filter runs on one data set
GUIDED = ["locally_optimal", "ekf", {"kind": "ukf", "alpha": 1.0}]


def constant_velocity(measurement_variance: float, steps: int = 10) -> LinearGaussian:
    return LinearGaussian(transition_matrix=[[1.0, 1.0], [0.0, 1.0]], measurement_matrix=[[1.0, 0.0]], steps=steps,
                          process_noise=Noise(variance=[0.5, 0.2]), measurement_noise=Noise(variance=measurement_variance),
                          initial=GaussianLaw(mean=[0.0, 0.0], covariance=[1.0, 1.0]))


def one_data_set(model, runs: int = RUNS):
    """One measurement sequence (the truth's trial 0), repeated for ``runs`` filter runs."""
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([11]))
    return np.repeat(measurements, runs, axis=0)


def run_particle(model, measurements, seed: int = 1000, **settings):
    FilterConfig = config_schema().FilterConfig
    prior = bind_law(model.default_prior(), model.state_dimension, "initial")
    runs = len(measurements)
    return run_filter("particle", model, measurements, TrialStreams.from_seeds(range(seed, seed + runs)),
                      settings=FilterConfig(kind="particle", **settings), prior=prior)


def kalman(model, measurements):
    prior = bind_law(model.default_prior(), model.state_dimension, "initial")
    return run_filter("kf", model, measurements, None, settings=config_schema().FilterConfig(kind="kf"), prior=prior)


def proposal(value):
    value = {"kind": value} if isinstance(value, str) else value
    return PROPOSALS[value["kind"]](**value)


# -- exactness on a linear-Gaussian model ------------------------------------------------------------

def test_locally_optimal_weight_is_the_predictive_density_and_ekf_ukf_draw_the_same():
    model = constant_velocity(0.01)
    previous = TrialStreams.from_seeds([1, 2, 3]).standard_normal((50, 2))            # (3, 50, 2)
    measurement = np.array([[0.3], [-1.0], [2.0]])
    A, H = model.matrices
    Q, R = model.process_noise.covariance(), model.measurement_noise.covariance()
    predicted = previous @ A.T
    predictive = stats.norm.logpdf(measurement[:, None, 0], (predicted @ H.T)[..., 0], np.sqrt((H @ Q @ H.T + R)[0, 0]))
    drawn = {}
    for name in GUIDED:
        state, adjustment = proposal(name).bind(model).propose(previous, 1, measurement, None, TrialStreams.from_seeds([5, 6, 7]))
        weight = model.log_likelihood(measurement[:, None, :], state) + adjustment
        np.testing.assert_allclose(weight, predictive, rtol=1e-9, atol=1e-9)
        drawn[str(name)] = state
    for state in drawn.values():
        np.testing.assert_allclose(state, drawn["locally_optimal"], rtol=1e-9, atol=1e-9)


def test_one_common_previous_state_keeps_equal_weights():
    """The locally optimal weight depends on x_prev alone: a cloud at one x_prev has ESS = N."""
    model = constant_velocity(0.01)
    previous = np.broadcast_to(np.array([0.5, -0.2]), (2, 100, 2)).copy()
    measurement = np.array([[1.0], [0.0]])
    state, adjustment = proposal("locally_optimal").bind(model).propose(previous, 1, measurement, None,
                                                            TrialStreams.from_seeds([3, 4]))
    _, weights, _ = normalise_weights(model.log_likelihood(measurement[:, None, :], state) + adjustment)
    np.testing.assert_allclose(1.0 / np.sum(weights ** 2, axis=-1), 100.0, rtol=1e-9)
    assert np.std(state[..., 0]) > 0.01          # the particles themselves do differ


# -- against the Kalman filter ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def informative():
    model = constant_velocity(0.01)
    measurements = one_data_set(model)
    return model, measurements, kalman(model, measurements)


def unbiased_log_likelihood(log_likelihood: np.ndarray, exact: float) -> tuple[float, float]:
    """(mean(l) + var(l)/2, its standard error) for l = log L_hat - log p (module docstring)."""
    errors = log_likelihood - exact
    n, variance = len(errors), errors.var(ddof=1)
    assert variance < 1.0, f"variance {variance:.2f}: outside the normal approximation"
    return errors.mean() + variance / 2, np.sqrt(variance / n + variance ** 2 / (2 * (n - 1)))


def assert_agrees_with_the_kalman_filter(trace, exact) -> None:
    """Over the runs (the trace's rows, filtering the same data): each step's mean error in
    posterior standard deviations, and the log-likelihood's bias-corrected error, within 4
    standard errors of 0."""
    runs = len(trace.log_likelihood)
    standardised = (trace.estimates - exact.estimates) / np.sqrt(np.diagonal(exact.covariances, axis1=-2, axis2=-1))
    mean_error = standardised.mean(axis=0)                                        # (T, d)
    standard_error = standardised.std(axis=0, ddof=1) / np.sqrt(runs)
    assert np.all(np.abs(mean_error) < 4 * standard_error), np.max(np.abs(mean_error) / standard_error)
    statistic, standard_error = unbiased_log_likelihood(trace.log_likelihood, exact.log_likelihood[0])
    assert abs(statistic) < 4 * standard_error, (statistic, standard_error)


@pytest.mark.parametrize("name", GUIDED, ids=["locally_optimal", "ekf", "ukf"])
def test_guided_posterior_means_and_likelihood_match_the_kalman_filter(informative, name, backend):
    model, measurements, exact = informative
    trace = run_particle(model, measurements, particles=RUNS, proposal=name, backend=backend)
    assert_agrees_with_the_kalman_filter(trace, exact)


@pytest.fixture(scope="module")
def moderate():
    """A moderately informative sensor (R = 0.5), where the auxiliary filter's look-ahead p(z | mu) fits."""
    model = constant_velocity(0.5)
    measurements = one_data_set(model)
    return model, measurements, kalman(model, measurements)


@pytest.mark.parametrize("name", ["bootstrap", "locally_optimal"])
def test_auxiliary_means_and_likelihood_match_the_kalman_filter(moderate, name, backend):
    model, measurements, exact = moderate
    trace = run_particle(model, measurements, particles=RUNS, proposal=name, auxiliary=True, backend=backend)
    assert_agrees_with_the_kalman_filter(trace, exact)
    assert trace.resampled.all()                 # threshold 1: the first stage resamples every step


def test_locally_optimal_likelihood_variance_is_far_below_the_bootstrap(informative):
    model, measurements, _ = informative
    bootstrap = run_particle(model, measurements, particles=RUNS).log_likelihood
    optimal = run_particle(model, measurements, particles=RUNS, proposal="locally_optimal").log_likelihood
    ratio = bootstrap.var(ddof=1) / optimal.var(ddof=1)
    critical = stats.f.ppf(1 - 0.001, RUNS - 1, RUNS - 1)
    assert ratio > 10 * critical, (ratio, critical)


@pytest.mark.parametrize("name", ["bootstrap", "ekf"])
def test_auxiliary_without_resampling_is_the_plain_filter(name, backend):
    model = constant_velocity(0.5)
    measurements = one_data_set(model, 20)
    settings = dict(particles=50, proposal=name, ess_threshold=0.0, backend=backend)
    plain = run_particle(model, measurements, **settings)
    auxiliary = run_particle(model, measurements, auxiliary=True, **settings)
    np.testing.assert_allclose(auxiliary.log_likelihood_increments, plain.log_likelihood_increments,
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(auxiliary.log_likelihood, plain.log_likelihood, rtol=1e-9)
    np.testing.assert_allclose(auxiliary.estimates, plain.estimates, rtol=1e-9, atol=1e-12)
    assert not auxiliary.resampled.any()


@pytest.mark.parametrize("auxiliary", [False, True], ids=["plain", "auxiliary"])
def test_missing_measurement_is_predict_only(backend, auxiliary):
    """A blank row: the guided proposal draws from the transition and adds nothing."""
    model = constant_velocity(0.5, steps=3)
    measurements = one_data_set(model, 4)
    blank = measurements.copy()
    blank[:, 2] = np.nan
    settings = dict(particles=50, proposal="ekf", auxiliary=auxiliary, backend=backend)
    truncated = run_particle(model, measurements[:, :2], **settings)
    with_blank = run_particle(model, blank, **settings)
    np.testing.assert_allclose(with_blank.log_likelihood, truncated.log_likelihood, rtol=1e-12)
    np.testing.assert_array_equal(with_blank.log_likelihood_increments[:, 2], 0.0)
    assert np.isfinite(with_blank.estimates).all()


# -- configuration -----------------------------------------------------------------------------------

REFUSALS = [
    ({"proposal": "ekf", "weighting": "euclidean"}, {}, "c.yaml: filter.proposal: a guided proposal's importance weight needs"),
    ({"auxiliary": True, "weighting": {"kind": "mahalanobis"}}, {}, "c.yaml: filter.auxiliary: the auxiliary particle filter weighs"),
    ({"kind": "sis", "auxiliary": True}, {}, "sis never resamples"),
    ({"proposal": "locally_optimal"}, {"kind": "growth"}, "needs a measurement linear in the state"),
    ({"proposal": "ekf"}, {"kind": "falling_body"}, "process noise covariance L Q L' is singular"),
    ({"proposal": "ukf"}, {"kind": "planar_robot"}, "has noise that does not enter additively"),
    ({"proposal": "ekf"}, {"process_noise": {"family": "laplace"}}, "has laplace process noise"),
]


@pytest.mark.parametrize("settings, model, words", REFUSALS)
def test_invalid_combinations_are_refused_in_one_line(settings, model, words):
    data = tiny_config_dict()
    data["filter"].update(settings)
    if "kind" in model:
        data["model"] = model
    else:
        data["model"].update(model)
    with pytest.raises(ConfigError) as refused:
        build_plan(data, "c.yaml")
    message = str(refused.value)
    assert words in message and "\n" not in message, message


def test_the_default_keeps_cell_keys_and_a_sweep_names_its_columns(tmp_path):
    import pfx

    plain = build_plan(tiny_config_dict(), "c.yaml").cells[0]
    explicit = tiny_config_dict()
    explicit["filter"].update(proposal="bootstrap", auxiliary=False)
    assert build_plan(explicit, "c.yaml").cells[0].key == plain.key
    swept = tiny_config_dict(sweep={"filter.proposal": ["bootstrap", "locally_optimal"], "filter.auxiliary": [False, True]})
    trials = pfx.run(swept, out=tmp_path / "swept").trials
    assert {"proposal", "auxiliary"} <= set(trials.columns)
    reference = pfx.run(tiny_config_dict(), out=tmp_path / "plain").trials
    bootstrap = trials[(trials.proposal == "bootstrap") & (~trials.auxiliary.astype(bool))]
    np.testing.assert_array_equal(bootstrap.log_likelihood.to_numpy(), reference.log_likelihood.to_numpy())
