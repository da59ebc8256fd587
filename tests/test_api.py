"""``pfx.api``: running, reading and comparing from Python gives what the command line gives.

A module fixture runs one two-arm config through the API (as a dict, and as a file, each into
its own folder) and through the command line (its entry point, ``pfx_in_process``) on the same
file, with ``--set``, and the ``compare`` and error cases. The tests then hold the two sides against each other: the same
tables (run times aside), the same printed run summary, the same comparison table as the CSV
``pfx compare`` writes, the same one-line error messages, nothing written on a mistake. The
worked example of docs/python-api.md is executed as written.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import re
import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, tiny_config_dict, write_config_file

import pfx
from pfx import api
from pfx.analysis.compare import output_name
from pfx.errors import ConfigError
from pfx.result_folder import read_table, write_csv

CONFIG = tiny_config_dict(name="api", trials=4, arms={"few": {"particles": 5}, "many": {"particles": 40}},
                          outputs={"trace_trials": 1, "figures": []})
OVERRIDES = {"trials": 3, "filter.particles": 30}        # particles: the arms' own values are replaced too
SET_OPTIONS = ["--set", "trials=3", "--set", "filter.particles=30"]
BAD_CONFIG = tiny_config_dict(model={"kind": "linear_gausian", "steps": 5})
STUDY = {"name": "offspring", "seed": 5, "study": {"kind": "offspring_counts", "draws": 4000},
         "outputs": {"figures": []}}
DOC = REPO_ROOT / "docs" / "python-api.md"
ERROR_PREFIX = "pfx: error: "
API_NAMES = {"run": api.run, "load": api.load, "Result": api.Result, "ConfigError": ConfigError}   # what `pfx.` offers


def _in_process(call):
    """Call ``call()``; return its result and what it printed on stdout and stderr."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        value = call()
    return value, stdout.getvalue(), stderr.getvalue()


@pytest.fixture(scope="module")
def runs(tmp_path_factory, pfx_in_process):
    """Every run, both sides: {name: Result or PfxResult}, and "root", the folder they ran in."""
    root = tmp_path_factory.mktemp("api")
    write_config_file(root, CONFIG, "api.yaml")
    write_config_file(root, BAD_CONFIG, "bad.yaml")
    write_config_file(root, STUDY, "study.yaml")
    results = {"root": root}
    results["dict"], results["dict-stdout"], results["dict-stderr"] = _in_process(
        lambda: api.run(CONFIG, out=root / "api-dict", quiet=False))
    results["path"], results["path-stdout"], results["path-stderr"] = _in_process(
        lambda: api.run(root / "api.yaml", out=root / "api-path"))
    results["overrides-dict"], _, results["overrides-stderr"] = _in_process(
        lambda: api.run(CONFIG, out=root / "api-overrides-dict", overrides=OVERRIDES, quiet=False))
    results["overrides-list"] = api.run(CONFIG, out=root / "api-overrides-list",
                                        overrides=[f"{key}={value}" for key, value in OVERRIDES.items()])
    results["study"] = api.run(STUDY, out=root / "api-study")
    shutil.copytree(root / "api-path", root / "compared")      # `pfx compare` writes into its folder
    results.update(pfx_in_process.many({
        "cli": (["run", "api.yaml", "--out", "cli"], root),
        "cli-set": (["run", "api.yaml", *SET_OPTIONS, "--out", "cli-set"], root),
        "cli-study": (["run", "study.yaml", "--out", "cli-study", "--quiet"], root),
        "cli-bad": (["run", "bad.yaml", "--out", "cli-bad"], root),
        "cli-bad-set": (["run", "api.yaml", "--set", "trials", "--out", "cli-bad-set"], root),
        "compare": (["compare", "compared", "--metric", "rmse_position"], root),
        "compare-options": (["compare", "compared", "--metric", "converged", "--by", "n_particles",
                             "--baseline", "40", "--higher-is-better", "--bootstrap", "200"], root),
        "compare-typo": (["compare", "compared", "--metric", "rmse_positon"], root),
    }))
    for name in ("cli", "cli-set", "cli-study", "compare", "compare-options"):
        assert results[name].returncode == 0, f"{name}: {results[name].output}"
    return results


def _cli_error(result) -> str:
    """The one error line of a failed command, without its ``pfx: error:`` prefix."""
    assert result.returncode == 2, result.output
    (line,) = result.stderr.splitlines()
    assert line.startswith(ERROR_PREFIX)
    return line.removeprefix(ERROR_PREFIX)


def _without_run_times(frame: pd.DataFrame) -> pd.DataFrame:
    """A table without its wall-clock columns (run_time_s and its statistics), which no two runs share."""
    return frame[[column for column in frame.columns if not column.startswith("run_time_s")]]


def _assert_same_tables(folder: Path, result: api.Result) -> None:
    """``result`` holds exactly the CSV tables of ``folder`` (as the one reader reads them)."""
    written = sorted(path.stem for path in folder.glob("*.csv"))
    assert sorted(result.tables) == written
    for name in written:
        pd.testing.assert_frame_equal(_without_run_times(result.tables[name]),
                                      _without_run_times(read_table(folder / f"{name}.csv")), check_exact=True)


# -- run: the same folder as `pfx run` ------------------------------------------------------------

@pytest.mark.parametrize("source", ["dict", "path"])
def test_run_gives_the_tables_pfx_run_writes(runs, source):
    result = runs[source]
    _assert_same_tables(runs["root"] / "cli", result)
    assert set(result.tables) == {"trials", "summary", "steps", "steps_summary"}
    assert result.trials["arm"].tolist() == ["few"] * 4 + ["many"] * 4
    assert result.particles is None and result.scene is None          # not kept, no fixed world


@pytest.mark.parametrize("source", ["dict", "path"])
def test_run_records_the_resolved_config_pfx_run_records(runs, source):
    cli_config = yaml.safe_load((runs["root"] / "cli" / "config.yaml").read_text())
    assert runs[source].config == cli_config
    cli_manifest = json.loads((runs["root"] / "cli" / "manifest.json").read_text())
    assert runs[source].manifest["results_hash"] == cli_manifest["results_hash"]


def test_a_dict_config_is_recorded_as_dict_and_a_file_by_its_path(runs):
    assert runs["dict"].manifest["config_file"] == "<dict>"
    assert runs["path"].manifest["config_file"] == str(runs["root"] / "api.yaml")


def test_quiet_false_prints_what_pfx_run_prints(runs):
    folder = str(runs["root"] / "api-dict")
    assert runs["dict-stdout"].replace(folder, "cli") == runs["cli"].stdout
    assert "api: 2 cell(s) x 4 trial(s) ->" in runs["dict-stdout"]
    assert "next: pfx compare" in runs["dict-stdout"]


def test_quiet_prints_nothing(runs):
    assert runs["path-stdout"] == "" and runs["path-stderr"] == ""


def test_out_defaults_to_runs_slash_name_in_the_working_folder(runs, tmp_path, monkeypatch):
    shutil.copytree(runs["root"] / "api-dict", tmp_path / "runs" / "api")      # up to date: only read
    monkeypatch.chdir(tmp_path)
    result = api.run(CONFIG)
    assert result.folder == Path("runs") / "api"
    pd.testing.assert_frame_equal(result.trials, runs["dict"].trials)


# -- overrides: the meaning of --set --------------------------------------------------------------

@pytest.mark.parametrize("form", ["overrides-dict", "overrides-list"])
def test_overrides_work_like_set(runs, form):
    result = runs[form]
    _assert_same_tables(runs["root"] / "cli-set", result)
    assert result.manifest["trials"] == 3
    assert set(result.trials["n_particles"]) == {30}               # the arms' own counts replaced, as --set does


def test_overrides_report_what_they_replace_as_set_does(runs):
    notes = runs["overrides-stderr"].replace("<dict>", "api.yaml").splitlines()
    assert notes and notes == runs["cli-set"].stderr.splitlines()[:len(notes)]


def test_a_dict_override_value_means_what_its_yaml_text_means():
    config = tiny_config_dict(arms={"few": {"particles": 5}, "many": {"particles": 40}})
    value_notes, text_notes = [], []
    by_value = api._plan(config, {"filter.particles": 30, "sweep.filter.resampler": ["systematic", "multinomial"],
                                  "model.measurement_noise": {"variance": 0.5}}, value_notes.append)
    by_text = api._plan(config, ["filter.particles=30", "sweep.filter.resampler=[systematic, multinomial]",
                                 "model.measurement_noise={variance: 0.5}"], text_notes.append)
    assert by_value.resolved == by_text.resolved
    assert value_notes == text_notes == ["<dict>: --set filter.particles also replaces the value of arms few, many"]
    assert [(cell.labels["n_particles"], cell.labels["resampler"]) for cell in by_value.cells] == [
        (30, "systematic"), (30, "multinomial")] * 2


# -- load -------------------------------------------------------------------------------------------

def test_load_reads_back_what_run_returned(runs):
    loaded = api.load(runs["root"] / "api-dict")
    assert loaded.table_names == runs["dict"].table_names
    for name in loaded.table_names:
        pd.testing.assert_frame_equal(loaded.tables[name], runs["dict"].tables[name])
    assert loaded.config == runs["dict"].config and loaded.manifest == runs["dict"].manifest


def test_repr_names_the_run_its_folder_cells_and_trials(runs):
    text = repr(api.load(runs["root"] / "cli"))
    assert text.startswith("Result(name='api', ")
    assert f"folder={str(runs['root'] / 'cli')!r}" in text
    assert "cells=2, trials=4" in text and "trials, steps, steps_summary, summary" in text


def test_a_table_the_folder_lacks_is_none_and_an_unknown_name_an_attribute_error(runs):
    result = runs["dict"]
    assert result.particles is None
    with pytest.raises(AttributeError, match="no attribute or table 'trails'.*trials, steps"):
        result.trails       # noqa: B018  (the attribute access is the test)
    with pytest.raises(KeyError, match="no table 'particles'"):
        result.table("particles")


def test_load_of_a_folder_that_is_no_finished_result_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not a finished pfx result folder"):
        api.load(tmp_path)


# -- studies ----------------------------------------------------------------------------------------

def test_a_study_runs_and_its_tables_are_attributes(runs):
    result = runs["study"]
    _assert_same_tables(runs["root"] / "cli-study", result)
    assert result.table_names == ["offspring"] and result.offspring is result.tables["offspring"]
    assert result.trials is None and result.summary is None
    assert repr(result).endswith("study='offspring_counts', tables=[offspring])")


def test_compare_on_a_study_is_the_error_pfx_compare_gives(runs):
    with pytest.raises(ConfigError, match=re.escape(f"{runs['study'].folder}: not a finished pfx result folder")):
        runs["study"].compare("rmse_position")


# -- compare: the table `pfx compare` writes ---------------------------------------------------------

def _written_like_the_command(table: pd.DataFrame, tmp_path: Path) -> str:
    """The table as `pfx compare` would write it (the same writer), as text."""
    write_csv(table, tmp_path / "table.csv")
    return (tmp_path / "table.csv").read_text()


def test_compare_returns_the_table_pfx_compare_writes(runs, tmp_path):
    table = runs["path"].compare("rmse_position")
    written = runs["root"] / "compared" / output_name("rmse_position", "arm")
    assert _written_like_the_command(table, tmp_path) == written.read_text()
    assert table[["arm", "baseline", "n_pairs"]].values.tolist() == [["many", "few", 4]]


def test_compare_passes_every_option_as_pfx_compare_does(runs, tmp_path):
    table = runs["path"].compare("converged", by="n_particles", baseline=40, higher_is_better=True, bootstrap=200)
    written = runs["root"] / "compared" / output_name("converged", "n_particles")
    assert _written_like_the_command(table, tmp_path) == written.read_text()
    assert set(table["better"]) == {"higher"} and set(table["ci_method"]) == {"bootstrap-200"}


def test_compare_writes_nothing(runs):
    assert not list(runs["path"].folder.glob("compare_*.csv"))


def test_compare_errors_are_the_lines_pfx_compare_prints(runs, monkeypatch):
    monkeypatch.chdir(runs["root"])
    with pytest.raises(ConfigError) as error:
        api.load("compared").compare("rmse_positon")
    assert str(error.value) == _cli_error(runs["compare-typo"])


# -- errors: the command's line, nothing written --------------------------------------------------------

def test_a_bad_config_file_raises_the_line_pfx_run_prints(runs, monkeypatch):
    monkeypatch.chdir(runs["root"])
    with pytest.raises(ConfigError) as error:
        api.run("bad.yaml", out="api-bad")
    assert str(error.value) == _cli_error(runs["cli-bad"])
    assert "did you mean 'linear_gaussian'" in str(error.value)


def test_a_bad_dict_config_raises_the_same_line_naming_dict(runs):
    with pytest.raises(ConfigError) as error:
        api.run(BAD_CONFIG, out=runs["root"] / "api-bad-dict")
    assert str(error.value) == _cli_error(runs["cli-bad"]).replace("bad.yaml", "<dict>", 1)


def test_a_bad_override_raises_the_line_pfx_run_prints(runs, monkeypatch):
    monkeypatch.chdir(runs["root"])
    with pytest.raises(ConfigError) as error:
        api.run("api.yaml", out="api-bad-set", overrides=["trials"])
    assert str(error.value) == _cli_error(runs["cli-bad-set"])


@pytest.mark.parametrize("config, overrides, message", [
    (BAD_CONFIG, None, "<dict>: model.kind: unknown model kind"),
    ({**CONFIG, "seed": object()}, None, "<dict>: seed: object is not config data"),
    (42, None, "config: expected a config file's path or a dict, not int"),
    (CONFIG, 3, "overrides: expected a dict"),
    (CONFIG, {"trials=3": 4}, "overrides: a key must be a dotted path without '='"),
    (CONFIG, {"filter.particles": "many"}, "<dict>: overrides filter.particles=many: input should be a valid integer"),
    ("missing.yaml", None, "missing.yaml: no such file"),
])
def test_a_mistake_raises_one_line_and_writes_nothing(tmp_path, monkeypatch, config, overrides, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError) as error:
        api.run(config, overrides=overrides)
    assert str(error.value).startswith(message) and "\n" not in str(error.value)
    assert list(tmp_path.iterdir()) == []                  # not even runs/


def test_a_folder_of_other_results_is_refused_unless_fresh(runs, tmp_path):
    folder = tmp_path / "other"
    shutil.copytree(runs["root"] / "api-dict", folder)
    before = (folder / "trials.csv").read_bytes()
    changed = {**CONFIG, "seed": 8}
    with pytest.raises(ConfigError, match="holds results of a different config.*--fresh"):
        api.run(changed, out=folder)
    assert (folder / "trials.csv").read_bytes() == before
    assert api.run(changed, out=folder, fresh=True).manifest["seed"] == 8


# -- the documentation's worked example ----------------------------------------------------------------

def test_pfx_exports_the_api_and_pfx_run_stays_the_function():
    """`import pfx` offers run, load, Result and ConfigError (pfx/__init__.py). The subpackage
    pfx/run/ shares the name `run`: importing its modules must not replace the function."""
    if not hasattr(pfx, "Result"):
        pytest.skip("pfx/__init__.py does not re-export the API yet")
    importlib.import_module("pfx.run.runner")          # the kind of import that would rebind pfx.run

    for name, value in API_NAMES.items():
        assert getattr(pfx, name) is value, name


def test_the_worked_example_of_the_docs_runs(tmp_path, monkeypatch, capsys):
    """docs/python-api.md's python blocks, run as written in a folder holding its config."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert blocks and "pfx.run(" in blocks[0] and ".compare(" in blocks[0] and "pfx.load(" in blocks[0]
    example = Path("configs/examples/falling-body.yaml")
    (tmp_path / example.parent).mkdir(parents=True)
    shutil.copy(REPO_ROOT / example, tmp_path / example)
    for name, value in API_NAMES.items():
        monkeypatch.setattr(pfx, name, value, raising=False)      # a no-op once pfx/__init__.py re-exports them
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile("\n".join(blocks), str(DOC), "exec"), namespace)  # noqa: S102  (our own documentation)
    printed = capsys.readouterr().out
    assert namespace["result"].folder == Path("runs/falling-body")
    assert len(namespace["result"].trials) == 2 * 10                        # two arms, overrides={"trials": 10}
    assert namespace["table"]["arm"].tolist() == ["MPF-innovation"]
    assert set(namespace["walk"].trials["resampler"]) == {"multinomial"}
    assert "<dict>: model.kind: unknown model kind 'linear_gausian' (did you mean 'linear_gaussian'?)" in printed
