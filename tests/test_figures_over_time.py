"""The figures over time read every trial, lay sweeps out as small multiples, and keep legends off the data.

Small real result folders (tiny linear-Gaussian runs through :func:`pfx.run.runner.run_plan`):

* ``sweep``: 4 resamplers x 2 particle counts = 8 cells, 4 trials of which 2 are traced, with
  NEES recorded; its figures must draw steps_summary.csv (all 4 trials), not steps.csv (2);
* ``arms``: a particle filter and a Kalman filter on a state named ``log_volatility``, 6 trials
  (the fewest with a 95% band), every one traced, so the steps.csv fallback must reproduce
  steps_summary.csv;
* ``single``: one trial, where ``state_error_over_time`` draws the signed error.

Figures are checked through the matplotlib objects the figure functions return: the lines'
data, the number of panels, the labels, and where the legend lies after drawing.
"""

from __future__ import annotations

import json
import shutil

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from conftest import tiny_config_dict

from pfx.config.plan import build_plan
from pfx.figures.degeneracy import ess_decay
from pfx.figures.layout import MOST_LINES_IN_ONE_PANEL, error_quantity, plan_panels, time_axis
from pfx.figures.state_errors import state_error_over_time
from pfx.figures.traces import error_over_time, ess_over_time, nees_over_time
from pfx.result_folder import ResultFolder
from pfx.run.runner import run_plan

matplotlib.use("Agg")                  # no screen: draw into memory

OVER_TIME = {"error_over_time": error_over_time, "ess_over_time": ess_over_time, "nees_over_time": nees_over_time,
             "state_error_over_time": state_error_over_time, "ess_decay": ess_decay}

TWO_STATES = {"kind": "linear_gaussian", "steps": 6, "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
              "measurement_matrix": [[1.0, 0.0]], "names": ["position", "velocity"], "position": [0]}
LOG_VOLATILITY = {"kind": "linear_gaussian", "steps": 6, "transition_matrix": [[0.9]],
                  "measurement_matrix": [[1.0]], "names": ["log_volatility"]}


def _run(root, name: str, **changes):
    config = tiny_config_dict(name=name, **changes)
    config.setdefault("outputs", {})["figures"] = []          # the tests call the figures themselves
    return run_plan(build_plan(config, f"{name}.yaml"), root / name)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("over-time")
    return {
        "sweep": _run(root, "sweep", model=TWO_STATES, trials=4, outputs={"trace_trials": 2},
                      metrics={"consistency": True},
                      sweep={"filter.resampler": ["multinomial", "stratified", "systematic", "residual"],
                             "filter.particles": [20, 40]}),
        "arms": _run(root, "arms", model=LOG_VOLATILITY, trials=6, outputs={"trace_trials": 6},
                     arms={"PF": {}, "KF": {"kind": "kf"}}),
        "single": _run(root, "single", model=TWO_STATES, trials=1, arms={"PF": {}, "SIS": {"kind": "sis"}}),
        "auxiliary": _run(root, "auxiliary", model=TWO_STATES, trials=4, outputs={"trace_trials": 4},
                          arms={"bootstrap": {}, "APF": {"auxiliary": True}}),
    }


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def _without_steps_summary(folder, tmp_path):
    """A copy of a folder as written before steps_summary.csv existed."""
    copy = tmp_path / folder.name
    shutil.copytree(folder, copy)
    (copy / "steps_summary.csv").unlink()
    return ResultFolder(copy)


def _line(figure, label: str):
    """The one line with this legend label (the figure's legend says which cell it is)."""
    lines = [line for axes in figure.axes for line in axes.get_lines() if line.get_label() == label]
    assert len(lines) == 1, [line.get_label() for axes in figure.axes for line in axes.get_lines()]
    return lines[0]


def _bounding_boxes_overlap(first, second) -> bool:
    return first.x0 < second.x1 and second.x0 < first.x1 and first.y0 < second.y1 and second.y0 < first.y1


# -- the data: every trial ------------------------------------------------------------------------

def test_error_over_time_draws_the_mean_over_every_trial(folders):
    result = ResultFolder(folders["arms"])
    summary = result.steps_summary
    assert set(summary["trials"]) == {6}
    figure = error_over_time(result)
    for arm in ("PF", "KF"):
        rows = summary[summary["arm"] == arm]
        line = _line(figure, arm)
        np.testing.assert_allclose(line.get_xdata(), rows["time"])
        np.testing.assert_allclose(line.get_ydata(), rows["error_distance_mean"])
    assert "mean over 6 trials per cell, band: 95% CI" in figure._suptitle.get_text()


def test_a_sweep_draws_steps_summary_not_the_traced_trials(folders):
    """4 trials, 2 traced: the line must be steps_summary's mean, which the traced trials' mean is not."""
    result = ResultFolder(folders["sweep"])
    summary, steps = result.steps_summary, result.steps
    cell = summary["cell"].iloc[0]
    rows = summary[summary["cell"] == cell]
    traced_mean = steps[steps["cell"] == cell].groupby("step")["error_distance"].mean().to_numpy()
    assert not np.allclose(traced_mean, rows["error_distance_mean"])     # else this test proves nothing
    figure = error_over_time(result)
    drawn = [line for axes in figure.axes for line in axes.get_lines()
             if len(line.get_ydata()) == len(rows) and np.allclose(line.get_ydata(), rows["error_distance_mean"])]
    assert len(drawn) == 1
    assert "4 trials" in figure._suptitle.get_text() and "traced" not in figure._suptitle.get_text()


def test_ess_over_time_is_the_mean_ess_over_n_and_leaves_out_the_kalman_filter(folders):
    result = ResultFolder(folders["arms"])
    summary = result.steps_summary
    figure = ess_over_time(result)
    particle = summary[summary["arm"] == "PF"]
    np.testing.assert_allclose(_line(figure, "PF").get_ydata(), particle["ess_mean"] / particle["n_particles"])
    assert "KF" not in [line.get_label() for axes in figure.axes for line in axes.get_lines()]
    assert "no values for: KF" in figure._suptitle.get_text()


def test_the_ess_figures_say_the_auxiliary_filter_s_ess_is_of_its_second_stage_weights(folders):
    """Its second-stage weights are flatter than other filters' weights after a first-stage
    resampling, so its ESS is not the same measure: the figures name its cells, the others none."""
    result = ResultFolder(folders["auxiliary"])
    cells = json.loads((folders["auxiliary"] / "manifest.json").read_text())["cells"]
    assert [cell.get("auxiliary", False) for cell in cells] == [False, True]
    note = "APF: the auxiliary filter's ESS is that of its second-stage weights"
    for figure in (ess_over_time(result), ess_decay(result)):
        assert note in figure._suptitle.get_text()
    for figure in (ess_over_time(ResultFolder(folders["arms"])), ess_decay(ResultFolder(folders["arms"]))):
        assert "auxiliary" not in figure._suptitle.get_text()


def test_a_folder_of_too_few_trials_for_an_interval_says_why_it_has_no_band(folders):
    figure = error_over_time(ResultFolder(folders["sweep"]))             # 4 trials
    assert "mean over 4 trials per cell, no band: a 95% CI needs 6 trials" in figure._suptitle.get_text()
    assert ResultFolder(folders["sweep"]).steps_summary["error_distance_ci95_low"].isna().all()


def test_nees_over_time_draws_the_mean_nees_against_the_state_dimension(folders):
    result = ResultFolder(folders["sweep"])
    figure = nees_over_time(result)
    axes = figure.axes[0]
    assert axes.get_yscale() == "log"
    assert any(np.allclose(line.get_ydata(), 2.0) for line in axes.get_lines())      # d = 2 states
    assert "expected: d = 2" in [text.get_text() for text in figure.legends[0].get_texts()]
    means = result.steps_summary.groupby("cell", sort=False)["nees_mean"].apply(np.asarray)
    drawn = [line.get_ydata() for axes in figure.axes for line in axes.get_lines() if len(line.get_ydata()) > 2]
    assert all(any(np.allclose(y, mean) for y in drawn) for mean in means)


def test_a_nees_beyond_any_reading_leaves_the_log_axis_with_a_note(folders, tmp_path):
    """A collapsed cloud's mean NEES of 1e278 made matplotlib's log ticks pass the largest double
    and the figure fail to draw; such a line now stops at the axes' top, and a note says so."""
    import io

    copy = tmp_path / "huge"
    shutil.copytree(folders["sweep"], copy)
    summary = pd.read_csv(copy / "steps_summary.csv")
    first = summary["cell"] == summary["cell"].iloc[0]
    summary.loc[first & (summary["step"] >= 3), ["nees_mean", "nees_ci95_high"]] = 3.7e278
    summary.to_csv(copy / "steps_summary.csv", index=False)
    result = ResultFolder(copy)
    figure = nees_over_time(result)
    figure.savefig(io.BytesIO(), format="png")                     # drawing is where it failed
    notes = [axes.get_title(loc="left") for axes in figure.axes]
    assert any("off scale from" in note and "3.7e+278" in note for note in notes), notes
    assert all(axes.get_ylim()[1] == 1e100 for axes in figure.axes)
    panel = next(axes for axes in figure.axes if axes.get_title(loc="left"))      # the note sits under the panel's title
    renderer = figure.canvas.get_renderer()
    note, title = (panel._left_title.get_window_extent(renderer), panel.title.get_window_extent(renderer))
    assert title.y1 - note.y1 >= 0.9 * note.height           # the title's line is a whole line above the note


def test_state_error_over_time_draws_the_rms_over_every_trial(folders):
    result = ResultFolder(folders["sweep"])
    summary = result.steps_summary
    figure = state_error_over_time(result)
    first = summary[summary["cell"] == summary["cell"].iloc[0]]
    label = result.cell_names(first).iloc[0]
    velocity_panel = figure.axes[1]
    line = next(line for line in velocity_panel.get_lines() if line.get_label() == label)
    np.testing.assert_allclose(line.get_ydata(), first["rms_error_velocity"])
    assert "RMS" in velocity_panel.get_ylabel() and "velocity" in velocity_panel.get_ylabel()
    assert "over 4 trials per cell" in figure._suptitle.get_text()


def test_state_error_over_time_of_one_trial_draws_its_signed_error(folders):
    result = ResultFolder(folders["single"])
    steps = result.steps
    figure = state_error_over_time(result)
    position_panel = figure.axes[0]
    for arm in ("PF", "SIS"):
        rows = steps[steps["arm"] == arm]
        line = next(line for line in position_panel.get_lines() if line.get_label() == arm)
        np.testing.assert_allclose(line.get_ydata(), rows["estimate_position"] - rows["truth_position"])
    assert figure.axes[0].get_ylim()[0] < 0                       # signed: the axis spans both sides
    assert "one trial" in figure._suptitle.get_text()


# -- the steps.csv fallback for older folders -----------------------------------------------------

def test_an_older_folder_derives_the_same_summary_from_its_traced_trials(folders, tmp_path):
    """Every trial traced: the table derived from steps.csv is the run's steps_summary.csv."""
    written = ResultFolder(folders["arms"])
    older = _without_steps_summary(folders["arms"], tmp_path)
    assert written.steps_summary_covers_every_trial and not older.steps_summary_covers_every_trial
    # Values, not dtypes: a label column with empty fields (the Kalman filter's resampler) reads
    # from the file as pandas text, but is built from Python objects here.
    pd.testing.assert_frame_equal(older.steps_summary, written.steps_summary, rtol=1e-12, check_dtype=False)


def test_an_older_folder_draws_its_traced_trials_and_says_so(folders, tmp_path):
    older = _without_steps_summary(folders["sweep"], tmp_path)
    steps = older.steps
    cell = steps["cell"].iloc[0]
    traced_mean = steps[steps["cell"] == cell].groupby("step")["error_distance"].mean().to_numpy()
    figure = error_over_time(older)
    assert "mean over 2 traced trials per cell" in figure._suptitle.get_text()
    assert sum(np.allclose(line.get_ydata(), traced_mean) for axes in figure.axes for line in axes.get_lines()
               if len(line.get_ydata()) == len(traced_mean)) == 1
    for name in ("ess_over_time", "nees_over_time", "state_error_over_time"):
        assert "traced trials" in OVER_TIME[name](older)._suptitle.get_text(), name


# -- the layout: small multiples and legends ------------------------------------------------------

def test_an_eight_cell_sweep_is_four_panels_of_two_lines_with_one_colour_per_particle_count(folders):
    result = ResultFolder(folders["sweep"])
    for name in ("error_over_time", "ess_over_time", "nees_over_time"):
        figure = OVER_TIME[name](result)
        assert len(figure.axes) == 4, name                         # one per resampler
        assert sorted(axes.get_title() for axes in figure.axes) == [
            "resampler=multinomial", "resampler=residual", "resampler=stratified", "resampler=systematic"]
        colours = {}
        for axes in figure.axes:
            cells = [line for line in axes.get_lines() if line.get_label().startswith("n_particles=")]
            assert sorted(line.get_label() for line in cells) == ["n_particles=20", "n_particles=40"], name
            for line in cells:
                colours.setdefault(line.get_label(), set()).add(line.get_color())
        assert all(len(found) == 1 for found in colours.values()) and len(set().union(*colours.values())) == 2
        assert axes.get_shared_y_axes().joined(figure.axes[0], figure.axes[-1])
        assert len(figure.legends) == 1 and not any(axes.get_legend() for axes in figure.axes)


def test_few_cells_share_one_panel(folders):
    figure = error_over_time(ResultFolder(folders["arms"]))
    assert len(figure.axes) == 1
    assert sorted(text.get_text() for text in figure.legends[0].get_texts()) == ["KF", "PF"]


@pytest.mark.parametrize("folder", ["sweep", "arms", "single"])
@pytest.mark.parametrize("name", sorted(OVER_TIME))
def test_no_legend_lies_over_any_axes(folders, folder, name):
    figure = OVER_TIME[name](ResultFolder(folders[folder]))
    if figure is None:                  # e.g. no NEES recorded
        return
    figure.canvas.draw()
    legends = list(figure.legends) + [axes.get_legend() for axes in figure.axes if axes.get_legend()]
    labels = {line.get_label() for axes in figure.axes for line in axes.get_lines()
              if not line.get_label().startswith("_")}
    assert legends or len(labels) == 1, "several lines and no legend"     # one line needs none
    for legend in legends:
        box = legend.get_window_extent()
        for axes in figure.axes:
            assert not _bounding_boxes_overlap(box, axes.get_window_extent()), (name, folder)


def test_plan_panels_splits_by_the_column_with_fewest_values():
    cells = pd.DataFrame({"cell": [f"c{i}" for i in range(6)], "arm": ["a", "a", "a", "b", "b", "b"],
                          "n_particles": [100.0, 200.0, 300.0] * 2})
    titles, lines = plan_panels(cells, ["arm", "n_particles"])
    assert titles == ["n_particles=100", "n_particles=200", "n_particles=300"]   # 100.0 read as 100
    assert [line.label for line in lines] == ["a", "a", "a", "b", "b", "b"]
    assert [line.colour for line in lines] == ["C0", "C0", "C0", "C1", "C1", "C1"]
    few = cells.iloc[:MOST_LINES_IN_ONE_PANEL]
    titles, lines = plan_panels(few, ["arm", "n_particles"])
    assert titles == [""] and {line.panel for line in lines} == {0}
    titles, lines = plan_panels(cells.assign(arm=[f"arm{i}" for i in range(6)]), ["arm"])
    assert len(titles) == 6 and [line.panel for line in lines] == list(range(6))


# -- axis labels follow the model -----------------------------------------------------------------

def test_axis_labels_name_the_state_not_a_position(folders):
    result = ResultFolder(folders["arms"])
    figure = error_over_time(result)
    axes = figure.axes[0]
    assert axes.get_ylabel() == "|error| of log volatility"
    assert "position" not in axes.get_ylabel() + figure._suptitle.get_text()
    assert axes.get_xlabel() == "time [s]"
    state_axes = state_error_over_time(result).axes[0]
    assert "log volatility" in state_axes.get_ylabel()


def _manifest_folder(tmp_path, **manifest) -> ResultFolder:
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    return ResultFolder(tmp_path)


@pytest.mark.parametrize("units, position_states, time_label, error_label", [
    ({"time": "s", "position": "m", "state_x": "m", "state_y": "m"}, ["x", "y"], "time [s]",
     "position error distance [m]"),
    ({"time": "s", "position": "ft", "state_altitude": "ft"}, ["altitude"], "time [s]", "|error| of altitude [ft]"),
    ({"time": "step", "position": "", "state_x": ""}, ["x"], "step", "|error| of x"),
    ({"time": "action", "position": "cm", "state_x": "cm", "state_y": "cm", "state_heading": "deg"}, ["x", "y"],
     "action", "position error distance [cm]"),
])
def test_axis_labels_follow_the_manifest_units(tmp_path, units, position_states, time_label, error_label):
    result = _manifest_folder(tmp_path, units=units, position_states=position_states)
    assert time_axis(result)[1] == time_label
    assert time_axis(result)[0] == ("time" if time_label.startswith("time") else "step")
    assert error_quantity(result).axis_label == error_label


def test_an_angle_error_is_wrapped_into_half_a_turn(tmp_path):
    result = _manifest_folder(tmp_path, units={"state_heading": "deg", "state_x": "cm"},
                              angular_states=["heading"], full_turn=360.0)
    rows = pd.DataFrame({"truth_heading": [359.0, 10.0], "estimate_heading": [1.0, 350.0],
                         "truth_x": [359.0, 10.0], "estimate_x": [1.0, 350.0]})
    np.testing.assert_allclose(result.state_error(rows, "heading"), [2.0, -20.0])
    np.testing.assert_allclose(result.state_error(rows, "x"), [-358.0, 340.0])


# -- a diverging cell ------------------------------------------------------------------------------

def test_a_diverging_cell_leaves_the_axes_and_is_named(folders, tmp_path):
    copy = tmp_path / "diverged"
    shutil.copytree(folders["arms"], copy)
    summary = pd.read_csv(copy / "steps_summary.csv", dtype={"cell": str})
    kalman = (summary["arm"] == "KF") & (summary["step"] >= 4)
    for column in ("error_distance_mean", "error_distance_ci95_low", "error_distance_ci95_high"):
        summary.loc[kalman, column] = 1e20
    summary.to_csv(copy / "steps_summary.csv", index=False)
    figure = error_over_time(ResultFolder(copy))
    axes = figure.axes[0]
    assert axes.get_ylim()[1] < 1e3                                   # the PF keeps its scale
    kalman_line = _line(figure, "KF")
    assert np.isnan(kalman_line.get_ydata()[3:]).all() and np.isfinite(kalman_line.get_ydata()[:3]).all()
    assert "KF: off scale from t = 4 s" in axes.get_title(loc="left")
