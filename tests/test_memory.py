"""Memory: the per-trial estimate bounds the measured peak; batches fit; too-large cells are refused."""

from __future__ import annotations

import copy
import tracemalloc

import pandas as pd
import pytest
import yaml

from pfx.config.plan import build_plan
from pfx.run.batch import run_batch
from pfx.run.memory import SPEED_PARTICLES, cell_trial_bytes, format_size, parse_size, trials_per_batch

CONFIGS = {
    "falling_body": {"name": "m", "trials": 2, "model": {"kind": "falling_body", "variant": "simon", "substeps": 2,
                                                         "steps": 5},
                     "filter": {"initial": {"kind": "gaussian", "mean": [3.0e5, -2.0e4, 1.0e-3],
                                            "covariance": [1.0e6, 4.0e6, 1.0e-7]},
                                "diffusion": {"kind": "roughening"}},
                     "arms": {"gaussian": {}, "mahalanobis": {"weighting": {"kind": "mahalanobis",
                                                                            "form": "innovation"}}}},
    "range_beacons": {"name": "m", "trials": 2,
                      "model": {"kind": "range_beacons", "steps": 5,
                                "beacons": [[0, 0], [10, 0], [0, 10], [10, 10], [5, 5], [2, 8]]},
                      "filter": {"ess_threshold": 0.5}},
    "linear_gaussian": {"name": "m", "trials": 2,
                        "model": {"kind": "linear_gaussian", "steps": 5,
                                  "transition_matrix": [[1, 1, 0], [0, 1, 0], [0, 0, 1]],
                                  "measurement_matrix": [[1, 0, 0], [0, 0, 1]]},
                        "filter": {"resampler": "residual"},
                        "metrics": {"convergence": {"criterion": "spread", "weighted": True}}},
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_estimate_bounds_the_measured_peak(name):
    """tracemalloc sees numpy's allocations: the peak of a batch must stay below the estimate."""
    raw = dict(CONFIGS[name])
    raw["filter"] = {**raw["filter"], "particles": 20000}
    for cell in build_plan(raw, "m.yaml").cells:
        # The first batch in a process also pays for lazy imports and compiled-loop caches (about
        # 25 MB): warm up, so the peak measured is the batch's own, whatever test ran before.
        run_batch(cell, 1, [0], 0)
        tracemalloc.start()
        run_batch(cell, 1, [0, 1], 0)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        estimate = 2 * cell_trial_bytes(cell)
        assert peak <= estimate, f"{name}/{cell.labels['arm']}: peak {peak} > estimate {estimate}"
        assert peak >= 0.3 * estimate, "the estimate should not be wildly pessimistic either"


def test_batches_fit_the_budget():
    cell = build_plan(CONFIGS["linear_gaussian"], "m.yaml").cells[0]
    one = cell_trial_bytes(cell)
    assert trials_per_batch(cell, 100, budget=10 * one) == 10
    assert trials_per_batch(cell, 100, budget=10 * one, workers=2) == 5
    assert trials_per_batch(cell, 100, budget=one // 2) == 1
    assert trials_per_batch(cell, 8, budget=100 * one) == 8


def test_batches_are_large_enough_to_be_fast():
    """Small clouds: ~10 batches for the progress bar, unless batches would hold fewer than
    SPEED_PARTICLES particles; never fewer batches than workers; memory still wins."""
    raw = copy.deepcopy(CONFIGS["linear_gaussian"])
    raw["filter"]["particles"] = 100
    cell = build_plan(raw, "m.yaml").cells[0]
    one = cell_trial_bytes(cell)
    plenty = 10_000 * one
    assert trials_per_batch(cell, 2000, budget=plenty) == -(-SPEED_PARTICLES // 100)     # 656 trials
    assert trials_per_batch(cell, 100, budget=plenty) == 100                              # one batch
    assert trials_per_batch(cell, 100, budget=plenty, workers=2) == 50                    # one per worker
    assert trials_per_batch(cell, 100, budget=20 * one) == 20                             # memory wins
    raw["filter"]["particles"] = 100_000
    assert trials_per_batch(build_plan(raw, "m.yaml").cells[0], 100, budget=10**12) == 10   # progress


def test_parse_and_format_sizes():
    assert parse_size("512M") == 512 * 1024**2
    assert parse_size("1.5G") == int(1.5 * 1024**3)
    assert parse_size("2GiB") == 2 * 1024**3
    assert parse_size("1000") == 1000
    assert format_size(3 * 1024**3) == "3.0 GiB"


def test_a_cell_that_cannot_fit_is_refused_with_the_estimate(pfx_in_process, tmp_path):
    config = tmp_path / "big.yaml"
    config.write_text(yaml.safe_dump({**CONFIGS["linear_gaussian"], "filter": {"particles": 1_000_000}}))
    done = pfx_in_process("run", config, "--out", tmp_path / "out", "--max-memory", "100M")
    assert done.returncode == 2
    line, = done.stderr.strip().splitlines()
    assert line.startswith("pfx: error: ") and "big.yaml" in line and "filter.particles" in line
    assert "needs about" in line and "MiB" in line and "100.0 MiB" in line
    assert not (tmp_path / "out").exists()


def test_splitting_trials_into_small_batches_changes_nothing(pfx_in_process, tmp_path):
    """A budget of about one trial forces batches of one; the tables must not change."""
    raw = {**CONFIGS["range_beacons"], "trials": 6, "filter": {"particles": 3000, "ess_threshold": 0.5}}
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump(raw))
    one_trial = cell_trial_bytes(build_plan(raw, "c.yaml").cells[0])
    outs = {}
    for label, limit in (("small", one_trial + 1), ("large", 1000 * one_trial)):
        outs[label] = tmp_path / label
        done = pfx_in_process("run", config, "--out", outs[label], "--max-memory", limit, "--quiet")
        assert done.returncode == 0, done.stderr
    small, large = (pd.read_csv(outs[k] / "trials.csv").drop(columns="run_time_s") for k in ("small", "large"))
    pd.testing.assert_frame_equal(small, large, check_exact=True)
