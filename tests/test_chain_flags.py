"""Bad chains named: posterior.csv's and maximum_likelihood.csv's ``flag`` column, and the one
line per flagged cell that says what to try (pfx/analysis/estimation_flags.py).

The thresholds are Vehtari et al. (2021)'s (R-hat above 1.01, a bulk or tail ESS under 100 per
chain) and IF2's likelihood-ratio tolerance ½ χ²_p(0.95) beyond two standard errors. Each
statistical case is built with a margin derived below, at a fixed seed, never tuned:

* hand-made draws (``posterior_summary`` on a chains table built here): independent normal draws
  have an ESS near the draw count, ten times the threshold; an AR(1) chain with φ = 0.98 has
  ESS ≈ n (1 - φ) / (1 + φ), a tenth of it;
* PMMH with the Kalman filter (exact likelihood, nothing to measure about particles): chains
  started three orders of magnitude apart, 60 iterations, no warm-up, must be flagged; chains
  started in the posterior's bulk with a near-optimal proposal, long enough for an ESS about
  three times the threshold, must not be;
* PMMH with 5 particles on the Nile: the likelihood estimate's sd is in the hundreds, and the
  line must say so and ask for particles;
* IF2 on the Nile from a scattered start, stopped after two passes: the replicates far from the
  maximum are flagged, the two started at it are not.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import write_config_file

import pfx
from pfx.analysis.estimation_flags import (
    ESS_PER_CHAIN,
    R_HAT_LIMIT,
    SPREAD_RUNS,
    ess_threshold,
    if2_advice,
    likelihood_ratio_tolerance,
    pmmh_advice,
    posterior_flag,
    replicate_flags,
    suggested_particles,
)
from pfx.estimation.summary import posterior_summary

ROOT = Path(__file__).resolve().parents[1]
NILE = str(ROOT / "examples" / "data" / "nile.csv")
MEASUREMENT = "model.measurement_noise.variance"
PROCESS = "model.process_noise.variance"


# -- the flag text and its thresholds, on hand-made draws ------------------------------------------------------

def chains_table(values: np.ndarray) -> pd.DataFrame:
    """A chains.csv-like table (no warm-up) from draws (chains, draws) of one parameter ``a``;
    the log-likelihood column a copy of them, every proposal accepted."""
    chains, draws = values.shape
    return pd.DataFrame({"chain": np.repeat(np.arange(chains), draws), "iteration": np.tile(np.arange(1, draws + 1), chains),
                         "a": values.ravel(), "log_likelihood": values.ravel(), "accepted": True})


def test_the_thresholds_are_vehtari_et_al_s_per_chain():
    assert R_HAT_LIMIT == 1.01 and ESS_PER_CHAIN == 100
    assert ess_threshold(4) == 400 and ess_threshold(1) == 100          # "400 for four chains"


def test_the_flag_names_each_failed_check_with_its_value_and_threshold():
    assert posterior_flag(1.92, 6.4, 50.0, chains=4, draws_per_chain=100) == \
        "r_hat 1.92 > 1.01; ess_bulk 6 < 400; ess_tail 50 < 400"
    assert posterior_flag(1.005, 400.0, 900.0, chains=4, draws_per_chain=1000) == ""   # at the thresholds: passes
    assert posterior_flag(1.01, 399.6, 400.0, chains=4, draws_per_chain=1000) == "ess_bulk 399 < 400"
    assert posterior_flag(1.0101, 800.0, 800.0, chains=4, draws_per_chain=1000) == "r_hat 1.0101 > 1.01"
    assert posterior_flag(math.inf, 4.5, 4.5, chains=2, draws_per_chain=50) == \
        "r_hat inf > 1.01; ess_bulk 4 < 200; ess_tail 4 < 200"
    assert posterior_flag(math.nan, 200.0, 200.0, chains=4, draws_per_chain=50).startswith("r_hat NaN")
    # one chain: R-hat needs two, so it is not a check; its ESS is (100 for one chain)
    assert posterior_flag(math.nan, 150.0, 150.0, chains=1, draws_per_chain=500) == ""
    assert posterior_flag(math.nan, math.nan, math.nan, chains=2, draws_per_chain=3) == \
        "too few draws for diagnostics: 3 per chain < 4"


def test_posterior_summary_flags_chains_that_disagree_or_mix_slowly_and_not_independent_ones():
    random = np.random.default_rng(2021)
    independent = random.standard_normal((4, 1000))      # ESS ≈ 4000 = 10 x 400; R-hat - 1 ~ 1/1000
    shifted = independent.copy()
    shifted[3] += 3.0                                     # one chain elsewhere: R-hat far above 1.01
    slow = np.empty((4, 1000))                            # AR(1), φ = 0.98: ESS ≈ 4000 * 0.02 / 1.98 ≈ 40
    slow[:, 0] = random.standard_normal(4)
    for step in range(1, 1000):
        slow[:, step] = 0.98 * slow[:, step - 1] + math.sqrt(1 - 0.98**2) * random.standard_normal(4)

    good = posterior_summary(chains_table(independent), ["a"], warm_up=0)
    assert list(good.columns)[-1] == "flag"
    assert (good["flag"] == "").all() and good["ess_bulk"].min() > 2000

    apart = posterior_summary(chains_table(shifted), ["a"], warm_up=0).set_index("parameter")
    assert apart.loc["a", "r_hat"] > 1.1
    assert apart.loc["a", "flag"].startswith(f"r_hat {apart.loc['a', 'r_hat']:.3g} > 1.01")
    assert apart.loc["log_likelihood", "flag"] != ""                # the log-likelihood row: the same rules

    sticky = posterior_summary(chains_table(slow), ["a"], warm_up=0).set_index("parameter")
    bulk = re.search(r"ess_bulk (\d+) < 400", sticky.loc["a", "flag"])
    assert bulk and int(bulk.group(1)) == math.floor(sticky.loc["a", "ess_bulk"]) < 100

    few = posterior_summary(chains_table(independent[:, :3]), ["a"], warm_up=0)
    assert (few["flag"] == "too few draws for diagnostics: 3 per chain < 4").all()


# -- what the line says, in the order of diagnosis ---------------------------------------------------------------

def posterior_rows(flag="r_hat 1.3 > 1.01", ess=(120.0, 300.0), acceptance=0.25, chains=4, draws=1000) -> pd.DataFrame:
    return pd.DataFrame([{"parameter": "a", "n": chains * draws, "mean": 1.5, "r_hat": 1.3, "ess_bulk": ess[0], "ess_tail": ess[1],
                          "acceptance_rate": acceptance, "chains": chains, "flag": flag},
                         {"parameter": "log_likelihood", "n": chains * draws, "mean": -80.0, "r_hat": 1.0, "ess_bulk": 900.0,
                          "ess_tail": 900.0, "acceptance_rate": acceptance, "chains": chains, "flag": ""}])


def test_the_line_asks_for_particles_first_when_the_estimate_is_too_noisy():
    spread = {"particles": 300, "runs": 40, "finite": 40, "sd": 3.4}
    line = pmmh_advice(posterior_rows(acceptance=0.003), 1000, spread)
    assert "more particles: sd of log L̂ at the posterior mean 3.4 over 40 runs at N = 300" in line
    assert "about N = 2400 by the 1/N law" in line and "particles: auto" in line     # 300 (3.4 / 1.2)² = 2408
    assert suggested_particles(300, 3.4) == 2400
    # far above sd 1 the 1/N law overstates N (the sd falls faster at first): measure instead
    far = pmmh_advice(posterior_rows(), 1000, {"particles": 300, "runs": 40, "finite": 40, "sd": 28.0})
    assert "N = 160000, likely too many" in far and "`particles: auto`" in far
    zero = pmmh_advice(posterior_rows(), 1000, {"particles": 10, "runs": 40, "finite": 31, "sd": 1.0})
    assert "more particles" in zero and "zero in 9 of 40 runs" in zero


def test_a_count_the_pilot_chose_is_measured_again_at_the_posterior_mean():
    """`particles: auto` measured where it was told (the chains' start, by default), which can be
    far from the posterior, where the estimate is noisier: the line says to measure there, not to
    use `particles: auto`, which the cell already does."""
    spread = {"particles": 256, "runs": 40, "finite": 40, "sd": 4.09}
    line = pmmh_advice(posterior_rows(), 2500, spread, chosen_by_pilot=True)
    assert "which chose 256 where it measured" in line and "estimation.particle_count.at" in line
    assert "measure at the posterior mean, a 1.5 (" in line and "or `particles: auto`" not in line
    far = pmmh_advice(posterior_rows(), 2500, {**spread, "sd": 28.0}, chosen_by_pilot=True)
    assert "likely too many" in far and "estimation.particle_count.at" in far and "use `particles: auto`" not in far


def test_then_a_proposal_scale_from_the_acceptance_rate_then_more_iterations():
    calm = {"particles": 300, "runs": 40, "finite": 40, "sd": 1.1}
    small = pmmh_advice(posterior_rows(acceptance=0.01), 1000, calm)
    assert "a smaller proposal scale" in small and "0.01 < 0.05" in small and "not the cause" in small
    assert "0.234" in small and "0.07-0.15" in small
    assert "a larger proposal scale" in pmmh_advice(posterior_rows(acceptance=0.8), 1000, None)
    # the worst ESS 120 of 400 after 1000 draws per chain: 1000 (400/120 - 1) = 2333 more, to two figures
    more = pmmh_advice(posterior_rows(acceptance=0.3), 1000, None)
    assert "more iterations: the worst ESS is 120 < 400" in more and "about 2300 more per chain, iterations: 3300" in more
    # R-hat alone: twice the draws
    assert "about 1000 more per chain" in pmmh_advice(posterior_rows(ess=(900.0, 900.0)), 1000, None)
    assert pmmh_advice(posterior_rows(flag=""), 1000, None) is None


# -- PMMH runs -------------------------------------------------------------------------------------------------

def kalman_config(starts, iterations: int, proposal_sd: float, chains: int = 4) -> dict:
    """The local level on 10 simulated steps, its measurement variance estimated with the Kalman
    filter's exact likelihood (plain Metropolis-Hastings: no particles), no adaptation."""
    return {"name": "kf-flags", "seed": 5,
            "model": {"kind": "linear_gaussian", "steps": 10, "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                      "process_noise": {"variance": 1.0}, "measurement_noise": {"variance": 2.0}},
            "filter": {"kind": "kf"}, "outputs": {"figures": []},
            "estimation": {"method": "pmmh", "chains": chains, "iterations": iterations, "warm_up": 0, "adapt": False,
                           "parameters": {MEASUREMENT: {"prior": {"law": "flat", "lower": 0.0}, "start": starts,
                                                        "proposal_sd": proposal_sd}}}}


def advice_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if "chains flagged for" in line]


def test_kalman_chains_started_far_apart_are_flagged_and_told_to_run_longer_or_rescale(tmp_path, capsys):
    config = kalman_config([0.01, 0.1, 300.0, 3000.0], iterations=60, proposal_sd=0.3)
    result = pfx.run(config, out=tmp_path / "out", quiet=False)
    posterior = result.table("posterior").set_index("parameter")
    assert posterior.loc["measurement_noise.variance", "flag"].startswith("r_hat")
    assert posterior.loc["measurement_noise.variance", "r_hat"] > 1.5
    [line] = advice_lines(capsys.readouterr().err)
    assert "more iterations" in line or "proposal scale" in line
    assert "particles" not in line                                     # the Kalman filter has none
    assert not (result.folder / "likelihood_spread.csv").exists()


def test_a_long_well_started_kalman_run_is_not_flagged(tmp_path, capsys):
    """2 chains x 2000 draws from the posterior's bulk (its median is near 6; the sd of log r is
    0.65, so a proposal sd of 1.6 ≈ 2.4 x 0.65 is near the optimal scale, inefficiency about 5):
    an ESS near 4000 / 5 = 800, four times the 200 two chains need. R-hat: with n_eff ≈ 200 per
    half chain, split R-hat - 1 ≈ (F - 1) / 400 with F ~ χ²_3 / 3, above 0.01 with probability
    0.002 (the Kalman filter costs milliseconds a call: 4000 calls are the test's time)."""
    config = kalman_config(5.0, iterations=2000, proposal_sd=1.6, chains=2)
    result = pfx.run(config, out=tmp_path / "out", quiet=False)
    posterior = result.table("posterior")
    assert posterior["flag"].isna().all()                               # empty in the file: NaN to pandas
    assert (posterior[["ess_bulk", "ess_tail"]] > 2 * 200).all().all() and (posterior["r_hat"] < R_HAT_LIMIT).all()
    assert advice_lines(capsys.readouterr().err) == []
    assert not (result.folder / "likelihood_spread.csv").exists()


def nile_pmmh(particles: int, iterations: int = 150, warm_up: int = 50) -> dict:
    return {"name": "nile-flags", "seed": 1871,
            "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                      "process_noise": {"variance": 1469.1}, "measurement_noise": {"variance": 15099.0},
                      "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0e7}},
            "data": {"measurements": NILE},
            "filter": {"particles": particles, "resampler": "systematic", "ess_threshold": 0.5},
            "outputs": {"figures": []},
            "estimation": {"method": "pmmh", "chains": 4, "iterations": iterations, "warm_up": warm_up,
                           "parameters": {MEASUREMENT: {"prior": {"law": "flat", "lower": 0}, "transform": "log",
                                                        "start": 10000, "proposal_sd": 0.3},
                                          PROCESS: {"prior": {"law": "flat", "lower": 0}, "transform": "log",
                                                    "start": 1000, "proposal_sd": 0.5}}}}


def test_five_particles_on_the_nile_are_flagged_and_the_line_shows_the_measured_spread(tmp_path, capsys):
    """At N = 5 the sd of the Nile's log-likelihood estimate is in the hundreds (0.81 at N = 200,
    docs/estimation.md): the chains stick, and the spread, measured at the posterior mean, is named."""
    result = pfx.run(nile_pmmh(particles=5), out=tmp_path / "out", quiet=False)
    posterior = result.table("posterior").set_index("parameter")
    assert posterior["flag"].notna().all()
    spread = result.table("likelihood_spread")
    assert len(spread) == 1 and spread["particles"].iloc[0] == 5 and spread["runs"].iloc[0] == SPREAD_RUNS
    assert spread["sd"].iloc[0] > 2
    for name in ("measurement_noise.variance", "process_noise.variance"):   # measured at the posterior mean
        assert spread[name].iloc[0] == pytest.approx(posterior.loc[name, "mean"], rel=1e-12)
    [line] = advice_lines(capsys.readouterr().err)
    assert f"more particles: sd of log L̂ at the posterior mean {spread['sd'].iloc[0]:.3g} over 40 runs at N = 5" in line
    assert "`particles: auto`" in line


# -- IF2 --------------------------------------------------------------------------------------------------------

def test_the_likelihood_ratio_tolerance():
    assert likelihood_ratio_tolerance(1) == pytest.approx(1.9207, abs=1e-4)      # ½ χ²_1(0.95) = ½ 3.8415
    assert likelihood_ratio_tolerance(2) == pytest.approx(2.9957, abs=1e-4)


def test_replicate_flags_allow_the_tolerance_plus_two_standard_errors_of_the_difference():
    # the best -100 (se 0.1); -110 with se 0.2: 10 > 1.9207 + 2 sqrt(0.01 + 0.04) = 2.368
    flags = replicate_flags([-100.0, -101.0, -110.0, -np.inf], [0.1, 0.1, 0.2, np.nan], parameters=1)
    assert flags[:3] == ["", "", "below the best by 10 > 2.37"]
    assert flags[3].startswith("log_likelihood -inf")
    edge = 1.9207 + 2 * math.sqrt(0.1**2 + 0.2**2)
    assert replicate_flags([-100.0, -100.0 - edge + 1e-3], [0.1, 0.2], 1) == ["", ""]
    assert replicate_flags([-100.0, -100.0 - edge - 1e-3], [0.1, 0.2], 1)[1].startswith("below the best by")
    line = if2_advice(flags, 1)
    assert line.startswith("2 of 4 IF2 replicates flagged") and "1.92" in line and "more iterations" in line
    assert if2_advice(["", ""], 1) is None


def nile_if2(starts, iterations: int = 2) -> dict:
    return {"name": "nile-if2-flags", "seed": 1871,
            "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                      "process_noise": {"variance": 1469.1}, "measurement_noise": {"variance": 15099.0},
                      "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0e7}},
            "data": {"measurements": NILE},
            "filter": {"particles": 300, "resampler": "systematic", "ess_threshold": 0.5},
            "outputs": {"figures": []},
            "estimation": {"method": "if2", "chains": len(starts), "iterations": iterations, "evaluations": 10,
                           "parameters": {MEASUREMENT: {"prior": {"law": "flat", "lower": 0}, "transform": "log",
                                                        "start": starts, "random_walk_sd": 0.02}}}}


def test_if2_replicates_stopped_early_far_from_the_maximum_are_flagged_the_agreeing_ones_not(tmp_path, capsys):
    """One variance, two passes: replicates 0 and 1 start at the maximum (15099), 2 and 3 a factor
    of 10 below and above it, and a random walk of 0.02 per step moves them about 0.2 on the log
    scale per pass: they stay tens of log-likelihood units below, far beyond 1.92 plus two
    standard errors (0.1 to 0.7 at N = 300)."""
    result = pfx.run(nile_if2([15099.0, 15099.0, 1500.0, 150000.0]), out=tmp_path / "out", quiet=False)
    table = result.table("maximum_likelihood")
    assert list(table.columns)[-1] == "flag"
    flags = table["flag"].fillna("")
    assert list(flags == "") == [True, True, False, False]
    for flag in flags[2:]:
        gap, limit = map(float, re.fullmatch(r"below the best by (\S+) > (\S+)", flag).groups())
        assert gap > 10 and 1.92 < limit < 1.92 + 2 * 2
    printed = capsys.readouterr()
    assert "2 of 4 IF2 replicates flagged" in printed.err
    assert "2 of 4" in printed.out.split("IF2, the replicate of highest log-likelihood")[1]


# -- the end-of-run table --------------------------------------------------------------------------------------

def tiny(method: str, **estimation) -> dict:
    config = {"name": f"tiny-{method}", "seed": 11,
              "model": {"kind": "linear_gaussian", "steps": 25, "transition_matrix": [[1.0]],
                        "measurement_matrix": [[1.0]], "process_noise": {"variance": 1.0},
                        "measurement_noise": {"variance": 2.0}},
              "filter": {"particles": 40, "resampler": "systematic"}, "outputs": {"figures": []},
              "estimation": {"method": method, "chains": 2, "iterations": 20,
                             "parameters": {PROCESS: {"prior": {"law": "flat", "lower": 0.0}, "start": [0.5, 2.0]}}}}
    config["estimation"].update(estimation)
    return config


def test_the_end_of_run_table_shows_the_flags_and_repeats_the_line(tmp_path, pfx_in_process):
    path = write_config_file(tmp_path, tiny("pmmh", warm_up=5))
    result = pfx_in_process("run", path, "--out", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    table = result.stdout.split("posterior after the warm-up")[1]
    header = table.splitlines()[1].split()
    assert header[-4:] == ["ESS", "tail", "ESS", "flag"]
    posterior = pd.read_csv(tmp_path / "out" / "posterior.csv")
    for flag in posterior["flag"]:
        assert flag in table
    # the run's line (stderr) and the table's (stdout, read from the folder's files) say the same
    [printed] = advice_lines(result.stderr)
    [repeated] = advice_lines(result.stdout)
    assert printed.split(": ", 2)[2] == repeated.split(": ", 1)[1]

    path = write_config_file(tmp_path, tiny("if2", iterations=2), name="if2.yaml")
    result = pfx_in_process("run", path, "--out", tmp_path / "if2")
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("IF2, the replicate of highest log-likelihood")[1].splitlines()[1].split()[-1] == \
        "flagged"
