"""Covariates: a table over time that a model reads at each (sub)step (``data.covariates``,
``Model.covariate_names``, ``Model.covariates_at``; docs/recorded-data.md, docs/plugins.md).

* interpolation: the table's own values at its times, linear in between, constant for one row,
  an error outside;
* a run: the model sees the covariate at the start of each step (a drift integrated exactly);
* the table is part of the cell key (a changed value is a changed cell);
* bad tables: one line naming the file (and column, or the key), exit status 2, nothing written.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import write_config_file

from pfx.config.plan import build_plan as build_plan_from
from pfx.errors import ConfigError


def build_plan(path):
    return build_plan_from(yaml.safe_load(path.read_text()), str(path))

DRIFT_PLUGIN = textwrap.dedent('''
    """x_k = x_(k-1) + c(t) dt + w_k: a walk whose drift c is a covariate read at the step's start."""
    from typing import Literal

    import pfx


    @pfx.register_model
    class Drift(pfx.Model):
        kind: Literal["drift"] = "drift"

        def presets(self):
            return {"steps": 6, "dt": 1.0, "process_noise": pfx.Noise(variance=0.0),
                    "measurement_noise": pfx.Noise(variance=0.1), "initial": pfx.PointLaw(state=[0.0])}

        @property
        def state_names(self):
            return ("x",)

        @property
        def measurement_dimension(self):
            return 1

        @property
        def covariate_names(self):
            return ("drift",)

        def propagate(self, state, control, noise, time=None):
            return state + self.covariates_at(time)[0] * self.dt + noise

        def measurement_mean(self, state):
            return state
''')


def drift_config(folder, covariates: str | None = "drift.csv", **changes) -> dict:
    (folder / "drift.py").write_text(DRIFT_PLUGIN)
    config = {"name": "drift", "plugins": ["drift.py"], "seed": 1, "trials": 2,
              "model": {"kind": "drift"}, "filter": {"particles": 20},
              "outputs": {"trace_trials": 2, "figures": []}}
    if covariates is not None:
        config["data"] = {"covariates": covariates}
    config.update(changes)
    return config


def write_table(folder, text: str, name: str = "drift.csv"):
    (folder / name).write_text(textwrap.dedent(text).lstrip())


# drift(t) = t on t in [0, 6]: x_k = sum_{j < k} j = k (k - 1) / 2 at the step starts t = k - 1
LINEAR_DRIFT = """
    time,drift
    0,0
    2,2
    6,6
"""


def test_covariates_are_interpolated_linearly(tmp_path):
    write_table(tmp_path, LINEAR_DRIFT)
    plan = build_plan(write_config_file(tmp_path, drift_config(tmp_path)))
    model = plan.cells[0].truth_model
    assert model.covariates == {"time": [0.0, 2.0, 6.0], "drift": [0.0, 2.0, 6.0]}
    for time in (0.0, 0.5, 2.0, 3.7, 6.0):
        assert model.covariates_at(time) == pytest.approx([time], abs=1e-15)
    with pytest.raises(ValueError, match="outside their table"):
        model.covariates_at(6.5)
    one_row = model.model_copy(update={"covariates": {"time": [0.0], "drift": [3.0]}})
    assert one_row.covariates_at(0.0) == pytest.approx([3.0])


def test_a_run_reads_the_covariate_at_each_step_start(pfx_in_process, tmp_path):
    write_table(tmp_path, LINEAR_DRIFT)
    config = write_config_file(tmp_path, drift_config(tmp_path))
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 0, result.output
    steps = pd.read_csv(tmp_path / "out" / "steps.csv")
    truth = steps[steps["trial"] == 0].sort_values("step")
    k = truth["step"].to_numpy()
    assert truth["time"].to_numpy() == pytest.approx(k * 1.0)
    assert truth["truth_x"].to_numpy() == pytest.approx(k * (k - 1) / 2.0, abs=1e-12)


def test_the_table_is_part_of_the_cell_key(tmp_path):
    write_table(tmp_path, LINEAR_DRIFT)
    first = build_plan(write_config_file(tmp_path, drift_config(tmp_path))).cells[0]
    write_table(tmp_path, LINEAR_DRIFT.replace("2,2", "2,2.5"))
    second = build_plan(write_config_file(tmp_path, drift_config(tmp_path))).cells[0]
    assert first.key != second.key and first.filter_key != second.filter_key


@pytest.mark.parametrize("table, where, reason", [
    ("step,drift\n1,0\n2,1\n", "drift.csv:1: column 1", "must be `time`"),
    ("time,slope\n0,0\n6,6\n", "drift.csv:1", "has no 'drift'"),
    ("time,drift,wind\n0,0,1\n6,6,1\n", "drift.csv:1", "has 'wind', which the model does not read"),
    ("time,drift\n0,0\n6,\n", "drift.csv:3: column drift", "blank cell"),
    ("time,drift\n0,0\n0,1\n", "drift.csv:3: column time", "appears twice"),
    ("time,drift\n1,0\n6,6\n", "data.covariates", "from 0 (the start of step 1)"),
    ("time,drift\n0,0\n4,4\n", "data.covariates", "to 5 (the start of the last substep of step 6)"),
])
def test_bad_covariate_tables_are_one_line_errors(pfx_in_process, tmp_path, table, where, reason):
    (tmp_path / "drift.csv").write_text(table)
    config = write_config_file(tmp_path, drift_config(tmp_path))
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 2, result.output
    assert "Traceback" not in result.output and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert where in result.stderr and reason in result.stderr, result.stderr
    assert not (tmp_path / "out").exists()


def test_a_model_that_reads_covariates_needs_them_and_others_refuse_them(tmp_path):
    with pytest.raises(ConfigError, match="reads the covariates drift over time") as missing:
        build_plan(write_config_file(tmp_path, drift_config(tmp_path, covariates=None)))
    assert missing.value.key == "model.covariates"
    write_table(tmp_path, LINEAR_DRIFT)
    builtin = {"name": "walk", "seed": 1, "trials": 1, "data": {"covariates": "drift.csv"},
               "model": {"kind": "growth", "steps": 3}, "filter": {"particles": 10}}
    with pytest.raises(ConfigError, match="reads no covariates") as refused:
        build_plan(write_config_file(tmp_path, builtin, "walk.yaml"))
    assert refused.value.file.endswith("drift.csv")


def test_covariates_given_twice_and_truth_without_measurements_are_refused(tmp_path):
    write_table(tmp_path, LINEAR_DRIFT)
    twice = drift_config(tmp_path, model={"kind": "drift", "covariates": {"time": [0.0, 6.0], "drift": [0.0, 6.0]}})
    with pytest.raises(ConfigError, match="given twice") as error:
        build_plan(write_config_file(tmp_path, twice))
    assert error.value.key == "data.covariates"
    lonely = drift_config(tmp_path)
    lonely["data"]["truth"] = "truth.csv"
    with pytest.raises(ConfigError, match="give data.measurements too") as error:
        build_plan(write_config_file(tmp_path, lonely))
    assert error.value.key == "data.truth"


def test_covariates_inline_in_the_model_work_too(tmp_path):
    inline = drift_config(tmp_path, covariates=None,
                          model={"kind": "drift", "covariates": {"time": [0.0, 6.0], "drift": [1.0, 1.0]}})
    model = build_plan(write_config_file(tmp_path, inline)).cells[0].truth_model
    assert np.array_equal(model.covariates_at(3.0), [1.0])



@pytest.mark.parametrize("with_measurements", [False, True])
def test_a_result_folder_records_the_file_and_reruns(pfx_in_process, tmp_path, with_measurements):
    write_table(tmp_path, LINEAR_DRIFT)
    config = drift_config(tmp_path)
    if with_measurements:
        (tmp_path / "z.csv").write_text("time,z1\n" + "".join(f"{k},{k * (k - 1) / 2}\n" for k in range(1, 7)))
        config["data"]["measurements"] = "z.csv"
    first = pfx_in_process("run", write_config_file(tmp_path, config), "--out", tmp_path / "first", cwd=tmp_path)
    assert first.returncode == 0, first.output
    record = yaml.safe_load((tmp_path / "first" / "config.yaml").read_text())
    assert "covariates" not in record["model"]
    assert record["data"]["covariates"] == "../drift.csv"         # relative to the folder, which reads it
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    again = pfx_in_process("run", tmp_path / "first" / "config.yaml", "--out", tmp_path / "again", cwd=elsewhere)
    assert again.returncode == 0, again.output
    first_trials, again_trials = (pd.read_csv(tmp_path / name / "trials.csv").drop(columns="run_time_s")
                                  for name in ("first", "again"))
    pd.testing.assert_frame_equal(first_trials, again_trials)


def test_a_table_that_ends_at_the_last_substep_read_is_enough(pfx_in_process, tmp_path):
    """The transition of step 6 starts at t = 5 and reads the covariates there: a table to 5 covers
    every time read (the measurement at t = 6 reads none), so the run goes ahead."""
    (tmp_path / "drift.csv").write_text("time,drift\n0,0\n5,5\n")
    config = write_config_file(tmp_path, drift_config(tmp_path))
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 0, result.output


START_PLUGIN = DRIFT_PLUGIN.replace(
    '"initial": pfx.PointLaw(state=[0.0])}',
    '"initial": pfx.PointLaw(state=[float(self.covariates_at(self.start_time)[0])])}').replace(
    'kind: Literal["drift"] = "drift"', 'kind: Literal["drift_from_start"] = "drift_from_start"').replace(
    "class Drift(", "class DriftFromStart(")


@pytest.mark.parametrize("with_measurements", [True, False])
def test_presets_may_read_the_covariates_at_the_start_of_a_record_that_starts_late(pfx_in_process, tmp_path,
                                                                                    with_measurements):
    """docs/plugins.md: presets may read a covariate at ``start_time`` (t_0), which with recorded
    data is the data's first time less dt. Before the data's times are attached, presets run once
    with t_0 = 0, outside a table of 1950's: that provisional lookup may not fail the model (its
    fields are derived again from the data's times). Without recorded data t_0 really is 0, and the
    table's span check refuses the run, naming the covariates."""
    (tmp_path / "drift.csv").write_text("time,drift\n1949,7\n1956,14\n")
    config = drift_config(tmp_path)
    (tmp_path / "drift_from_start.py").write_text(START_PLUGIN)
    config["plugins"] = ["drift_from_start.py"]
    config["model"] = {"kind": "drift_from_start", "steps": 6}
    if with_measurements:
        (tmp_path / "z.csv").write_text("time,z1\n" + "".join(f"{1949 + k},{k}\n" for k in range(1, 7)))
        config["data"]["measurements"] = "z.csv"
    path = write_config_file(tmp_path, config)
    result = pfx_in_process("validate", path, cwd=tmp_path)
    if with_measurements:
        assert result.returncode == 0, result.output
        model = build_plan(path).cells[0].filter_model
        assert model.start_time == 1949.0
        assert model.initial.state == [7.0]             # the covariate at t_0 = 1949, not at the provisional 0
    else:
        assert result.returncode == 2, result.output
        assert "covariates" in result.output and "from 1949 to 1956" in result.output, result.output
