"""The stochastic-volatility plugin's own proposal and look-ahead, and the sv-gbp-usd benchmark
(examples/plugins/stochastic_volatility.py; docs/benchmarks/sv-gbp-usd.md).

* the proposal ``stochastic_volatility_taylor`` draws from the Gaussian its docstring states
  (the prior N(m, sigma^2) times the first- or second-order Taylor expansion of log p(y | x)
  about m): its draws have that mean and variance, and its importance correction is
  log N(x; m, sigma^2) - log N(x; mean, variance), both computed here with scipy;
* the look-ahead of each order is the closed form of log int N(x; m, sigma^2) exp(l_hat(x)) dx
  (checked by numerical integration) and stays finite at extreme returns and states;
* unbiasedness: on the first 20 returns, the mean of exp(log L_hat - log L) over many runs of
  the bootstrap, guided and auxiliary filters is 1 within 4 standard errors, log L from the
  grid recursion of tests/test_gbp_usd.py (independent of pfx's filters).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from conftest import REPO_ROOT
from scipy import integrate, stats
from test_gbp_usd import MU, PHI, SIGMA, quadrature_log_likelihood, returns

from pfx.config.plan import build_plan
from pfx.numerics.seeding import TrialStreams
from pfx.run.runner import run_plan

PLUGIN = REPO_ROOT / "examples" / "plugins" / "stochastic_volatility.py"


def config(tmp_path, steps: int = 20, look_ahead: str = "second_order", **extra) -> dict:
    data = tmp_path / "returns.csv"
    pd.DataFrame({"step": range(1, steps + 1), "z1": returns()[:steps]}).to_csv(data, index=False)
    return {"name": "sv", "seed": 11, "trials": 2, "plugins": [str(PLUGIN)],
            "model": {"kind": "stochastic_volatility", "mu": MU, "phi": PHI, "sigma": SIGMA,
                      "look_ahead": look_ahead},
            "data": {"measurements": str(data)},
            "filter": {"kind": "particle", "particles": 10, "resampler": "systematic", "ess_threshold": 0.5},
            "outputs": {"trace_trials": 0, "figures": []}, **extra}


def bound(tmp_path, order: int, look_ahead: str = "second_order"):
    """The plan's model and the proposal of the given order, bound to it."""
    raw = config(tmp_path, look_ahead=look_ahead,
                 filter={"kind": "particle", "particles": 10,
                         "proposal": {"kind": "stochastic_volatility_taylor", "order": order}})
    cell = build_plan(raw, str(tmp_path / "sv.yaml")).cells[0]
    return cell.filter_model, cell.filter.proposal.bind(cell.filter_model)


def stated_moments(previous: float, y: float, order: int) -> tuple[float, float, float]:
    """The prior mean m and the proposal's mean and variance, from the docstring's formulas."""
    m = MU + PHI * (previous - MU)
    ratio = y**2 * math.exp(-m)
    variance = 1.0 / (1.0 / SIGMA**2 + 0.5 * ratio) if order == 2 else SIGMA**2
    return m, m + variance * 0.5 * (ratio - 1.0), variance


@pytest.mark.parametrize("order", [1, 2])
def test_the_proposal_draws_the_stated_gaussian_and_returns_the_importance_correction(tmp_path, order):
    model, proposal = bound(tmp_path, order)
    previous_value, y = -2.0, 2.17                     # a low volatility and the data's largest return
    draws = 200_000
    previous = np.full((1, draws, 1), previous_value)
    state, correction = proposal.propose(previous, 5, np.array([[y]]), None, TrialStreams.from_seeds([3]))
    assert state.shape == (1, draws, 1) and correction.shape == (1, draws)
    m, mean, variance = stated_moments(previous_value, y, order)
    x = state[0, :, 0]
    # the draws' moments: the mean within 4 standard errors, the variance within 4 of its own
    assert abs(x.mean() - mean) < 4 * math.sqrt(variance / draws)
    assert abs(x.var() / variance - 1) < 4 * math.sqrt(2 / draws)
    # the correction is log p(x | x_prev) - log q(x), with q the stated (normalised) Gaussian
    expected = stats.norm.logpdf(x, m, SIGMA) - stats.norm.logpdf(x, mean, math.sqrt(variance))
    np.testing.assert_allclose(correction[0], expected, rtol=1e-10, atol=1e-10)
    if order == 2:                                    # the return sharpens the proposal
        assert variance < SIGMA**2


def test_a_missing_return_proposes_from_the_prior_with_no_correction(tmp_path):
    _, proposal = bound(tmp_path, 2)
    previous = np.full((2, 5000, 1), -1.0)
    state, correction = proposal.propose(previous, 3, np.array([[2.0], [np.nan]]), np.array([True, False]),
                                         TrialStreams.from_seeds([1, 2]))
    assert np.all(correction[1] == 0.0) and np.any(correction[0] != 0.0)
    m = MU + PHI * (-1.0 - MU)
    assert abs(state[1, :, 0].mean() - m) < 4 * SIGMA / math.sqrt(5000)


@pytest.mark.parametrize("order, look_ahead", [(1, "first_order"), (2, "second_order")])
def test_the_look_ahead_is_the_predictive_density_of_the_expansion(tmp_path, order, look_ahead):
    model, _ = bound(tmp_path, order, look_ahead)
    previous_value, y = -1.3, 1.2
    m = MU + PHI * (previous_value - MU)
    ratio = y**2 * math.exp(-m)
    value = -0.5 * (math.log(2 * math.pi) + m + ratio)
    slope, curvature = 0.5 * (ratio - 1), (-0.5 * ratio if order == 2 else 0.0)

    def integrand(x):
        approximation = value + slope * (x - m) + 0.5 * curvature * (x - m) ** 2
        return stats.norm.pdf(x, m, SIGMA) * math.exp(approximation)

    expected = math.log(integrate.quad(integrand, m - 12 * SIGMA, m + 12 * SIGMA, epsabs=0, epsrel=1e-12)[0])
    got = model.look_ahead_log_weight(np.array([[[previous_value]]]), 4, np.array([[[y]]]))
    assert got.shape == (1, 1) and got[0, 0] == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("look_ahead", ["point", "first_order", "second_order"])
def test_the_look_ahead_is_finite_at_extreme_returns(tmp_path, look_ahead):
    model, _ = bound(tmp_path, 2, look_ahead)
    previous = np.linspace(-20.0, 10.0, 61)[None, :, None].repeat(4, axis=0)
    measurement = np.array([0.0, 1e-8, 50.0, 1e3])[:, None, None]
    with np.errstate(over="raise"):
        weight = model.look_ahead_log_weight(previous, 2, measurement)
    assert weight.shape == (4, 61) and np.all(np.isfinite(weight))


def test_the_second_order_look_ahead_falls_where_the_first_order_one_explodes(tmp_path):
    """At a large return the first-order weight grows without bound as the predicted log-variance
    falls, against the true predictive density; the second-order one falls as the truth does."""
    first, _ = bound(tmp_path, 1, "first_order")
    second, _ = bound(tmp_path, 2, "second_order")
    previous = np.array([-6.0, -4.0, -2.0])[None, :, None]
    y = np.array([[[2.17]]])
    g1, g2 = first.look_ahead_log_weight(previous, 1, y)[0], second.look_ahead_log_weight(previous, 1, y)[0]
    assert g1[0] > g1[1] > g1[2]                   # favours the particles the return rules out
    assert g2[0] < g2[1] < g2[2]


@pytest.mark.parametrize("arm", ["bootstrap", "guided", "auxiliary"])
def test_the_likelihood_estimate_is_unbiased(tmp_path, arm):
    """E[exp(log L_hat - log L)] = 1: the mean over R runs is within 4 standard errors of 1 (the
    standard error from the runs themselves; at N = 25 on 20 returns the ratio's variance is
    about 0.1, so 4 standard errors are about +-0.03)."""
    arms = {"bootstrap": {}, "guided": {"proposal": "stochastic_volatility_taylor"},
            "auxiliary": {"proposal": "stochastic_volatility_taylor", "auxiliary": True}}
    raw = config(tmp_path, arms={arm: arms[arm]}, trials=2000)
    raw["filter"]["particles"] = 25
    folder = run_plan(build_plan(raw, str(tmp_path / "sv.yaml")), tmp_path / "out")
    estimates = pd.read_csv(folder / "trials.csv")["log_likelihood"].to_numpy()
    assert len(estimates) == 2000
    ratio = np.exp(estimates - quadrature_log_likelihood(returns()[:20]))
    standard_error = ratio.std(ddof=1) / math.sqrt(len(ratio))
    assert abs(ratio.mean() - 1.0) < 4 * standard_error, (ratio.mean(), standard_error)
    assert ratio.var() > 0.0


def test_the_histogram_filter_takes_the_constant_gain_and_matches_the_quadrature(tmp_path):
    """The model as the plugin writes it, x' = mu + phi (x - mu) + sigma w with w ~ N(0, 1): a
    constant gain sigma on the noise, which the histogram filter now takes (its axis variance is
    sigma^2). Its log-likelihood of all 201 returns equals the independent grid recursion of
    test_gbp_usd: both are the filtering recursion on a fine grid, whose error is < 1e-9 there."""
    data = tmp_path / "all-returns.csv"
    y = returns()
    pd.DataFrame({"step": range(1, len(y) + 1), "z1": y}).to_csv(data, index=False)
    raw = config(tmp_path, filter={"kind": "histogram", "grid": {"low": [-8.4], "high": [6.4], "cells": [3000]}},
                 data={"measurements": str(data)}, trials=1)
    run_plan(build_plan(raw, str(tmp_path / "sv.yaml")), tmp_path / "out", progress=False)
    log_likelihood = pd.read_csv(tmp_path / "out" / "trials.csv")["log_likelihood"].iloc[0]
    assert abs(log_likelihood - quadrature_log_likelihood(y)) < 1e-6
