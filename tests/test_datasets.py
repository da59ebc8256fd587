"""``datasets``: trials that share simulated datasets are repeated filter runs on the same data.

Trial ``t`` filters dataset ``t mod datasets``; the dataset's truth stream is the one trial
``t mod datasets`` has without the key, so the first ``datasets`` trials are exactly the trials
of the config without it, and every later trial repeats one of their truths with its own
filter stream.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import REPO_ROOT, tiny_config_dict

import pfx
from pfx.errors import ConfigError
from pfx.safe_yaml import load_config_file

TRUTH_ONLY = ["truth_seed", "steps"]


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    folder = tmp_path_factory.mktemp("datasets")
    config = tiny_config_dict(name="datasets", trials=6, outputs={"trace_trials": 6, "figures": []})
    plain = pfx.run(config, out=folder / "plain").trials
    shared = pfx.run({**config, "datasets": 2}, out=folder / "shared").trials
    steps = pfx.run({**config, "datasets": 2}, out=folder / "shared").steps
    return plain, shared, steps


def test_trial_t_sees_dataset_t_mod_datasets(tables):
    plain, shared, _ = tables
    seeds = shared.set_index("trial")["truth_seed"]
    for trial in range(6):
        assert seeds[trial] == plain.set_index("trial")["truth_seed"][trial % 2]
    assert shared["filter_seed"].nunique() == 6          # every trial keeps its own filter stream


def test_the_first_trials_are_those_of_the_config_without_datasets(tables):
    plain, shared, _ = tables
    columns = [c for c in plain.columns if c not in ("run_time_s", "cell")]
    first = shared[shared["trial"] < 2].reset_index(drop=True)
    pd.testing.assert_frame_equal(first[columns], plain[plain["trial"] < 2].reset_index(drop=True)[columns])


def test_the_trials_of_one_dataset_share_the_truth_not_the_estimates(tables):
    _, _, steps = tables
    truth = [c for c in steps.columns if c.startswith("truth_")]
    by_trial = {trial: frame.reset_index(drop=True) for trial, frame in steps.groupby("trial")}
    pd.testing.assert_frame_equal(by_trial[0][truth], by_trial[4][truth])
    assert not np.allclose(by_trial[0][truth].to_numpy(), by_trial[1][truth].to_numpy())
    estimates = [c for c in steps.columns if c.startswith("estimate_")]
    assert not np.allclose(by_trial[0][estimates].to_numpy(), by_trial[4][estimates].to_numpy())


def test_datasets_is_refused_with_recorded_data(tmp_path):
    config = load_config_file(REPO_ROOT / "configs" / "examples" / "nile.yaml")
    config["data"]["measurements"] = str(REPO_ROOT / "examples" / "data" / "nile.csv")
    config["datasets"] = 3
    with pytest.raises(ConfigError, match="recorded data is one dataset") as caught:
        pfx.run(config, out=tmp_path / "out")
    assert caught.value.key == "datasets"
    assert not (tmp_path / "out").exists()
