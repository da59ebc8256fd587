"""Messages that say what is wrong, where, and what to do (issue 34, "Messages"; covariates that
overflow; a run whose every weight is zero).

* an unknown kind in a list names the component, never the list index ("unknown 0 kind");
* "an ekf", "an int": the article goes by the sound of the name (:func:`pfx.registry.with_article`);
* a data file's header that names other columns: the columns found and those expected;
* a ``--set`` typo is the override's, not the config file's (and ``pfx.run``'s ``overrides``);
* ``inf`` in a data file is refused at the file, row and column;
* a smoother or proposal refused for want of a transition density names the remedy;
* the end-of-run table says the convergence radius and whether it is the default;
* covariates whose interpolation would overflow are refused at the covariate file;
* a run whose every weight is zero says so: a column, ``-inf``, and one line per cell.
"""

from __future__ import annotations

import math

import pandas as pd
import pytest
import yaml
from conftest import tiny_config_dict, write_config_file
from test_covariates import drift_config

import pfx
from pfx.analysis.run_summary import print_run_summary
from pfx.config.overrides import apply_overrides, blame_override
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.registry import with_article
from pfx.result_folder import read_manifest


def plan_of(folder, config: dict, name: str = "config.yaml"):
    path = write_config_file(folder, config, name)
    return build_plan(yaml.safe_load(path.read_text()), str(path))


def refusal(folder, config: dict) -> str:
    with pytest.raises(ConfigError) as caught:
        plan_of(folder, config)
    message = str(caught.value)
    assert "\n" not in message
    return message


# -- names in messages ---------------------------------------------------------------------------

def test_an_unknown_kind_in_a_list_is_named_by_its_component_not_its_index(tmp_path):
    config = tiny_config_dict()
    config["filter"]["smoothers"] = ["ffbs", {"kind": "ffsb"}]
    message = refusal(tmp_path, config)
    assert message.endswith("filter.smoothers[1].kind: unknown smoother kind 'ffsb' (did you mean 'ffbs'?)"), message
    config["filter"]["smoothers"] = "fixed_lag"         # not a list: named by its key, as before
    config["filter"]["move"] = "mcmcc"
    assert "filter.move.kind: unknown move kind 'mcmcc' (did you mean 'mcmc'?)" in refusal(tmp_path, config)


@pytest.mark.parametrize("phrase, expected", [
    ("ekf", "an ekf"), ("ukf", "a ukf"), ("kf", "a kf"), ("rts smoother", "an rts smoother"),
    ("int", "an int"), ("str", "a str"), ("list", "a list"), ("particle", "a particle"),
    ("histogram", "a histogram"), ("uniform law", "a uniform law"), ("ffbs", "an ffbs"),
])
def test_the_article_goes_by_the_sound_of_the_name(phrase, expected):
    assert with_article(phrase) == expected


def test_messages_built_from_names_take_the_right_article(tmp_path):
    config = tiny_config_dict()
    config["filter"]["smoothers"] = ["rts"]
    assert "the rts smoother runs after an ekf, kf or ukf filter, not particle" in refusal(tmp_path, config)
    (tmp_path / "number.yaml").write_text("5\n")
    with pytest.raises(ConfigError, match="top level must be a mapping of sections, not an int"):
        pfx.run(str(tmp_path / "number.yaml"), out=tmp_path / "out")


# -- data files ----------------------------------------------------------------------------------

def recorded(folder, measurements: str, **data_files) -> dict:
    (folder / "measurements.csv").write_text(measurements)
    data = {"measurements": "measurements.csv"}
    for key, text in data_files.items():
        (folder / f"{key}.csv").write_text(text)
        data[key] = f"{key}.csv"
    model = {k: v for k, v in tiny_config_dict()["model"].items() if k != "steps"}
    return tiny_config_dict(model=model, data=data)


def test_a_header_of_other_columns_names_those_found_and_those_expected(tmp_path):
    message = refusal(tmp_path, recorded(tmp_path, "step,flow\n1,1.0\n2,2.0\n"))
    assert message.endswith("measurements.csv:1: column flow: found flow after `step`, expected the 1 measurement "
                            "component(s) of model linear_gaussian: z1 (flow is not among them; z1 is missing)"), message
    message = refusal(tmp_path, recorded(tmp_path, "step,z1\n1,1.0\n", truth="step,level,x1\n1,0,0\n"))
    assert message.endswith("truth.csv:1: column level: found level, x1 after `step`, expected the 1 state "
                            "component(s) of model linear_gaussian: x1 (level is not among them)"), message


@pytest.mark.parametrize("files, where", [
    ({"measurements": "step,z1\n1,1.0\n2,inf\n"}, "measurements.csv:3: column z1: 'inf' is not a finite number"),
    ({"measurements": "step,z1\n1,1.0\n2,2.0\n", "truth": "step,x1\n1,-inf\n2,0\n"},
     "truth.csv:2: column x1: '-inf' is not a finite number"),
    ({"measurements": "step,z1\n1,1.0\n2,1e999\n"}, "measurements.csv:3: column z1: '1e999' is not a finite number"),
])
def test_inf_in_a_data_file_is_refused_at_its_row_and_column(tmp_path, files, where):
    """Already so before issue 34 (pfx/config/data_files.py reads every cell as a finite number): kept."""
    files = dict(files)
    message = refusal(tmp_path, recorded(tmp_path, files.pop("measurements"), **files))
    assert where in message and "model" not in message.split(where)[0], message


# -- --set and overrides -------------------------------------------------------------------------

def test_a_set_typo_is_reported_as_the_overrides_with_exit_2_and_nothing_written(run_pfx, tmp_path):
    config = write_config_file(tmp_path, tiny_config_dict(), "tiny.yaml")
    result = run_pfx("run", config.name, "--out", "out", "--set", "filter.particels=10", cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr == ("pfx: error: tiny.yaml: --set filter.particels=10: unknown key filter.particels "
                             "(did you mean filter.particles?)\n"), result.stderr
    assert not (tmp_path / "out").exists()


def blamed(config: dict, assignments: list[str]) -> str:
    changed, _ = apply_overrides(config, assignments, "tiny.yaml")
    with pytest.raises(ConfigError) as caught:
        build_plan(changed, "tiny.yaml")
    return str(blame_override(caught.value, config, assignments, "tiny.yaml"))


def test_an_override_is_blamed_where_it_put_the_value_and_only_there():
    config = tiny_config_dict(arms={"few": {"particles": 10}})
    assert blamed(config, ["filter.particles=abc"]) == \
        "tiny.yaml: --set filter.particles=abc: input should be a valid integer (got 'abc')"
    assert blamed(config, ["filtr.particles=10"]) == \
        "tiny.yaml: --set filtr.particles=10: unknown key filtr (did you mean filter?)"
    assert blamed(config, ["trials=2", "filter.weighting={kind: gausian}"]) == \
        ("tiny.yaml: --set filter.weighting={kind: gausian}: filter.weighting.kind: unknown weighting kind 'gausian' "
         "(did you mean 'gaussian'?)")
    # --set filter.particles also sets the arm that sets it: the arm's error is the override's too
    assert blamed(config, ["filter.particles=-5"]).startswith("tiny.yaml: --set filter.particles=-5: ")
    # the file's own mistake stays the file's, whatever else is overridden
    broken = tiny_config_dict()
    broken["filter"]["particels"] = 20
    assert blamed(broken, ["trials=2"]) == "tiny.yaml: filter.particels: unknown key 'particels' (did you mean 'particles'?)"


def test_pfx_run_names_the_override_too(tmp_path):
    with pytest.raises(ConfigError) as caught:
        pfx.run(tiny_config_dict(), out=tmp_path / "out", overrides={"filter.particels": 10})
    assert str(caught.value) == \
        "<dict>: overrides filter.particels=10: unknown key filter.particels (did you mean filter.particles?)"
    assert not (tmp_path / "out").exists()


# -- remedies --------------------------------------------------------------------------------------

@pytest.mark.parametrize("setting, remedy", [
    ({"proposal": "ekf"}, "use the bootstrap proposal, which needs no transition density, or give the model a "
                          "process noise of full rank"),
    ({"smoothers": ["ffbs"]}, "use the fixed_lag or genealogy smoother, which need no transition density, or give "
                              "the model a process noise of full rank"),
])
def test_a_singular_process_noise_refusal_names_the_remedy(tmp_path, setting, remedy):
    config = {"name": "fall", "seed": 1, "trials": 1, "model": {"kind": "falling_body", "steps": 5},
              "filter": {"particles": 10, **setting}}
    message = refusal(tmp_path, config)
    assert "process noise covariance L Q L' is singular" in message and remedy in message, message


# -- covariates --------------------------------------------------------------------------------------

def test_covariates_whose_interpolation_overflows_are_refused_at_the_file(run_pfx, tmp_path):
    (tmp_path / "drift.csv").write_text("time,drift\n0,0\n3,1e308\n6,-1e308\n")
    config = write_config_file(tmp_path, drift_config(tmp_path))
    result = run_pfx("run", config.name, "--out", "out", cwd=tmp_path)
    assert result.returncode == 2, result.output
    assert result.stderr == ("pfx: error: drift.csv:4: column drift: -1e+308 after 1e+308: the change between the "
                             "two rows is too large to be represented as a number, so the values between them cannot "
                             "be interpolated; use smaller values (other units)\n"), result.stderr
    assert not (tmp_path / "out").exists()


def test_inline_covariates_that_overflow_are_refused_at_their_key(tmp_path):
    config = drift_config(tmp_path, covariates=None,
                          model={"kind": "drift", "covariates": {"time": [0.0, 6.0], "drift": [-1.7e308, 1.7e308]}})
    message = refusal(tmp_path, config)
    assert "model.covariates.drift[1]: 1.7e+308 after -1.7e+308: the change between the two rows" in message


# -- the end-of-run table ------------------------------------------------------------------------------

def end_of_run(folder) -> list[str]:
    lines: list[str] = []
    print_run_summary(folder, read_manifest(folder), lines.append, rich_console=False)
    return lines


def test_the_table_says_the_convergence_radius_and_whether_it_is_the_default(tmp_path):
    pfx.run(tiny_config_dict(), out=tmp_path / "default")
    lines = end_of_run(tmp_path / "default")
    assert "converged (r = 1, default)" in lines[1], lines
    assert not any(line.startswith("converged:") for line in lines), lines     # it told the cells something
    # A model a hundred times wider: with the default radius no trial converges, and a line says why.
    wide = {**tiny_config_dict()["model"], "process_noise": {"variance": 1e4}, "measurement_noise": {"variance": 1e4}}
    pfx.run(tiny_config_dict(model=wide), out=tmp_path / "wide")
    assert pd.read_csv(tmp_path / "wide" / "summary.csv")["converged_mean"].eq(0).all()
    assert ("converged: every cell 0% with the default radius r = 1, which may not suit this model's "
            "scale: set metrics.convergence.radius in its position units (docs/configuration.md)") in end_of_run(
                tmp_path / "wide")
    pfx.run(tiny_config_dict(model=wide, metrics={"convergence": {"radius": 0.5}}), out=tmp_path / "chosen")
    lines = end_of_run(tmp_path / "chosen")
    assert "converged (r = 0.5)" in lines[1] and not any(line.startswith("converged:") for line in lines), lines


# A uniform measurement noise far narrower than the truth's: at almost every step no particle
# lies within its support, so every weight is zero.
ZERO_WEIGHTS = tiny_config_dict(model={**tiny_config_dict()["model"], "steps": 20},
                                filter={"particles": 20, "model": {"measurement_noise": {"family": "uniform",
                                                                                         "variance": 1e-4}}})


def test_a_run_whose_every_weight_is_zero_says_so(tmp_path, capsys):
    pfx.run(ZERO_WEIGHTS, out=tmp_path / "zero", quiet=False)
    printed = capsys.readouterr().out.splitlines()
    trials = pd.read_csv(tmp_path / "zero" / "trials.csv")
    counts = trials["degenerate_steps"]
    assert counts.min() == counts.max() > 10 and (trials["log_likelihood"] == -math.inf).all()
    header = next(line for line in printed if line.split()[:2] == ["arm", "trials"])
    row = next(line for line in printed if line.strip().startswith("default"))
    assert header.split()[-2:] == ["degenerate", "steps"] and "log-likelihood" in header
    assert "-inf" in row.split() and f"{counts.iloc[0]} [no CI]" in row, row
    assert (f"cell arm=default: every particle weight was zero at {counts.iloc[0]} of 20 steps in every trial (reset "
            "to uniform, counted in degenerate_steps): the estimates there follow the model, not the measurements, "
            "and its log-likelihood is -inf; try more particles, a wider or heavier-tailed assumed measurement noise "
            "(filter.model.measurement_noise), or check the measurements' units") in printed
    # a run without degenerate steps prints neither the column nor a line
    pfx.run(tiny_config_dict(), out=tmp_path / "fine", quiet=False)
    printed = capsys.readouterr().out
    assert "degenerate" not in printed and "-inf" not in printed
