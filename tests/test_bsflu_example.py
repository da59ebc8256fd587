"""The boarding-school flu example (docs/bsflu.md): pomp's ``bsflu`` data, its SIRR plugin
(examples/plugins/bsflu.py) and the four configs configs/examples/bsflu*.yaml.

* The data file holds the published series: the boys confined to bed on days 1..14.
* The plugin's likelihood is the Poisson log-probability of the reports given rho R1, by hand,
  with probability 1 of no report when nobody is in bed; one substep's draws have the mean its
  ``propagate`` says (the binomial exits' expectations), within 4 standard errors.
* Every bsflu config validates and runs at a tiny size, in process.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import pfx
from pfx.config.overrides import apply_overrides
from pfx.config.plan import build_plan
from pfx.numerics.seeding import TrialStreams
from pfx.run.runner import run_plan
from pfx.safe_yaml import load_config_file

pytestmark = pytest.mark.usefixtures("fresh_plugins")
REPOSITORY = Path(__file__).resolve().parents[1]
PLUGIN = REPOSITORY / "examples" / "plugins" / "bsflu.py"
DATA = REPOSITORY / "examples" / "data" / "bsflu.csv"
CONFIGS = sorted((REPOSITORY / "configs" / "examples").glob("bsflu*.yaml"))
PUBLISHED = [3, 8, 28, 76, 222, 293, 257, 237, 192, 126, 70, 28, 12, 5]     # pomp's bsflu$B
TINY = {"bsflu.yaml": ["filter.particles=50", "outputs.figures=[]"],
        "bsflu-if2.yaml": ["filter.particles=50", "estimation.iterations=2", "estimation.evaluations=2"],
        "bsflu-profile.yaml": ["filter.particles=50", "estimation.iterations=2", "estimation.evaluations=2",
                               "outputs.figures=[]"],
        "bsflu-pmmh.yaml": ["filter.particles=50", "estimation.iterations=12", "estimation.warm_up=4",
                            "outputs.forecasts.trials=4"]}


def flu(**parameters):
    pfx.load_plugin(str(PLUGIN))
    return pfx.model("bsflu", **parameters)


def test_the_data_file_is_the_published_series():
    frame = pd.read_csv(DATA)
    assert list(frame.columns) == ["time", "reports"]
    assert frame["time"].tolist() == list(range(1, 15))
    assert frame["reports"].tolist() == PUBLISHED
    assert sum(PUBLISHED) == 1557          # the bed-days behind pomp's mu_R1 = 512 / 1557


def test_the_likelihood_is_the_poisson_log_probability():
    model = flu(rho=0.8)
    state = np.array([[[500.0, 40.0, 150.0, 70.0], [700.0, 5.0, 0.0, 57.0], [600.0, 3.0, 0.0, 160.0]]])
    reports = np.array([[[130.0], [0.0], [4.0]]])
    got = np.asarray(model.log_likelihood(reports, state))
    mean = 0.8 * 150.0
    by_hand = 130.0 * math.log(mean) - mean - math.lgamma(131.0)
    assert got.shape == (1, 3)
    assert got[0, 0] == pytest.approx(by_hand, rel=1e-12)
    assert got[0, 1] == 0.0                # nobody in bed and no report: probability 1
    assert got[0, 2] == -math.inf          # reports while nobody is in bed: impossible


def test_one_substep_has_the_mean_propagate_gives():
    model = flu(Beta=3.0, mu_IR=1.5, mu_R1=0.4)
    trials, particles = 50, 400
    start = np.array([600.0, 80.0, 60.0, 23.0])
    state = np.broadcast_to(start, (trials, particles, 4)).copy()
    random = TrialStreams([np.random.default_rng(seed) for seed in range(trials)])
    draws = np.asarray(model.sample_substep(state, None, 0.0, random)).reshape(-1, 4)
    mean = np.asarray(model.propagate(start[None, None, :], None, None))[0, 0]
    step = 1.0 / 12.0
    assert mean[0] == pytest.approx(600.0 * math.exp(-3.0 * 80.0 / 763.0 * step))
    assert draws.sum(axis=1) == pytest.approx(763.0)            # nobody is lost
    standard_error = draws.std(axis=0) / math.sqrt(len(draws))
    assert np.all(np.abs(draws.mean(axis=0) - mean) < 4.0 * standard_error + 1e-12)


@pytest.mark.parametrize("config", CONFIGS, ids=lambda path: path.name)
def test_each_config_runs_small(config, tmp_path):
    assert config.name in TINY
    raw, _ = apply_overrides(load_config_file(config), TINY[config.name], str(config))
    estimation = "estimation" in raw
    folder = run_plan(build_plan(raw, str(config), trials=None if estimation else 2), tmp_path / "out")
    expected = {"bsflu.yaml": "forecasts.csv", "bsflu-if2.yaml": "maximum_likelihood.csv",
                "bsflu-profile.yaml": "profile_interval.csv", "bsflu-pmmh.yaml": "posterior.csv"}[config.name]
    table = pd.read_csv(folder / expected)
    assert len(table) > 0
    if config.name == "bsflu.yaml":
        likelihoods = pd.read_csv(folder / "trials.csv")["log_likelihood"]
        assert len(likelihoods) == 2 and np.all(np.isfinite(likelihoods))


def test_the_configs_are_all_listed():
    assert sorted(path.name for path in CONFIGS) == sorted(TINY)
