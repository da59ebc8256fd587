"""Parameter estimation on the jax backend (pfx/estimation/compiled_*.py): the filter as a compiled
function of the parameters, PMMH's chains and IF2's swarm as compiled blocks.

The two backends draw from different generators, so these checks are backend-invariant ones:
the compiled likelihood estimate is unbiased for the Kalman filter's exact likelihood and agrees
with the NumPy backend's within Monte Carlo error; PMMH targets the exact posterior; IF2 climbs
into the likelihood-ratio region of the maximum. And what the runner promises on numpy holds on
jax: a stopped or extended run continues to the same numbers, proposals the model refuses are
rejected, and what the compiled path cannot do is refused by its key before anything runs."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_estimation import exact_log_likelihoods, nile_config, target_of

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.estimation.compiled_if2 import CompiledSwarm
from pfx.estimation.compiled_pmmh import CompiledChains
from pfx.estimation.if2 import IteratedFiltering
from pfx.estimation.pmmh import ParticleMarginalMetropolisHastings
from pfx.estimation.target import EstimationTarget, dataset
from pfx.numerics.seeding import chain_seeds
from pfx.papers.estimation_nile_exact import local_level_log_likelihood

pytest.importorskip("jax")

ROOT = Path(__file__).resolve().parents[1]
DURBIN_KOOPMAN = np.array([[15099.0, 1469.1]])


def on_jax(config: dict) -> dict:
    config = copy.deepcopy(config)
    config["filter"]["backend"] = "jax"
    return config


def sv_config(backend: str) -> dict:
    """The stochastic-volatility plugin on the GBP/USD returns: its initial law is the stationary
    one, N(mu, sigma^2 / (1 - phi^2)), so it follows the estimated parameters."""
    return {"name": "sv", "seed": 3, "plugins": [str(ROOT / "examples" / "plugins" / "stochastic_volatility.py")],
            "model": {"kind": "stochastic_volatility", "mu": -1.0, "phi": 0.9, "sigma": 0.3},
            "data": {"measurements": str(ROOT / "examples" / "data" / "gbp-usd-returns.csv")},
            "filter": {"particles": 200, "resampler": "systematic", "ess_threshold": 0.5, "backend": backend},
            "estimation": {"method": "pmmh", "chains": 2, "iterations": 10, "warm_up": 5, "parameters": {
                "model.mu": {"prior": {"law": "normal", "mean": 0.0, "sd": 2.0}, "start": -1.0, "proposal_sd": 0.2},
                "model.phi": {"prior": {"law": "beta", "a": 9.0, "b": 1.0}, "start": 0.9, "proposal_sd": 0.5},
                "model.sigma": {"prior": {"law": "gamma", "shape": 2.0, "rate": 2.0}, "start": 0.3,
                                "proposal_sd": 0.4}}}}


def estimates(target: EstimationTarget, point: np.ndarray, runs: int, seed: int) -> np.ndarray:
    return target.log_likelihoods(np.repeat(point, runs, axis=0), [chain_seeds(seed, 0, r, 1)[0] for r in range(runs)])


def test_the_compiled_likelihood_is_unbiased_and_agrees_with_numpy():
    """E[L_hat / L] = 1 (the bootstrap filter's estimate is unbiased): the mean of 256 ratios is
    within 4 standard errors of 1; the mean log-likelihood estimates of the two backends agree
    within 4 standard errors of their difference."""
    config = nile_config()
    config["filter"]["particles"] = 500
    _, numpy_target = target_of(config)
    _, jax_target = target_of(on_jax(config))
    exact = exact_log_likelihoods(DURBIN_KOOPMAN)[0]
    on_numpy, compiled = estimates(numpy_target, DURBIN_KOOPMAN, 256, 1), estimates(jax_target, DURBIN_KOOPMAN, 256, 2)
    ratios = np.exp(compiled - exact)
    assert abs(ratios.mean() - 1.0) < 4 * ratios.std(ddof=1) / np.sqrt(len(ratios)), ratios.mean()
    error = np.hypot(on_numpy.std(ddof=1), compiled.std(ddof=1)) / np.sqrt(256)
    assert abs(on_numpy.mean() - compiled.mean()) < 4 * error, (on_numpy.mean(), compiled.mean(), error)
    # a row's estimate depends on its parameters and seed only, not on the rows beside it (4 rows:
    # the program IF2's 4 replicates at 500 particles check their starts with, compiled once)
    rows = np.array([[8000.0, 500.0], *np.repeat(DURBIN_KOOPMAN, 3, axis=0)])
    beside = jax_target.log_likelihoods(rows, [chain_seeds(2, 0, r, 1)[0] for r in range(4)])
    assert np.all(beside[1:] == compiled[1:4]) and np.isfinite(beside[0]) and beside[0] != compiled[0]


def test_an_initial_law_that_follows_the_parameters_is_drawn_per_row():
    """The stochastic-volatility model's stationary initial law, at two points whose laws differ:
    each row's mean log-likelihood estimate agrees with the NumPy backend's (4 standard errors)."""
    points = np.array([[-1.0, 0.9, 0.3], [-0.2, 0.5, 0.8]])
    results = {}
    for backend in ("numpy", "jax"):
        plan = build_plan(sv_config(backend), "sv.yaml")
        cell = plan.cells[0]
        target = EstimationTarget(cell, plan.experiment.estimation, dataset(cell, plan.experiment.seed))
        if backend == "jax":
            assert target.compiled_filter.follows
        results[backend] = np.stack([estimates(target, point[None], 128, 5 + len(results)) for point in points])
    for row in range(len(points)):
        first, second = results["numpy"][row], results["jax"][row]
        error = np.hypot(first.std(ddof=1), second.std(ddof=1)) / np.sqrt(len(first))
        assert abs(first.mean() - second.mean()) < 4 * error, (row, first.mean(), second.mean(), error)


def test_an_extended_jax_pmmh_run_equals_one_long_run(tmp_path):
    """Blocks end where the run stops; the chains carry the points the table holds, so a run
    extended from its folder continues to the same numbers (across the warm-up's end too).
    Every run compiles its own block programs, one per block length (their host callback keeps
    them out of JAX's compilation cache): the long run's two blocks, the warm-up's 8 iterations
    and 8 after it, are one program."""
    config = on_jax(nile_config(iterations=16, warm_up=8, adapt=True, adapt_after=4))
    long = pfx.run(config, out=tmp_path / "long")
    short = copy.deepcopy(config)
    short["estimation"]["iterations"] = 11
    pfx.run(short, out=tmp_path / "short")
    extended = pfx.run(config, out=tmp_path / "short")
    left, right = (pd.read_csv(Path(result.folder) / "chains.csv") for result in (long, extended))
    pd.testing.assert_frame_equal(left, right)
    assert len(left) == 4 * 17 and left["accepted"].any()
    assert set(left["backend"]) == {"jax"}


def test_jax_if2_resumes_to_the_same_numbers(tmp_path):
    """A run stopped after pass 2 and extended to pass 4 (blocks 1-2 and 3-4) ends where one run
    of a block of 4 passes ends. 4 replicates: the starts' check (4 rows) and the final
    evaluations (10 a replicate, 40 rows) are the likelihood programs the PMMH runs of this file
    compile too (their starts, their likelihood spread's 40 runs), compiled once."""
    config = on_jax(nile_config("if2", iterations=4, chains=4))
    whole = pfx.run(config, out=tmp_path / "whole")
    part = copy.deepcopy(config)
    part["estimation"]["iterations"] = 2
    pfx.run(part, out=tmp_path / "part")
    extended = pfx.run(config, out=tmp_path / "part")
    for name in ("if2.csv", "maximum_likelihood.csv"):
        left, right = (pd.read_csv(Path(result.folder) / name) for result in (whole, extended))
        pd.testing.assert_frame_equal(left, right)


def test_a_proposal_the_model_refuses_is_rejected_on_jax():
    """The measurement variance on its natural scale (transform: none) under a prior reaching
    below zero: proposals there are refused by the model (the host's check, as on numpy), get
    -inf and are rejected; the chains stay where the model is defined."""
    config = on_jax(nile_config(iterations=20, chains=4))
    parameter = config["estimation"]["parameters"]["model.process_noise.variance"]
    parameter.update(prior={"law": "uniform", "lower": -5000.0, "upper": 100000.0}, transform="none", start=300.0,
                     proposal_sd=800.0)
    plan, target = target_of(config)
    sampler = CompiledChains(ParticleMarginalMetropolisHastings(target, plan.experiment.seed, plan.cells[0].stream_key))
    refused, checked = [], sampler.host_view

    def counting(proposed):
        view = checked(proposed)
        refused.append(int(np.sum(np.isfinite(view[2]) & ~view[4])))      # inside the prior, refused by the model
        return view

    sampler.host_view = counting
    chains, accepted = sampler.start(), []
    sampler.run(chains, 1, 20, lambda iteration, accept: accepted.append(accept))
    history = np.stack(chains.history)
    assert sum(refused) > 0 and np.all(history[..., 1] > 0) and np.all(np.isfinite(chains.log_likelihood))
    assert len(accepted) == 20 and any(a.any() for a in accepted)


@pytest.mark.slow        # 16 chains x 500 iterations, as the NumPy backend's check
def test_jax_pmmh_recovers_the_posterior_of_the_exact_likelihood():
    """As tests/test_estimation.py's check of the NumPy backend: the posterior means of the compiled
    chains agree with the exact posterior's (a grid of the Kalman likelihood) within 4 MCSE."""
    from arviz_stats.base import array_stats

    plan, target = target_of(on_jax(nile_config(iterations=500, warm_up=150, chains=16)))
    sampler = CompiledChains(ParticleMarginalMetropolisHastings(target, plan.experiment.seed, plan.cells[0].stream_key))
    state = sampler.start()
    sampler.run(state, 1, 500, lambda iteration, accepted: None)
    draws = np.stack(state.history[151:], axis=1)
    first, second = np.meshgrid(np.geomspace(2000.0, 80000.0, 48), np.geomspace(5.0, 60000.0, 48), indexing="ij")
    points = np.column_stack([first.ravel(), second.ravel()])
    # the Kalman filter's exact likelihood, its recursion vectorised over the grid (the two are
    # equal: tests/test_estimation_nile.py)
    flows = pd.read_csv(ROOT / "examples" / "data" / "nile.csv")["z1"].to_numpy(dtype=float)
    exact = local_level_log_likelihood(flows, points[:, 0], points[:, 1], 0.0, 1.0e7)
    log_posterior = exact + np.log(points).sum(axis=1)
    weights = np.exp(log_posterior - log_posterior.max())
    exact_means = (weights / weights.sum()) @ points
    for j in range(2):
        mean = draws[..., j].mean()
        error = float(array_stats.mcse(draws[..., j], chain_axis=0, draw_axis=1, method="mean"))
        assert abs(mean - exact_means[j]) < 4 * error, (j, mean, exact_means[j], error)


def test_jax_if2_climbs_into_the_likelihood_ratio_region_of_the_maximum():
    """As the NumPy backend's check: from starts a factor 3-10 away, every replicate's estimate
    after 50 passes has an exact log-likelihood within 3.0 (chi2_2(0.95) / 2) of the maximum."""
    from scipy.optimize import minimize

    starts = {"model.measurement_noise.variance": [3000.0, 60000.0, 5000.0, 40000.0],
              "model.process_noise.variance": [15000.0, 150.0, 300.0, 10000.0]}
    config = on_jax(nile_config("if2", iterations=50, chains=4))
    config["filter"]["particles"] = 500
    for path, values in starts.items():
        config["estimation"]["parameters"][path].update(start=values, random_walk_sd=0.15)
    plan, target = target_of(config)
    method = IteratedFiltering(target, plan.experiment.seed, plan.cells[0].stream_key)
    passes = []
    swarm = CompiledSwarm(method).run(method.start(), 1, 50, lambda iteration, swarm, log_l: passes.append(iteration))
    assert passes == list(range(1, 51))
    best = minimize(lambda u: -exact_log_likelihoods(np.exp(u)[None])[0], np.log([15099.0, 1469.1]),
                    method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6})
    found = method.estimates(swarm)
    assert np.all(exact_log_likelihoods(found) > -best.fun - 3.0), (found, np.exp(best.x))


def test_what_the_compiled_estimation_cannot_do_is_refused_by_its_key(tmp_path):
    """A parameter the model cannot take as an array (dt) is refused on jax before anything is
    written."""
    config = on_jax(nile_config())
    config["estimation"]["parameters"]["model.dt"] = {"prior": {"law": "uniform", "lower": 0.5, "upper": 2.0},
                                                      "start": 1.0}
    with pytest.raises(ConfigError) as error:
        pfx.run(config, out=tmp_path / "out")
    assert error.value.key == "estimation.parameters.model.dt" and "vectorised_parameters" in str(error.value)
    assert not (tmp_path / "out").exists()
