"""What a user of R's pomp expects of a fit to recorded data (docs/output-files.md#summarycsv,
docs/commands.md, docs/recorded-data.md):

* the log of the mean likelihood with its jackknife standard error, pomp's
  ``logmeanexp(ll, se = TRUE)`` (pfx/numerics/log_mean_exp.py), against known values and a
  direct leave-one-out computation;
* summary.csv's ``log_mean_likelihood`` and ``log_mean_likelihood_se`` agree with the trials'
  ``log_likelihood``, and the end-of-run table shows them where the trials share their data;
* on recorded data without a truth the end-of-run table has no error and no converged columns
  (unless the config chose a radius);
* a config's ``time_unit`` reaches the figures' time axis and the folder's record.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import tiny_config_dict

import pfx
from pfx.analysis.run_summary import print_run_summary
from pfx.figures.traces import ess_over_time
from pfx.numerics.log_mean_exp import log_mean_exp, log_mean_exp_jackknife
from pfx.result_folder import ResultFolder, read_manifest

TRIALS = 6


def leave_one_out(values: np.ndarray) -> tuple[float, float]:
    """pomp's definition written out: log(mean(exp(x))) and (n-1) sd(jackknife values) / sqrt(n)."""
    def direct(x):
        top = max(x)
        return top + math.log(sum(math.exp(v - top) for v in x) / len(x))

    n = len(values)
    jackknife = [direct([v for j, v in enumerate(values) if j != i]) for i in range(n)]
    return direct(list(values)), (n - 1) * float(np.std(jackknife, ddof=1)) / math.sqrt(n)


# -- the function -----------------------------------------------------------------------------

def test_equal_log_likelihoods_give_themselves_and_no_standard_error():
    for value in (-641.585643, 0.1, -3.0e4):
        estimate, standard_error = log_mean_exp_jackknife(np.full(7, value))
        assert estimate == value and standard_error == 0.0


def test_three_values_by_hand():
    # likelihoods 1, 2, 3: their mean is 2; leaving one out gives 5/2, 4/2 and 3/2
    estimate, standard_error = log_mean_exp_jackknife(np.log([1.0, 2.0, 3.0]))
    assert estimate == pytest.approx(math.log(2.0), abs=1e-15)
    left_out = [math.log(2.5), math.log(2.0), math.log(1.5)]
    centre = sum(left_out) / 3
    by_hand = math.sqrt(2 / 3 * sum((value - centre) ** 2 for value in left_out))
    assert standard_error == pytest.approx(by_hand, rel=1e-14)
    assert standard_error == pytest.approx(0.2957, abs=5e-5)


@pytest.mark.parametrize("values", [
    np.random.default_rng(1).normal(-3800.0, 5.0, size=25),      # a long record's likelihoods
    np.random.default_rng(2).normal(0.0, 30.0, size=9),          # spread over orders of magnitude
    np.array([-1000.0, -1.0, -2.0]),                              # one far below the others
    np.array([-1.0, -1.0, -1000.0, -3.0]),                        # a tie at the largest
])
def test_against_a_direct_leave_one_out_computation(values):
    estimate, standard_error = log_mean_exp_jackknife(values)
    direct_estimate, direct_error = leave_one_out(values)
    assert estimate == pytest.approx(direct_estimate, rel=1e-13, abs=1e-13)
    assert standard_error == pytest.approx(direct_error, rel=1e-9)


def test_zero_likelihoods_count_as_zero_and_the_standard_error_says_when_it_cannot_be_judged():
    estimate, standard_error = log_mean_exp_jackknife(np.array([-np.inf, -2.0, -3.0]))
    assert estimate == pytest.approx(math.log((math.exp(-2.0) + math.exp(-3.0)) / 3), rel=1e-14)
    assert standard_error == pytest.approx(leave_one_out([-np.inf, -2.0, -3.0])[1], rel=1e-9)
    assert log_mean_exp_jackknife(np.full(3, -np.inf))[0] == -np.inf           # every likelihood zero
    assert math.isnan(log_mean_exp_jackknife(np.full(3, -np.inf))[1])
    assert math.isnan(log_mean_exp_jackknife(np.array([-np.inf, -np.inf, 2.0]))[1])   # one run carries it
    assert log_mean_exp_jackknife(np.array([4.0]))[0] == 4.0 and math.isnan(log_mean_exp_jackknife([4.0])[1])
    assert all(math.isnan(value) for value in log_mean_exp_jackknife(np.array([])))
    np.testing.assert_array_equal(log_mean_exp(np.array([[0.0, 0.0], [-np.inf, -np.inf]]), axis=1), [0.0, -np.inf])


# -- a run on recorded data -------------------------------------------------------------------

def recorded_config(folder, **changes) -> dict:
    """A local-level model filtered by a Kalman and a particle filter on 30 recorded values,
    without their truth."""
    rows = np.random.default_rng(5).normal(0.0, 2.0, size=30).cumsum()
    data = folder / "counts.csv"
    data.write_text("time,z1\n" + "".join(f"{day},{value:.4f}\n" for day, value in enumerate(rows, start=1)))
    config = tiny_config_dict(
        name="recorded", trials=TRIALS,
        model={"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
               "process_noise": {"variance": 4.0}, "measurement_noise": {"variance": 1.0},
               "initial": {"kind": "gaussian", "mean": [0.0], "covariance": [100.0]}},
        data={"measurements": str(data)}, filter={"particles": 200}, arms={"KF": {"kind": "kf"}, "PF": {}},
        outputs={"figures": ["ess_over_time"]})
    config.update(changes)
    return config


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("recorded")
    pfx.run(recorded_config(folder), out=folder / "run")
    return folder / "run"


def end_of_run(folder) -> list[str]:
    lines: list[str] = []
    print_run_summary(folder, read_manifest(folder), lines.append, rich_console=False)
    return lines


def test_summary_has_the_log_mean_likelihood_of_the_trials(recorded):
    summary = pd.read_csv(recorded / "summary.csv").set_index("arm")
    trials = pd.read_csv(recorded / "trials.csv")
    columns = list(summary.columns)
    assert columns.index("log_mean_likelihood") == columns.index("log_likelihood_median") + 1
    assert columns.index("log_mean_likelihood_se") == columns.index("log_mean_likelihood") + 1
    for arm, rows in trials.groupby("arm"):
        estimate, standard_error = leave_one_out(rows["log_likelihood"].to_numpy())
        assert summary.loc[arm, "log_mean_likelihood"] == pytest.approx(estimate, rel=1e-13)
        assert summary.loc[arm, "log_mean_likelihood_se"] == pytest.approx(standard_error, rel=1e-9, abs=1e-12)
    # The Kalman filter's likelihood is exact: every trial's is the same, and so is their mean.
    assert summary.loc["KF", "log_mean_likelihood"] == pytest.approx(summary.loc["KF", "log_likelihood_mean"], rel=1e-15)
    assert summary.loc["KF", "log_mean_likelihood_se"] == 0.0
    # The particle filter's estimates vary: the log of their mean is above their mean (Jensen).
    assert summary.loc["PF", "log_mean_likelihood_se"] > 0
    assert summary.loc["PF", "log_mean_likelihood"] > summary.loc["PF", "log_likelihood_mean"]


def test_the_table_shows_the_log_mean_likelihood_and_no_truth_metric(recorded):
    lines = end_of_run(recorded)
    header = lines[1]
    assert "log-likelihood" in header and "log mean likelihood (se)" in header, lines
    for absent in ("converged", "RMSE", "final error"):
        assert absent not in "\n".join(lines), lines
    summary = pd.read_csv(recorded / "summary.csv").set_index("arm")
    row = next(line for line in lines if line.split()[:1] == ["PF"])
    estimate, standard_error = summary.loc["PF", ["log_mean_likelihood", "log_mean_likelihood_se"]]
    assert row.rstrip().endswith(f"{estimate:.6g} ({standard_error:.2g})"), row
    kalman = next(line for line in lines if line.split()[:1] == ["KF"])
    assert kalman.rstrip().endswith("(0)"), kalman
    # trials.csv keeps its columns (a public contract), empty where they need the truth
    trials = pd.read_csv(recorded / "trials.csv")
    assert {"rmse_position", "error_distance_final", "converged"} <= set(trials.columns)
    assert trials["rmse_position"].isna().all()


def test_without_the_truth_the_share_converged_is_shown_only_for_a_radius_the_config_chose(recorded, tmp_path):
    summary = pd.read_csv(recorded / "summary.csv").set_index("arm")
    assert summary.loc["PF", "converged_n"] == TRIALS          # the spread criterion needs no truth: computed,
    assert "converged" not in end_of_run(recorded)[1]          # but a default radius of 1 means nothing here
    config = recorded_config(tmp_path, metrics={"convergence": {"radius": 5.0}})
    pfx.run(config, out=tmp_path / "run")
    lines = end_of_run(tmp_path / "run")
    assert "converged (r = 5)" in lines[1] and "RMSE" not in lines[1], lines


def test_simulated_datasets_show_no_log_mean_likelihood_but_one_dataset_does(tmp_path):
    pfx.run(tiny_config_dict(), out=tmp_path / "independent")
    lines = end_of_run(tmp_path / "independent")
    assert "log-likelihood" in lines[1] and "log mean likelihood" not in lines[1], lines
    assert "converged (r = 1, default)" in lines[1], lines          # the truth is known: as before
    assert "log_mean_likelihood" in pd.read_csv(tmp_path / "independent" / "summary.csv")
    pfx.run(tiny_config_dict(datasets=1), out=tmp_path / "one")
    assert "log mean likelihood (se)" in end_of_run(tmp_path / "one")[1]


# -- the time unit ------------------------------------------------------------------------------

def test_the_configs_time_unit_reaches_the_axis_and_the_record(tmp_path):
    pfx.run(recorded_config(tmp_path, time_unit="day", trials=2), out=tmp_path / "days")
    folder = tmp_path / "days"
    assert json.loads((folder / "manifest.json").read_text())["units"]["time"] == "day"
    assert yaml.safe_load((folder / "config.yaml").read_text())["time_unit"] == "day"
    figure = ess_over_time(ResultFolder(folder))
    assert {axes.get_xlabel() for axes in figure.axes if axes.get_xlabel()} == {"time [day]"}
    # Without the key: the model's own unit, and a record without the key.
    pfx.run(recorded_config(tmp_path, trials=2), out=tmp_path / "seconds")
    assert json.loads((tmp_path / "seconds" / "manifest.json").read_text())["units"]["time"] == "s"
    assert "time_unit" not in yaml.safe_load((tmp_path / "seconds" / "config.yaml").read_text())


@pytest.mark.parametrize("unit", ["", "day [d]", "a unit longer than twenty"])
def test_a_time_unit_an_axis_cannot_show_is_refused_at_its_key(tmp_path, unit):
    with pytest.raises(pfx.ConfigError, match=r"time_unit: a unit's name of 1 to 20 characters without square "
                                              r"brackets or line breaks, e\.g\. day") as refusal:
        pfx.run(recorded_config(tmp_path, time_unit=unit), out=tmp_path / "bad")
    assert repr(unit) in str(refusal.value)
    assert not (tmp_path / "bad").exists()
