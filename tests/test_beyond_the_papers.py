"""The "beyond the papers" section: its statistics, its configs, ``also_run``, its figures and its
report on small generated result folders.

The statistics are checked against their definitions (the pooled within-dataset variance by
hand, the chi-square and F intervals by their coverage on normal samples with fixed seeds, the
Wilson interval against statsmodels), the recovery rule on made-up traces.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import REPO_ROOT, tiny_config_dict, write_config_file

import pfx
from pfx.analysis.estimator_spread import variance_ratio_interval, within_dataset_spread
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.figures.registry import render_figures
from pfx.papers.base import REPORTS, VERDICTS, PaperResults
from pfx.papers.beyond_the_papers import recovery, wilson_interval
from pfx.papers.reproduce import paper_configs
from pfx.safe_yaml import load_config_file

SECTION = REPO_ROOT / "configs" / "papers" / "beyond-the-papers"


# -- the statistics -------------------------------------------------------------------------------

def _frame(values_by_dataset: dict[int, list[float]], cell: str = "a") -> pd.DataFrame:
    rows = [{"cell": cell, "arm": cell, "n_particles": 10, "truth_seed": seed, "log_likelihood": value}
            for seed, values in values_by_dataset.items() for value in values]
    return pd.DataFrame(rows)


def test_within_dataset_variance_pools_the_squares_about_each_datasets_own_mean():
    frame = _frame({1: [1.0, 2.0, 3.0], 2: [10.0, 14.0], 3: [7.0]})     # dataset 3: one run, no spread
    row = within_dataset_spread(frame, ["arm", "n_particles"]).iloc[0]
    squares = (1 + 0 + 1) + (4 + 4)
    assert row["degrees_of_freedom"] == 2 + 1
    assert row["variance"] == pytest.approx(squares / 3)
    assert row["datasets"] == 3 and row["runs"] == 6
    assert row["variance_ci95_low"] < row["variance"] < row["variance_ci95_high"]


def test_non_finite_runs_are_left_out_and_a_cell_without_repeats_has_no_variance():
    frame = pd.concat([_frame({1: [1.0, 3.0, -np.inf]}), _frame({1: [5.0], 2: [6.0]}, cell="b")])
    spread = within_dataset_spread(frame, ["arm"]).set_index("arm")
    assert spread.loc["a", "variance"] == pytest.approx(2.0) and spread.loc["a", "runs"] == 2
    assert math.isnan(spread.loc["b", "variance"])


def test_the_variance_and_ratio_intervals_cover_at_their_stated_rate():
    """1000 normal experiments (fixed seed): each interval covers the truth in 95% of them, within
    3 binomial standard errors (sqrt(0.95 * 0.05 / 1000) = 0.0069)."""
    random = np.random.default_rng(20260)
    experiments, runs = 1000, 12
    a, b = np.empty((experiments, runs)), np.empty((experiments, runs))
    for experiment in range(experiments):
        a[experiment] = random.normal(0.0, 2.0, size=runs)            # variance 4
        b[experiment] = random.normal(5.0, 1.0, size=runs)            # variance 1
    # every experiment's two samples as cells of one table, one call: each cell's interval is
    # computed on its own runs alone, as 1000 calls on two-cell tables would
    cells = [f"{arm}{experiment}" for arm in "ab" for experiment in range(experiments)]
    frame = pd.DataFrame({"cell": np.repeat(cells, runs), "n_particles": 10, "truth_seed": 7,
                          "log_likelihood": np.concatenate([a.ravel(), b.ravel()])})
    frame["arm"] = frame["cell"]
    spread = within_dataset_spread(frame, ["arm"]).set_index("arm")
    assert len(spread) == 2 * experiments and (spread["runs"] == runs).all()
    covered_variance = covered_ratio = 0
    for experiment in range(experiments):
        first, second = spread.loc[f"a{experiment}"], spread.loc[f"b{experiment}"]
        covered_variance += first["variance_ci95_low"] <= 4.0 <= first["variance_ci95_high"]
        _, low, high = variance_ratio_interval(first["variance"], runs - 1, second["variance"], runs - 1)
        covered_ratio += low <= 4.0 <= high
    for covered in (covered_variance, covered_ratio):
        assert abs(covered / experiments - 0.95) < 3 * math.sqrt(0.95 * 0.05 / experiments), covered


def test_wilson_interval_is_statsmodels():
    from statsmodels.stats.proportion import proportion_confint

    for successes, trials in ((0, 10), (6, 100), (57, 100), (20, 20)):
        assert wilson_interval(successes, trials) == pytest.approx(
            proportion_confint(successes, trials, alpha=0.05, method="wilson"), abs=1e-12)


def test_recovery_needs_the_final_error_within_the_radius_and_times_the_last_stay():
    errors = {"recovers": [5, 5, 90, 40, 10, 20, 12, 9],      # kidnapped at step 3; within 15 from step 6 on
              "never": [5, 5, 90, 80, 60, 40, 30, 20],
              "unhurt": [5, 5, 4, 6, 5, 5, 5, 5]}             # the kidnapping did not throw it off
    steps = pd.DataFrame([{"arm": "mcl", "trial": trial, "step": step, "error_distance": value}
                          for trial, (name, values) in enumerate(errors.items()) for step, value in enumerate(values)])
    outcome = recovery(steps, kidnap_step=2, radius=15.0).set_index("trial")
    assert outcome["recovered"].tolist() == [True, False, True]
    assert outcome.loc[0, "time_to_recover"] == 6 - 2
    assert math.isnan(outcome.loc[1, "time_to_recover"])
    assert outcome.loc[2, "time_to_recover"] == 0


# -- the configs and also_run ------------------------------------------------------------------------

def test_the_section_runs_its_folder_and_the_configs_its_paper_yaml_lists():
    configs = paper_configs(REPO_ROOT / "configs" / "papers")["beyond-the-papers"]
    names = [path.name for path in configs]
    assert {"kld-sampling.yaml", "kidnapped-robot.yaml", "proposals-stochastic-volatility.yaml",
            "loglik-stochastic-volatility.yaml"} <= set(names)
    own = sorted(p.name for p in SECTION.glob("*.yaml") if p.name != "paper.yaml")
    assert names[:len(own)] == own and len(own) == 9
    for path in configs:
        plan = build_plan(load_config_file(path), str(path))
        assert plan.cells, path


def test_each_loglik_config_is_its_proposals_config_on_one_dataset():
    for loglik in sorted(SECTION.glob("loglik-*.yaml")) + [REPO_ROOT / "examples" / "plugins" /
                                                           "loglik-stochastic-volatility.yaml"]:
        twin = loglik.with_name(loglik.name.replace("loglik-", "proposals-"))
        a, b = load_config_file(loglik), load_config_file(twin)
        assert a.pop("datasets") == 1
        for key in ("name", "description", "outputs"):
            a.pop(key), b.pop(key)
        assert a == b, loglik.name


def test_an_also_run_entry_that_is_not_a_config_is_one_error_naming_paper_yaml(tmp_path, pfx_in_process):
    folder = tmp_path / "configs" / "toy"
    write_config_file(folder, tiny_config_dict(name="toy"), "toy.yaml")
    write_config_file(folder, {"also_run": ["toy.yaml", "../missing.yaml"]}, "paper.yaml")
    with pytest.raises(ConfigError) as caught:
        paper_configs(tmp_path / "configs")
    assert caught.value.key == "also_run[1]" and caught.value.file.endswith("paper.yaml")
    result = pfx_in_process("reproduce", "--configs", tmp_path / "configs", "--out", tmp_path / "results")
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "paper.yaml: also_run[1]: no config file '../missing.yaml'" in result.stderr
    assert not (tmp_path / "results").exists()


# -- the figures and the report on small runs ----------------------------------------------------------

CHECKED_FIGURES = {"loglik-growth": ("log_likelihood_spread_vs_particles",), "kld-sampling": ("particles_over_time",)}


@pytest.fixture(scope="module")
def section(tmp_path_factory) -> Path:
    """The section's configs cut down (few trials, small N), run into a results folder."""
    root = tmp_path_factory.mktemp("beyond") / "beyond-the-papers"
    for path in paper_configs(REPO_ROOT / "configs" / "papers")["beyond-the-papers"]:
        raw = load_config_file(path)
        if "plugins" in raw:
            raw["plugins"] = [str(path.parent / plugin) for plugin in raw["plugins"]]
        raw["trials"] = 6
        if raw.get("datasets") is None:
            raw["outputs"]["trace_trials"] = min(6, raw["outputs"].get("trace_trials", 3))
        raw["outputs"].pop("particles", None)
        # only the figures a test here looks at: the report shows a figure when its file is there
        # and reads none (its verdicts come from the tables); each of the others is drawn by
        # the figure tests (tests/test_figures_smoothing.py, tests/test_figure_fixes.py, ...)
        raw["outputs"]["figures"] = [f for f in raw["outputs"]["figures"] if f in CHECKED_FIGURES.get(raw["name"], ())]
        raw["filter"]["particles"] = min(raw["filter"].get("particles", 200), 200)
        if "sweep" in raw:
            raw["sweep"]["filter.particles"] = [20, 60]
        if "model.steps" in raw.get("sweep", {}):         # the ancestral tree: short records
            raw["sweep"]["model.steps"] = [60, 120]
        pfx.run(raw, out=root / raw["name"])
    (root / "paper.yaml").write_text((SECTION / "paper.yaml").read_text())
    return root


def test_the_report_gives_a_verdict_per_claim_and_a_table_per_model(section):
    report = REPORTS["beyond-the-papers"](PaperResults(section))
    assert len(report.verdicts) == 7
    assert all(verdict.verdict in VERDICTS for verdict in report.verdicts)
    titles = [item.title for item in report.items if hasattr(item, "title")]
    for model in ("linear-Gaussian", "growth", "falling body", "stochastic volatility", "KLD", "Recovery",
                  "Smoothers against the filter: the growth model", "Smoothers against the filter: range beacons",
                  "Size of the ancestral tree"):
        assert any(model in title for title in titles), (model, titles)


def test_the_log_likelihood_spread_figure_and_the_particles_figure_are_drawn(section):
    spread = section / "loglik-growth" / "figures" / "log_likelihood_spread_vs_particles.png"
    counts = section / "kld-sampling" / "figures" / "particles_over_time.png"
    assert spread.stat().st_size > 10_000 and counts.stat().st_size > 10_000


def test_the_spread_figure_is_skipped_without_repeated_datasets(section, tmp_path):
    """Independent datasets have no within-dataset spread: the figure draws nothing."""
    written = render_figures(section / "proposals-growth", ["log_likelihood_spread_vs_particles"], ("png",))
    assert not written
