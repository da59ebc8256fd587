"""Forecasts after PMMH (pfx/estimation/posterior_forecasts.py): one filter per posterior draw,
and their mixture, the posterior predictive forecast."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import pfx

pytestmark = pytest.mark.usefixtures("fresh_plugins")

CONFIG = """
name: posterior-forecasts
seed: 3
model:
  kind: linear_gaussian
  transition_matrix: [[0.9]]
  measurement_matrix: [[1.0]]
  steps: 30
  process_noise: {variance: 1.0}
  measurement_noise: {variance: 1.0}
  initial: {kind: gaussian, mean: [0.0], covariance: 1.0}
filter: {particles: 150}
estimation:
  method: METHOD
  chains: 2
  iterations: 120
  warm_up: 40
  parameters:
    model.measurement_noise.variance: {prior: {law: flat, lower: 0}, transform: log, start: 1.0, proposal_sd: 0.3}
outputs:
  figures: []
  forecasts: {horizons: [1, 4], origins: [20], trials: 5}
"""


def test_forecasts_from_posterior_draws_and_their_mixture(tmp_path):
    config = tmp_path / "pmmh.yaml"
    config.write_text(CONFIG.replace("METHOD", "pmmh"))
    pfx.run(config, out=tmp_path / "out")
    table = pd.read_csv(tmp_path / "out" / "forecasts.csv")
    chains = pd.read_csv(tmp_path / "out" / "chains.csv")
    draws = table[table["draw"] != "pooled"]
    assert sorted(set(draws["draw"].astype(int))) == [0, 1, 2, 3, 4]
    assert (draws["iteration"] > 40).all()                 # after the warm-up
    # each draw's parameter value is its chain's at that iteration
    merged = draws.merge(chains, on=["chain", "iteration"], suffixes=("", "_chain"))
    assert np.allclose(merged["measurement_noise.variance"], merged["measurement_noise.variance_chain"])
    for horizon in (1, 4):
        rows = draws[draws["horizon"] == horizon]
        mixture = table[(table["draw"] == "pooled") & (table["horizon"] == horizon)].iloc[0]
        # the mixture of equally weighted draws: the law of total expectation and of total variance, exactly
        means, sds = rows["state_mean_x1"].to_numpy(), rows["state_sd_x1"].to_numpy()
        assert mixture["state_mean_x1"] == pytest.approx(means.mean(), rel=1e-12)
        assert mixture["state_sd_x1"] ** 2 == pytest.approx(np.mean(sds ** 2) + np.var(means), rel=1e-10)
        assert mixture["observed_z1"] == rows["observed_z1"].iloc[0] and np.isfinite(mixture["crps_z1"])


def test_if2_forecasts_are_refused_by_key(tmp_path):
    from typer.testing import CliRunner

    from pfx.cli import app

    config = tmp_path / "if2.yaml"
    config.write_text(CONFIG.replace("METHOD", "if2").replace("proposal_sd: 0.3", "random_walk_sd: 0.1")
                      .replace("  warm_up: 40\n", ""))
    result = CliRunner().invoke(app, ["run", str(config), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "outputs.forecasts" in result.output and "PMMH" in result.output


def test_a_draw_whose_filter_fails_is_left_out_in_one_line(tmp_path, monkeypatch, pfx_in_process):
    """A posterior draw the forecasts cannot use (here one whose parameters the model refuses, as no
    accepted draw can be, put there by hand) is not dropped without a word: the run says how many
    draws the cell's forecasts come from, and why the first left out was."""
    from pfx.estimation import posterior_forecasts as module

    original = module.posterior_draws

    def with_a_refused_draw(chains, columns, count):
        draws = original(chains, columns, count)
        draws.loc[0, columns[0]] = -1.0          # a negative variance
        return draws

    monkeypatch.setattr(module, "posterior_draws", with_a_refused_draw)
    config = tmp_path / "pmmh.yaml"
    config.write_text(CONFIG.replace("METHOD", "pmmh"))
    result = pfx_in_process("run", config, "--out", tmp_path / "out")
    assert result.returncode == 0, result.output
    lines = [line for line in result.stderr.splitlines() if "posterior draws" in line]
    assert len(lines) == 1 and "forecasts from 4 of 5 posterior draws; 1 left out" in lines[0], result.stderr
    assert "draw 0: the model refuses its parameters" in lines[0]
    table = pd.read_csv(tmp_path / "out" / "forecasts.csv")
    assert sorted(set(table.loc[table["draw"] != "pooled", "draw"].astype(int))) == [1, 2, 3, 4]
