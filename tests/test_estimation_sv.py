"""The estimation-sv benchmark (docs/benchmarks/estimation-sv.md): its autocorrelation times, the
N-choice theory it compares with, and its report on small synthetic result folders.

* both estimators of the integrated autocorrelation time recover tau = (1 + rho) / (1 - rho) of
  AR(1) chains, and the bootstrap's standard error of batch means matches its theory;
* the theory's two limits have their minima where Pitt et al. (2012) and Doucet et al. (2015)
  put them (0.92, 1.68); the noise's mean acceptance is 2 Phi(-sigma / sqrt 2); a simulated
  pseudo-marginal chain in the perfect limit has the inefficiency IF_1(sigma);
* the report's verdicts follow the numbers: posterior means within 3 combined Monte Carlo errors
  of particles' agree (and a shifted one does not), the published posterior and the other data
  are "not comparable", and the N-choice verdict is reproduced when the cheapest N has sd of
  log L_hat in [0.92, 1.68] and not when it lies outside; the figure draws the curve;
* the repository leaves n-choice's chains out: the table `pfx reproduce` keeps of them gives the
  same section, to the digit, as the chains, and a folder with neither says its results are
  missing instead of dropping the verdict.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT
from scipy import optimize, stats

from pfx.analysis.autocorrelation import (
    autocorrelation_time,
    batch_means_time,
    inefficiency_table,
    mean_over_parameters,
)
from pfx.figures.pmmh_efficiency import inefficiency_vs_particles
from pfx.papers.base import REPORTS, VERDICTS, PaperResults
from pfx.papers.estimation_sv import (
    REPRODUCE,
    WORK_TABLE,
    inefficiency_perfect,
    noise_acceptance,
    relative_inefficiency_slow,
    work,
)
from pfx.papers.reproduce import write_kept_tables
from pfx.result_folder import ResultFolder

PAPER = REPO_ROOT / "configs" / "benchmarks" / "estimation-sv" / "paper.yaml"


def ar1_chains(rho: float, chains: int, length: int, seed: int) -> np.ndarray:
    """Stationary AR(1) chains x_t = rho x_(t-1) + sqrt(1 - rho^2) e_t, shaped (chains, length):
    N(0, 1) marginals and tau = (1 + rho) / (1 - rho)."""
    generator = np.random.default_rng(seed)
    noise = generator.standard_normal((chains, length))
    draws = np.empty_like(noise)
    draws[:, 0] = noise[:, 0]
    scale = math.sqrt(1.0 - rho**2)
    for t in range(1, length):
        draws[:, t] = rho * draws[:, t - 1] + scale * noise[:, t]
    return draws


# -- the two estimators -----------------------------------------------------------------------------

def test_both_estimators_recover_the_autocorrelation_time_of_ar1_chains():
    rho, chains, length = 0.8, 1000, 1000
    tau = (1 + rho) / (1 - rho)                      # 9
    draws = ar1_chains(rho, chains, length, seed=26)
    # batch means: relative standard error sqrt(2 / (C - 1)) = 0.045; its bias, -2 rho / (L (1 - rho)^2 tau),
    # is 0.2 %: four standard errors
    assert abs(batch_means_time(draws) / tau - 1) < 4 * math.sqrt(2 / (chains - 1))
    # ArviZ: Geyer's truncated sum over n = 1e6 draws, relative sd about sqrt(2 (2M + 1) / n) with a
    # window M of a few tau (M = 30: 1.1 %): 5 % is four and a half of them
    assert abs(autocorrelation_time(draws) / tau - 1) < 0.05


def test_the_bootstrap_standard_error_of_batch_means_matches_its_theory():
    rho, chains, length, replicates = 0.8, 100, 1000, 100
    tau = (1 + rho) / (1 - rho)
    draws = ar1_chains(rho, chains, length, seed=27)
    frame = pd.DataFrame({"n_particles": 10, "chain": np.repeat(np.arange(chains), length),
                          "iteration": np.tile(np.arange(length), chains), "x": draws.ravel()})
    table, resampled = inefficiency_table(frame, ["x"], ["n_particles"], np.random.default_rng(1), replicates)
    batch = table[table["estimator"] == "batch means"].iloc[0]
    theory = tau * math.sqrt(2 / (chains - 1))       # the sd of the variance ratio over C - 1 degrees of freedom
    # a standard deviation from B replicates is itself uncertain by 1 / sqrt(2 (B - 1)) = 7 %: four of them,
    # and a little for the bootstrap's own O(1/C) bias
    assert abs(batch["tau_se"] / theory - 1) < 0.35
    assert batch["cost"] == pytest.approx(10 * batch["tau"]) and batch["cost_se"] == pytest.approx(10 * batch["tau_se"])
    assert len(resampled) == 2 * replicates and set(resampled["replicate"]) == set(range(replicates))
    mean = mean_over_parameters(table, resampled, ["n_particles"])
    assert set(mean["estimator"]) == {"ArviZ ESS", "batch means"}
    assert mean.set_index("estimator").loc["batch means", "cost_se"] == pytest.approx(batch["cost_se"])


# -- the theory of the N-choice rule ----------------------------------------------------------------

def test_the_two_limits_have_their_published_optima():
    perfect = optimize.minimize_scalar(lambda s: work("perfect", s), bounds=(0.3, 3.0), method="bounded",
                                       options={"xatol": 1e-6})
    inefficient = optimize.minimize_scalar(lambda s: work("inefficient", s), bounds=(0.3, 3.0), method="bounded",
                                           options={"xatol": 1e-6})
    assert perfect.x == pytest.approx(0.92, abs=0.005)          # Pitt, Silva, Giordani & Kohn (2012)
    assert inefficient.x == pytest.approx(1.68, abs=0.005)      # Doucet, Pitt, Deligiannidis & Kohn (2015)


@pytest.mark.parametrize("sigma", [0.5, 1.2, 2.0])
def test_the_noise_acceptance_is_its_definition_and_averages_to_the_closed_form(sigma):
    # alpha(z) = E min(1, exp(W - z)), W ~ N(-sigma^2/2, sigma^2): 4 Monte Carlo standard errors
    generator = np.random.default_rng(3)
    w = generator.normal(-0.5 * sigma**2, sigma, 400_000)
    for z in (-1.0, 0.3, 2.0):
        draws = np.minimum(1.0, np.exp(w - z))
        assert abs(draws.mean() - noise_acceptance(np.array(z), sigma)) < 4 * draws.std() / math.sqrt(w.size)
    # its mean under the stationary law of the current error, N(sigma^2/2, sigma^2), is 2 Phi(-sigma / sqrt 2)
    z = np.random.default_rng(4).normal(0.5 * sigma**2, sigma, 400_000)
    values = noise_acceptance(z, sigma)
    assert abs(values.mean() - 2 * stats.norm.cdf(-sigma / math.sqrt(2))) < 4 * values.std() / math.sqrt(z.size)
    assert relative_inefficiency_slow(sigma) == pytest.approx(1 / (2 * stats.norm.cdf(-sigma / math.sqrt(2))))


def test_a_simulated_pseudo_marginal_chain_in_the_perfect_limit_has_the_stated_inefficiency():
    """The exact chain proposes independent posterior draws and always accepts; the noisy chain
    accepts a fresh error W with probability min(1, exp(W - z)) and otherwise stays: the
    inefficiency of h = the (standard normal) draw is IF_1(sigma)."""
    sigma, chains, length = 1.0, 400, 5000
    generator = np.random.default_rng(5)
    z = generator.normal(0.5 * sigma**2, sigma, chains)          # start in the stationary law of the error
    h = generator.standard_normal(chains)
    draws = np.empty((chains, length))
    for t in range(length):
        w = generator.normal(-0.5 * sigma**2, sigma, chains)
        accept = np.log(generator.random(chains)) < w - z
        z = np.where(accept, w, z)
        h = np.where(accept, generator.standard_normal(chains), h)
        draws[:, t] = h
    expected = inefficiency_perfect(sigma)                           # 5.43
    # 2e6 draws of a chain with tau about 5.4: ArviZ's estimate is good to about 2 %; 8 % is four of that
    assert abs(autocorrelation_time(draws) / expected - 1) < 0.08


# -- the report, on synthetic folders ---------------------------------------------------------------

def write_folder(path, manifest: dict, config: dict, tables: dict) -> None:
    path.mkdir(parents=True)
    (path / "manifest.json").write_text(json.dumps({"complete": True, "wall_time_s": 1.0, **manifest}))
    (path / "config.yaml").write_text(yaml.safe_dump(config))
    for name, frame in tables.items():
        frame.to_csv(path / f"{name}.csv", index=False)


def posterior_folder(root, shift_mu: float = 0.0) -> None:
    """A posterior whose means are particles' (paper.yaml) plus, for mu, ``shift_mu`` combined errors."""
    reference = yaml.safe_load(PAPER.read_text())["particles_reference"]["parameters"]
    mcse = 0.005
    rows = []
    for name, theirs in (("mu", reference["mu"]), ("phi", reference["rho"]), ("sigma", reference["sigma"])):
        mean = theirs["mean"] + (shift_mu * math.hypot(mcse, theirs["mcse_mean"]) if name == "mu" else 0.0)
        rows.append({"parameter": name, "n": 1000, "mean": mean, "sd": theirs["sd"], "quantile_2_5": mean - 0.4,
                     "median": mean, "quantile_97_5": mean + 0.4, "r_hat": 1.002, "ess_bulk": 900.0,
                     "ess_tail": 900.0, "mcse_mean": mcse, "acceptance_rate": 0.18, "chains": 4})
    rows.append({**rows[0], "parameter": "log_likelihood", "mean": -158.5})
    chains = pd.DataFrame({"cell": "c", "chain": np.repeat(np.arange(4), 5), "iteration": np.tile(np.arange(5), 4),
                           "warm_up": False, "mu": -1.4, "phi": 0.78, "sigma": 0.43, "log_likelihood": -158.0,
                           "log_prior": -3.0, "accepted": True})
    write_folder(root / "posterior", {"name": "posterior"},
                 {"filter": {"particles": 36}, "estimation": {"chains": 4, "iterations": 5, "warm_up": 0}},
                 {"posterior": pd.DataFrame(rows), "chains": chains})


def exact_folder(root) -> None:
    """Metropolis-Hastings on the exact likelihood: particles' means (paper.yaml), mcse 0.01."""
    reference = yaml.safe_load(PAPER.read_text())["particles_reference"]["parameters"]
    rows = [{"parameter": name, "n": 1000, "mean": theirs["mean"], "sd": theirs["sd"], "r_hat": 1.01,
             "ess_bulk": 300.0, "mcse_mean": 0.01, "acceptance_rate": 0.26, "chains": 4}
            for name, theirs in (("mu", reference["mu"]), ("phi", reference["rho"]), ("sigma", reference["sigma"]))]
    config = {"filter": {"kind": "histogram", "grid": {"low": [-10.0], "high": [8.0], "cells": [400]}},
              "estimation": {"chains": 4, "iterations": 1500, "warm_up": 300, "parameters": {
                  "model.sigma": {"prior": {"law": "gamma", "shape": 2.0, "rate": 2.0}}}}}
    write_folder(root / "exact-posterior", {"name": "exact-posterior"}, config, {"posterior": pd.DataFrame(rows)})


def n_choice_folders(root, taus: dict[int, float], delta: float = 50.0) -> None:
    """spread: 1000 runs per N with sd sqrt(delta / N); n-choice: 40 AR(1) chains per N of 1500
    draws after a warm-up of 1, with autocorrelation time taus[N]."""
    generator = np.random.default_rng(8)
    trials = pd.concat([pd.DataFrame({"n_particles": n, "log_likelihood": generator.normal(-158, math.sqrt(delta / n),
                                                                                            1000)})
                        for n in taus], ignore_index=True)
    write_folder(root / "spread", {"name": "spread"}, {}, {"trials": trials})
    frames, rows = [], []
    for index, (n, tau) in enumerate(taus.items()):
        draws = ar1_chains((tau - 1) / (tau + 1), 40, 1501, seed=10 + index)
        frames.append(pd.DataFrame({"cell": f"cell{n}", "arm": "default", "n_particles": n,
                                    "chain": np.repeat(np.arange(40), 1501), "iteration": np.tile(np.arange(1501), 40),
                                    "warm_up": np.tile(np.arange(1501) == 0, 40), "mu": draws.ravel(),
                                    "log_likelihood": -158.0, "log_prior": -3.0, "accepted": True}))
        rows.append({"cell": f"cell{n}", "arm": "default", "n_particles": n, "parameter": "mu", "mean": 0.0,
                     "acceptance_rate": 0.1, "chains": 40})
    write_folder(root / "n-choice", {"name": "n-choice", "label_columns": ["arm", "n_particles"]}, {},
                 {"chains": pd.concat(frames, ignore_index=True), "posterior": pd.DataFrame(rows)})


def benchmark(tmp_path, shift_mu: float = 0.0, taus: dict | None = None) -> PaperResults:
    root = tmp_path / "estimation-sv"
    root.mkdir()
    (root / "paper.yaml").write_text(PAPER.read_text())
    posterior_folder(root, shift_mu)
    exact_folder(root)
    n_choice_folders(root, taus or {10: 120.0, 36: 10.0, 200: 6.0})
    return PaperResults(root)


def verdicts_of(results: PaperResults) -> dict[str, str]:
    section = REPORTS["estimation-sv"](results)
    assert all(verdict.verdict in VERDICTS for verdict in section.verdicts)
    claims = yaml.safe_load(PAPER.read_text())["claims"]
    return {key: next(v.verdict for v in section.verdicts if v.claim == claims[key])
            for key in ("posterior", "exact_posterior", "published_posterior", "other_data", "n_choice")}


def test_the_report_reproduces_what_agrees_and_says_not_comparable_where_nothing_is_published(tmp_path):
    # N = 10, 36, 200 have sd of log L_hat 2.24, 1.18, 0.50 and tau x N 1200, 360, 1200: the rule's minimum
    verdicts = verdicts_of(benchmark(tmp_path))
    assert verdicts == {"posterior": "reproduced", "exact_posterior": "reproduced",
                        "published_posterior": "not comparable", "other_data": "not comparable",
                        "n_choice": "reproduced"}


def test_a_mean_beyond_three_combined_errors_and_a_cheapest_n_outside_the_range_are_not_reproduced(tmp_path):
    # mu 10 combined Monte Carlo errors off particles' (phi and sigma still agree), 5.7 off the exact
    # chain's (0.064 against hypot(0.005, 0.01)); N = 10 (sd 2.24) cheapest
    verdicts = verdicts_of(benchmark(tmp_path, shift_mu=10.0, taus={10: 20.0, 36: 60.0, 200: 6.0}))
    assert verdicts["posterior"] == "partly reproduced" and verdicts["exact_posterior"] == "partly reproduced"
    assert verdicts["n_choice"] == "not reproduced"


def test_the_exact_chain_s_note_gives_the_grid_and_the_prior_mass_it_cannot_reach(tmp_path):
    section = REPORTS["estimation-sv"](benchmark(tmp_path))
    table = next(item for item in section.items if getattr(item, "title", "").startswith("PMMH against"))
    # the grid's cells are 18 / 400 = 0.045 wide; P(Gamma(2, rate 2) < 0.045) = 1 - exp(-0.09) (1 + 0.09)
    assert "400 cells over [-10, 8]" in table.note and "(0.045)" in table.note
    assert f"{1 - math.exp(-0.09) * 1.09:.1%}" in table.note


def test_the_figure_draws_the_work_per_effective_draw_against_n(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = benchmark(tmp_path)
    figure = inefficiency_vs_particles(ResultFolder(results.path / "n-choice"))
    assert figure is not None
    plt.close(figure)
    assert inefficiency_vs_particles(ResultFolder(results.path / "posterior")) is None     # no sweep over N


# -- the numbers kept where the chains are not ------------------------------------------------------

def n_choice_verdict(section):
    claim = yaml.safe_load(PAPER.read_text())["claims"]["n_choice"]
    return next(verdict for verdict in section.verdicts if verdict.claim == claim)


def test_the_kept_table_gives_the_same_n_choice_section_as_the_chains(tmp_path):
    results = benchmark(tmp_path)
    folder = results.path / "n-choice"
    from_chains = REPORTS["estimation-sv"](results)
    for experiment in ("posterior", "exact-posterior", "spread", "n-choice"):
        write_kept_tables("estimation-sv", experiment, results.path / experiment)
    # only n-choice's draws are left out of the repository, so only its folder gets a table
    assert [path.parent.name for path in results.path.rglob(WORK_TABLE)] == ["n-choice"]
    (folder / "chains.csv").unlink()
    from_table = REPORTS["estimation-sv"](results)
    verdict = n_choice_verdict(from_table)
    assert verdict.verdict == "reproduced" and "resamples of the chains" in verdict.evidence
    # every verdict, table and text the same, to the last character
    assert from_table.verdicts == from_chains.verdicts
    assert from_table.items == from_chains.items


def test_a_n_choice_folder_with_neither_chains_nor_kept_table_says_its_results_are_missing(tmp_path):
    results = benchmark(tmp_path)
    (results.path / "n-choice" / "chains.csv").unlink()
    section = REPORTS["estimation-sv"](results)
    verdict = n_choice_verdict(section)
    assert verdict.verdict == "not reproduced"
    assert verdict.evidence.startswith("missing:") and WORK_TABLE in verdict.evidence and REPRODUCE in verdict.evidence
    assert not any(getattr(item, "title", "").startswith("The N-choice curve") for item in section.items)
    # the other claims are untouched
    assert verdicts_of(results)["posterior"] == "reproduced"
