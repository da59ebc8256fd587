"""Parameter estimation (PMMH, IF2): transforms, per-row parameters, batching, seeding, resume,
and the Nile local level against its exact (Kalman) likelihood."""

from __future__ import annotations

import copy
import functools
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.estimation.if2 import IteratedFiltering
from pfx.estimation.pmmh import ParticleMarginalMetropolisHastings
from pfx.estimation.target import EstimationTarget, dataset
from pfx.laws.priors import make_transform
from pfx.numerics.seeding import TrialStreams
from pfx.papers.estimation_nile_exact import local_level_log_likelihood

ROOT = Path(__file__).resolve().parents[1]
NILE = str(ROOT / "examples" / "data" / "nile.csv")


def nile_config(method="pmmh", **estimation):
    config = {
        "name": "nile-estimation", "seed": 7,
        "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                  "names": ["level"], "process_noise": {"variance": 1469.1},
                  "measurement_noise": {"variance": 15099.0},
                  "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0e7}},
        "data": {"measurements": NILE},
        "filter": {"particles": 100, "resampler": "systematic", "ess_threshold": 0.5},
        "estimation": {"method": method, "chains": 4, "iterations": 20, "warm_up": 5 if method == "pmmh" else 0,
                       "parameters": {
                           "model.measurement_noise.variance": {"prior": {"law": "uniform", "lower": 1.0,
                                                                          "upper": 100000.0},
                                                                "start": 12000.0, "proposal_sd": 0.3},
                           "model.process_noise.variance": {"prior": {"law": "uniform", "lower": 1.0,
                                                                      "upper": 100000.0},
                                                            "start": 2000.0, "proposal_sd": 0.5}}}}
    if method == "if2":                      # PMMH's proposal, which an IF2 config refuses
        for parameter in config["estimation"]["parameters"].values():
            del parameter["proposal_sd"]
    config["estimation"].update(estimation)
    config["outputs"] = {"figures": []}      # the numbers are checked here; tests/test_estimation_figures.py draws
    return config


def target_of(config, cell=0):
    plan = build_plan(copy.deepcopy(config), "nile.yaml")
    chosen = plan.cells[cell]
    return plan, EstimationTarget(chosen, plan.experiment.estimation, dataset(chosen, plan.experiment.seed))


# -- transforms and priors -----------------------------------------------------------------------

@pytest.mark.parametrize("name, support, point", [("log", (0.0, math.inf), 2.5), ("logit", (-1.0, 1.0), 0.3),
                                                  ("none", (-math.inf, math.inf), -4.0), ("log", (2.0, math.inf), 3.0)])
def test_transform_round_trip_and_jacobian(name, support, point):
    transform = make_transform(name, support)
    u = float(transform.to_unconstrained(point))
    assert float(transform.to_natural(u)) == pytest.approx(point, rel=1e-12)
    step = 1e-6
    derivative = (float(transform.to_natural(u + step)) - float(transform.to_natural(u - step))) / (2 * step)
    assert float(transform.log_jacobian(u)) == pytest.approx(math.log(derivative), abs=1e-7)


def test_transform_follows_the_prior_support_and_refuses_a_mismatch():
    assert make_transform(None, (0.0, math.inf)).name == "log"
    assert make_transform(None, (0.0, 1.0)).name == "logit"
    assert make_transform(None, (-math.inf, math.inf)).name == "none"
    with pytest.raises(ValueError, match="@transform"):
        make_transform("log", (-math.inf, math.inf))


def test_row_variances_scale_each_row_and_its_density():
    model = pfx.model("linear_gaussian", steps=5, transition_matrix=[[1.0]], measurement_matrix=[[1.0]])
    variances = np.array([0.5, 4.0, 25.0])
    stacked = model.with_parameter_arrays({"process_noise.variance": variances[:, None, None],
                                           "measurement_noise.variance": variances[:, None, None]})
    draws = stacked.process_noise.sample(TrialStreams.from_seeds([1, 2, 3]), (20000,))
    # the sample sd of n normal draws has relative standard error 1 / sqrt(2 n) = 0.005: 5 of them
    assert np.allclose(draws.std(axis=(1, 2)) / np.sqrt(variances), 1.0, atol=0.025)
    residual = np.array([0.3, -1.0, 2.0])[:, None, None] * np.ones((3, 4, 1))
    expected = -0.5 * (np.log(2 * np.pi * variances)[:, None] + residual[..., 0] ** 2 / variances[:, None])
    assert np.allclose(stacked.log_likelihood(np.zeros((3, 1, 1)), -residual), expected, rtol=1e-12)


def test_a_model_refuses_arrays_for_a_parameter_it_does_not_declare():
    model = pfx.model("linear_gaussian", steps=5, transition_matrix=[[1.0]], measurement_matrix=[[1.0]])
    with pytest.raises(ValueError, match="vectorised_parameters"):
        model.with_parameter_arrays({"dt": np.ones((2, 1, 1))})


# -- batching and seeding --------------------------------------------------------------------------

def test_batched_rows_give_the_numbers_of_one_filter_per_row():
    _, target = target_of(nile_config())
    assert target.batched
    values = np.array([[12000.0, 2000.0], [15099.0, 1469.1], [8000.0, 500.0]])
    batched = target.log_likelihoods(values, [11, 12, 13])
    target.batched = False
    one_by_one = target.log_likelihoods(values, [11, 12, 13])
    assert np.allclose(batched, one_by_one, rtol=0, atol=1e-9)
    # and a row's number does not depend on the other rows
    target.batched = True
    assert target.log_likelihoods(values[1:2], [12])[0] == pytest.approx(batched[1], abs=1e-9)


def test_a_chain_does_not_depend_on_how_many_chains_run_beside_it():
    results = []
    for chains in (2, 4):
        plan, target = target_of(nile_config(chains=chains))
        sampler = ParticleMarginalMetropolisHastings(target, plan.experiment.seed, plan.cells[0].stream_key)
        state = sampler.start()
        sampler.run(state, 1, 15, lambda iteration, accepted: None)
        results.append(np.stack(state.history)[:, :2])
    assert np.array_equal(results[0], results[1])


def test_values_outside_the_prior_are_rejected_without_running_the_filter():
    plan, target = target_of(nile_config())
    sampler = ParticleMarginalMetropolisHastings(target, plan.experiment.seed, plan.cells[0].stream_key)
    state = sampler.start()
    state.values[0] = [99999.0, 99999.0]          # at the prior's edge: most proposals fall outside
    calls = []
    original = target.log_likelihoods
    target.log_likelihoods = lambda values, seeds: calls.append(len(values)) or original(values, seeds)
    accepted = sampler.iterate(state, 1)
    assert sum(calls) <= 4 and np.all(np.isfinite(state.log_prior))
    assert accepted.dtype == bool


def test_an_extended_run_equals_one_long_run(tmp_path):
    long = pfx.run(nile_config(iterations=24), out=tmp_path / "long")
    pfx.run(nile_config(iterations=12), out=tmp_path / "short")
    extended = pfx.run(nile_config(iterations=24), out=tmp_path / "short")
    left, right = (pd.read_csv(Path(result.folder) / "chains.csv") for result in (long, extended))
    pd.testing.assert_frame_equal(left, right)
    assert len(left) == 4 * 25
    with pytest.raises(ConfigError, match="would drop"):
        pfx.run(nile_config(iterations=10), out=tmp_path / "short")


def test_if2_resumes_to_the_same_numbers(tmp_path):
    config = nile_config("if2", iterations=6, chains=2)
    whole = pfx.run(config, out=tmp_path / "whole")
    pfx.run(nile_config("if2", iterations=3, chains=2), out=tmp_path / "part")
    extended = pfx.run(config, out=tmp_path / "part")
    for name in ("if2.csv", "maximum_likelihood.csv"):
        left, right = (pd.read_csv(Path(result.folder) / name) for result in (whole, extended))
        pd.testing.assert_frame_equal(left, right)


# -- bad input ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("change, key", [
    (lambda e: e["parameters"].update({"model.nothing_here": {"prior": {"law": "normal", "sd": 1.0}}}),
     "estimation.parameters.model.nothing_here"),
    (lambda e: e["parameters"].update({"mu": {"prior": {"law": "normal", "sd": 1.0}}}), "estimation"),
    (lambda e: e.update(warm_up=30), "estimation"),
    (lambda e: e["parameters"]["model.process_noise.variance"].update(start=-3.0), "estimation"),
    (lambda e: e["parameters"]["model.process_noise.variance"].update(transform="logit",
                                                                       prior={"law": "gamma", "shape": 2.0}),
     "estimation"),
    (lambda e: e["parameters"]["model.process_noise.variance"].update(start="prior",
                                                                       prior={"law": "flat", "lower": 0.0}),
     "estimation.parameters.model.process_noise.variance.start"),
])
def test_bad_estimation_settings_name_their_key(change, key):
    config = nile_config()
    change(config["estimation"])
    with pytest.raises(ConfigError) as error:
        build_plan(config, "nile.yaml")
    assert (error.value.key or "").startswith(key)


def test_if2_refuses_a_parameter_the_model_cannot_vary_per_particle():
    config = nile_config("if2")
    config["model"]["transition_matrix"] = [[1.0]]
    config["estimation"]["parameters"]["model.dt"] = {"prior": {"law": "uniform", "lower": 0.5, "upper": 2.0},
                                                      "start": 1.0}
    with pytest.raises(ConfigError, match="vectorised_parameters"):
        build_plan(config, "nile.yaml")


# -- the Nile local level against its exact likelihood ------------------------------------------------

@functools.lru_cache(maxsize=None)
def nile_flows() -> np.ndarray:
    return pd.read_csv(NILE)["z1"].to_numpy(dtype=float)


def exact_log_likelihoods(values):
    """The Kalman filter's exact log-likelihood at each row of values (measurement, process
    variance): its recursion written for arrays, equal to pfx's ``kf`` on this model to 1e-9
    (tests/test_estimation_nile.py), which costs a plan and a model per row, tens of times the
    recursion, at each of an optimiser's calls."""
    initial = nile_config()["model"]["initial"]
    values = np.asarray(values, dtype=float)
    return local_level_log_likelihood(nile_flows(), values[:, 0], values[:, 1], initial["mean"][0], initial["covariance"])


@pytest.mark.slow        # 16 chains x 500 iterations: the Monte Carlo error the comparison needs
def test_pmmh_recovers_the_posterior_of_the_exact_likelihood():
    """PMMH with a particle filter targets the exact posterior: its posterior means agree with the
    means under the Kalman likelihood, integrated on a grid (uniform priors), within 4 Monte Carlo
    standard errors (ArviZ's MCSE of the mean, from the chains' own autocorrelation)."""
    from arviz_stats.base import array_stats

    # 16 chains of 350 draws after the warm-up rather than 4 of 1200: as many draws, a quarter of
    # the filter calls (the chains advance as one batch), and more chains for the MCSE to see
    plan, target = target_of(nile_config(iterations=500, warm_up=150, chains=16))
    sampler = ParticleMarginalMetropolisHastings(target, plan.experiment.seed, plan.cells[0].stream_key)
    state = sampler.start()
    sampler.run(state, 1, 500, lambda iteration, accepted: None)
    draws = np.stack(state.history[151:], axis=1)                        # (chains, draws, 2)
    # The grid: log-spaced, so each point stands for a cell of area proportional to theta_1 theta_2.
    first, second = np.meshgrid(np.geomspace(2000.0, 80000.0, 48), np.geomspace(5.0, 60000.0, 48), indexing="ij")
    points = np.column_stack([first.ravel(), second.ravel()])
    # the Kalman filter's exact likelihood, its recursion vectorised over the grid (the two are
    # equal: tests/test_estimation_nile.py)
    exact = local_level_log_likelihood(nile_flows(), points[:, 0], points[:, 1], 0.0, 1.0e7)
    log_posterior = exact + np.log(points).sum(axis=1)
    weights = np.exp(log_posterior - log_posterior.max())
    weights /= weights.sum()
    exact_means = weights @ points
    for j in range(2):
        mean = draws[..., j].mean()
        error = float(array_stats.mcse(draws[..., j], chain_axis=0, draw_axis=1, method="mean"))
        assert abs(mean - exact_means[j]) < 4 * error, (j, mean, exact_means[j], error)


def test_if2_climbs_into_the_likelihood_ratio_region_of_the_maximum():
    """From starts a factor 3-10 away, IF2's estimates end where the exact log-likelihood is within
    3.0 of its maximum (the 95% likelihood-ratio region for two parameters: chi2_2(0.95) / 2)."""
    starts = {"model.measurement_noise.variance": [3000.0, 60000.0, 5000.0, 40000.0],
              "model.process_noise.variance": [15000.0, 150.0, 300.0, 10000.0]}
    config = nile_config("if2", iterations=50, chains=4)
    config["filter"]["particles"] = 500
    for path, values in starts.items():
        config["estimation"]["parameters"][path].update(start=values, random_walk_sd=0.15)
    plan, target = target_of(config)
    method = IteratedFiltering(target, plan.experiment.seed, plan.cells[0].stream_key)
    swarm = method.start()
    for iteration in range(1, 51):
        swarm, _ = method.iterate(swarm, iteration)
    estimates = method.estimates(swarm)
    # the maximum of the exact likelihood (this prior, not the diffuse one), by a fine search
    from scipy.optimize import minimize

    best = minimize(lambda u: -exact_log_likelihoods(np.exp(u)[None])[0], np.log([15099.0, 1469.1]),
                    method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6})
    assert np.all(exact_log_likelihoods(estimates) > -best.fun - 3.0), (estimates, np.exp(best.x))


def test_an_estimation_config_has_no_trials():
    config = nile_config()
    config["trials"] = 5
    with pytest.raises(ConfigError) as error:
        build_plan(config, "nile.yaml")
    assert error.value.key == "trials"
    plan = build_plan(nile_config(), "nile.yaml")
    assert "trials" not in plan.resolved and plan.size_text == "1 cell(s) x 4 chain(s) x 20 iteration(s)"


def test_the_result_of_an_estimation_run_lists_its_tables_and_prints_its_posterior(tmp_path, capsys):
    result = pfx.run(nile_config(), out=tmp_path / "run", quiet=False)
    # 15 draws per chain are flagged, and the particle filter's spread measured (likelihood_spread.csv)
    assert result.table_names == ["chains", "posterior", "priors", "likelihood_spread"]
    assert list(result.posterior["parameter"]) == ["measurement_noise.variance", "process_noise.variance",
                                                   "log_likelihood"]
    assert len(result.chains) == 4 * 21 and "trials" not in result.manifest
    printed = capsys.readouterr().out
    assert "posterior after the warm-up" in printed and "process_noise.variance" in printed
    again = pfx.run(nile_config(), out=tmp_path / "run")          # up to date: the same tables, times summed
    assert again.chains.equals(result.chains)
    first, second = result.manifest["wall_time_s"], again.manifest["wall_time_s"]
    assert second >= first


def test_a_value_the_filter_refuses_is_rejected_not_an_error(monkeypatch):
    """A filter's set-up may refuse the model at some parameters (a histogram filter's grid that
    cannot cover it): that value gets likelihood zero; the chain goes on."""
    from pfx.filters import FILTERS

    config = nile_config()
    config["filter"] = {"kind": "kf"}
    _, target = target_of(config)
    plan_of = FILTERS["kf"].plan

    def refusing(model, settings, prior):
        if model.process_noise.variance > 50000:
            raise ValueError("@grid: cannot cover the model there")
        return plan_of(model, settings, prior)

    monkeypatch.setattr(FILTERS["kf"], "plan", refusing)
    values = target.log_likelihoods(np.array([[15099.0, 1469.1], [15099.0, 60000.0]]), [1, 2])
    assert np.isfinite(values[0]) and values[1] == -np.inf


def test_set_reaches_the_settings_of_an_estimated_parameter():
    """A parameter's key is itself a dotted path, so `--set` enters `estimation.parameters` at
    the longest key the path continues with."""
    from pfx.config.overrides import apply_overrides

    path = "estimation.parameters.model.process_noise.variance"
    raw, notes = apply_overrides(nile_config(), [f"{path}.proposal_sd=0.8", f"{path}.prior.upper=50000",
                                                 "estimation.chains=2"], "nile.yaml")
    assert notes == []
    plan = build_plan(raw, "nile.yaml")
    settings = plan.experiment.estimation.parameters["model.process_noise.variance"]
    assert settings.proposal_sd == 0.8 and settings.prior.upper == 50000.0
    assert plan.experiment.estimation.parameters["model.measurement_noise.variance"].proposal_sd == 0.3
    assert set(raw["estimation"]["parameters"]) == {"model.measurement_noise.variance",
                                                    "model.process_noise.variance"}
    misspelt, _ = apply_overrides(nile_config(), [f"{path}x.proposal_sd=0.8"], "nile.yaml")
    with pytest.raises(ConfigError, match="dotted path into the model") as error:
        build_plan(misspelt, "nile.yaml")
    assert error.value.key == "estimation.parameters.model"
