"""PMMH that a person can get to converge (issue 49, section 2).

* **The correlated pair is named.** Flagged chains whose draws after the warm-up have two
  parameters correlated beyond 0.5 get a flag line naming them, their correlation, and what
  helps given how the run's proposal adapted (pfx/analysis/estimation_flags.py), the same line
  from the run and from the folder's files alone (pfx/analysis/run_summary.py).
* **Forecasts from a finished PMMH folder.** ``outputs.forecasts`` only reads the chains: it is
  not part of an estimation config's results hash (pfx/config/plan.py), so a finished folder
  asked for forecasts keeps its chains byte for byte, runs none again, and gains forecasts.csv
  (the very bytes a run that made them with the chains writes) and the ``forecast_fan`` figure,
  which draws the posterior predictive forecast on an estimation folder
  (pfx/run/estimation_outputs.py, pfx/figures/forecasts.py).

The runs are tiny (a simulated local level of 30 steps, 40 particles, 2 chains, 30 iterations).
"""

from __future__ import annotations

import contextlib
import copy
import io
import shutil

import numpy as np
import pandas as pd
import pytest

import pfx
from pfx.analysis.estimation_flags import CORRELATION_LIMIT, pmmh_advice, strongest_correlation
from pfx.analysis.run_summary import print_estimation_summary
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.estimation.pmmh import ParticleMarginalMetropolisHastings
from pfx.estimation.summary import posterior_summary
from pfx.result_folder import ResultFolder

FORECASTS = {"horizons": [1, 3], "origins": [10.0, 20.0], "trials": 4}
CHAIN_TABLES = ("chains.csv", "posterior.csv", "priors.csv")


def pmmh_config(**outputs) -> dict:
    """A tiny PMMH config: the two variances of a simulated local level."""
    return {
        "name": "tiny-pmmh", "seed": 5,
        "model": {"kind": "linear_gaussian", "steps": 30, "transition_matrix": [[0.9]], "measurement_matrix": [[1.0]],
                  "process_noise": {"variance": 1.0}, "measurement_noise": {"variance": 1.0},
                  "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0}},
        "filter": {"particles": 40, "resampler": "systematic"},
        "estimation": {"method": "pmmh", "chains": 2, "iterations": 30, "warm_up": 10,
                       "parameters": {"model.process_noise.variance": {"prior": {"law": "flat", "lower": 0.0},
                                                                       "start": 1.0, "proposal_sd": 0.3},
                                      "model.measurement_noise.variance": {"prior": {"law": "flat", "lower": 0.0},
                                                                           "start": 1.0, "proposal_sd": 0.3}}},
        "outputs": {"figures": [], **outputs},
    }


# -- the correlated pair, named ---------------------------------------------------------------------------------

def correlated_chains(rho: float, iterations: int = 200, warm_up: int = 0, seed: int = 1) -> pd.DataFrame:
    """Two chains' rows of a slowly mixing walk (an AR(1) of coefficient 0.98, so that the ESS
    is flagged) in parameters a, b of correlation ``rho``, and c independent of both."""
    generator = np.random.default_rng(seed)
    frames = []
    factor = np.linalg.cholesky(np.array([[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    for chain in range(2):
        values = np.zeros((iterations + 1, 3))
        for index in range(1, iterations + 1):
            values[index] = 0.98 * values[index - 1] + np.sqrt(1 - 0.98 ** 2) * factor @ generator.standard_normal(3)
        frames.append(pd.DataFrame({"chain": chain, "iteration": np.arange(iterations + 1),
                                    "warm_up": np.arange(iterations + 1) <= warm_up,
                                    "a": values[:, 0], "b": values[:, 1], "c": values[:, 2],
                                    "log_likelihood": -values[:, 0] ** 2, "log_prior": 0.0,
                                    "accepted": generator.random(iterations + 1) < 0.3}))
    return pd.concat(frames, ignore_index=True)


def advice_for(chains: pd.DataFrame, warm_up: int, **proposal) -> str:
    summary = posterior_summary(chains, ["a", "b", "c"], warm_up)
    assert (summary["flag"] != "").any()            # the walk is slow: flagged
    return pmmh_advice(summary, int(chains["iteration"].max()), chains=chains, **proposal)


def test_a_strongly_correlated_pair_is_named_with_what_helps():
    chains = correlated_chains(0.9)
    first, second, rho = strongest_correlation(chains, ["a", "b", "c"])
    kept = chains[~chains["warm_up"]]
    assert (first, second) == ("a", "b") and rho == pytest.approx(np.corrcoef(kept["a"], kept["b"])[0, 1])
    advice = advice_for(chains, warm_up=0)
    assert "\n" not in advice
    assert f"a and b are correlated (corr {rho:.2f} in the draws after the warm-up, above 0.5)" in advice
    # the default run adapts nothing: warm_up is 0; the line says to set it, with adapt: true, or reparametrise
    assert "set estimation.warm_up (0 unless set, so nothing adapted) with adapt: true" in advice
    assert "e.g. warm_up: 200 with iterations: 400" in advice and "reparametrise" in advice
    assert "c are correlated" not in advice


def test_the_advice_follows_how_the_proposal_adapted():
    chains = correlated_chains(-0.95, iterations=400, warm_up=150)
    adapted = advice_for(chains, warm_up=150, adapt=True, adapt_after=100)
    assert "a and b are correlated (corr -0.90" in adapted
    assert "the proposal adapted to the draws' covariance over the warm-up's 150 iterations: a longer " \
           "estimation.warm_up learns it better" in adapted
    fixed = advice_for(chains, warm_up=150, adapt=False)
    assert "set adapt: true, with a warm_up longer than adapt_after (100)" in fixed
    too_short = advice_for(chains, warm_up=150, adapt=True, adapt_after=200)
    assert "a warm_up longer than adapt_after (200, the iterations before the first adaptation)" in too_short


def test_without_a_correlated_pair_the_line_says_only_whether_the_proposal_adapted():
    chains = correlated_chains(0.3)
    assert abs(strongest_correlation(chains, ["a", "b", "c"])[2]) < CORRELATION_LIMIT
    unadapted = advice_for(chains, warm_up=0)
    assert "correlated" not in unadapted
    assert unadapted.endswith("; also, the proposal did not learn the posterior's covariance (Haario et al. 2001), "
                              "which it does only during the warm-up: set estimation.warm_up (0 unless set, so nothing "
                              "adapted) with adapt: true (the default), e.g. warm_up: 200 with iterations: 400, keeping "
                              "as many draws (a new run, --fresh)")
    uncorrelated = correlated_chains(0.0, iterations=400, warm_up=150, seed=2)
    assert abs(strongest_correlation(uncorrelated, ["a", "b", "c"])[2]) < CORRELATION_LIMIT
    adapted = advice_for(uncorrelated, warm_up=150)
    assert "also," not in adapted and "warm_up" not in adapted         # nothing to add to an adapted proposal
    # without the chains (a caller that has none): no aside at all
    assert "also," not in pmmh_advice(posterior_summary(correlated_chains(0.9), ["a", "b", "c"], 0), 200)


def test_the_run_and_the_end_of_run_table_name_the_same_pair(tmp_path, capsys):
    """The run computes the line from its rows, the end-of-run table from chains.csv and
    config.yaml: the same words. (This tiny posterior's two variances trade off: the data cannot
    tell the process noise from the measurement noise well.)"""
    result = pfx.run(pmmh_config(), out=tmp_path / "out", quiet=False)
    run_lines = [line for line in capsys.readouterr().err.splitlines() if "are correlated" in line]
    assert len(run_lines) == 1, run_lines
    assert "process_noise.variance and measurement_noise.variance are correlated (corr -0." in run_lines[0]
    assert "set estimation.warm_up" not in run_lines[0]          # this run has a warm-up...
    assert "adapt_after (100, the iterations before" in run_lines[0]   # ... too short to adapt
    printed = io.StringIO()
    print_estimation_summary(result.folder, result.manifest, lambda line: print(line, file=printed))
    (table_line,) = [line for line in printed.getvalue().splitlines() if "are correlated" in line]
    assert table_line.split(": ", 1)[1] == run_lines[0].split(": cell ", 1)[1].split(": ", 1)[1]


# -- forecasts from a finished folder ------------------------------------------------------------------------------

def test_forecasts_are_not_part_of_an_estimation_configs_results_hash():
    plain = build_plan(pmmh_config(), "pmmh.yaml")
    with_forecasts = build_plan(pmmh_config(forecasts=FORECASTS), "pmmh.yaml")
    assert with_forecasts.results_hash == plain.results_hash
    assert with_forecasts.config_hash != plain.config_hash          # the record says what was asked
    # a filter run's forecasts.csv is a table of its trials: there they still are part of it
    filter_run = {key: value for key, value in pmmh_config().items() if key != "estimation"}
    filter_run["trials"] = 2
    assert build_plan({**filter_run, "outputs": {"figures": [], "forecasts": FORECASTS}}, "run.yaml").results_hash \
        != build_plan(filter_run, "run.yaml").results_hash


@pytest.fixture(scope="module")
def extended(tmp_path_factory):
    """A finished PMMH folder without forecasts, then the same config with forecasts and
    forecast_fan run into it, the chains' sampler forbidden; and a folder that made its
    forecasts with its chains."""
    root = tmp_path_factory.mktemp("pmmh-forecasts")
    folder = pfx.run(pmmh_config(), out=root / "out").folder
    before = {name: (folder / name).read_bytes() for name in CHAIN_TABLES}
    times = pfx.load(folder).manifest["cell_wall_time_s"]
    said = io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stderr(said):
        patch.setattr(ParticleMarginalMetropolisHastings, "__init__",
                      lambda *arguments, **keywords: pytest.fail("the chains were run again"))
        pfx.run(pmmh_config(forecasts=FORECASTS, figures=["forecast_fan"]), out=folder, quiet=False)
    messages = said.getvalue().splitlines()
    whole = pfx.run(pmmh_config(forecasts=FORECASTS), out=root / "whole").folder
    return folder, before, times, messages, whole


def test_a_finished_folder_gains_forecasts_without_running_its_chains(extended):
    folder, before, times, messages, whole = extended
    assert {name: (folder / name).read_bytes() for name in CHAIN_TABLES} == before
    manifest = pfx.load(folder).manifest
    assert manifest["cell_wall_time_s"] == times and manifest["complete"] is True
    assert manifest["figures"] == ["forecast_fan"]
    # the forecasts of the kept chains are those a run that made them with the chains writes
    assert (folder / "forecasts.csv").read_bytes() == (whole / "forecasts.csv").read_bytes()
    assert (folder / "figures" / "forecast_fan.png").is_file()
    (said,) = [message for message in messages if "chains up to date" in message]
    assert "forecasts.csv made from the kept chains" in said and "figures rendered: forecast_fan" in said
    # and the same config again: up to date, nothing rewritten
    assert pfx.run(pmmh_config(forecasts=FORECASTS, figures=["forecast_fan"]), out=folder).folder == folder


def test_changed_forecasts_are_made_again_and_dropped_ones_removed(extended, tmp_path):
    folder, before, *_ = extended
    copy_of = tmp_path / "copy"
    shutil.copytree(folder, copy_of)
    changed = copy.deepcopy(FORECASTS)
    changed["horizons"] = [2]
    pfx.run(pmmh_config(forecasts=changed), out=copy_of)
    assert set(pd.read_csv(copy_of / "forecasts.csv")["horizon"]) == {2}
    assert not (copy_of / "figures" / "forecast_fan.png").exists()        # no longer asked for
    pfx.run(pmmh_config(), out=copy_of)
    assert not (copy_of / "forecasts.csv").exists()
    assert {name: (copy_of / name).read_bytes() for name in CHAIN_TABLES} == before


def test_forecast_fan_draws_the_posterior_predictive_on_an_estimation_folder(extended):
    from pfx.estimation.posterior_forecasts import POOLED
    from pfx.figures import forecasts as fan_module

    folder = extended[0]
    assert fan_module.POOLED == POOLED
    figure = fan_module.forecast_fan(ResultFolder(folder))
    assert figure is not None
    from matplotlib.text import Text

    texts = " ".join(text.get_text() for text in figure.findobj(Text))
    assert "forecasts of the measurement from the posterior predictive (4 posterior draws pooled)" in texts
    pooled = pd.read_csv(folder / "forecasts.csv")
    pooled = pooled[pooled["draw"].astype(str) == POOLED]
    medians = {line.get_gid(): line for axes in figure.axes for line in axes.get_lines()
               if (line.get_gid() or "").endswith("median")}
    origin = int(pooled["origin_step"].min())
    expected = pooled[pooled["origin_step"] == origin].sort_values("horizon")["measurement_q50_z1"].to_numpy()
    assert np.allclose(medians[f"origin {origin}: median"].get_ydata()[-len(expected):], expected)


def test_forecast_fan_is_refused_on_an_estimation_folder_without_forecasts(extended, tmp_path):
    from pfx.figures import render_figures

    folder = pfx.run(pmmh_config(), out=tmp_path / "plain").folder
    with pytest.raises(ConfigError, match="figure forecast_fan draws forecasts.csv, which a PMMH estimation folder "
                                          r"does not have \(outputs.forecasts writes it\)"):
        render_figures(folder, ["forecast_fan"])
    assert not (folder / "figures" / "forecast_fan.png").exists()
    # named in a config without outputs.forecasts: refused by key, as for a filter run
    with pytest.raises(ConfigError, match="draws what outputs.forecasts writes") as refused:
        build_plan(pmmh_config(figures=["forecast_fan"]), "pmmh.yaml")
    assert refused.value.key == "outputs.figures[0]"

