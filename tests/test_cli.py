"""The ``pfx`` command line, end to end.

A module fixture starts the base run (a tiny run with a two-cell sweep) as a real ``python -m pfx``
process, the end-to-end check of the command as users start it, and the other invocations (a
run with ``--set``/``--trials``, ``validate``, ``list``, ``schema``, ``reproduce`` ...) through the
command line's entry point in the test's process; tests that need a finished result folder work
on copies of it, again in the test's process (what they check, messages, exit statuses and
files, a process of its own would not show any better).
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import stat
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, csv_fields, tiny_config_dict, write_config_file
from scipy import stats

import pfx
from pfx.analysis.summary import MINIMUM_VALUES
from pfx.analysis.value_ranges import metric_range

EXAMPLES = sorted((REPO_ROOT / "configs" / "examples").glob("*.yaml"))
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
TRIALS, PARTICLES, STEPS, TRACE_TRIALS, HOLD = 6, [10, 20], [5, 2], 2, 3     # 6: the fewest with intervals
CELLS = len(PARTICLES) * len(STEPS)
# hold 3 > 2 steps: those cells never converge, so empty (never 'nan') fields must appear
BASE = tiny_config_dict(name="cli-base", seed=11, trials=TRIALS,
                        sweep={"filter.particles": PARTICLES, "model.steps": STEPS},
                        metrics={"convergence": {"criterion": "truth", "radius": 1.0, "hold": HOLD}},
                        outputs={"trace_trials": TRACE_TRIALS})
REQUIRED_TRIAL_COLUMNS = [
    "cell", "arm", "n_particles", "resampler", "weighting", "trial", "seed", "truth_seed", "filter_seed",
    "rmse_x1", "rmse_position", "error_distance_mean", "error_distance_final", "convergence_step",
    "converged", "error_at_convergence", "ess_mean", "resample_count", "degenerate_steps", "run_time_s"]
SUMMARY_STATISTICS = ("n", "mean", "std", "sem", "ci95_low", "ci95_high", "median")


@pytest.fixture(scope="module")
def cli(tmp_path_factory, run_pfx, pfx_in_process):
    """Run the independent invocations; {name: PfxResult}, plus the folders."""
    root = tmp_path_factory.mktemp("cli")
    write_config_file(root, BASE, "exp.yaml")
    write_config_file(root, tiny_config_dict(name="single", outputs={"trace_trials": 1, "figures": []}),
                      "single.yaml")
    write_config_file(root, tiny_config_dict(sweep={"metrics.convergence.radius": [1.0, 2.0]}),
                      "metric-sweep.yaml")
    (root / "empty-configs").mkdir()
    write_config_file(root / "paper-configs" / "toy-paper",
                      tiny_config_dict(name="toy-experiment", outputs={"trace_trials": 1, "figures": []}),
                      "first.yaml")
    jobs = {
        "run-set": (["run", "single.yaml", "--out", "out-set", "--set", "filter.particles=7", "--trials", "3"], root),
        "validate": (["validate", "exp.yaml"], root),
        "list": (["list"], root),
        "list-resamplers": (["list", "resamplers"], root),
        "list-nonsense": (["list", "nonsense"], root),
        "schema": (["schema"], root),
        "schema-markdown": (["schema", "--format", "markdown"], root),
        "compare": (["compare", "out-missing", "--metric", "rmse_position"], root),
        "bench": (["bench", "--repeats", "0"], root),
        "reproduce-empty": (["reproduce", "--configs", "empty-configs", "--out", "results-empty"], root),
        "reproduce": (["reproduce", "--configs", "paper-configs", "--out", "results"], root),
        "reproduce-unknown": (["reproduce", "toy-papr", "--configs", "paper-configs", "--out", "results-unknown"],
                              root),
        "bad-option": (["run", "exp.yaml", "--trials", "0", "--out", "out-bad-option"], root),
        "metric-sweep": (["validate", "metric-sweep.yaml"], root),
    }
    for example in EXAMPLES:
        jobs[f"example:{example.name}"] = (["validate", str(example)], REPO_ROOT)
    results = {"run": run_pfx("run", "exp.yaml", "--out", "out", cwd=root)} | pfx_in_process.many(jobs)
    results["root"] = root
    return results


@pytest.fixture(scope="module")
def out(cli) -> Path:
    """The finished result folder of the base run."""
    result = cli["run"]
    assert result.returncode == 0, result.output
    return cli["root"] / "out"


@pytest.fixture(scope="module")
def followups(out, cli, pfx_in_process, tmp_path_factory):
    """The second wave, in the test's process, on copies of the finished folder: run again, run a changed
    config into it, re-render its figures; and `pfx figures` on a folder that is no result."""
    root = tmp_path_factory.mktemp("cli-followups")
    folders = {name: root / name for name in ("again", "changed", "figures-again")}
    for folder in folders.values():
        shutil.copytree(out, folder)
    before = {name: {table: (folder / table).read_bytes() for table in ("trials.csv", "summary.csv", "manifest.json")}
              for name, folder in folders.items()}
    shutil.rmtree(folders["figures-again"] / "figures")
    (folders["figures-again"] / "config.yaml").unlink()   # figures come from the CSV files (and manifest) alone
    # another seed changes the config; no figures, which the test of this config does not check
    changed = write_config_file(root, {**BASE, "seed": 12, "outputs": {**BASE["outputs"], "figures": []}},
                                "changed.yaml")
    (root / "not-a-result").mkdir()
    jobs = {
        "again": (["run", cli["root"] / "exp.yaml", "--out", folders["again"]], root),
        "changed": (["run", changed, "--out", folders["changed"]], root),
        "figures": (["figures", folders["figures-again"]], root),
        "figures-not-a-result": (["figures", root / "not-a-result"], root),
    }
    results = pfx_in_process.many(jobs)
    return {"folders": folders, "before": before, "changed-config": changed, "root": root, **results}


def _one_error_line(result) -> str:
    assert "Traceback" not in result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("pfx: error: "), lines[0]
    return lines[0]


# --- pfx run: the result folder ------------------------------------------------------------------

def test_run_writes_every_output_and_no_leftovers(out, cli):
    names = {p.name for p in out.iterdir()}
    assert {"config.yaml", "manifest.json", "trials.csv", "summary.csv", "steps.csv", "figures"} <= names
    assert "cells" not in names and not [n for n in names if n.startswith(".tmp")], names
    figures = sorted(p.name for p in (out / "figures").iterdir())
    manifest = json.loads((out / "manifest.json").read_text())
    # the default figures of a sweep over particle counts: the metric against N, then over time
    assert manifest["figures"] == ["rmse_vs_particles", "error_over_time", "ess_over_time"]
    assert figures == sorted(f"{name}.png" for name in manifest["figures"])
    for png in (out / "figures").iterdir():
        assert png.read_bytes().startswith(PNG_SIGNATURE)
    assert "cli-base" in cli["run"].stdout


def test_config_yaml_is_the_resolved_config_that_validate_prints(out, cli):
    result = cli["validate"]
    assert result.returncode == 0, result.output
    printed = yaml.safe_load(result.stdout)
    written = yaml.safe_load((out / "config.yaml").read_text())
    assert printed == written
    assert written["filter"]["resampler"] == "systematic" and written["model"]["dt"] == 1.0   # defaults filled in
    assert written["sweep"] == BASE["sweep"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert f"config hash {manifest['config_hash']}" in result.stdout
    assert f"{CELLS} cell(s) x {TRIALS} trial(s)" in result.stdout


def test_manifest_records_provenance(out):
    manifest = json.loads((out / "manifest.json").read_text())
    assert re.fullmatch(r"[0-9a-f]{16}", manifest["config_hash"])
    assert manifest["seed"] == 11
    assert manifest["pfx_version"] == pfx.__version__
    assert manifest["python"] == platform.python_version()
    assert manifest["numpy"] == np.__version__
    assert isinstance(manifest["platform"], str) and manifest["platform"]
    assert manifest["complete"] is True
    assert manifest["started"] and manifest["finished"]
    trials = pd.read_csv(out / "trials.csv")
    assert [c["cell"] for c in manifest["cells"]] == list(trials["cell"].unique())
    for cell in manifest["cells"]:
        assert isinstance(cell["wall_time_s"], float) and cell["wall_time_s"] >= 0


def test_trials_csv_has_one_row_per_cell_and_trial(out):
    trials = pd.read_csv(out / "trials.csv")
    missing = [c for c in REQUIRED_TRIAL_COLUMNS if c not in trials.columns]
    assert not missing, f"trials.csv lacks {missing}"
    assert len(trials) == CELLS * TRIALS
    assert trials["cell"].nunique() == CELLS
    assert sorted(trials["n_particles"].unique()) == PARTICLES
    assert sorted(trials["model_steps"].unique()) == sorted(STEPS)         # a swept key becomes a column
    assert (trials["steps"] == trials["model_steps"]).all()
    for _, group in trials.groupby("cell"):
        assert sorted(group["trial"]) == list(range(TRIALS))
        assert group["n_particles"].nunique() == 1
    assert (trials["seed"] == 11).all()
    assert (trials["arm"] == "default").all() and (trials["resampler"] == "systematic").all()
    assert trials["converged"].dtype == bool
    # a convergence step (and the error then) exactly where the trial converged
    assert (trials["convergence_step"].notna() == trials["converged"]).all()
    assert (trials["error_at_convergence"].notna() == trials["converged"]).all()
    assert not trials.loc[trials["steps"] < HOLD, "converged"].any()
    assert (trials["resample_count"] == trials["steps"]).all()          # ess_threshold 1: every step


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_result_files_get_the_usual_permissions(out):
    expected = 0o666 & ~_umask()
    if expected == 0o600:
        pytest.skip("this umask makes private files the expected result")
    for path in [*out.glob("*.csv"), out / "manifest.json", out / "config.yaml", *(out / "figures").iterdir()]:
        assert stat.S_IMODE(path.stat().st_mode) == expected, f"{path.name}: {oct(stat.S_IMODE(path.stat().st_mode))}"


@pytest.mark.parametrize("table", ["trials.csv", "summary.csv", "steps.csv"])
def test_no_nan_text_in_csv(out, table):
    text = (out / table).read_text()
    assert text.strip()
    bad = {field for field in csv_fields(text) if field.strip().lower() in ("nan", "-nan", "+nan", "<na>")}
    assert not bad, f"{table} holds {bad}"


def test_summary_matches_statistics_recomputed_from_trials(out):
    trials = pd.read_csv(out / "trials.csv")
    summary = pd.read_csv(out / "summary.csv")
    assert len(summary) == trials["cell"].nunique()
    assert (summary["trials"] == TRIALS).all()
    metrics = [c for c in trials.columns if f"{c}_mean" in summary.columns]
    for metric in ("rmse_position", "error_distance_mean", "ess_mean", "convergence_step", "converged"):
        assert metric in metrics
        for statistic in SUMMARY_STATISTICS:
            assert f"{metric}_{statistic}" in summary.columns
    assert (summary.loc[summary["model_steps"] < HOLD, "convergence_step_n"] == 0).all()
    for _, row in summary.iterrows():
        group = trials[trials["cell"] == row["cell"]]
        assert row["n_particles"] == group["n_particles"].iloc[0]
        for metric in metrics:
            values = group[metric].to_numpy(dtype=float)
            values = values[np.isfinite(values)]
            n = len(values)
            assert row[f"{metric}_n"] == n, metric
            if n == 0:
                assert np.isnan(row[f"{metric}_mean"]) and np.isnan(row[f"{metric}_median"]), metric
                continue
            assert row[f"{metric}_mean"] == pytest.approx(values.mean(), rel=1e-9, abs=1e-12), metric
            assert row[f"{metric}_median"] == pytest.approx(np.median(values), rel=1e-9, abs=1e-12), metric
            if n < 2:
                assert np.isnan(row[f"{metric}_std"]) and np.isnan(row[f"{metric}_ci95_low"]), metric
                continue
            std = values.std(ddof=1)
            sem = std / np.sqrt(n)
            half = stats.t.ppf(0.975, n - 1) * sem
            assert row[f"{metric}_std"] == pytest.approx(std, rel=1e-9, abs=1e-12), metric
            assert row[f"{metric}_sem"] == pytest.approx(sem, rel=1e-9, abs=1e-12), metric
            if n < MINIMUM_VALUES:             # too few values for an interval
                assert np.isnan(row[f"{metric}_ci95_low"]) and np.isnan(row[f"{metric}_ci95_high"]), metric
                continue
            value_range = metric_range(metric)
            if value_range.share:              # the Wilson score interval of the share
                interval = stats.binomtest(int(values.sum()), n).proportion_ci(method="wilson")
                low, high = interval.low, interval.high
            else:                              # the t-interval, cut at the metric's bounds
                low = max(values.mean() - half, value_range.low)
                high = min(values.mean() + half, value_range.high)
            assert row[f"{metric}_ci95_low"] == pytest.approx(low, rel=1e-9, abs=1e-12), metric
            assert row[f"{metric}_ci95_high"] == pytest.approx(high, rel=1e-9, abs=1e-12), metric


def test_steps_csv_traces_the_first_trials_of_each_cell(out):
    steps = pd.read_csv(out / "steps.csv")
    for column in ("cell", "trial", "step", "truth_x1", "estimate_x1", "error_distance", "ess"):
        assert column in steps.columns
    assert steps["cell"].nunique() == CELLS
    for _, group in steps.groupby("cell"):
        assert sorted(group["trial"].unique()) == list(range(TRACE_TRIALS))
        for _, trace in group.groupby("trial"):
            assert sorted(trace["step"]) == list(range(1, trace["model_steps"].iloc[0] + 1))
    assert np.allclose(steps["error_distance"], (steps["estimate_x1"] - steps["truth_x1"]).abs())


# --- running again ---------------------------------------------------------------------------------

def test_run_again_is_up_to_date_and_changes_nothing(followups):
    result, folder = followups["again"], followups["folders"]["again"]
    assert result.returncode == 0, result.output
    assert "up to date" in result.output
    assert {table: (folder / table).read_bytes() for table in followups["before"]["again"]} == \
        followups["before"]["again"]


def test_changed_config_into_same_folder_is_refused_unless_fresh(followups, pfx_in_process):
    refused, folder = followups["changed"], followups["folders"]["changed"]
    before = followups["before"]["changed"]
    assert refused.returncode == 2, refused.output
    line = _one_error_line(refused)
    assert str(folder) in line and "different config" in line and "--fresh" in line
    assert {table: (folder / table).read_bytes() for table in before} == before

    fresh = pfx_in_process("run", followups["changed-config"], "--out", folder, "--fresh", cwd=followups["root"])
    assert fresh.returncode == 0, fresh.output
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["config_hash"] != json.loads(before["manifest.json"])["config_hash"]
    assert manifest["seed"] == 12 and manifest["complete"] is True
    assert (pd.read_csv(folder / "trials.csv")["seed"] == 12).all()


def test_set_and_trials_override_the_config(cli):
    result = cli["run-set"]
    assert result.returncode == 0, result.output
    folder = cli["root"] / "out-set"
    trials = pd.read_csv(folder / "trials.csv")
    assert (trials["n_particles"] == 7).all()
    assert sorted(trials["trial"]) == [0, 1, 2]
    config = yaml.safe_load((folder / "config.yaml").read_text())
    assert config["filter"]["particles"] == 7 and config["trials"] == 3
    assert json.loads((folder / "manifest.json").read_text())["trials"] == 3


def test_bad_command_line_option_exits_2_and_writes_nothing(cli):
    result = cli["bad-option"]
    assert result.returncode == 2
    assert "Traceback" not in result.output
    assert "--trials" in result.stderr
    assert not (cli["root"] / "out-bad-option").exists()


def test_bad_command_line_option_is_one_error_line(cli):
    _one_error_line(cli["bad-option"])


def test_sweep_over_a_metric_parameter_is_valid(cli):
    result = cli["metric-sweep"]
    assert result.returncode == 0, result.output
    assert "2 cell(s)" in result.stdout


# --- the other commands --------------------------------------------------------------------------

def test_list_names_every_registry(cli):
    result = cli["list"]
    assert result.returncode == 0, result.output
    for section in ("models", "resamplers", "weightings", "noises", "metrics", "figures"):
        assert re.search(rf"^{section}:$", result.stdout, re.M), section
    for name in ("linear_gaussian", "falling_body", "systematic", "mahalanobis", "student_t", "error_over_time"):
        assert re.search(rf"^  {name}\s+\S", result.stdout, re.M), name      # with a description


def test_list_resamplers_flags_han_lee_iv_as_biased(cli):
    result = cli["list-resamplers"]
    assert result.returncode == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0] == "resamplers:"
    assert {"multinomial", "stratified", "systematic", "residual", "han_lee_iv"} <= {
        line.split()[0] for line in lines[1:]}
    biased = [line.split()[0] for line in lines[1:] if re.search(r"\bbiased\b", line, re.I)]
    assert biased == ["han_lee_iv"]


def test_list_of_nonsense_is_an_error(cli):
    result = cli["list-nonsense"]
    assert result.returncode == 2
    assert "nonsense" in _one_error_line(result)
    assert result.stdout == ""


def test_schema_is_json_schema_of_the_config(cli):
    result = cli["schema"]
    assert result.returncode == 0, result.output
    schema = json.loads(result.stdout)
    # a config is an experiment or a study
    assert [choice["$ref"] for choice in schema["anyOf"]] == ["#/$defs/Experiment", "#/$defs/StudyExperiment"]
    experiment = schema["$defs"]["Experiment"]
    assert {"model", "filter", "arms", "sweep", "trials", "seed", "metrics", "outputs"} <= set(experiment["properties"])
    assert "name" in experiment["required"] and "model" in experiment["required"]
    assert "study" in schema["$defs"]["StudyExperiment"]["required"]


def test_schema_markdown_is_the_config_reference(cli):
    result = cli["schema-markdown"]
    assert result.returncode == 0, result.output
    assert "### `filter`" in result.stdout
    assert "| `particles` |" in result.stdout and "| `ess_threshold` |" in result.stdout
    assert "#### `kind: linear_gaussian`" in result.stdout


def test_figures_are_rerendered_from_the_csv_files(out, followups):
    result, folder = followups["figures"], followups["folders"]["figures-again"]
    assert result.returncode == 0, result.output
    expected = sorted(p.name for p in (out / "figures").iterdir())
    assert expected and sorted(p.name for p in (folder / "figures").iterdir()) == expected
    for name in expected:
        assert (folder / "figures" / name).read_bytes().startswith(PNG_SIGNATURE)
        assert name in result.stdout


def test_figures_of_a_folder_that_is_no_result_is_an_error(followups):
    result, folder = followups["figures-not-a-result"], followups["root"] / "not-a-result"
    assert result.returncode == 2
    assert str(folder) in _one_error_line(result)
    assert list(folder.iterdir()) == []


def test_bench_rejects_a_bad_option_in_one_line(cli):
    """(The benchmark itself runs in tests/test_bench.py, in --quick mode.)"""
    result = cli["bench"]
    assert result.returncode == 2
    assert "--repeats" in _one_error_line(result)


def test_compare_on_a_missing_folder_is_one_error_line(cli):
    result = cli["compare"]
    assert result.returncode == 2
    assert "not a finished pfx result folder" in _one_error_line(result)


def test_reproduce_with_no_paper_configs_does_nothing(cli):
    result = cli["reproduce-empty"]
    assert result.returncode == 0, result.output
    assert "nothing to reproduce" in result.output
    assert not (cli["root"] / "results-empty").exists()


def test_reproduce_runs_each_paper_folder(cli):
    result = cli["reproduce"]
    assert result.returncode == 0, result.output
    folder = cli["root"] / "results" / "toy-paper" / "toy-experiment"
    trials = pd.read_csv(folder / "trials.csv")
    assert len(trials) == tiny_config_dict()["trials"]
    assert json.loads((folder / "manifest.json").read_text())["complete"] is True
    assert sorted(p.name for p in (cli["root"] / "results").iterdir()) == ["README.md", "toy-paper"]
    # the gallery has no section for a paper without a report
    assert "toy-paper" not in (cli["root"] / "results" / "README.md").read_text()


def test_reproduce_of_an_unknown_paper_is_an_error(cli):
    result = cli["reproduce-unknown"]
    assert result.returncode == 2
    assert "did you mean 'toy-paper'" in _one_error_line(result)
    assert not (cli["root"] / "results-unknown").exists()


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.name for e in EXAMPLES])
def test_example_config_validates(cli, example):
    result = cli[f"example:{example.name}"]
    assert result.returncode == 0, result.output
    assert "valid" in result.stdout.splitlines()[0]
    assert yaml.safe_load(result.stdout)["name"]


def test_there_are_example_configs():
    assert EXAMPLES, "configs/examples/ holds no config"


def test_readme_names_the_two_newcomer_commands():
    readme = REPO_ROOT / "README.md"
    if not readme.exists():
        pytest.skip("README.md does not exist yet")
    text = readme.read_text()
    assert "make reproduce-papers" in text
    assert "make test" in text
