"""``pfx reproduce`` keeps the committed record where the numbers agree (pfx/papers/record.py).

results/ is committed; a fresh clone's ``make reproduce-papers`` must leave ``git status`` clean
when pfx computes the same numbers. A run's own timings and another machine's last bits must
not rewrite the record; any real change must, and must be named.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from conftest import tiny_config_dict, write_config_file

import pfx
from pfx.papers.base import format_number
from pfx.papers.record import RELATIVE_TOLERANCE, compare_folders, compare_tables
from pfx.papers.reproduce import reproduce_papers


def _table(**columns):
    return pd.DataFrame(columns)


def test_tables_agree_despite_run_times_and_last_bit_noise():
    old = _table(arm=["a", "b"], rmse=[0.1, 2.5], run_time_s=[0.01, 0.02], lost_mass=[0.0, 1e-16])
    new = _table(arm=["a", "b"], rmse=[0.1 * (1 + 3e-16), 2.5], run_time_s=[0.7, 0.9], lost_mass=[4e-16, 0.0])
    assert compare_tables(old, new) is None


@pytest.mark.parametrize("change", [
    {"rmse": [0.1, 2.5 * (1 + 10 * RELATIVE_TOLERANCE)]},     # a real change of a number
    {"rmse": [0.1, np.nan]},                                   # a value gone missing
    {"rmse": [0.1, np.inf]},                                   # a value diverged
    {"arm": ["a", "c"]},                                       # a label
])
def test_tables_differ_when_a_number_or_a_label_really_changes(change):
    old = _table(arm=["a", "b"], rmse=[0.1, 2.5])
    new = old.assign(**change)
    assert compare_tables(old, new) is not None


def test_tables_with_other_columns_or_rows_differ():
    old = _table(arm=["a", "b"], rmse=[0.1, 2.5])
    assert "columns" in compare_tables(old, old.rename(columns={"rmse": "rmse_position"}))
    assert "rows" in compare_tables(old, old.iloc[:1])


def _paper(tmp_path, seed=7):
    configs = tmp_path / "configs"
    write_config_file(configs / "toy", tiny_config_dict(seed=seed, outputs={"trace_trials": 2,
                                                                            "figures": ["error_over_time"]}),
                      "tiny.yaml")
    return configs


def _reproduce(configs, out):
    messages = []
    reproduce_papers([], configs, out, fresh=True, report=messages.append, progress=False)
    return messages


def test_a_second_reproduction_keeps_the_record_byte_for_byte(tmp_path):
    configs, out = _paper(tmp_path), tmp_path / "results"
    _reproduce(configs, out)
    folder = out / "toy" / "tiny"
    before = {path: path.read_bytes() for path in folder.rglob("*") if path.is_file() and "figures" not in path.parts}
    messages = _reproduce(configs, out)
    after = {path: path.read_bytes() for path in folder.rglob("*") if path.is_file() and "figures" not in path.parts}
    assert after == before                       # run times and manifest times included
    assert any("the same numbers" in message for message in messages)
    assert (folder / "figures" / "error_over_time.png").is_file()
    assert sorted(path.name for path in (out / "toy").iterdir()) == ["tiny"]       # no staging left behind


def test_a_reproduction_with_new_numbers_replaces_the_record_and_says_what_moved(tmp_path):
    out = tmp_path / "results"
    _reproduce(_paper(tmp_path, seed=7), out)
    trials = pd.read_csv(out / "toy" / "tiny" / "trials.csv")
    messages = _reproduce(_paper(tmp_path, seed=8), out)
    assert any("new numbers" in message for message in messages), messages
    assert not pd.read_csv(out / "toy" / "tiny" / "trials.csv")["log_likelihood"].equals(trials["log_likelihood"])
    assert json.loads((out / "toy" / "tiny" / "manifest.json").read_text())["seed"] == 8


def test_compare_folders_finds_a_changed_table(tmp_path):
    configs, out = _paper(tmp_path), tmp_path / "results"
    _reproduce(configs, out)
    folder = out / "toy" / "tiny"
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    assert compare_folders(folder, copy) is None
    trials = pd.read_csv(copy / "trials.csv")
    trials.loc[0, "log_likelihood"] *= 1.01
    trials.to_csv(copy / "trials.csv", index=False)
    assert "trials.csv" in str(compare_folders(folder, copy))


@pytest.mark.parametrize("value, digits, text", [
    (1.1649999999999998, 3, "1.17"), (1.1650000000000000, 3, "1.17"),     # one machine's bits, another's
    (71.84999999999999, 3, "71.9"), (71.85000000000001, 3, "71.9"),
    (265719.49999999997, 3, "265,720"), (0.0998, 3, "0.0998"), (5.8e-11, 2, "5.8e-11")])
def test_shown_digits_do_not_depend_on_the_last_bits(value, digits, text):
    assert format_number(value, digits) == text


def test_a_folder_with_data_keeps_its_record_in_a_clone_elsewhere(tmp_path, capsys):
    """A repository holding data, config and results, cloned into another folder: the rerun finds
    its results up to date, and a fresh run there writes the same config.yaml (the data named
    relative to the result folder, the config hash from the data's content), where an absolute
    path made every clone's record differ."""
    project = tmp_path / "here"
    (project / "data").mkdir(parents=True)
    (project / "data" / "flow.csv").write_text("step,z1\n1,0.5\n2,0.7\n3,\n4,1.1\n")
    model = {key: value for key, value in tiny_config_dict()["model"].items() if key != "steps"}
    write_config_file(project, tiny_config_dict(model=model, data={"measurements": "data/flow.csv"}), "flow.yaml")
    pfx.run(str(project / "flow.yaml"), out=project / "results" / "flow")
    record = (project / "results" / "flow" / "config.yaml").read_bytes()
    assert b"../../data/flow.csv" in record and str(project).encode() not in record

    clone = tmp_path / "elsewhere" / "clone"
    shutil.copytree(project, clone)
    capsys.readouterr()
    pfx.run(str(clone / "flow.yaml"), out=clone / "results" / "flow", quiet=False)
    assert "up to date (same config hash" in capsys.readouterr().err
    pfx.run(str(clone / "flow.yaml"), out=clone / "results" / "flow", fresh=True)
    assert (clone / "results" / "flow" / "config.yaml").read_bytes() == record
    hashes = [json.loads((root / "results" / "flow" / "manifest.json").read_text())["config_hash"]
              for root in (project, clone)]
    assert hashes[0] == hashes[1]
