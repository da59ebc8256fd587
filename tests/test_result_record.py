"""A result folder is a record of what ran: its config.yaml reruns to the same numbers, and
what a later run does with the folder (resume, extend, re-render, refuse) keeps that true.

* Every shipped config (examples, papers, studies, benchmarks, the plugin examples), run with 2
  trials (the heaviest also shrunk, see SHRUNK and SHORTENED), then rerun from the folder's own
  config.yaml (for a plugin run: with the folder's copy of the plugin's code): every table
  identical apart from run times. ``pfx validate``'s output is itself a config that resolves to the same plan.
* ``--set`` wins over arms and the sweep, and says so; ``--set sweep.KEY=[...]`` adds an axis.
* A run that fails keeps only what a rerun can resume from, and says what it kept.
* Changing only the outputs, the name or the trial count keeps the results: figures are
  re-rendered, more trials extend the run to exactly what a fresh run gives.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, tiny_config_dict, write_config_file

from pfx.config.overrides import apply_overrides
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.papers.record import TIMING_COLUMN_PREFIXES
from pfx.run.runner import run_plan
from pfx.safe_yaml import load_config_file

# the configs/ tree and the plugin examples (whose folders rerun from their own copy of the plugin)
SHIPPED = sorted(path for folder in ("configs", "examples") for path in (REPO_ROOT / folder).rglob("*.yaml")
                 if path.name != "paper.yaml")
# Estimation configs write chains, not trials: their reruns (extend, resume) are checked to the
# last digit in tests/test_estimation.py, on a short run rather than the examples' minutes.
RERUN = [path for path in SHIPPED if "\nestimation:" not in path.read_text()]

# Whether a folder's config.yaml reruns to the same tables does not depend on a run's size: the
# record holds a particle count, a step count or a grid size like any other setting. The configs
# that take a minute or more even at 2 trials rerun shrunk by `--set` assignments that keep every
# arm, every sweep axis (with as many values) and every kind of setting; the rest run as shipped.
SHRUNK = {
    # three histogram grids of 3000, 1000 and 6000 cells; 120 keeps the cells narrower than the
    # process noise's standard deviation on the widest grid, as the grid's check requires
    "configs/benchmarks/sv-gbp-usd/exact.yaml": ["filter.grid.cells=[120]"],
    # 1001 steps of 25 RK4 substeps; 16 steps with a burn-in of t <= 2 (8 steps) still score 8
    "configs/benchmarks/dapper-lorenz/lorenz63.yaml": ["model.steps=16", "metrics.burn_in=2.0"],
    # 1280 steps; 40 steps with a burn-in of t <= 1 (20 steps) still score 20
    "configs/benchmarks/dapper-lorenz/lorenz96.yaml": ["model.steps=40", "metrics.burn_in=1.0"],
    # 600 months (the data's) of 20 substeps, each a call of the plugin, at 1000 and 5000 particles
    "configs/benchmarks/dacca-cholera/dacca.yaml": ["sweep.filter.particles=[50, 100]", "model.substeps=4"],
    # the same months, scored (each cell's predictive draws at every step)
    "configs/benchmarks/dacca-cholera/scores.yaml": ["sweep.filter.particles=[50, 100]", "model.substeps=4"],
    # the same on the jax backend (each cell compiles its own program)
    "configs/benchmarks/dacca-cholera/dacca-jax.yaml": ["sweep.filter.particles=[50, 100]", "model.substeps=4"],
    # 730 weeks of 7 daily substeps of count draws at 2000 particles
    "configs/benchmarks/measles-london/measles.yaml": ["filter.particles=50", "model.substeps=2"],
    # its histogram arm's default grid of 2000 cells
    "configs/examples/growth.yaml": ["arms.grid.grid.cells=[300]"],
    # the genealogy of 400 and 800 steps
    "configs/papers/beyond-the-papers/ancestral-tree.yaml": ["sweep.model.steps=[40, 80]"],
    # 300 particles casting sonar rays in the arena, each step's cloud written
    "configs/examples/kidnapped-robot.yaml": ["filter.particles=30"],
    # 300 and 500 particles, each smoothed by 100 backward trajectories
    "configs/papers/beyond-the-papers/smoothing-range-beacons.yaml": [
        "filter.particles=50", "filter.smoothers=[{kind: ffbs, trajectories: 20}, {kind: fixed_lag, lag: 5}, genealogy]"],
    "configs/papers/beyond-the-papers/smoothing-growth.yaml": [
        "filter.particles=50", "filter.smoothers=[{kind: ffbs, trajectories: 20}, {kind: fixed_lag, lag: 5}, genealogy]"],
    # 3 arms at 100 and 1000 particles
    "configs/benchmarks/sv-gbp-usd/filters.yaml": ["sweep.filter.particles=[20, 50]"],
    # grids of 150 x 80 and 120 x 120 cells (multiples of check_block = 2), each checked by
    # 20,000 draws of the sampler per setting
    "configs/papers/prob-robotics/fig-5.3-velocity-density.yaml": ["study.cells=[30, 16]", "study.check_samples=2000"],
    "configs/papers/prob-robotics/fig-5.8-odometry-density.yaml": ["study.cells=[30, 30]", "study.check_samples=2000"],
}

# Recorded data sets a run's step count (its rows): these runs read only the first rows of their
# measurements, and of their covariates the rows up to the last of those times (what the
# transitions read), from shortened copies written beside the run (`--set data.KEY=...`).
SHORTENED = {
    "configs/benchmarks/dacca-cholera/dacca.yaml": 60,              # of 600 months
    "configs/benchmarks/dacca-cholera/scores.yaml": 60,
    "configs/benchmarks/dacca-cholera/dacca-jax.yaml": 60,
    "configs/benchmarks/measles-london/measles.yaml": 52,           # of 730 weeks
}


def _id(path: Path) -> str:
    return str(path.relative_to(REPO_ROOT))


def _tables(folder: Path) -> dict[str, pd.DataFrame]:
    """Every CSV of a folder without its timing columns (the only ones allowed to differ)."""
    tables = {}
    for path in sorted(folder.glob("*.csv")):
        frame = pd.read_csv(path)
        tables[path.name] = frame[[c for c in frame.columns if not c.startswith(TIMING_COLUMN_PREFIXES)]]
    return tables


def _cells(plan) -> list:
    return [(cell.key, cell.labels) for cell in plan.cells]


def test_every_shipped_config_is_found():
    assert len(SHIPPED) >= 38
    assert any(path.parent.name == "plugins" for path in SHIPPED)
    assert any("study" in load_config_file(path) for path in SHIPPED)


def test_the_shrunk_configs_are_shipped_configs():
    assert set(SHRUNK) | set(SHORTENED) <= {_id(path) for path in RERUN}


def _shortened_data(config: Path, rows: int, folder: Path) -> list[str]:
    """The assignments that read the config's data shortened to its first ``rows`` steps, from
    copies in ``folder``: the measurements' first rows, the covariates' up to the first at or
    after the last measurement's time."""
    data = load_config_file(config)["data"]
    folder.mkdir(parents=True, exist_ok=True)

    def shortened(key: str, keep: int) -> Path:
        original = config.parent / data[key]
        written = folder / original.name
        lines = original.read_text(encoding="utf-8").splitlines(keepends=True)
        written.write_text("".join(lines[:1 + keep]), encoding="utf-8")    # the header, then the rows
        return written

    measurements = shortened("measurements", rows)
    assignments = [f"data.measurements={measurements}"]
    if data.get("covariates"):
        last = pd.read_csv(measurements)["time"].iloc[-1]
        times = pd.read_csv(config.parent / data["covariates"])["time"]
        assignments.append(f"data.covariates={shortened('covariates', 1 + int(np.searchsorted(times, last)))}")
    return assignments


@pytest.mark.parametrize("config", RERUN, ids=_id)
def test_the_saved_config_reruns_to_identical_tables(config, tmp_path):
    assignments = SHRUNK.get(_id(config), [])
    if _id(config) in SHORTENED:
        assignments = assignments + _shortened_data(config, SHORTENED[_id(config)], tmp_path / "data")
    raw, _ = apply_overrides(load_config_file(config), assignments, str(config))
    raw.setdefault("outputs", {})["figures"] = []           # the numbers are what is checked here
    study = "study" in raw
    first = run_plan(build_plan(raw, str(config), trials=None if study else 2), tmp_path / "first")
    saved = first / "config.yaml"
    second = run_plan(build_plan(load_config_file(saved), str(saved)), tmp_path / "second")
    before, after = _tables(first), _tables(second)
    assert list(before) == list(after) and "trials.csv" in before or study
    for name, table in before.items():
        pd.testing.assert_frame_equal(table, after[name], check_exact=True, obj=name)


@pytest.fixture(scope="module")
def validated(pfx_in_process) -> dict[Path, str]:
    """``pfx validate`` of every shipped config, all in one call (in this process: what is checked
    is what it prints): what it printed for each, by path (each config's part starts with its
    header line, '# FILE: valid; ...')."""
    result = pfx_in_process("validate", *SHIPPED, cwd=REPO_ROOT)
    assert result.returncode == 0, result.output
    headers = [f"# {path}: valid; " for path in SHIPPED]
    starts = [result.stdout.index(header) for header in headers]
    assert starts == sorted(starts), "the configs printed in another order than given"
    return {path: result.stdout[start:end]
            for path, start, end in zip(SHIPPED, starts, starts[1:] + [len(result.stdout)])}


@pytest.mark.parametrize("config", SHIPPED, ids=_id)
def test_validate_prints_a_config_that_resolves_to_the_same_plan(config, validated, tmp_path):
    printed = yaml.safe_load(validated[config])        # the header line is a YAML comment
    original = build_plan(load_config_file(config), str(config))
    again = build_plan(printed, str(config.parent / "printed.yaml"))     # saved beside it: plugins are found
    assert again.resolved == original.resolved == printed
    assert _cells(again) == _cells(original)
    assert again.results_hash == original.results_hash


def test_validate_prints_only_the_settings_of_the_filter_kind():
    plan = build_plan(tiny_config_dict(), "tiny")
    assert "unscented" not in plan.resolved["filter"] and "grid" not in plan.resolved["filter"]
    ukf = build_plan(tiny_config_dict(filter={"kind": "ukf"}), "tiny")
    assert "unscented" in ukf.resolved["filter"] and "particles" not in ukf.resolved["filter"]
    # a setting given explicitly stays, even where the kind does not read it
    explicit = build_plan(tiny_config_dict(filter={"particles": 20, "grid": {"cells": [11]}}), "tiny")
    assert explicit.resolved["filter"]["grid"]["cells"] == [11]


def test_arms_are_recorded_as_what_they_change_against_the_filter_section():
    """The defect: arms were written filled with the filter's defaults, not merged with filter:."""
    config = tiny_config_dict(filter={"particles": 20, "diffusion": {"kind": "roughening", "factor": 0.2}},
                              arms={"plain": {}, "many": {"particles": 40}})
    plan = build_plan(config, "tiny")
    assert plan.resolved["arms"] == {"plain": {}, "many": {"particles": 40}}
    assert plan.resolved["filter"]["particles"] == 20
    assert plan.resolved["filter"]["diffusion"] == {"kind": "roughening", "factor": 0.2}
    assert [cell.filter.particles for cell in plan.cells] == [20, 40]
    assert all(cell.filter.diffusion.kind == "roughening" for cell in plan.cells)


# --- --set wins ------------------------------------------------------------------------------------

SWEPT = tiny_config_dict(filter={"particles": 20, "weighting": {"kind": "mahalanobis", "form": "paper"}},
                         arms={"own": {"particles": 30, "weighting": "gaussian"},
                               "form": {"weighting": {"kind": "mahalanobis", "form": "paper"}},
                               "inherits": {"resampler": "multinomial"}},
                         sweep={"filter.particles": [10, 50], "metrics.convergence.radius": [1.0, 2.0]})


def _plan(config: dict, *assignments: str):
    raw, notes = apply_overrides(config, list(assignments), "swept.yaml")
    return build_plan(raw, "swept.yaml"), notes


def test_set_overrides_the_arms_and_replaces_the_sweep_axis():
    plan, notes = _plan(SWEPT, "filter.particles=500")
    assert {cell.filter.particles for cell in plan.cells} == {500}
    assert len(plan.cells) == 3 * 2                     # the particle axis is gone, the radius axis stays
    assert any("sweep axis filter.particles ([10, 50])" in note for note in notes)
    assert any("arm own" in note for note in notes)


def test_set_below_a_key_reaches_only_the_arms_that_set_it():
    plan, notes = _plan(SWEPT, "filter.weighting.form=innovation")
    labels = {cell.labels["arm"]: cell.labels["weighting"] for cell in plan.cells}
    assert labels == {"own": "gaussian", "form": "mahalanobis-innovation", "inherits": "mahalanobis-innovation"}
    assert notes == ["--set filter.weighting.form also replaces the value of arm form"]


def test_set_sweep_adds_replaces_and_removes_an_axis():
    base = tiny_config_dict()
    plan, _ = _plan(base, "sweep.filter.particles=[10, 20, 40]")
    assert [cell.filter.particles for cell in plan.cells] == [10, 20, 40]
    plan, _ = _plan(SWEPT, "sweep.filter.particles=[5]", "sweep.metrics.convergence.radius=null")
    assert {cell.filter.particles for cell in plan.cells} == {5} and len(plan.cells) == 3


@pytest.mark.parametrize("assignment, words", [
    ("sweep.filter.particles=100", "takes a list"),
    ("sweep.model.steps=null", "no axis"),
    ("metrics.convergence.radius.value=3", "the sweep sets metrics.convergence.radius"),
    ("arms.inherits.particles=5", "the sweep sets filter.particles for every arm"),
])
def test_set_that_cannot_apply_to_every_cell_is_refused(assignment, words):
    with pytest.raises(ConfigError) as error:
        _plan(SWEPT, assignment)
    assert words in str(error.value) and str(error.value).startswith("swept.yaml: ")


def test_readme_quick_start_set_reaches_every_cell(pfx_in_process):
    config = REPO_ROOT / "configs" / "examples" / "linear-gaussian.yaml"
    result = pfx_in_process("validate", config, "--set", "filter.particles=500")
    assert result.returncode == 0, result.output
    printed = yaml.safe_load(result.stdout)
    assert printed["filter"]["particles"] == 500 and "filter.particles" not in printed.get("sweep", {})
    assert "replaces the sweep axis filter.particles" in result.stderr


# --- a failed run keeps only what a rerun can use -------------------------------------------------

def _failing(order: list[str]) -> dict:
    """Two arms; 'blows-up' assumes a transition that overflows, so its particles become infinite."""
    arms = {"fine": {}, "blows-up": {"model": {"transition_matrix": [[1.0e200]]}}}
    return tiny_config_dict(name="failing", arms={name: arms[name] for name in order},
                            outputs={"trace_trials": 1, "figures": []})


def test_failure_in_the_first_cell_leaves_no_folder(tmp_path, pfx_in_process):
    config = write_config_file(tmp_path, _failing(["blows-up", "fine"]), "failing.yaml")
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 1, result.output
    assert result.stderr.count("\n") == 1 and "nothing was kept" in result.stderr
    assert not (tmp_path / "out").exists()
    fixed = write_config_file(tmp_path, _failing(["fine"]), "fixed.yaml")     # a later run is not refused
    assert pfx_in_process("run", fixed, "--out", tmp_path / "out", "--quiet", cwd=tmp_path).returncode == 0


def test_failure_after_a_finished_cell_keeps_it_for_a_resume(tmp_path, pfx_in_process):
    config = write_config_file(tmp_path, _failing(["fine", "blows-up"]), "failing.yaml")
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 1 and "1 of 2 cells finished and are kept" in result.stderr, result.output
    assert len(list((tmp_path / "out" / "cells").glob("*.trials.csv"))) == 1
    other = pfx_in_process("run", config, "--out", tmp_path / "out", "--trials", "9", cwd=tmp_path)
    assert other.returncode == 2 and "interrupted run of 4 trials" in other.stderr, other.output


# --- changing the outputs, the name or the trials keeps the results --------------------------------

@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished folder of 3 trials per cell, and a fresh 6-trial folder to compare with."""
    root = tmp_path_factory.mktemp("record")
    config = tiny_config_dict(name="record", trials=3, sweep={"filter.resampler": ["systematic", "multinomial"]},
                              outputs={"trace_trials": 4, "figures": ["error_over_time"]})
    folder = run_plan(build_plan(config, "record.yaml"), root / "three")
    fresh = run_plan(build_plan(config, "record.yaml", trials=6), root / "six")
    return config, folder, fresh


def _copy(folder: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(folder, tmp_path / folder.name))


def test_more_trials_extend_a_finished_run_to_what_a_fresh_run_gives(finished, tmp_path):
    config, three, six = finished
    folder = _copy(three, tmp_path)
    messages = []
    run_plan(build_plan(config, "record.yaml", trials=6), folder, report=messages.append)
    assert any("extending from 3 to 6 trials" in m for m in messages)
    extended, fresh = _tables(folder), _tables(six)
    for name in ("trials.csv", "steps.csv", "summary.csv"):
        pd.testing.assert_frame_equal(extended[name], fresh[name], check_exact=True, obj=name)
    # per-step means and deviations merge exactly in exact arithmetic: here to rounding
    pd.testing.assert_frame_equal(extended["steps_summary.csv"], fresh["steps_summary.csv"], rtol=1e-12)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["trials"] == 6 and manifest["complete"] and "extending_from" not in manifest
    assert not (folder / "cells").exists()


def test_fewer_trials_than_the_folder_holds_is_refused(finished, tmp_path):
    config, three, _ = finished
    folder = _copy(three, tmp_path)
    before = (folder / "trials.csv").read_bytes()
    with pytest.raises(ConfigError, match="holds 3 trials per cell and the config asks for 2"):
        run_plan(build_plan(config, "record.yaml", trials=2), folder)
    assert (folder / "trials.csv").read_bytes() == before


def test_changing_figures_and_name_rerenders_without_recomputing(finished, tmp_path):
    config, three, _ = finished
    folder = _copy(three, tmp_path)
    before = {name: (folder / name).read_bytes() for name in ("trials.csv", "steps.csv", "summary.csv")}
    changed = {**config, "name": "renamed", "description": "new words",
               "outputs": {**config["outputs"], "figures": ["ess_over_time"], "formats": ["png", "svg"]}}
    messages = []
    run_plan(build_plan(changed, "record.yaml"), folder, report=messages.append)
    assert {name: (folder / name).read_bytes() for name in before} == before
    assert sorted(p.name for p in (folder / "figures").iterdir()) == ["ess_over_time.png", "ess_over_time.svg"]
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["name"] == "renamed" and manifest["figures"] == ["ess_over_time"]
    assert yaml.safe_load((folder / "config.yaml").read_text())["description"] == "new words"
    assert any("record updated" in m and "removed: error_over_time" in m for m in messages)


def test_figures_command_adds_a_figure_to_the_record(finished, tmp_path, pfx_in_process):
    _, three, _ = finished
    folder = _copy(three, tmp_path)
    result = pfx_in_process("figures", folder, "--figure", "ess_over_time")
    assert result.returncode == 0, result.output
    assert (folder / "figures" / "ess_over_time.png").exists()
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["figures"] == ["error_over_time", "ess_over_time"]
    saved = yaml.safe_load((folder / "config.yaml").read_text())
    assert saved["outputs"]["figures"] == manifest["figures"]
    again = build_plan(saved, "saved")                  # the record still resolves to its own hash
    assert again.config_hash == manifest["config_hash"]
    wrong = pfx_in_process("figures", folder, "--figure", "ess_over_tim")
    assert wrong.returncode == 2 and "did you mean 'ess_over_time'" in wrong.stderr


def test_a_figure_added_to_a_folder_of_recorded_data_keeps_it_up_to_date(tmp_path, pfx_in_process):
    """The record's config hash names its data files by content (and a plugin by its code): the
    hash written with an added figure is the plan's, so the folder's own config finds it up to date."""
    folder = tmp_path / "nile"
    ran = pfx_in_process("run", REPO_ROOT / "configs" / "examples" / "nile.yaml", "--out", folder, "--trials", "2",
                         "--quiet")
    assert ran.returncode == 0, ran.output
    added = pfx_in_process("figures", folder, "--figure", "log_likelihood_increment_over_time")
    assert added.returncode == 0, added.output
    again = pfx_in_process("run", folder / "config.yaml", "--out", folder)
    assert again.returncode == 0 and "up to date (same config hash" in again.stderr, again.output


def test_end_of_run_prints_a_summary_and_the_next_command(tmp_path, pfx_in_process):
    config = write_config_file(tmp_path, tiny_config_dict(        # 6 trials: the fewest with an interval
        trials=6, arms={"few": {"particles": 10}, "many": {"particles": 40}}, outputs={"figures": []}), "arms.yaml")
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 0, result.output
    lines = result.stdout.splitlines()
    header = next(line for line in lines if "position RMSE" in line)
    assert header.split()[:2] == ["arm", "trials"]
    summary = pd.read_csv(tmp_path / "out" / "summary.csv")
    few = next(line for line in lines if line.strip().startswith("few"))
    assert f"{summary['rmse_position_mean'].iloc[0]:.4g}" in few
    assert f"next: pfx compare {tmp_path / 'out'} --metric rmse_position --by arm" in result.stdout
    assert np.isfinite(summary["rmse_position_ci95_low"]).all()


def _summary_folder(tmp_path, rows: list[dict], units: dict) -> tuple[Path, dict]:
    """A folder holding only summary.csv, with the manifest the end-of-run table reads."""
    pd.DataFrame(rows).to_csv(tmp_path / "summary.csv", index=False)
    manifest = {"name": "units", "legend_columns": ["arm"], "units": units,
                "cells": [{"cell": row["cell"]} for row in rows]}
    return tmp_path, manifest


def test_the_end_of_run_table_keeps_its_units_on_a_terminal_and_marks_too_few_trials(tmp_path):
    """On a terminal rich drew the table and read "[m]" as markup: the units vanished. A cell of
    3 trials has no interval, and says so; a share's Wilson interval is shown in percent."""
    import io

    from rich.console import Console

    from pfx.analysis.run_summary import print_run_summary

    statistics = {"rmse_position": (1.5, 1.2, 1.8), "error_distance_final": (0.8, 0.0, 1.9),
                  "converged": (1.0, 0.8389, 1.0), "log_likelihood": (-40.0, -44.0, -36.0)}
    many = {"cell": "a", "arm": "many", "trials": 20}
    few = {"cell": "b", "arm": "few", "trials": 3}
    for metric, (mean, low, high) in statistics.items():
        many.update({f"{metric}_n": 20, f"{metric}_mean": mean, f"{metric}_ci95_low": low, f"{metric}_ci95_high": high})
        few.update({f"{metric}_n": 3, f"{metric}_mean": mean, f"{metric}_ci95_low": None, f"{metric}_ci95_high": None})
    folder, manifest = _summary_folder(tmp_path, [many, few], {"position": "m"})
    screen = io.StringIO()
    plain: list[str] = []
    print_run_summary(folder, manifest, plain.append, rich_console=True,
                      console=Console(file=screen, force_terminal=True, color_system=None, width=200))
    table = screen.getvalue()
    assert "position RMSE [m]" in table and "final error [m]" in table
    assert "1.5 [1.2, 1.8]" in table and "100% [83.89%, 100%]" in table and "0.8 [0, 1.9]" in table
    assert table.count("[no CI]") == 4
    assert any(line.startswith("no CI: fewer than 6 values") for line in plain)


def test_recorded_data_without_a_truth_is_compared_by_log_likelihood(tmp_path):
    from pfx.analysis.run_summary import next_command

    rows = [{"cell": cell, "arm": cell, "trials": 6, "rmse_position_mean": None, "log_likelihood_mean": -160.9}
            for cell in ("bootstrap", "auxiliary")]
    folder, manifest = _summary_folder(tmp_path, rows, {})
    assert next_command(folder, manifest) == (f"pfx compare {folder} --metric log_likelihood "
                                              "--higher-is-better --by arm")


def test_a_cell_key_that_looks_like_a_number_stays_text(tmp_path):
    """Cell keys are 12 hex digits; "910808017e06" (a real kim-mcl key) must not be read as
    9.1e14, nor "012345678901" lose its leading zero, anywhere a result folder is read."""
    from pfx.result_folder import ResultFolder, read_table, write_csv

    keys = ["910808017e06", "012345678901", "ed6f45077bf8"]
    write_csv(pd.DataFrame({"cell": keys, "trial": [0, 1, 2]}), tmp_path / "trials.csv")
    assert list(read_table(tmp_path / "trials.csv")["cell"]) == keys
    assert list(ResultFolder(tmp_path).trials["cell"]) == keys
