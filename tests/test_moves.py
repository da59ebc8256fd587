r"""Moves after resampling (filter.move, pfx.filters.particle.moves): the MCMC move's invariance
and acceptance rate, the regularised filter's kernel and bandwidth, refusals, and runs.

Every tolerance is a multiple of a standard error derived from theory (stated at each test);
seeds are fixed. Four standard errors: a two-sided miss probability of 6e-5 per check.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from pfx.config.plan import build_plan
from pfx.config.schema import config_schema
from pfx.errors import ConfigError
from pfx.filters.particle.moves import (
    MoveContext,
    Regularisation,
    ResampleMove,
    square_root,
    unbiased_weighted_covariance,
    weighted_covariance,
)
from pfx.models import MODELS
from pfx.numerics.seeding import TrialStreams

Z_LIMIT = 4.0          # standard errors
KS_LEVEL = 1e-3        # a KS test fails at this level only (stated level of every KS check)


# -- the MCMC move leaves the step's target invariant ---------------------------------------------

PROCESS_VARIANCE, MEASUREMENT_VARIANCE, MEASUREMENT = 1.0, 0.5, 0.7


def one_step_model():
    """x_1 = x_0 + w, w ~ N(0, q); z_1 = x_1 + v, v ~ N(0, r)."""
    return MODELS["linear_gaussian"](
        kind="linear_gaussian", steps=1, transition_matrix=[[1.0]], measurement_matrix=[[1.0]],
        process_noise={"variance": PROCESS_VARIANCE}, measurement_noise={"variance": MEASUREMENT_VARIANCE},
        initial={"kind": "gaussian", "mean": [0.0], "covariance": [[1.0]]})


def test_mcmc_move_leaves_the_target_invariant_and_accepts_at_the_gaussian_rate():
    r"""Given its parent x_0, a particle's target is p(z | x_1) p(x_1 | x_0) = N(mu, tau^2) with
    tau^2 = q r / (q + r), mu = tau^2 (x_0 / q + z / r). Particles drawn exactly from it stay
    distributed so after k Metropolis steps: the standardised u = (x - mu) / tau are n
    independent N(0, 1) draws, whose mean has standard error 1 / sqrt(n) and whose variance has
    standard error sqrt(2 / n); a KS test against N(0, 1) at level 1e-3.

    The proposal covariance is the weighted covariance of the cloud before resampling, here a
    two-point cloud mu_0 +- tau (weights 1/2) whose covariance is tau^2 exactly, so the proposal
    is N(x, s^2 tau^2). For a 1-D Gaussian target and that random walk started in stationarity
    the acceptance probability is E[min(1, exp((X^2 - Y^2)/2))], X ~ N(0,1), Y = X + s Z, which
    is (2/pi) arctan(2/s) (0.445 at s = 2.38). Each particle's mean acceptance over its k steps
    lies in [0, 1] with that mean, so its variance is at most alpha (1 - alpha): the standard
    error of the mean over n independent chains is at most sqrt(alpha (1 - alpha) / n).
    """
    model = one_step_model()
    trials, particles, steps = 2, 20_000, 5
    tau2 = PROCESS_VARIANCE * MEASUREMENT_VARIANCE / (PROCESS_VARIANCE + MEASUREMENT_VARIANCE)
    tau = math.sqrt(tau2)
    setup = np.random.default_rng(11)
    parents = setup.standard_normal((trials, particles, 1))
    mean = tau2 * (parents / PROCESS_VARIANCE + MEASUREMENT / MEASUREMENT_VARIANCE)
    start = mean + tau * setup.standard_normal((trials, particles, 1))
    weights = np.zeros((trials, particles))
    weights[:, :2] = 0.5
    cloud = np.zeros((trials, particles, 1))
    cloud[:, 0], cloud[:, 1] = tau, -tau
    context = MoveContext(model=model, step=1, resampled=start.copy(), cloud=cloud, weights=weights,
                          measurement=np.full((trials, 1), MEASUREMENT), parents=parents,
                          indices=np.broadcast_to(np.arange(particles), (trials, particles)),
                          log_weights=np.where(weights > 0, np.log(np.maximum(weights, 1e-300)), -np.inf))
    move = ResampleMove(steps=steps).bind(model, config_schema().FilterConfig())
    moved, acceptance = move.apply(context, TrialStreams.from_seeds([101, 102]))

    standardised = ((moved - mean) / tau).ravel()
    n = standardised.size
    assert np.mean(moved != start) > 0.5                    # the chains did move
    assert abs(standardised.mean()) < Z_LIMIT / math.sqrt(n)
    assert abs(standardised.var() - 1.0) < Z_LIMIT * math.sqrt(2.0 / n)
    assert stats.kstest(standardised, "norm").pvalue > KS_LEVEL

    expected = 2.0 / math.pi * math.atan(2.0 / 2.38)
    assert acceptance.shape == (trials,) and np.all((acceptance > 0) & (acceptance < 1))
    assert abs(acceptance.mean() - expected) < Z_LIMIT * math.sqrt(expected * (1 - expected) / n)


def test_mcmc_move_without_a_measurement_targets_the_transition_density():
    """A missing measurement (NaN): the target is p(x_1 | x_0) = N(x_0, q); same checks as above."""
    model = one_step_model()
    trials, particles = 1, 20_000
    setup = np.random.default_rng(12)
    parents = setup.standard_normal((trials, particles, 1))
    std = math.sqrt(PROCESS_VARIANCE)
    start = parents + std * setup.standard_normal((trials, particles, 1))
    context = MoveContext(model=model, step=1, resampled=start, cloud=start, weights=np.full((1, particles), 1 / particles),
                          measurement=np.full((trials, 1), np.nan), parents=parents,
                          indices=np.arange(particles)[None], log_weights=np.full((1, particles), -math.log(particles)))
    moved, acceptance = ResampleMove(steps=3).bind(model, config_schema().FilterConfig()).apply(
        context, TrialStreams.from_seeds([7]))
    standardised = ((moved - parents) / std).ravel()
    n = standardised.size
    assert abs(standardised.mean()) < Z_LIMIT / math.sqrt(n)
    assert abs(standardised.var() - 1.0) < Z_LIMIT * math.sqrt(2.0 / n)
    assert 0 < acceptance[0] < 1


# -- the regularised filter's kernel and bandwidth ------------------------------------------------

def test_optimal_bandwidths_follow_musso_oudjane_le_gland():
    """h = A N^(-1/(d+4)): A = (4/(d+2))^(1/(d+4)) (gaussian); for epanechnikov in 2-D,
    c_2 = pi and A = (8/pi * 6 * (2 sqrt(pi))^2)^(1/6) = 192^(1/6)."""
    assert Regularisation(kernel="gaussian").bandwidth_for(1000, 1) == pytest.approx((4 / 3) ** 0.2 * 1000 ** -0.2)
    assert Regularisation(kernel="epanechnikov").bandwidth_for(500, 2) == pytest.approx(192 ** (1 / 6) * 500 ** (-1 / 6))
    assert Regularisation(bandwidth=0.3).bandwidth_for(500, 2) == 0.3


@pytest.mark.parametrize("dimension", [1, 2, 3])
def test_epanechnikov_draws_lie_in_the_unit_ball_with_the_beta_radial_law(dimension):
    """K(e) ~ (1 - |e|^2) on the unit ball: the radius density ~ r^(d-1) (1 - r^2), so |e|^2 ~
    Beta(d/2, 2); KS test at level 1e-3. The direction is uniform: each component's mean is 0
    with standard error sqrt(1/(d+4) / n)."""
    draws = Regularisation(kernel="epanechnikov").draw_kernel(TrialStreams.from_seeds([dimension]), 40_000, dimension)
    squared = np.sum(draws[0] ** 2, axis=-1)
    assert squared.max() < 1.0
    assert stats.kstest(squared, stats.beta(dimension / 2, 2).cdf).pvalue > KS_LEVEL
    assert np.all(np.abs(draws[0].mean(axis=0)) < Z_LIMIT * math.sqrt(1 / (dimension + 4) / len(squared)))


@pytest.mark.parametrize("kernel", ["gaussian", "epanechnikov"])
def test_regularisation_noise_has_covariance_h_squared_times_the_cloud_covariance(kernel):
    r"""The added noise h D eps has covariance h^2 c_K D D', c_K the kernel's variance (1 for the
    standard Gaussian, 1/(d+4) for the Epanechnikov kernel on the unit ball), D D' the unbiased
    weighted covariance of the cloud before resampling, Sigma = sum_j w_j (x_j - m)(x_j - m)' /
    (1 - sum_j w_j^2). Checked along directions a: v = a' noise has E v^2 = h^2 c_K a' Sigma a
    and, eps being spherically symmetric, Var v^2 = (h^2 a' Sigma a)^2 (m_4 - c_K^2) with
    m_4 = E eps_1^4: 3 for the Gaussian, 3 / ((d+4)(d+6)) for the Epanechnikov kernel
    (E r^4 = d(d+2)/((d+4)(d+6)) for r^2 ~ Beta(d/2, 2), E u_1^4 = 3/(d(d+2)) on the sphere).

    Five particles hold 0.16 of the weight each (the rest share 0.2), so N_eff is about 7.8 and
    the unbiasing factor 1 / (1 - sum w^2) = N_eff / (N_eff - 1) is 1.15: the check tells the
    unbiased covariance from the plain weighted one (asserted: their gap exceeds the tolerance).
    """
    d, particles = 2, 60_000
    setup = np.random.default_rng(5)
    cloud = setup.standard_normal((1, particles, d)) @ np.array([[1.4, 0.0], [0.5, 0.6]]).T
    weights = np.full((1, particles), 0.2 / (particles - 5))
    weights[0, :5] = 0.16
    factor = 1.0 / (1.0 - np.sum(weights ** 2))
    plain = np.cov(cloud[0].T, aweights=weights[0], bias=True)
    assert np.allclose(weighted_covariance(weights, cloud)[0], plain)
    covariance = unbiased_weighted_covariance(weights, cloud, np.ones_like(weights, dtype=bool))[0]
    assert np.allclose(covariance, factor * plain)
    move = Regularisation(kernel=kernel)
    h = move.bandwidth_for(particles, d)
    resampled = np.zeros((1, particles, d))
    context = MoveContext(model=None, step=1, resampled=resampled, cloud=cloud, weights=weights,
                          measurement=np.zeros((1, 1)), parents=None,
                          indices=np.arange(particles)[None], log_weights=np.log(weights))
    moved, acceptance = move.apply(context, TrialStreams.from_seeds([9]))
    assert acceptance is None
    noise = moved[0] - resampled[0]
    variance, fourth = (1.0, 3.0) if kernel == "gaussian" else (1 / (d + 4), 3 / ((d + 4) * (d + 6)))
    for direction in (np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([1.0, 1.0]) / math.sqrt(2)):
        projected = noise @ direction
        spread = h * h * direction @ covariance @ direction
        standard_error = spread * math.sqrt((fourth - variance ** 2) / particles)
        assert abs(np.mean(projected ** 2) - variance * spread) < Z_LIMIT * standard_error
        assert variance * spread * (1 - 1 / factor) > 2 * Z_LIMIT * standard_error    # the check has power


def test_square_root_of_a_singular_covariance():
    """A collapsed cloud (every particle equal in one component): D D' = Sigma all the same."""
    covariance = np.array([[[2.0, 0.0], [0.0, 0.0]]])
    root = square_root(covariance)
    assert np.allclose(root @ root.transpose(0, 2, 1), covariance)


# -- configs: refusals, identity of the default, end-to-end runs ----------------------------------

def _config(filter_settings: dict, model: dict | None = None, **extra) -> dict:
    return {"name": "moves", "seed": 3, "trials": 4, "model": model or {"kind": "growth", "steps": 15},
            "filter": {"particles": 200, **filter_settings}, **extra}


@pytest.mark.parametrize("settings, model, message", [
    ({"move": "mcmc", "diffusion": {"kind": "roughening"}}, None,
     "filter.move: a move (mcmc) and a diffusion (roughening) would both rejuvenate the resampled particles; "
     "set diffusion: none (or move: none)"),
    ({"kind": "sis", "move": "regularise"}, None,
     "filter.move: sis never resamples, so there are no resampled particles to move (regularise); use kind: particle"),
    ({"move": "mcmc", "weighting": "euclidean"}, None,
     "filter.move: the mcmc move targets p(z | x) p(x | parent), the filter's target only with weighting: "
     "gaussian, not euclidean"),
    ({"move": "mcmc"}, {"kind": "planar_robot"},
     "filter.move: the mcmc move evaluates the transition density p(x_k | x_k-1), which needs additive process "
     "noise; model planar_robot has noise that does not enter additively (x' = f(x, u) + L w does not hold for "
     "its propagate)"),
    ({"move": "mcmc"}, {"kind": "growth", "process_noise": {"variance": 0.0}},
     "filter.move: the mcmc move evaluates the transition density, which needs a positive-definite process noise "
     "covariance L Q L' (model growth's is singular); use a move that needs no transition density (diffusion, "
     "roughening, regularisation), or give the model a process noise of full rank"),
])
def test_invalid_moves_are_refused_in_one_line(settings, model, message):
    with pytest.raises(ConfigError) as caught:
        build_plan(_config(settings, model), "moves.yaml")
    assert str(caught.value).splitlines() == [f"moves.yaml: {message}"]


def test_move_none_keeps_the_cell_keys():
    """The default (move: none) is today's filter: an explicit none changes no cell key."""
    plain = build_plan(_config({}), "moves.yaml")
    explicit = build_plan(_config({"move": "none"}), "moves.yaml")
    assert [cell.key for cell in plain.cells] == [cell.key for cell in explicit.cells]


def test_growth_with_move_arms_runs_end_to_end(tmp_path):
    """The growth model (configs/examples/growth.yaml, shortened) with a plain, a regularised and
    a resample-move arm, and a resample-move arm under the ESS rule: move_acceptance is filled
    for the mcmc arms only, inside (0, 1); the moved arms are not worse than the plain one by
    more than chance would allow (a loose sanity bound: RMSE within a factor 2)."""
    import pfx

    config = _config({}, arms={
        "PF": {}, "RPF": {"move": {"kind": "regularise", "kernel": "epanechnikov"}},
        "RM": {"move": {"kind": "mcmc", "steps": 2}},
        "RM-ess": {"move": {"kind": "mcmc", "scale": 0.5}, "ess_threshold": 0.5}})
    result = pfx.run(config, out=tmp_path / "run")
    trials = result.trials
    by_arm = trials.groupby("arm")
    acceptance = by_arm["move_acceptance"]
    assert acceptance.count()[["PF", "RPF"]].tolist() == [0, 0]
    for arm in ("RM", "RM-ess"):
        values = trials.loc[trials.arm == arm, "move_acceptance"]
        assert values.notna().all() and values.between(0, 1, inclusive="neither").all()
    rmse = by_arm["rmse_position"].mean()
    assert (rmse[["RPF", "RM", "RM-ess"]] < 2 * rmse["PF"]).all()


def test_only_resampled_trials_are_moved():
    """A trial that never resamples is never moved: its move_acceptance is empty (NaN)."""
    from pfx.config.schema import config_schema
    from pfx.filters.base import run_filter

    model = one_step_model()
    settings = config_schema().FilterConfig(particles=50, ess_threshold=1e-9, move={"kind": "mcmc"})
    trace = run_filter("particle", model, np.full((3, 1, 1), 0.2), TrialStreams.from_seeds([1, 2, 3]),
                       settings=settings, prior=model.default_prior())
    assert not trace.resampled.any() and np.isnan(trace.move_acceptance).all()
