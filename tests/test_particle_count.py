"""`particles: auto`: PMMH's particle count chosen by a pilot (pfx/estimation/particle_count.py).

The rule on synthetic spreads whose sd follows the 1/N law exactly (the N nearest the target, the
ladder, the refusal at the cap, runs without a likelihood); the rule against the committed
N-choice curve of the stochastic-volatility benchmark; the pilot inside an estimation run (its
table, the manifest, the chains at the chosen N, a resumed or extended run reading the choice
back, a damaged pilot file, the refusal that writes nothing); `auto` refused where it means
nothing; and ``pfx.choose_particles``.
"""

from __future__ import annotations

import copy
import importlib
import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import REPO_ROOT, tiny_config_dict, write_config_file
from test_estimation_folders import estimation_config, interrupt_at, snapshot

import pfx
from pfx.config.estimation import ParticleCount
from pfx.config.estimation_tables import PARTICLE_COUNT
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.estimation.likelihood_spread import Spread, log_likelihood_spread
from pfx.estimation.particle_count import choose_particle_count, ladder
from pfx.estimation.pmmh import ParticleMarginalMetropolisHastings
from pfx.estimation.target import EstimationTarget, dataset
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, restart_seed
from pfx.safe_yaml import load_config_file

pilot_module = importlib.import_module("pfx.run.particle_count_pilot")     # where the run measures the pilot

# -- the rule, on spreads that follow the 1/N law exactly ----------------------------------------------


def law(c: float, calls: list[int] | None = None, lost_below: int = 0, lost_sd: float = 0.01):
    """``spread_at`` with sd = sqrt(c / N) exactly; below ``lost_below`` particles a run of each
    measurement has no likelihood (-inf), and the others an sd of ``lost_sd`` (tiny: it must
    still count as above the target)."""
    def spread_at(particles: int) -> Spread:
        if calls is not None:
            calls.append(particles)
        if particles < lost_below:
            return Spread(particles, 40, 39, -100.0, lost_sd, 0.0)
        return Spread(particles, 40, 40, -100.0, math.sqrt(c / particles), 0.0)
    return spread_at


def choose(spread_at, **settings):
    return choose_particle_count(spread_at, ParticleCount(**settings), key="filter.particles", point_text="mu=0")


def test_the_ladder_doubles_up_to_the_cap():
    assert ladder(ParticleCount(smallest=16, largest=100)) == [16, 32, 64, 100]
    assert ladder(ParticleCount(smallest=16, largest=16)) == [16]


@pytest.mark.parametrize("c", [30.0, 100.0, 1000.0, 5000.0])
def test_the_rule_picks_the_particle_count_the_law_puts_at_the_target(c):
    calls: list[int] = []
    choice = choose(law(c, calls))
    exact = c / 1.2**2                          # sd = target where c / N = target^2
    assert choice.particles == round(exact)
    rungs = [16]                                # the ladder up to the first rung at or below the target
    while rungs[-1] < exact:
        rungs.append(2 * rungs[-1])
    assert calls == [*rungs, round(exact)]      # then the law's prediction
    assert [row.particles for row in choice.rows] == calls
    assert choice.table()["chosen"].tolist() == [row.particles == round(exact) for row in choice.rows]


def test_a_target_below_the_smallest_count_chooses_the_smallest():
    calls: list[int] = []
    choice = choose(law(5.0, calls))            # sd at 16 is 0.56, below 1.2: no count below 16 is tried
    assert choice.particles == 16 and calls == [16]


def test_the_nearest_on_the_log_scale_wins_and_a_tie_goes_to_the_smaller_count():
    measured = {16: 2.0, 32: 0.5, 23: 4.0}      # 16 and 32 equally far from 1 on the log scale; 23 far off
    choice = choose(lambda n: Spread(n, 40, 40, 0.0, measured[n], 0.0), target_sd=1.0)
    assert [row.particles for row in choice.rows] == [16, 32, 23]    # 23 = sqrt(16 * 4 * 32 / 4), the law's
    assert choice.particles == 16


def test_the_cap_above_the_target_is_refused_in_one_line_naming_the_key_the_sd_and_the_cap():
    with pytest.raises(ConfigError) as refused:
        choose(law(10_000.0), largest=256)
    text = str(refused.value)
    assert "\n" not in text and refused.value.key == "filter.particles"
    assert "cap of 256 particles" in text and "is 6.25 at mu=0" in text and "target 1.2" in text
    assert "asks for about 6,944 particles" in text                     # 10000 / 1.44
    assert "estimation.particle_count.largest" in text and "better proposal" in text


def test_runs_without_a_likelihood_count_as_an_sd_above_any_target():
    calls: list[int] = []
    choice = choose(law(20.0, calls, lost_below=64))      # 16 and 32: tiny sd, one run -inf each
    assert calls[:3] == [16, 32, 64] and choice.particles == 64
    assert choice.table()["finite"].tolist()[:2] == [39, 39]
    with pytest.raises(ConfigError, match=r"1 of 40 filter runs lost every particle's weight.*cannot say"):
        choose(law(20.0, lost_below=10**9), largest=64)


def test_an_sd_of_zero_chooses_the_smallest_count():
    """A filter whose estimate does not vary (sd 0) needs no more particles than the first rung."""
    choice = choose(lambda n: Spread(n, 40, 40, -10.0, 0.0, 0.0))
    assert choice.particles == 16 and len(choice.rows) == 1


# -- against the committed N-choice curve of the stochastic-volatility benchmark -------------------------

SV_CONFIG = REPO_ROOT / "configs" / "benchmarks" / "estimation-sv" / "posterior.yaml"
SV_CURVE = REPO_ROOT / "results" / "benchmarks" / "estimation-sv" / "spread" / "summary.csv"
SV_POINT = np.array([-1.40, 0.78, 0.43])      # (mu, phi, sigma), where the committed curve was measured
PILOT_RUNS = 200


def test_the_pilot_chooses_where_the_committed_curve_puts_the_target_sd():
    """The committed curve (1000 runs per N) puts sd = 1.2 between its rows N = 22 and 36; the
    1/N law through those two rows (on the log scale, slope -1/2) gives N_curve. The pilot's
    N comes from sds of 200 runs, whose relative standard error is 1/sqrt(2 (R - 1)); N goes as
    sd^2, so log N has a standard error of 2/sqrt(2 (R - 1)): 0.100 at R = 200, and 0.045 for
    the curve's own 1000 runs. 200 runs make 3 combined standard errors (0.33, a factor 1.39) a
    band narrower than the ladder's factor 2, so the check can fail."""
    curve = pd.read_csv(SV_CURVE).sort_values("n_particles")
    sd = curve.set_index("n_particles")["log_likelihood_std"]
    above, below = sd[sd > 1.2].index.max(), sd[sd <= 1.2].index.min()
    n_curve = math.sqrt(above * (sd[above] / 1.2) ** 2 * below * (sd[below] / 1.2) ** 2)
    plan = build_plan(load_config_file(SV_CONFIG), str(SV_CONFIG))
    cell = plan.cells[0]
    target = EstimationTarget(cell, plan.experiment.estimation, dataset(cell, plan.experiment.seed))
    choice = choose_particle_count(
        lambda n: log_likelihood_spread(target, SV_POINT, n, PILOT_RUNS, plan.experiment.seed),
        ParticleCount(runs=PILOT_RUNS), key="filter.particles", point_text="the benchmark's point")
    band = 3 * math.hypot(2 / math.sqrt(2 * (PILOT_RUNS - 1)), 2 / math.sqrt(2 * (1000 - 1)))
    assert abs(math.log(choice.particles / n_curve)) < band, (choice.particles, n_curve, choice.table())


# -- inside an estimation run ----------------------------------------------------------------------------

# the tests of the count chosen before the chains keep it for every iteration (after_warm_up: false);
# those of the second measurement, after the warm-up, are further down
PILOT = {"runs": 20, "smallest": 4, "largest": 512, "after_warm_up": False}


def auto_config(**pilot) -> dict:
    """The tiny PMMH config of test_estimation_folders with ``particles: auto``: 20 runs per N."""
    config = estimation_config("pmmh")
    config["filter"]["particles"] = "auto"
    config["estimation"]["particle_count"] = {**PILOT, **pilot}
    return config


@pytest.fixture(scope="module")
def auto_run(tmp_path_factory):
    return pfx.run(auto_config(), out=tmp_path_factory.mktemp("auto") / "run")


def no_pilot(monkeypatch):
    """Any measurement of the spread fails: what runs must read the choice back."""
    def refuse(*args, **kwargs):
        raise AssertionError("the pilot measured again")
    monkeypatch.setattr(pilot_module, "log_likelihood_spread", refuse)


def test_the_folder_says_the_choice_in_its_table_and_manifest(auto_run):
    table = auto_run.tables["particle_count"]
    cell = auto_run.chains["cell"].iloc[0]
    labels = build_plan(auto_config(), "auto.yaml").label_columns
    assert list(table.columns) == ["cell", *labels, "stage", *PARTICLE_COUNT.own]
    assert (table["stage"] == "before_chains").all()
    assert table["chosen"].sum() == 1 and (table["cell"] == cell).all() and (table["n_particles"] == "auto").all()
    chosen = int(table.loc[table["chosen"], "particles"].iloc[0])
    assert auto_run.manifest["particle_count"] == {cell: chosen}
    assert (table["runs"] == PILOT["runs"]).all()
    assert np.allclose(table["sd_standard_error"], table["sd"] / np.sqrt(2 * (table["finite"] - 1)))
    # the rule's own choice among the rows measured
    measured = table[table["finite"] == table["runs"]]
    assert chosen == measured.loc[(np.log(measured["sd"]) - np.log(1.2)).abs().idxmin(), "particles"]


def test_the_chains_ran_at_the_chosen_count_on_the_cell_s_own_streams(auto_run):
    """The chains are PMMH at the chosen N with the auto cell's streams. A config giving that N
    as a number is another cell (its key holds the number, not auto), so its chains differ."""
    config = auto_config()
    plan = build_plan(copy.deepcopy(config), "auto.yaml")
    cell = plan.cells[0]
    chosen = auto_run.manifest["particle_count"][cell.key]
    target = EstimationTarget(cell, plan.experiment.estimation, dataset(cell, plan.experiment.seed))
    sampler = ParticleMarginalMetropolisHastings(target.with_particles(chosen), plan.experiment.seed, cell.stream_key)
    chains = sampler.start()
    values = [chains.values.copy()]
    for iteration in range(1, config["estimation"]["iterations"] + 1):
        sampler.iterate(chains, iteration)
        values.append(chains.values.copy())
    written = auto_run.chains[target.columns].to_numpy().reshape(len(values), -1, len(target.columns))
    assert np.array_equal(written, np.array(values))
    numbered = copy.deepcopy(config)
    numbered["filter"]["particles"] = chosen
    del numbered["estimation"]["particle_count"]
    assert build_plan(numbered, "numbered.yaml").cells[0].key != cell.key


def test_an_extended_run_reads_the_choice_back_instead_of_measuring(auto_run, tmp_path, monkeypatch):
    folder = tmp_path / "extended"
    pfx.run(auto_config(), out=folder)
    longer = auto_config()
    longer["estimation"]["iterations"] = 9
    with monkeypatch.context() as patch:
        no_pilot(patch)
        extended = pfx.run(longer, out=folder)
    whole = pfx.run(longer, out=tmp_path / "whole")
    untimed = [name for name in PARTICLE_COUNT.own if name != "run_time_s"]
    assert extended.tables["particle_count"][untimed].equals(whole.tables["particle_count"][untimed])
    assert (extended.folder / "chains.csv").read_bytes() == (whole.folder / "chains.csv").read_bytes()


def test_an_interrupted_run_keeps_its_pilot_and_resumes_without_measuring(auto_run, tmp_path, monkeypatch):
    with monkeypatch.context() as patch:
        interrupt_at(patch, "pmmh", 3)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(auto_config(), out=tmp_path / "stopped")
    assert list((tmp_path / "stopped" / "estimation").glob("*.particle_count.csv"))
    with monkeypatch.context() as patch:
        no_pilot(patch)
        resumed = pfx.run(auto_config(), out=tmp_path / "stopped")
    assert (resumed.folder / "chains.csv").read_bytes() == (auto_run.folder / "chains.csv").read_bytes()


@pytest.mark.parametrize("damage, what", [
    (lambda text: text.replace(",True", ",False"), "0 rows are marked chosen"),
    (lambda text: text[:-1], "cut short"),
    (lambda text: "\n".join(line for index, line in enumerate(text.split("\n")) if index != 2), "the rule measures"),
    (lambda text: text.replace(",20,20,", ",20,25,", 1), "no measurement gives"),
])
def test_a_damaged_pilot_file_is_refused_and_the_folder_left_as_it_was(auto_run, tmp_path, damage, what):
    folder = tmp_path / "damaged"
    pfx.run(auto_config(), out=folder)
    path = next((folder / "estimation").glob("*.particle_count.csv"))
    path.write_text(damage(path.read_text()))
    before = snapshot(folder)
    longer = auto_config()
    longer["estimation"]["iterations"] = 8
    with pytest.raises(ConfigError) as refused:
        pfx.run(longer, out=folder)
    assert refused.value.file == str(path) and what in refused.value.reason
    assert snapshot(folder) == before


def test_the_cap_refusal_through_the_command_line_is_one_line_and_writes_nothing(tmp_path, pfx_in_process):
    path = write_config_file(tmp_path, auto_config(largest=8))
    ran = pfx_in_process("run", path, "--out", tmp_path / "out")
    assert ran.returncode == 2 and ran.stdout == ""
    assert len(ran.stderr.strip().splitlines()) == 1
    assert "filter.particles: even at the cap of 8 particles" in ran.stderr
    assert not (tmp_path / "out").exists()


def test_an_arm_s_cap_refusal_is_at_the_arm_s_key(tmp_path):
    config = auto_config(largest=8)
    config["filter"]["particles"] = 40
    config["arms"] = {"fixed": {"particles": 30}, "chosen": {"particles": "auto"}}
    with pytest.raises(ConfigError) as refused:
        pfx.run(config, out=tmp_path / "out")
    assert refused.value.key == "arms.chosen.particles" and not (tmp_path / "out").exists()


def test_the_pilot_point_may_be_given_and_is_said(tmp_path):
    at = {"model.process_noise.variance": 1.0, "model.measurement_noise.variance": 2.0}
    result = pfx.run(auto_config(at=at), out=tmp_path / "at")
    assert result.manifest["particle_count"]
    with pytest.raises(ConfigError, match="process_noise.variance=1, measurement_noise.variance=2 "
                                          r"\(estimation.particle_count.at\)"):
        pfx.run(auto_config(at=at, largest=8), out=tmp_path / "refused")


def filter_run_with_auto():
    config = tiny_config_dict()
    config["filter"] = {**config.get("filter", {}), "particles": "auto"}
    return config


def if2_with_auto():
    config = estimation_config("if2")
    config["filter"]["particles"] = "auto"
    return config


def pmmh_sweeping_auto():
    config = auto_config()
    config["filter"]["particles"] = 40
    config["sweep"] = {"filter.particles": [40, "auto"]}
    return config


def settings_without_auto():
    config = estimation_config("pmmh")
    config["estimation"]["particle_count"] = {"runs": 20}
    return config


def at_missing_a_parameter():
    return auto_config(at={"model.process_noise.variance": 1.0})


def at_outside_the_prior():
    return auto_config(at={"model.process_noise.variance": -1.0, "model.measurement_noise.variance": 1.0})


@pytest.mark.parametrize("config, key, words", [
    (filter_run_with_auto, "filter.particles", "a filter run needs a number of particles"),
    (if2_with_auto, "filter.particles", "IF2 needs a number of particles"),
    (pmmh_sweeping_auto, "sweep.filter.particles[1]", "a sweep compares the counts it lists"),
    (settings_without_auto, "estimation.particle_count", "would do nothing"),
    (at_missing_a_parameter, "estimation.particle_count.at", "gives no value for model.measurement_noise.variance"),
    (at_outside_the_prior, "estimation.particle_count.at.model.process_noise.variance", "outside the prior"),
])
def test_auto_where_it_means_nothing_is_refused_at_its_key(config, key, words):
    with pytest.raises(ConfigError) as refused:
        build_plan(config(), "auto.yaml")
    assert refused.value.key == key and words in refused.value.reason


def test_a_config_without_auto_keeps_its_record_and_hashes():
    """No `particle_count` appears in the record of a config without it: its config and results
    hashes, and so every committed folder, are unchanged."""
    plan = build_plan(estimation_config("pmmh"), "plain.yaml")
    assert "particle_count" not in plan.resolved["estimation"]
    assert "particle_count" not in json.dumps(plan.resolved)


# -- from Python ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def local_level():
    model = pfx.model("linear_gaussian", steps=50, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 0.5})
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([3]))
    return model, measurements[0]


def test_choose_particles_returns_the_count_and_its_table(local_level):
    model, measurements = local_level
    chosen = pfx.choose_particles(model, measurements, runs=20, smallest=8, seed=1)
    table = chosen.table
    assert list(table.columns) == list(PARTICLE_COUNT.own)
    assert table["chosen"].sum() == 1 and chosen.particles == int(table.loc[table["chosen"], "particles"].iloc[0])
    assert table["particles"].tolist()[:2] == [8, 16] and (table["runs"] == 20).all()
    again = pfx.choose_particles(model, measurements, runs=20, smallest=8, seed=1)
    assert again.particles == chosen.particles and again.table["sd"].equals(table["sd"])


@pytest.mark.parametrize("argument, value, words", [
    ("runs", 5, "greater than or equal to 10"),
    ("target_sd", 0.0, "greater than 0"),
    ("smallest", "many", "valid integer"),
    ("largest", 4, "below smallest"),
    ("seed", -1, "whole number"),
    ("particles", 100, "chooses the particle count"),
    ("kind", "kf", "no particles"),
])
def test_choose_particles_refuses_a_bad_argument_naming_it(local_level, argument, value, words):
    model, measurements = local_level
    with pytest.raises(ConfigError) as refused:
        pfx.choose_particles(model, measurements, **{argument: value})
    assert refused.value.file == "<python>" and refused.value.key == argument and words in refused.value.reason


def test_choose_particles_refuses_more_than_one_dataset_and_a_cap_too_small(local_level):
    model, measurements = local_level
    with pytest.raises(ConfigError, match="give one dataset"):
        pfx.choose_particles(model, np.stack([measurements, measurements]))
    with pytest.raises(ConfigError) as refused:
        pfx.choose_particles(model, measurements, runs=20, smallest=2, largest=4)
    assert refused.value.key == "largest" and "raise largest" in refused.value.reason


def test_particle_filter_refuses_auto():
    with pytest.raises(ConfigError, match="choose_particles"):
        pfx.particle_filter(pfx.model("linear_gaussian", transition_matrix=[[1.0]], measurement_matrix=[[1.0]]),
                            particles="auto")



# -- measured again after the warm-up (after_warm_up, the default) ---------------------------------------

def test_the_count_is_measured_again_after_the_warm_up_by_default():
    assert ParticleCount().after_warm_up is True


@pytest.fixture(scope="module")
def twice_run(tmp_path_factory):
    return pfx.run(auto_config(after_warm_up=True), out=tmp_path_factory.mktemp("twice") / "run")


def _tiny_problem():
    plan = build_plan(auto_config(after_warm_up=True), "auto.yaml")
    cell = plan.cells[0]
    return plan, cell, EstimationTarget(cell, plan.experiment.estimation, dataset(cell, plan.experiment.seed))


def test_after_the_warm_up_the_pilot_measures_where_the_chains_went(twice_run):
    """The second measurement is the rule at the median of the chains over the warm-up's second
    half (iteration 2 of a warm-up of 2), and the manifest gives the count the draws used."""
    plan, cell, target = _tiny_problem()
    table = twice_run.tables["particle_count"]
    assert table["stage"].tolist() == sorted(table["stage"], key=["before_chains", "after_warm_up"].index)
    after = table[table["stage"] == "after_warm_up"]
    chains = twice_run.chains
    point = np.median(chains[chains["iteration"] == 2][target.columns].to_numpy(), axis=0)
    settings = plan.experiment.estimation.pilot
    again = choose_particle_count(lambda n: log_likelihood_spread(target, point, n, settings.runs, plan.experiment.seed),
                                  settings, key="filter.particles", point_text="")
    assert after["particles"].tolist() == [row.particles for row in again.rows]
    assert np.array_equal(after["sd"].to_numpy(), np.array([row.sd for row in again.rows]))
    assert twice_run.manifest["particle_count"] == {cell.key: again.particles}


def test_after_the_warm_up_the_chains_are_pmmh_at_the_new_count_from_where_the_warm_up_left_them(twice_run):
    """Iterations 1-2 at the first count; then every chain's current estimate computed again at
    the second count from its own restart stream, and iterations 3-6 at that count."""
    plan, cell, target = _tiny_problem()
    table = twice_run.tables["particle_count"]
    first, second = (int(table[(table["stage"] == stage) & table["chosen"]]["particles"].iloc[0])
                     for stage in ("before_chains", "after_warm_up"))
    sampler = ParticleMarginalMetropolisHastings(target.with_particles(first), plan.experiment.seed, cell.stream_key)
    chains = sampler.start()
    rows = [(chains.values.copy(), chains.log_likelihood.copy())]
    for iteration in range(1, 7):
        if iteration == 3:
            moved = target.with_particles(second)
            chains.log_likelihood = moved.log_likelihoods(
                chains.values, [restart_seed(plan.experiment.seed, cell.stream_key, chain) for chain in range(2)])
            sampler = ParticleMarginalMetropolisHastings(moved, plan.experiment.seed, cell.stream_key)
        sampler.iterate(chains, iteration)
        rows.append((chains.values.copy(), chains.log_likelihood.copy()))
    written = twice_run.chains
    assert np.array_equal(written[target.columns].to_numpy().reshape(7, 2, -1), np.array([v for v, _ in rows]))
    assert np.array_equal(written["log_likelihood"].to_numpy().reshape(7, 2), np.array([ll for _, ll in rows]))


@pytest.mark.parametrize("stop", [3, 5])
def test_a_run_stopped_after_the_warm_up_resumes_at_the_count_measured_after_it(twice_run, tmp_path, monkeypatch,
                                                                                 stop):
    """Stopped at iteration 3 (just after the second measurement) or 5: the same command reads
    both counts back, measures nothing, and ends with the uninterrupted run's chains."""
    folder = tmp_path / "stopped"
    with monkeypatch.context() as patch:
        interrupt_at(patch, "pmmh", stop)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(auto_config(after_warm_up=True), out=folder)
    assert list((folder / "estimation").glob("*.particle_count_after_warm_up.csv"))
    with monkeypatch.context() as patch:
        no_pilot(patch)
        resumed = pfx.run(auto_config(after_warm_up=True), out=folder)
    assert (resumed.folder / "chains.csv").read_bytes() == (twice_run.folder / "chains.csv").read_bytes()
    pd.testing.assert_frame_equal(resumed.tables["particle_count"].drop(columns="run_time_s"),
                                  twice_run.tables["particle_count"].drop(columns="run_time_s"))


def test_chains_past_the_warm_up_without_their_second_count_are_refused(tmp_path, monkeypatch):
    folder = tmp_path / "stopped"
    with monkeypatch.context() as patch:
        interrupt_at(patch, "pmmh", 5)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(auto_config(after_warm_up=True), out=folder)
    [after] = (folder / "estimation").glob("*.particle_count_after_warm_up.csv")
    after.unlink()
    before = snapshot(folder)
    with pytest.raises(ConfigError, match="particle_count_after_warm_up.csv.*is missing, and the chains are past"):
        pfx.run(auto_config(after_warm_up=True), out=folder)
    assert snapshot(folder) == before


def test_the_radar_example_runs_both_measurements(tmp_path, pfx_in_process):
    """examples/plugins/radar-range-noise.yaml (its full run: docs/estimation.md), shrunk by
    --set to a few iterations and pilot runs: it validates, measures before the chains and after
    the warm-up, and names both counts."""
    config = REPO_ROOT / "examples" / "plugins" / "radar-range-noise.yaml"
    shrink = ["--set", "estimation.iterations=8", "--set", "estimation.warm_up=4",
              "--set", "estimation.particle_count.runs=10"]
    assert pfx_in_process("validate", config).returncode == 0
    result = pfx_in_process("run", config, "--out", tmp_path / "radar", *shrink)
    assert result.returncode == 0, result.stderr
    assert "particles auto ->" in result.stderr and "particles auto after the warm-up ->" in result.stderr
    table = pd.read_csv(tmp_path / "radar" / "particle_count.csv")
    assert table.groupby("stage")["chosen"].sum().to_dict() == {"after_warm_up": 1, "before_chains": 1}
