"""Plugin code that raises, anywhere, is one line naming the plugin file, its line, the component
and the function (pfx/config/plugin_faults.py; docs/plugins.md, "When a plugin fails").

Through the command line (its entry point in the test's process; with worker processes, a real
``pfx`` process): before any trial ran (validation, planning) the line comes with
exit status 2 and nothing is written; during a run, with exit status 1 and the finished cells
kept. ``--traceback`` (or PFX_TRACEBACK=1) shows the traceback too. A model inconsistent with
itself is refused at plan time, naming the plugin, not a data file.
"""

from __future__ import annotations

import pandas as pd
import pytest
from conftest import write_config_file

PREFIX = "pfx: error: "

# {members} is replaced by the case's members; everything else is the minimal walk model.
TEMPLATE = '''from typing import Literal
import numpy as np
import pfx

@pfx.register_model
class Walk(pfx.Model):
    kind: Literal["hidden_walk"] = "hidden_walk"
    a: float = 0.8
{members}
'''

STATE_NAMES = '''    @property
    def state_names(self):
        return ("x",)
'''
DIMENSION = '''    @property
    def measurement_dimension(self):
        return 1
'''
PROPAGATE = '''    def propagate(self, state, control, noise):
        return self.a * state + noise
'''
MEAN = '''    def measurement_mean(self, state):
        return state
'''


def plugin_source(**replaced: str) -> str:
    members = {"state_names": STATE_NAMES, "dimension": DIMENSION, "propagate": PROPAGATE, "mean": MEAN}
    members.update(replaced)
    return TEMPLATE.format(members="".join(members.values()))


def walk_config(**changes) -> dict:
    config = {"name": "walk", "plugins": ["walk.py"], "trials": 4,
              "model": {"kind": "hidden_walk", "steps": 8, "process_noise": {"variance": 1.0},
                        "measurement_noise": {"variance": 0.5},
                        "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0}},
              "filter": {"kind": "particle", "particles": 50}, "outputs": {"figures": []}}
    config.update(changes)
    return config


def setup_case(folder, source: str, **changes):
    (folder / "walk.py").write_text(source)
    write_config_file(folder, walk_config(**changes), "walk.yaml")
    return "walk.yaml"           # relative to the folder the commands run in: messages say walk.py


def line_number(source: str, text: str) -> int:
    """The line of ``source`` (1-based) that holds ``text``."""
    return next(number for number, line in enumerate(source.splitlines(), 1) if text in line)


def the_error_line(result, status: int) -> str:
    assert result.returncode == status, result.output
    assert "Traceback" not in result.output, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(PREFIX), result.output
    return lines[0].removeprefix(PREFIX)


# -- before any trial: exit 2, nothing written ------------------------------------------------------

FORGOT_PROPERTY = '''    def state_names(self):
        return ("x",)
'''
RAISING_NAMES = '''    @property
    def state_names(self):
        return self.table["x"]
'''
RAISING_PRESETS = '''    def presets(self):
        raise KeyError("no preset for this a")
'''
INCONSISTENT_NAMES = '''    @property
    def measurement_names(self):
        return ("range",)
'''


@pytest.mark.parametrize("command", ["validate", "run"])
def test_a_method_meant_as_a_property_is_named_with_its_line(pfx_in_process, tmp_path, command):
    source = plugin_source(state_names=FORGOT_PROPERTY)
    config = setup_case(tmp_path, source)
    out = tmp_path / "out"
    result = pfx_in_process(command, config, *(["--out", out] if command == "run" else []), cwd=tmp_path)
    line = line_number(source, "def state_names")
    assert the_error_line(result, 2) == (
        f"walk.py:{line}: model hidden_walk (class Walk): state_names is a method, and pfx reads it as a "
        "property: write @property on the line above `def state_names`")
    assert not out.exists()


@pytest.mark.parametrize("case, member, text, expected", [
    ("state_names raises", {"state_names": RAISING_NAMES}, 'self.table["x"]',
     "model hidden_walk: state_names raised AttributeError: 'Walk' object has no attribute 'table'"),
    ("presets raises", {"mean": MEAN + RAISING_PRESETS}, "raise KeyError",
     "model hidden_walk: presets raised KeyError: 'no preset for this a'"),
])
def test_plugin_code_raising_during_validation_is_one_line(pfx_in_process, tmp_path, case, member, text, expected):
    source = plugin_source(**member)
    config = setup_case(tmp_path, source)
    for command in ("validate", "run"):
        result = pfx_in_process(command, config, "--out" if command == "run" else "--set",
                         tmp_path / "out" if command == "run" else "trials=4", cwd=tmp_path)
        assert the_error_line(result, 2) == f"walk.py:{line_number(source, text)}: {expected}", case
    assert not (tmp_path / "out").exists()


def test_a_model_inconsistent_with_itself_is_refused_naming_the_plugin(pfx_in_process, tmp_path):
    """measurement_names of length 1 beside measurement_dimension 2: refused at plan time, in
    the plugin's words and at its line, before any data file is read."""
    dimension_two = DIMENSION.replace("return 1", "return 2")
    mean_two = MEAN.replace("return state", "return np.concatenate([state, state], axis=-1)")
    source = plugin_source(dimension=dimension_two, mean=mean_two + INCONSISTENT_NAMES)
    config = setup_case(tmp_path, source, data={"measurements": "measurements.csv"})
    (tmp_path / "measurements.csv").write_text("step,range,z2\n" + "".join(f"{k},0.5,0.1\n" for k in range(1, 9)))
    result = pfx_in_process("validate", config, cwd=tmp_path)
    line = line_number(source, "def measurement_names") - 1      # where its definition starts: @property
    assert the_error_line(result, 2) == (
        f"walk.py:{line}: model hidden_walk: measurement_names returned 1 name(s) ('range',), and "
        "measurement_dimension says 2: give one per component")



def test_a_vectorised_parameter_that_is_not_a_number_of_the_model_is_refused(pfx_in_process, tmp_path):
    """vectorised_parameters (parameter estimation's batched chains) naming a field the model
    does not have: refused at plan time, naming the plugin, whatever the config runs."""
    source = plugin_source(mean=MEAN + '    vectorised_parameters = ("a", "b")\n')
    result = pfx_in_process("validate", setup_case(tmp_path, source), cwd=tmp_path)
    assert the_error_line(result, 2) == (
        "walk.py: model hidden_walk: vectorised_parameters names 'b', which is not a number of the model; "
        "expected its scalar fields or process_noise.variance or measurement_noise.variance")

# -- during the run: exit 1, the finished cells kept --------------------------------------------------

RAISES_ON_THE_REAL_BATCH = '''    def propagate(self, state, control, noise):
        if state.ndim == 3 and state.shape[1] > 3 and self.a > 1.0:
            raise RuntimeError("particle store full")
        return self.a * state + noise
'''
WRONG_SHAPE_FOR_LARGE_N = '''    def propagate(self, state, control, noise):
        moved = self.a * state + noise
        return moved[:, :3] if state.ndim == 3 and self.a > 1.0 else moved
'''


def test_an_exception_in_the_run_names_the_line_and_keeps_the_finished_cells(pfx_in_process, tmp_path):
    """propagate passes the 3-particle check and raises on the real batch of the second cell."""
    source = plugin_source(propagate=RAISES_ON_THE_REAL_BATCH)
    config = setup_case(tmp_path, source, sweep={"model.a": [0.5, 1.01]})
    out = tmp_path / "out"
    result = pfx_in_process("run", config, "--out", out, cwd=tmp_path)
    line = line_number(source, "raise RuntimeError")
    assert the_error_line(result, 1) == (
        f"walk.py:{line}: model hidden_walk: propagate raised RuntimeError: particle store full "
        f"(step 1 of the filter); 1 of 2 cells finished and are kept in {out}; run the same command again to resume")
    assert len(list((out / "cells").glob("*.trials.csv"))) == 1


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_wrong_shape_for_the_runs_particle_count_is_named(request, tmp_path, workers):
    """Right for 3 particles, wrong for the run's 50: the engine's check names the method, the
    step and the shapes, in worker processes too; nothing finished, nothing kept. (Worker
    processes are started from a real pfx process, not forked from the test's.)"""
    source = plugin_source(propagate=WRONG_SHAPE_FOR_LARGE_N)
    config = setup_case(tmp_path, source, model={**walk_config()["model"], "a": 1.01}, trials=8)
    out = tmp_path / "out"
    command_line = request.getfixturevalue("pfx_in_process" if workers == "1" else "run_pfx")
    result = command_line("run", config, "--out", out, "--workers", workers, cwd=tmp_path)
    line = the_error_line(result, 1)
    assert line.startswith("walk.py: model hidden_walk: the transition (propagate) returned shape (")
    assert "x 50 particles; expected (" in line and "at step 1 of the filter" in line
    assert line.endswith("no cell had finished, so nothing was kept")
    assert not out.exists()


def test_the_traceback_is_shown_on_request(run_pfx, pfx_in_process, tmp_path):
    """--traceback before or after the command; the traceback of a worker process's fault comes
    back through a real pfx process with workers (once: where the option stands is read before any
    worker starts, so the second place is checked in the test's process, without workers)."""
    source = plugin_source(propagate=RAISES_ON_THE_REAL_BATCH)
    config = setup_case(tmp_path, source, model={**walk_config()["model"], "a": 1.01})
    for command_line, arguments, workers in ((run_pfx, ["--traceback", "run", config], "2"),
                                             (pfx_in_process, ["run", config, "--traceback"], "1")):
        result = command_line(*arguments, "--out", tmp_path / "out", "--workers", workers, cwd=tmp_path)
        assert result.returncode == 1
        assert "Traceback (most recent call last)" in result.stderr
        assert 'File "walk.py", line' in result.stderr and "in propagate" in result.stderr
        assert result.stderr.strip().splitlines()[-1].startswith(
            f"{PREFIX}walk.py:{line_number(source, 'raise RuntimeError')}: model hidden_walk: propagate raised")


def test_a_plugin_fault_reaches_python_as_one_exception(tmp_path):
    """pfx.run raises the same one-line error (pfx.errors.PluginFault), the original as its cause."""
    import pfx
    from pfx.errors import PluginFault

    source = plugin_source(propagate=RAISES_ON_THE_REAL_BATCH)
    config = setup_case(tmp_path, source, model={**walk_config()["model"], "a": 1.01})
    with pytest.raises(PluginFault, match=r"walk\.py:\d+: model hidden_walk: propagate raised RuntimeError"):
        pfx.run(tmp_path / config, out=tmp_path / "out")


def test_a_built_in_run_is_unchanged_by_the_checks(pfx_in_process, tmp_path, tiny_config_dict):
    """The engine's per-step shape checks pass every built-in run (here: the tiny config)."""
    config = write_config_file(tmp_path, tiny_config_dict(), "tiny.yaml")
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 0, result.output
    assert len(pd.read_csv(tmp_path / "out" / "trials.csv")) == 4


def test_a_plugin_figure_that_raises_after_the_run_keeps_the_tables(pfx_in_process, tmp_path, tiny_config_dict):
    source = ('from pfx.figures import FIGURES\n\n@FIGURES.register("broken_figure")\n'
              'def broken_figure(result):\n    """A figure that fails."""\n    return 1 / 0\n')
    (tmp_path / "figure_plugin.py").write_text(source)
    write_config_file(tmp_path, tiny_config_dict(plugins=["figure_plugin.py"], outputs={"figures": ["broken_figure"]}),
                      "tiny.yaml")
    result = pfx_in_process("run", "tiny.yaml", "--out", "out", cwd=tmp_path)
    assert the_error_line(result, 1) == (
        f"figure_plugin.py:{line_number(source, '1 / 0')}: figure broken_figure: broken_figure raised "
        "ZeroDivisionError: division by zero; every trial finished and the tables are written in out, but not "
        "every figure")
    assert len(pd.read_csv(tmp_path / "out" / "trials.csv")) == 4
