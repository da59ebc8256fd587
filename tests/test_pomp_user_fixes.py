"""What a user who knows R's pomp met fitting the boarding-school flu with pfx, each fixed:

* a key of the other estimation method (PMMH's ``proposal_sd``, ``warm_up`` in an IF2 config;
  IF2's ``random_walk_sd``, ``cooling_fraction_50`` in a PMMH one) is refused in one line naming
  the method it belongs to and the key that does its job, never silently ignored;
* IF2's random walk leaving a parameter's range on ``transform: none`` is one line at the
  parameter's ``transform`` key naming it and the transform to use, whether the model refuses
  the value itself (a field's bounds) or a law refuses it later (``binomial: probability must be
  in [0, 1]``), never the law's own error;
* a NaN log-likelihood from 0 * log 0 names the plugin's ``log_likelihood``, its file and the
  line of its ``def``, and the cure (xlogy);
* a result folder of other results names the keys that differ from its recorded config;
* a measurements file whose ``time`` column holds ISO dates is read in the run's time unit,
  counted from the first date, and says so; a unit a date does not convert to is refused;
* the README says what ``make install`` installs (the test extra) and what ``pip install .``.
"""

from __future__ import annotations

import copy
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, tiny_config_dict, write_config_file

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError

sys.path.insert(0, str(Path(__file__).parent))
from test_estimation_folders import PROCESS, estimation_config  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_plugins")
ERROR = "pfx: error: "


def error_line(result, status: int) -> str:
    """The one ``pfx: error:`` line of a command that failed with ``status`` (numpy's own
    warnings may precede it), and no traceback."""
    assert result.returncode == status, result.output
    assert "Traceback" not in result.output, result.output
    lines = [line for line in result.stderr.splitlines() if line.startswith(ERROR)]
    assert len(lines) == 1, result.output
    return lines[0].removeprefix(ERROR)


# -- 1. a key of the other method --------------------------------------------------------------------

@pytest.mark.parametrize("method, where, key, value, words", [
    ("if2", "estimation", "warm_up", 100, ["a PMMH setting, which IF2 does not read", "cooling_fraction_50"]),
    ("if2", "estimation", "adapt", False, ["a PMMH setting", "cooling_fraction_50"]),
    ("if2", "estimation", "adapt_after", 50, ["a PMMH setting", "cooling_fraction_50"]),
    ("if2", "estimation", "particle_count", {"runs": 20}, ["a PMMH setting", "filter.particles"]),
    ("if2", "parameter", "proposal_sd", 0.3, ["a PMMH setting, which IF2 does not read",
                                               "IF2's random walk is set by random_walk_sd"]),
    ("pmmh", "estimation", "cooling_fraction_50", 0.3, ["an IF2 setting, which PMMH does not read", "warm_up"]),
    ("pmmh", "estimation", "evaluations", 20, ["an IF2 setting", "chains.csv"]),
    ("pmmh", "parameter", "random_walk_sd", 0.1, ["an IF2 setting, which PMMH does not read",
                                                  "PMMH's proposal is set by proposal_sd"]),
])
def test_a_key_of_the_other_method_is_refused_naming_the_method_and_its_counterpart(method, where, key, value,
                                                                                   words):
    config = estimation_config(method)
    section = config["estimation"] if where == "estimation" else config["estimation"]["parameters"][PROCESS]
    section[key] = value
    with pytest.raises(ConfigError) as refused:
        build_plan(config, "flu.yaml")
    expected_key = f"estimation.{key}" if where == "estimation" else f"estimation.parameters.{PROCESS}.{key}"
    assert refused.value.key == expected_key
    message = str(refused.value)
    assert message.startswith(f"flu.yaml: {expected_key}: ") and len(message.splitlines()) == 1
    assert all(word in message for word in words), message


def test_the_record_of_either_method_holds_every_key_and_runs_again():
    """config.yaml records every key with its default (proposal_sd in an IF2 record, say): such
    a key at its default value is let through, so the record reruns to the same plan."""
    for method in ("if2", "pmmh"):
        plan = build_plan(estimation_config(method), "flu.yaml")
        record = yaml.safe_load(yaml.safe_dump(plan.resolved))
        other = {"if2": "proposal_sd", "pmmh": "random_walk_sd"}[method]
        assert other in record["estimation"]["parameters"][PROCESS]
        assert build_plan(record, "again.yaml").results_hash == plan.results_hash


def test_the_command_line_refuses_a_pmmh_key_in_an_if2_config_in_one_line(pfx_in_process, tmp_path):
    config = estimation_config("if2")
    config["estimation"]["parameters"][PROCESS]["proposal_sd"] = 0.3
    write_config_file(tmp_path, config, "flu.yaml")
    line = error_line(pfx_in_process("validate", "flu.yaml", cwd=tmp_path), 2)
    assert line.startswith(f"flu.yaml: estimation.parameters.{PROCESS}.proposal_sd: a PMMH setting"), line


# -- 2. IF2's random walk leaving the model's range --------------------------------------------------

SURVIVAL = '''from typing import ClassVar, Literal
from pydantic import Field
import pfx

@pfx.register_model
class Survival(pfx.Model):
    kind: Literal["survival"] = "survival"
    survival: float = {field}
    vectorised_parameters: ClassVar[tuple] = ("survival",)

    def presets(self):
        return {{"process_noise": pfx.Noise(variance=0.0), "measurement_noise": pfx.Noise(variance=4.0),
                "initial": pfx.PointLaw(state=[100.0])}}

    @property
    def state_names(self):
        return ("n",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return self.survival * state + 20.0

    def sample_substep(self, state, control, time, random):
        xp = pfx.namespace(state)
        return random.binomial(xp.full_like(state, 100.0), xp.asarray(self.survival) * xp.ones_like(state))

    def measurement_mean(self, state):
        return state
'''
BOUNDED_FIELD = "Field(0.8, gt=0, lt=1)"


def survival_case(folder: Path, field: str, backend: str = "numpy") -> str:
    (folder / "survive.py").write_text(SURVIVAL.format(field=field))
    config = {"name": "survive", "seed": 3, "plugins": ["survive.py"], "model": {"kind": "survival", "steps": 20},
              "filter": {"particles": 100, "backend": backend}, "outputs": {"figures": []},
              "estimation": {"method": "if2", "chains": 2, "iterations": 5,
                             "parameters": {"model.survival": {"prior": {"law": "uniform", "lower": 0.0, "upper": 1.0},
                                                               "transform": "none", "start": 0.8,
                                                               "random_walk_sd": 0.3}}}}
    write_config_file(folder, config, "survive.yaml")
    return "survive.yaml"


@pytest.mark.parametrize("field, refusal", [
    (BOUNDED_FIELD, "model.survival: input should be greater than 0"),     # the model's own bounds
    ("0.8", "binomial: probability must be in [0, 1]"),                    # only the law says so
])
def test_if2_whose_walk_takes_a_probability_out_of_range_names_it_and_logit(pfx_in_process, tmp_path, field, refusal):
    line = error_line(pfx_in_process("run", survival_case(tmp_path, field), "--out", "out", cwd=tmp_path), 2)
    assert line.startswith("survive.yaml: estimation.parameters.model.survival.transform: IF2's random walk "
                           "(transform: none) moved model.survival to "), line
    assert refusal in line and "transform: logit" in line, line
    assert not (tmp_path / "out" / "if2.csv").exists()


REPORTING = '''from typing import ClassVar, Literal
from pydantic import Field
import pfx

@pfx.register_model
class Reporting(pfx.Model):
    kind: Literal["reporting"] = "reporting"
    rho: float = Field(0.5, gt=0, lt=1)
    vectorised_parameters: ClassVar[tuple] = ("rho",)

    def presets(self):
        return {"process_noise": pfx.Noise(variance=1.0), "measurement_noise": pfx.Noise(variance=1.0),
                "initial": pfx.GaussianLaw(mean=[10.0], covariance=1.0)}

    @property
    def state_names(self):
        return ("x",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return state + noise

    def measurement_mean(self, state):
        return self.rho * state

    def log_likelihood(self, measurement, state):
        xp = pfx.namespace(state)
        return (measurement[..., 0] * xp.log(self.rho[..., 0] if xp.ndim(self.rho) else self.rho)
                - xp.abs(state[..., 0]) * 0.0)
'''


def test_if2_whose_walk_makes_the_likelihood_nan_names_the_parameter(pfx_in_process, tmp_path):
    """No law refuses the value: the log-likelihood is NaN at rho < 0 (log of a negative number).
    The pass's particles show the parameter the model refuses: named as above."""
    (tmp_path / "reporting.py").write_text(REPORTING)
    config = {"name": "reporting", "seed": 4, "plugins": ["reporting.py"], "model": {"kind": "reporting", "steps": 15},
              "filter": {"particles": 60}, "outputs": {"figures": []},
              "estimation": {"method": "if2", "chains": 2, "iterations": 5,
                             "parameters": {"model.rho": {"prior": {"law": "uniform", "lower": 0.0, "upper": 1.0},
                                                          "transform": "none", "start": 0.5,
                                                          "random_walk_sd": 0.5}}}}
    write_config_file(tmp_path, config, "reporting.yaml")
    line = error_line(pfx_in_process("run", "reporting.yaml", "--out", "out", cwd=tmp_path), 2)
    assert line.startswith("reporting.yaml: estimation.parameters.model.rho.transform: IF2's random walk (transform: "
                           "none) moved model.rho to "), line
    assert "transform: logit" in line, line


def test_if2_on_jax_names_the_parameter_a_law_refused(pfx_in_process, tmp_path):
    """The jax backend's compiled pass cannot stop at the failing step: where the swarm it leaves
    is back inside the range, the law's refusal is put down to the parameter on transform: none."""
    pytest.importorskip("jax")
    line = error_line(pfx_in_process("run", survival_case(tmp_path, BOUNDED_FIELD, "jax"), "--out", "out",
                                     cwd=tmp_path), 2)
    assert line.startswith("survive.yaml: estimation.parameters.model.survival.transform: IF2's random walk"), line
    assert "binomial: probability must be in [0, 1]" in line and "transform: logit" in line, line


# -- 3. a NaN likelihood from 0 * log 0 --------------------------------------------------------------

COUNTS = '''from typing import Literal
import pfx

@pfx.register_model
class Counts(pfx.Model):
    kind: Literal["zero_counts"] = "zero_counts"
    a: float = 0.8

    @property
    def state_names(self):
        return ("x",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return self.a * state + noise

    def measurement_mean(self, state):
        return pfx.namespace(state).maximum(state, 0.0)

    def log_likelihood(self, measurement, state):
        xp = pfx.namespace(state, measurement)
        mean = xp.maximum(state[..., 0], 0.0)
        count = measurement[..., 0]
        return count * xp.log(mean) - mean - pfx.special_functions(xp).gammaln(count + 1.0)
'''


def test_a_nan_likelihood_from_zero_log_zero_names_the_plugins_log_likelihood(pfx_in_process, tmp_path, backend):
    (tmp_path / "counts.py").write_text(COUNTS)
    (tmp_path / "counts.csv").write_text("step,z1\n1,0\n2,1\n3,0\n4,0\n")
    config = {"name": "counts", "plugins": ["counts.py"], "trials": 2,
              "model": {"kind": "zero_counts", "process_noise": {"variance": 1.0},
                        "measurement_noise": {"variance": 1.0},
                        "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0}},
              "data": {"measurements": "counts.csv"}, "filter": {"particles": 50, "backend": backend},
              "outputs": {"figures": []}}
    write_config_file(tmp_path, config, "counts.yaml")
    line = error_line(pfx_in_process("run", "counts.yaml", "--out", "out", cwd=tmp_path), 1)
    definition = 1 + COUNTS.splitlines().index("    def log_likelihood(self, measurement, state):")
    assert f"its log_likelihood (counts.py:{definition}) returned NaN" in line, line
    assert "for particles that are finite" in line and "0 * log 0" in line and "xlogy(z, mu)" in line, line
    assert "did particles leave" not in line


def test_an_infinite_likelihood_is_said_with_its_own_cause():
    from pfx.filters.particle.likelihood_failure import bad_log_likelihood_message

    class Model:
        kind = "lonely"

        def log_likelihood(self, measurement, state):
            return state

    message = bad_log_likelihood_message(Model(), 3, "an infinite")
    assert message.startswith("model lonely gave an infinite log-likelihood at step 3 of the filter: its "
                              f"log_likelihood ({__file__}:")
    assert "returned +inf for particles that are finite" in message and "zero variance" in message
    built_in = build_plan(tiny_config_dict(), "tiny.yaml").cells[0].filter_model     # pfx's own likelihood
    assert bad_log_likelihood_message(built_in, 2, "NaN") == (
        "model linear_gaussian gave NaN log-likelihood at step 2 of the filter for particles that are finite (check "
        "the measurement noise and the model's parameters)")


# -- 4. a folder of other results names what changed -------------------------------------------------

def test_a_folder_of_other_results_names_the_keys_that_differ(tmp_path):
    config = tiny_config_dict()
    pfx.run(config, out=tmp_path / "out")
    changed = copy.deepcopy(config)
    changed.update(name="renamed", seed=8)                   # the name keeps the results: not named
    changed["filter"]["particles"] = 21
    with pytest.raises(ConfigError) as refused:
        pfx.run(changed, out=tmp_path / "out")
    assert re.search(r"results hash \w+ != \w+; keys that differ from its record: seed, filter\.particles\); use "
                     r"--fresh", str(refused.value)), str(refused.value)
    many = copy.deepcopy(changed)
    many["model"].update(transition_matrix=[[0.9]], measurement_matrix=[[2.0]], steps=6)
    many["filter"].update(resampler="multinomial", ess_threshold=0.3)
    with pytest.raises(ConfigError, match=r"keys that differ from its record: seed, model\.steps, "
                                          r"model\.transition_matrix, model\.measurement_matrix, filter\.particles "
                                          r"and 2 more\)"):
        pfx.run(many, out=tmp_path / "out")


def test_a_folder_of_recorded_data_names_the_key_not_the_data_path(tmp_path):
    """The record names its data file relative to the folder: the same file is no difference."""
    (tmp_path / "flow.csv").write_text("step,z1\n1,0.5\n2,0.7\n3,\n4,1.1\n")
    model = {key: value for key, value in tiny_config_dict()["model"].items() if key != "steps"}
    config = tiny_config_dict(model=model, data={"measurements": "flow.csv"})
    write_config_file(tmp_path, config, "flow.yaml")
    pfx.run(str(tmp_path / "flow.yaml"), out=tmp_path / "results" / "flow")
    config["model"]["transition_matrix"] = [[0.5]]
    write_config_file(tmp_path, config, "flow.yaml")
    with pytest.raises(ConfigError) as refused:
        pfx.run(str(tmp_path / "flow.yaml"), out=tmp_path / "results" / "flow")
    assert "keys that differ from its record: model.transition_matrix)" in str(refused.value), str(refused.value)


# -- 5. dates in the time column ---------------------------------------------------------------------

def dates_case(folder: Path, dates: list[str], **changes) -> str:
    rows = "".join(f"{date},{value}\n" for date, value in zip(dates, (1.0, 1.5, "", 2.0, 2.5)))
    (folder / "flu.csv").write_text("time,z1\n" + rows)
    config = {"name": "flu", "trials": 2, "data": {"measurements": "flu.csv"}, "filter": {"particles": 30},
              "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]]},
              "outputs": {"figures": []}, **changes}
    write_config_file(folder, config, "flu.yaml")
    return "flu.yaml"


DAILY = ["2024-01-22", "2024-01-23", "2024-01-24", "2024-01-25", "2024-01-26"]
WEEKLY = ["2024-01-01", "2024-01-08", "2024-01-15", "2024-01-22", "2024-01-29"]


def test_iso_dates_are_read_as_days_since_the_first_and_said(pfx_in_process, tmp_path):
    result = pfx_in_process("run", dates_case(tmp_path, DAILY), "--out", "out", cwd=tmp_path)
    assert result.returncode == 0, result.output
    assert ("flu.yaml: flu.csv: column time: the dates are read as days since 2024-01-22 (time 0): model "
            "linear_gaussian declares no time unit, so they count days (time_unit: day)") in result.stderr.splitlines()
    steps = pd.read_csv(tmp_path / "out" / "steps.csv")
    assert sorted(steps["time"].unique()) == [0.0, 1.0, 2.0, 3.0, 4.0]
    record = yaml.safe_load((tmp_path / "out" / "config.yaml").read_text())
    assert record["time_unit"] == "day" and record["model"]["dt"] == 1.0
    again = pfx_in_process("run", "out/config.yaml", "--out", "out", cwd=tmp_path)     # the record reruns
    assert again.returncode == 0 and "up to date" in again.stderr, again.output


def test_weekly_dates_count_weeks_when_the_config_says_so(tmp_path):
    plan = build_plan(yaml.safe_load((tmp_path / dates_case(tmp_path, WEEKLY, time_unit="week")).read_text()),
                      str(tmp_path / "flu.yaml"))
    assert plan.cells[0].filter_model.dt == 1.0
    assert plan.notes == [f"{tmp_path / 'flu.csv'}: column time: the dates are read as weeks since 2024-01-01 "
                          "(time 0): the config's time_unit"]
    days = build_plan(yaml.safe_load((tmp_path / dates_case(tmp_path, WEEKLY)).read_text()), str(tmp_path / "flu.yaml"))
    assert days.cells[0].filter_model.dt == 7.0


@pytest.mark.parametrize("rows, changes, expected", [
    (WEEKLY, {"time_unit": "year"}, "flu.csv:2: column time: holds dates, and the config's time_unit is 'year', which "
                                    "a date does not convert to exactly: write the times as numbers in year (for "
                                    "years, decimal years such as 1944.0192), or use a `step` column"),
    (DAILY[:2] + ["5", *DAILY[3:]], {}, "flu.csv:4: column time: '5' is not a date (YYYY-MM-DD), as the first "
                                         "row's time is"),
    (DAILY[:2] + ["2024-02-30", *DAILY[3:]], {}, "flu.csv:4: column time: '2024-02-30' is not a date"),
    (DAILY[:2] + [DAILY[1], *DAILY[3:]], {}, "flu.csv:4: column time: time 2024-01-23 appears twice (lines 3 and 4)"),
])
def test_dates_that_cannot_be_read_are_refused_in_one_line(pfx_in_process, tmp_path, rows, changes, expected):
    line = error_line(pfx_in_process("validate", dates_case(tmp_path, rows, **changes), cwd=tmp_path), 2)
    assert line.startswith(expected), line


def test_a_truth_file_gives_the_measurements_dates(tmp_path):
    dates_case(tmp_path, DAILY)
    config = yaml.safe_load((tmp_path / "flu.yaml").read_text())
    config["data"]["truth"] = "truth.csv"
    (tmp_path / "truth.csv").write_text("time,x1\n" + "".join(f"{date},0.5\n" for date in DAILY))
    plan = build_plan(config, str(tmp_path / "flu.yaml"))
    assert plan.cells[0].data.truth.shape == (5, 1)
    (tmp_path / "truth.csv").write_text("time,x1\n" + "".join(f"{k},0.5\n" for k in range(5)))
    with pytest.raises(ConfigError, match="the times are numbers, the measurements' .* dates: use the same"):
        build_plan(config, str(tmp_path / "flu.yaml"))


# -- 6. the README -----------------------------------------------------------------------------------

def test_the_readme_says_what_make_install_and_pip_install_install():
    """`make install` installs the test extra (JAX, Dask, pytest, statsmodels...): the README
    names the very pip command the Makefile runs, and every extra pfx offers."""
    readme = (REPO_ROOT / "README.md").read_text()
    target = re.search(r"pip install --quiet (-e '\.\[\w+\]')", (REPO_ROOT / "Makefile").read_text()).group(1)
    assert f"pip install {target}" in readme
    said = readme.split(f"pip install {target}", 1)[1].split("`pip install .`", 1)[0]     # what it installs
    assert all(name in said for name in ("JAX", "Dask", "pytest", "statsmodels")), said
    extras = re.search(r"\[project\.optional-dependencies\](.*?)\n\[", (REPO_ROOT / "pyproject.toml").read_text(),
                       re.S).group(1)
    for extra in re.findall(r"^([\w-]+) = ", extras, re.M):
        if extra != "test":
            assert f"'pfx[{extra}]'" in readme, extra
    assert not np.any([line.startswith("| `make install` |") and "numpy, scipy, pandas, matplotlib, numba, dask"
                       in line for line in readme.splitlines()])
