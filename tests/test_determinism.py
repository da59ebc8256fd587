"""Reproducibility: same config, same numbers; batching, workers and other arms change nothing.

docs/configuration.md#seeding-and-pairing: one root seed; every (cell, trial) has its own stream; trial t of every
arm sees the same true trajectory and measurements; results do not depend on --workers.
"""

from __future__ import annotations

import copy

import numpy as np
import pandas as pd
import pytest
from conftest import tiny_config_dict, write_config_file

from pfx.config.plan import build_plan
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, filter_seed, truth_seed
from pfx.run.batch import run_batch

SEED = 2024
TRIALS = 25                     # > 20: the runner splits each cell into several batches
ARMS = {"A": {"resampler": "systematic"},
        "B": {"resampler": "multinomial", "weighting": "euclidean", "ess_threshold": 0.7}}
TWO_ARMS = tiny_config_dict(
    name="determinism", seed=SEED, trials=TRIALS,
    model={"kind": "linear_gaussian", "steps": 6, "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
           "process_noise": {"family": "student_t", "df": 5.0, "variance": 0.5}},
    filter={"particles": 16, "ess_threshold": 0.5},
    arms=ARMS, sweep={"filter.particles": [8, 16]},
    outputs={"trace_trials": 2, "figures": []})
ONE_ARM = {**copy.deepcopy(TWO_ARMS), "arms": {"A": ARMS["A"]}}


def _trials(folder) -> pd.DataFrame:
    return pd.read_csv(folder / "trials.csv")


def _without_time(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.drop(columns=[c for c in frame.columns if c.startswith("run_time_s")])


@pytest.fixture(scope="module")
def runs(tmp_path_factory, run_pfx, pfx_in_process):
    """Four runs: two arms (twice, and with 2 workers), and arm A alone. The second and the one
    with workers are real processes (so the first two runs are in two processes, each with its
    own hash seed and state), the others the command line in the test's process."""
    root = tmp_path_factory.mktemp("determinism")
    write_config_file(root, TWO_ARMS, "two-arms.yaml")
    write_config_file(root, ONE_ARM, "one-arm.yaml")
    results = run_pfx.many({
        "second": (["run", "two-arms.yaml", "--out", "second"], root),
        "workers": (["run", "two-arms.yaml", "--out", "workers", "--workers", "2"], root),
    })
    results.update(pfx_in_process.many({
        "first": (["run", "two-arms.yaml", "--out", "first"], root),
        "one-arm": (["run", "one-arm.yaml", "--out", "one-arm"], root),
    }))
    for name, result in results.items():
        assert result.returncode == 0, f"{name}: {result.output}"
    return {name: root / name for name in results}


def test_same_config_twice_gives_identical_tables(runs):
    first, second = _trials(runs["first"]), _trials(runs["second"])
    assert len(first) == 2 * 2 * TRIALS
    pd.testing.assert_frame_equal(_without_time(first), _without_time(second), check_exact=True)
    assert (runs["first"] / "steps.csv").read_bytes() == (runs["second"] / "steps.csv").read_bytes()
    pd.testing.assert_frame_equal(_without_time(pd.read_csv(runs["first"] / "summary.csv")),
                                  _without_time(pd.read_csv(runs["second"] / "summary.csv")), check_exact=True)


def test_workers_do_not_change_results(runs):
    pd.testing.assert_frame_equal(_without_time(_trials(runs["first"])), _without_time(_trials(runs["workers"])),
                                  check_exact=True)
    assert (runs["first"] / "steps.csv").read_bytes() == (runs["workers"] / "steps.csv").read_bytes()


def test_trial_t_of_every_arm_sees_the_same_truth(runs):
    trials = _trials(runs["first"])
    assert trials["cell"].nunique() == 4 and set(trials["arm"]) == {"A", "B"}
    for t, group in trials.groupby("trial"):
        assert len(group) == 4
        assert group["truth_seed"].nunique() == 1, f"trial {t}: truth differs between cells"
        assert group["filter_seed"].nunique() == 4, f"trial {t}: cells share a filter stream"
    assert trials.groupby("cell")["filter_seed"].nunique().eq(TRIALS).all()
    # the traced true trajectories themselves are the same in every cell
    steps = pd.read_csv(runs["first"] / "steps.csv")
    assert steps["cell"].nunique() == 4
    assert steps.groupby(["trial", "step"])["truth_x1"].nunique().eq(1).all()
    assert steps.groupby(["trial", "step"])["estimate_x1"].nunique().gt(1).any()


def test_adding_an_arm_leaves_the_other_arm_unchanged(runs):
    alone = _without_time(_trials(runs["one-arm"]))
    with_b = _without_time(_trials(runs["first"]))
    with_b = with_b[with_b["arm"] == "A"].reset_index(drop=True)
    assert len(alone) == 2 * TRIALS
    pd.testing.assert_frame_equal(alone, with_b, check_exact=True)


def test_seed_columns_recreate_the_streams(runs):
    trials = _trials(runs["first"])
    # the cell keys are the plan's, so the filter seeds can be recomputed from a config alone
    plan = build_plan(copy.deepcopy(TWO_ARMS), "two-arms.yaml")
    assert [c.key for c in plan.cells] == list(trials["cell"].unique())
    stream_keys = {c.key: c.stream_key for c in plan.cells}
    for row in trials.itertuples():
        assert row.seed == SEED
        assert row.truth_seed == truth_seed(SEED, row.trial)
        assert row.filter_seed == filter_seed(SEED, stream_keys[row.cell], row.trial)
    # truth_seed alone regenerates the trial's true trajectory
    steps = pd.read_csv(runs["first"] / "steps.csv")
    cell = plan.cells[0]
    for t in (0, 1):
        seed = int(trials.loc[(trials["cell"] == cell.key) & (trials["trial"] == t), "truth_seed"].iloc[0])
        states, _ = simulate_truth(cell.truth_model, TrialStreams.from_seeds([seed]))
        traced = steps[(steps["cell"] == cell.key) & (steps["trial"] == t)].sort_values("step")
        np.testing.assert_allclose(states[0, 1:, 0], traced["truth_x1"].to_numpy(), rtol=1e-12, atol=0)


# --- batching, in process -------------------------------------------------------------------------

BATCH_ARMS = {
    "multinomial": {"resampler": "multinomial"},
    "stratified": {"resampler": "stratified"},
    "systematic": {"resampler": "systematic"},
    "residual": {"resampler": "residual"},
    "han_lee_iv": {"resampler": "han_lee_iv"},
    "sis": {"kind": "sis"},
    "roughening": {"diffusion": {"kind": "roughening", "factor": 0.2}},
    "mahalanobis": {"weighting": {"kind": "mahalanobis", "form": "innovation"}},
}
BATCH_CONFIG = tiny_config_dict(
    name="batching", seed=99, trials=6,
    model={"kind": "linear_gaussian", "steps": 8,
           "transition_matrix": [[1.0, 1.0], [0.0, 1.0]], "measurement_matrix": [[1.0, 0.0]],
           "process_noise": {"family": "student_t", "df": 4.0, "variance": [0.1, 0.05]},
           "measurement_noise": {"family": "laplace", "variance": 0.5}},
    filter={"particles": 24, "ess_threshold": 0.5},      # some trials resample at a step, others not
    arms=BATCH_ARMS)


@pytest.fixture(scope="module")
def batch_plan():
    return build_plan(copy.deepcopy(BATCH_CONFIG), "test.yaml")


@pytest.mark.numpy_only
@pytest.mark.parametrize("arm", list(BATCH_ARMS))
def test_batched_trials_equal_trials_run_one_by_one(batch_plan, arm):
    cell = next(c for c in batch_plan.cells if c.labels["arm"] == arm)
    trials = list(range(6))
    batched = run_batch(cell, 99, trials, trace_trials=6)
    singles = [run_batch(cell, 99, [t], trace_trials=6) for t in trials]
    one_by_one = pd.concat([s.trials for s in singles], ignore_index=True)
    pd.testing.assert_frame_equal(_without_time(batched.trials), _without_time(one_by_one), check_exact=True)
    pd.testing.assert_frame_equal(batched.steps, pd.concat([s.steps for s in singles], ignore_index=True),
                                  check_exact=True)
    if arm != "sis":
        # the ESS rule really split the batch: not every trial resampled at the same steps
        assert batched.trials["resample_count"].nunique() > 1 or batched.steps["resampled"].nunique() > 1


def test_cell_identity_leaves_out_defaults_but_keeps_every_kind():
    """Cell keys (and so the filter streams) hash only settings that differ from their declared
    defaults, so a new option with a default leaves existing results unchanged; every `kind`
    is kept, so two weightings at their own defaults still differ."""
    from pfx.config.plan import identity_dump
    from pfx.config.schema import FilterConfig

    assert identity_dump(FilterConfig()) == {"kind": "particle"}
    assert identity_dump(FilterConfig(particles=7)) == {"kind": "particle", "particles": 7}
    mahalanobis = identity_dump(FilterConfig(weighting={"kind": "mahalanobis"}))
    euclidean = identity_dump(FilterConfig(weighting={"kind": "euclidean"}))
    assert mahalanobis != euclidean
    assert mahalanobis["weighting"] == {"kind": "mahalanobis"}
