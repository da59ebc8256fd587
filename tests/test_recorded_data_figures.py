"""The figures of a run on recorded data (``data:`` without ``data.truth``), and ``pfx simulate``.

* ``filtered_over_data``: each state's filtered mean and its band mean +- 2 sd, steps.csv's,
  with the measurements over the state they measure;
* ``predictions_over_data``: the one-step-ahead predictive mean and band of each measurement
  (``metrics.scores``) against the measurements;
* no figure of a truth that does not exist: ``state_error_over_time`` refused in one line (in
  the config, and asked of the folder), ``trajectory_map`` drawn without a true path;
* ``pfx simulate``: simulations.csv (path p drawn from trial p's truth stream, so the same seed
  gives the same table) and ``simulations_over_data``; bad input refused in one line, exit 2.

One small run (a 2-D random walk measured in noise, 12 steps, a Kalman and a particle filter,
2 trials) serves the figure tests; each figure is drawn once.
"""

from __future__ import annotations

import matplotlib
import numpy as np
import pandas as pd
import pytest
from conftest import write_config_file
from matplotlib.collections import PathCollection, PolyCollection

from pfx.figures.filtered_over_data import filtered_over_data
from pfx.figures.maps import trajectory_map
from pfx.figures.predictions_over_data import predictions_over_data
from pfx.result_folder import ResultFolder

matplotlib.use("Agg")

STEPS = 12
MODEL = {"kind": "linear_gaussian", "transition_matrix": [[1.0, 0.0], [0.0, 1.0]],
         "measurement_matrix": [[1.0, 0.0], [0.0, 1.0]], "names": ["x", "y"],
         "process_noise": {"variance": 0.2}, "measurement_noise": {"variance": 0.5},
         "initial": {"kind": "gaussian", "mean": [0.0, 0.0], "covariance": 4.0}}
RECORDED = {
    "name": "recorded-walk", "seed": 5, "trials": 2, "model": MODEL,
    "data": {"measurements": "measurements.csv"},
    "filter": {"particles": 60},
    "arms": {"KF": {"kind": "kf"}, "PF": {}},
    "metrics": {"scores": True},
    "outputs": {"figures": ["filtered_over_data", "predictions_over_data", "trajectory_map"]},
}


def write_measurements(folder) -> None:
    """A walk in the plane measured in noise, with step 4 missing."""
    rng = np.random.default_rng(49)
    walk = np.cumsum(rng.normal(scale=0.45, size=(STEPS, 2)), axis=0)
    measured = walk + rng.normal(scale=0.7, size=(STEPS, 2))
    rows = ["step,z1,z2"] + [f"{k + 1},{a:.6f},{b:.6f}" if k != 3 else f"{k + 1},," for k, (a, b) in enumerate(measured)]
    (folder / "measurements.csv").write_text("\n".join(rows) + "\n")


@pytest.fixture(scope="module")
def recorded_folder(pfx_in_process, tmp_path_factory):
    """The run's result folder: the two figures drawn by `pfx run` itself."""
    folder = tmp_path_factory.mktemp("recorded-figures")
    write_measurements(folder)
    config = write_config_file(folder, RECORDED, "recorded.yaml")
    result = pfx_in_process("run", config, "--out", folder / "run")
    assert result.returncode == 0, result.stderr
    return folder


@pytest.fixture(autouse=True)
def close_figures():
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


def _labelled(axes, label: str):
    return [artist for artist in [*axes.lines, *axes.collections] if artist.get_label() == label]


def _first_trial(result: ResultFolder, arm: str) -> pd.DataFrame:
    steps = result.steps
    return steps[(steps["arm"] == arm) & (steps["trial"] == 0)].sort_values("step")


# -- 1. the filtered means and the one-step predictions, over the data ----------------------------

def test_filtered_over_data_draws_each_state_with_its_band_and_the_measurements_over_it(recorded_folder):
    run = recorded_folder / "run"
    assert (run / "figures" / "filtered_over_data.png").is_file()
    result = ResultFolder(run)
    figure = filtered_over_data(result)
    panels = figure.axes
    assert len(panels) == 4                               # (x, y) x (KF, PF)
    for axes, (state, arm, component) in zip(panels, [("x", "KF", "z1"), ("x", "PF", "z1"),
                                                      ("y", "KF", "z2"), ("y", "PF", "z2")]):
        rows = _first_trial(result, arm)
        mean = rows[f"estimate_{state}"].to_numpy()
        sd = rows[f"sd_{state}"].to_numpy()
        line, = _labelled(axes, "filtered mean")
        np.testing.assert_allclose(line.get_ydata(), mean)
        band, = _labelled(axes, "± 2 sd")
        assert isinstance(band, PolyCollection)
        edges = band.get_paths()[0].vertices[:, 1]
        assert np.isclose(edges.max(), (mean + 2 * sd).max()) and np.isclose(edges.min(), (mean - 2 * sd).min())
        points, = _labelled(axes, "measurement")
        assert isinstance(points, PathCollection)
        np.testing.assert_allclose(points.get_offsets()[:, 1].filled(np.nan), rows[f"measurement_{component}"],
                                   equal_nan=True)
        assert not _labelled(axes, "true state")          # recorded data without data.truth
    assert "z1 over x, z2 over y" in figure._suptitle.get_text()


def test_predictions_over_data_draws_the_predictive_band_against_the_measurements(recorded_folder):
    run = recorded_folder / "run"
    assert (run / "figures" / "predictions_over_data.png").is_file()
    result = ResultFolder(run)
    figure = predictions_over_data(result)
    assert len(figure.axes) == 4                          # (z1, z2) x (KF, PF)
    for axes, (component, arm) in zip(figure.axes, [("z1", "KF"), ("z1", "PF"), ("z2", "KF"), ("z2", "PF")]):
        rows = _first_trial(result, arm)
        mean, sd = rows[f"predictive_mean_{component}"].to_numpy(), rows[f"predictive_sd_{component}"].to_numpy()
        observed = rows[f"measurement_{component}"].to_numpy()
        assert np.isnan(mean[3]) and np.isnan(observed[3])       # the missing step has no prediction
        line, = _labelled(axes, "predictive mean")
        np.testing.assert_allclose(line.get_ydata(), mean, equal_nan=True)
        assert _labelled(axes, "± 2 sd") and _labelled(axes, "measurement")
        present = ~np.isnan(observed)
        outside = int((np.abs(observed[present] - mean[present]) > 2 * sd[present]).sum())
        assert axes.get_title().endswith(f"{outside} of {STEPS - 1} outside the band")


# -- 2. no figure of a truth that does not exist -------------------------------------------------------

def test_state_error_over_time_is_refused_on_recorded_data_without_truth(recorded_folder, pfx_in_process):
    config = write_config_file(recorded_folder, {**RECORDED, "outputs": {"figures": ["state_error_over_time"]}},
                               "errors.yaml")
    refused = pfx_in_process("validate", config)
    assert refused.returncode == 2 and refused.stdout == ""
    line, = refused.stderr.strip().splitlines()
    assert "outputs.figures[0]: figure state_error_over_time draws the true states" in line and "data.truth" in line

    asked = pfx_in_process("figures", recorded_folder / "run", "--figure", "state_error_over_time")
    assert asked.returncode == 2
    line, = asked.stderr.strip().splitlines()          # no All-NaN warning, no traceback
    assert "state_error_over_time draws the true states" in line
    assert not (recorded_folder / "run" / "figures" / "state_error_over_time.png").exists()

    # with the truth recorded, the same figure is the config's to ask for
    steps = pd.read_csv(recorded_folder / "run" / "steps.csv")
    truth = steps[(steps["arm"] == "KF") & (steps["trial"] == 0)][["step", "estimate_x", "estimate_y"]]
    truth.set_axis(["step", "x", "y"], axis=1).to_csv(recorded_folder / "truth.csv", index=False)
    with_truth = write_config_file(recorded_folder, {**RECORDED, "outputs": {"figures": ["state_error_over_time"]},
                                                     "data": {**RECORDED["data"], "truth": "truth.csv"}},
                                   "with-truth.yaml")
    assert pfx_in_process("validate", with_truth).returncode == 0


def test_trajectory_map_draws_the_estimated_path_alone_without_a_truth(recorded_folder):
    result = ResultFolder(recorded_folder / "run")
    figure = trajectory_map(result)
    for axes, arm in zip(figure.axes, ["KF", "PF"]):
        assert not _labelled(axes, "true path")
        path, = _labelled(axes, "estimated path")
        np.testing.assert_allclose(path.get_xdata(), _first_trial(result, arm)["estimate_x"])
        start, = _labelled(axes, "start")
        np.testing.assert_allclose(start.get_offsets()[0], _first_trial(result, arm)[["estimate_x", "estimate_y"]].iloc[0])
    assert "true path" not in [text.get_text() for text in figure.legends[0].get_texts()]
    assert "no true path" in figure._suptitle.get_text()


# -- 3. pfx simulate ------------------------------------------------------------------------------------

def test_simulate_writes_its_table_and_figure_reproducibly(recorded_folder, pfx_in_process):
    import pfx

    config = recorded_folder / "recorded.yaml"
    first = pfx_in_process("simulate", config, "--out", recorded_folder / "sim-a", "--paths", "3")
    assert first.returncode == 0, first.stderr
    table = pd.read_csv(recorded_folder / "sim-a" / "simulations.csv")
    assert list(table.columns) == ["path", "truth_seed", "step", "time", "state_x", "state_y", "measurement_z1",
                                   "measurement_z2", "observed_z1", "observed_z2"]
    assert len(table) == 3 * STEPS and sorted(table["path"].unique()) == [0, 1, 2]
    recorded = pd.read_csv(recorded_folder / "measurements.csv")
    np.testing.assert_allclose(table.loc[table["path"] == 2, "observed_z1"], recorded["z1"], equal_nan=True)
    # path p: the truth stream of trial p of the config's seed, as pfx.simulate draws it
    expected = pfx.simulate(pfx.model("linear_gaussian", steps=STEPS, **{k: v for k, v in MODEL.items() if k != "kind"}),
                            trials=3, seed=RECORDED["seed"])
    np.testing.assert_allclose(table["measurement_z2"].to_numpy().reshape(3, STEPS), expected.measurements[:, :, 1])
    assert table.groupby("path")["truth_seed"].first().tolist() == expected.seeds
    assert (recorded_folder / "sim-a" / "figures" / "simulations_over_data.png").is_file()

    again = pfx_in_process("simulate", config, "--out", recorded_folder / "sim-b", "--paths", "3")
    assert again.returncode == 0, again.stderr
    assert (recorded_folder / "sim-a" / "simulations.csv").read_bytes() == \
        (recorded_folder / "sim-b" / "simulations.csv").read_bytes()
    redrawn = pfx_in_process("figures", recorded_folder / "sim-b")           # from the CSV alone
    assert redrawn.returncode == 0, redrawn.stderr


@pytest.mark.parametrize("case", ["paths", "run folder", "model sweep", "missing config"])
def test_simulate_refuses_bad_input_in_one_line(recorded_folder, pfx_in_process, case):
    config = recorded_folder / "recorded.yaml"
    out = recorded_folder / f"refused-{case.replace(' ', '-')}"
    arguments = {"paths": [config, "--out", out, "--paths", "0"],
                 "run folder": [config, "--out", recorded_folder / "run"],
                 "model sweep": [write_config_file(recorded_folder, {**RECORDED, "sweep": {
                     "model.measurement_noise.variance": [0.5, 1.0]}}, "swept.yaml"), "--out", out],
                 "missing config": [recorded_folder / "nowhere.yaml", "--out", out]}[case]
    before = sorted(path.name for path in (recorded_folder / "run").iterdir())
    result = pfx_in_process("simulate", *arguments)
    assert result.returncode == 2 and result.stdout == ""
    line, = result.stderr.strip().splitlines()
    assert line.startswith("pfx: error:")
    assert {"paths": "--paths", "run folder": "other files than pfx simulate's", "model sweep": "sweep",
            "missing config": "nowhere.yaml"}[case] in line
    assert not out.exists()
    assert sorted(path.name for path in (recorded_folder / "run").iterdir()) == before
