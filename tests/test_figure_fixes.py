"""Four figures a reader can trust: what each draws, read back from its artists.

* ``smoothing_error_over_time``: each panel (cell) has its own y axis, and a line that diverges
  is clipped to the panel's finite scale with a note, rather than flattening the other cells.
* the ``*_vs_particles`` figures: log axes where N or the means span a decade, points with error
  bars for a sparse sweep (a band for a dense one), the lines dodged in N.
* ``trajectory_map``: one trial, the same in every panel: the smallest traced in every cell.
* ``posterior_marginals`` and ``posterior_pairs``: the true value where pfx simulated the data,
  from the folder's config.yaml; nothing with recorded data.

The result folders are written by hand to the tables' contract (docs/output-files.md), with
values chosen so that the old drawing rule and the new one differ; one small PMMH run checks
that a real folder's config.yaml gives the truth.
"""

from __future__ import annotations

import json

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
import yaml
from matplotlib.collections import PathCollection, PolyCollection
from matplotlib.container import ErrorbarContainer

from pfx.figures.estimation_chains import posterior_marginals, true_parameter_values
from pfx.figures.estimation_pairs import posterior_pairs
from pfx.figures.maps import shared_trial, trajectory_map
from pfx.figures.smoothing import smoothing_error_over_time
from pfx.figures.sweeps import (
    DECADE,
    MOST_DODGE_DECADES,
    convergence_vs_particles,
    particle_axis,
    rmse_vs_particles,
    spans_a_decade,
)
from pfx.result_folder import ResultFolder, write_csv

matplotlib.use("Agg")                  # no screen: draw into memory


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def _manifest(cells: dict[str, dict], **extra) -> dict:
    """The keys of a run's manifest.json that the figures read."""
    return {"name": "fixes", "complete": True, "figures": [], "formats": ["png"], "trials": 3,
            "label_columns": ["arm", "n_particles"], "legend_columns": ["arm"],
            "units": {"time": "s", "position": "m", "state_x": "m", "state_y": "m"},
            "position_states": ["x", "y"], "angular_states": [], "full_turn": 2 * np.pi,
            "cells": [{"cell": key, **labels} for key, labels in cells.items()], **extra}


def _write_manifest(path, manifest: dict) -> None:
    path.mkdir(parents=True, exist_ok=True)
    (path / "manifest.json").write_text(json.dumps(manifest, indent=2))


def _line(axes, label: str):
    return next(line for line in axes.get_lines() if line.get_label() == label)


# -- 1. smoothing_error_over_time: a y axis per panel ----------------------------------------------

SMOOTHING_CELLS = {"aaaaaaaaaaa1": "calm", "aaaaaaaaaaa2": "rough", "aaaaaaaaaaa3": "diverged",
                   "aaaaaaaaaaa4": "all diverged"}
STEPS = np.arange(1, 7)


def _smoothing_rms(arm: str) -> dict[str, np.ndarray]:
    """Per estimator, the RMS error of each of x and y at steps 1..6 (the drawn line is sqrt(2) x it).

    calm: the filter 1..6, the smoother half; rough: 40 times calm (within the off-scale factor
    of 100, so one shared axis would have flattened calm to a fortieth); diverged: the filter
    infinite from step 4 (the smoother stays finite); all diverged: both infinite from step 5.
    """
    filter_rms = STEPS.astype(float) * (40.0 if arm == "rough" else 3.0 if arm == "all diverged" else 1.0)
    smoother_rms = filter_rms / 2
    if arm == "diverged":
        filter_rms = np.where(STEPS >= 4, np.inf, filter_rms)
    if arm == "all diverged":
        filter_rms, smoother_rms = (np.where(STEPS >= 5, np.inf, values) for values in (filter_rms, smoother_rms))
    return {"": filter_rms, "ffbs": smoother_rms}


def _smoothing_folder(path):
    rows = []
    for cell, arm in SMOOTHING_CELLS.items():
        rms = _smoothing_rms(arm)
        for index, step in enumerate(STEPS):
            row = {"cell": cell, "arm": arm, "n_particles": 8, "step": step, "time": 0.5 * step, "trials": 3}
            for kind, values in rms.items():
                infix = f"{kind}_" if kind else ""
                row |= {f"rms_error_{infix}x": values[index], f"rms_error_{infix}y": values[index]}
            rows.append(row)
    _write_manifest(path, _manifest({cell: {"arm": arm, "n_particles": 8} for cell, arm in SMOOTHING_CELLS.items()}))
    write_csv(pd.DataFrame(rows), path / "steps_summary.csv")
    return ResultFolder(path)


def test_smoothing_error_gives_each_panel_its_own_y_axis(tmp_path):
    figure = smoothing_error_over_time(_smoothing_folder(tmp_path / "run"))
    panels = dict(zip(SMOOTHING_CELLS.values(), figure.axes))
    assert [axes.get_title().strip() for axes in figure.axes] == list(SMOOTHING_CELLS.values())
    calm, rough = panels["calm"], panels["rough"]
    assert not calm.get_shared_y_axes().joined(calm, rough)
    assert calm.get_shared_x_axes().joined(calm, rough)                  # time stays shared
    # Each axis reaches 1.15 times its own panel's peak: sqrt(2) x 6 and 40 x that.
    assert calm.get_ylim() == pytest.approx((0, 1.15 * np.sqrt(2) * 6))
    assert rough.get_ylim() == pytest.approx((0, 1.15 * np.sqrt(2) * 240))
    np.testing.assert_allclose(_line(calm, "filter").get_ydata(), np.sqrt(2) * STEPS)
    assert calm.get_title(loc="left") == "" and rough.get_title(loc="left") == ""     # nothing clipped there
    assert "each panel has its own y scale" in figure._suptitle.get_text()


def test_a_diverging_line_is_clipped_to_its_panel_s_finite_values_and_named(tmp_path):
    figure = smoothing_error_over_time(_smoothing_folder(tmp_path / "run"))
    panels = dict(zip(SMOOTHING_CELLS.values(), figure.axes))
    diverged = panels["diverged"]
    # The smoother keeps the scale (its peak sqrt(2) x 3); the filter stops before step 4.
    assert diverged.get_ylim() == pytest.approx((0, 1.15 * np.sqrt(2) * 3))
    filter_line = _line(diverged, "filter").get_ydata()
    np.testing.assert_allclose(filter_line[:3], np.sqrt(2) * STEPS[:3])
    assert np.isnan(filter_line[3:]).all()
    assert diverged.get_title(loc="left") == "filter: off scale from t = 2 s (up to ∞ m)"
    # Every line of the panel diverges: the axis spans their finite values (3 x 4 x sqrt(2) at step 4).
    both = panels["all diverged"]
    top = both.get_ylim()[1]
    assert np.isfinite(top) and top == pytest.approx(1.15 * np.sqrt(2) * 12)
    assert both.get_title(loc="left").splitlines() == ["filter: off scale from t = 2.5 s (up to ∞ m)",
                                                       "ffbs: off scale from t = 2.5 s (up to ∞ m)"]
    np.testing.assert_allclose(_line(both, "filter").get_ydata()[:4], 3 * np.sqrt(2) * STEPS[:4])


# -- 2. the *_vs_particles figures -------------------------------------------------------------------

def _sweep_folder(path, arms: dict[str, list[float]], counts: list[int]) -> ResultFolder:
    """summary.csv of arms x counts: each arm's metrics its list of means (one per count), the
    95% interval mean ± 10%, every trial converged."""
    rows, cells = [], {}
    for arm_index, (arm, means) in enumerate(arms.items()):
        for count_index, (count, mean) in enumerate(zip(counts, means)):
            cell = f"{arm_index:06d}{count_index:06d}"
            cells[cell] = {"arm": arm, "n_particles": count}
            row = {"cell": cell, "arm": arm, "n_particles": count, "trials": 20, "converged_mean": 0.9}
            for metric in ("rmse_position", "error_distance_final", "convergence_step", "error_at_convergence"):
                row |= {f"{metric}_mean": mean, f"{metric}_ci95_low": 0.9 * mean, f"{metric}_ci95_high": 1.1 * mean}
            rows.append(row)
    _write_manifest(path, _manifest(cells, trials=20))
    write_csv(pd.DataFrame(rows), path / "summary.csv")
    return ResultFolder(path)


# Five arms over a decade of N; four within 3% of each other (hidden behind one another on one
# x), one thirty times larger: the means span a decade.
SPARSE_COUNTS = [100, 1000]
SPARSE_ARMS = {"A": [1.00, 0.50], "B": [1.01, 0.51], "C": [1.02, 0.52], "D": [1.03, 0.53], "E": [30.0, 15.0]}


def test_a_sparse_sweep_gets_log_axes_error_bars_and_a_dodge(tmp_path):
    figure = rmse_vs_particles(_sweep_folder(tmp_path / "run", SPARSE_ARMS, SPARSE_COUNTS))
    axes = figure.axes[0]
    assert axes.get_xscale() == "log" and axes.get_yscale() == "log"
    assert not [c for c in axes.collections if isinstance(c, PolyCollection)]      # no band between 2 values
    bars = [c for c in axes.containers if isinstance(c, ErrorbarContainer)]
    assert [bar.get_label() for bar in bars] == list(SPARSE_ARMS)
    positions = np.array([bar.lines[0].get_xdata() for bar in bars])              # (arm, count)
    for column, count in enumerate(SPARSE_COUNTS):
        at_count = positions[:, column]
        assert np.all(np.diff(at_count) > 0)                                       # apart, in the arms' order
        np.testing.assert_allclose(np.exp(np.log(at_count).mean()), count)         # centred on N
        ratios = at_count[1:] / at_count[:-1]
        np.testing.assert_allclose(ratios, ratios[0])                              # one factor between neighbours
        assert ratios[0] <= 10 ** MOST_DODGE_DECADES + 1e-12
    for bar, means in zip(bars, SPARSE_ARMS.values()):
        np.testing.assert_allclose(bar.lines[0].get_ydata(), means)
        (segments,) = bar.lines[2]
        np.testing.assert_allclose([segment[:, 1] for segment in segments.get_segments()],
                                   [[0.9 * mean, 1.1 * mean] for mean in means])
    assert list(axes.get_xticks()) == SPARSE_COUNTS
    assert "bars: 95% confidence interval" in axes.get_title()


def test_a_dense_sweep_keeps_its_bands_and_linear_axes(tmp_path):
    counts = [10, 20, 30, 40]                       # 4x: no decade
    arms = {"A": [2.0, 1.6, 1.4, 1.3], "B": [2.1, 1.7, 1.5, 1.35]}
    figure = rmse_vs_particles(_sweep_folder(tmp_path / "run", arms, counts))
    axes = figure.axes[0]
    assert axes.get_xscale() == "linear" and axes.get_yscale() == "linear"
    assert not [c for c in axes.containers if isinstance(c, ErrorbarContainer)]
    assert len([c for c in axes.collections if isinstance(c, PolyCollection)]) == len(arms)
    first, second = (_line(axes, arm).get_xdata() for arm in arms)
    shift = second - first                                 # one step for every N, small beside the gaps
    np.testing.assert_allclose(shift, shift[0])
    assert shift[0] == pytest.approx(0.01 * (counts[-1] - counts[0]))     # 1% of the range: less than the gaps allow
    np.testing.assert_allclose((first + second) / 2, counts)
    assert "band: 95% confidence interval" in axes.get_title()


def test_axis_rules_at_their_edges():
    assert spans_a_decade([1.0, DECADE]) and not spans_a_decade([1.0, 9.99])
    assert not spans_a_decade([0.0, 5.0, 50.0])            # a zero has no place on a log axis
    assert spans_a_decade([1.0, np.inf, np.nan, 20.0])     # the finite ones decide
    lines = pd.DataFrame({"n_particles": [10, 100, 10, 100], "_line": ["a", "a", "b", "b"]})
    assert particle_axis(lines).log
    assert not particle_axis(lines.replace({100: 99})).log


def test_convergence_panels_share_the_dodge(tmp_path):
    figure = convergence_vs_particles(_sweep_folder(tmp_path / "run", SPARSE_ARMS, SPARSE_COUNTS))
    top, bottom = figure.axes
    assert top.get_xscale() == bottom.get_xscale() == "log"
    bars = {bar.get_label(): bar.lines[0].get_xdata() for bar in top.containers}
    for arm in SPARSE_ARMS:
        np.testing.assert_allclose(_line(bottom, arm).get_xdata(), bars[arm])


# -- 3. trajectory_map: one trial in every panel -------------------------------------------------

MAP_CELLS = {"bbbbbbbbbbb1": ("A", [0, 1, 2]), "bbbbbbbbbbb2": ("B", [1, 2, 3]), "bbbbbbbbbbb3": ("C", [2, 1])}
# Each cell's median-RMSE trial differs (A: 2, B: 3, C: 1 or 2): the old rule's choices.
MAP_RMSE = {"A": {0: 1.0, 1: 3.0, 2: 2.0}, "B": {1: 5.0, 2: 1.0, 3: 3.0}, "C": {1: 0.5, 2: 4.0}}


def _map_folder(path, cells=MAP_CELLS) -> ResultFolder:
    rng = np.random.default_rng(3)
    step_rows, trial_rows = [], []
    for cell, (arm, traced) in cells.items():
        for trial in traced:
            for step in range(5):
                truth = rng.normal(size=2) + step
                step_rows.append({"cell": cell, "arm": arm, "trial": trial, "step": step, "time": float(step),
                                  "truth_x": truth[0], "truth_y": truth[1],
                                  "estimate_x": truth[0] + 0.1 * rng.normal(), "estimate_y": truth[1]})
        for trial, rmse in MAP_RMSE[arm].items():
            trial_rows.append({"cell": cell, "arm": arm, "trial": trial, "rmse_position": rmse})
    _write_manifest(path, _manifest({cell: {"arm": arm} for cell, (arm, _) in cells.items()}))
    write_csv(pd.DataFrame(step_rows), path / "steps.csv")
    write_csv(pd.DataFrame(trial_rows), path / "trials.csv")
    return ResultFolder(path)


def test_trajectory_map_draws_the_first_trial_traced_in_every_cell_in_every_panel(tmp_path):
    result = _map_folder(tmp_path / "run")
    figure = trajectory_map(result)
    steps = result.steps
    assert len(figure.axes) == len(MAP_CELLS)
    for axes, (cell, (arm, _)) in zip(figure.axes, MAP_CELLS.items()):
        rows = steps[(steps["cell"] == cell) & (steps["trial"] == 1)].sort_values("step")
        np.testing.assert_array_equal(_line(axes, "estimated path").get_xdata(), rows["estimate_x"])
        np.testing.assert_array_equal(_line(axes, "true path").get_xdata(), rows["truth_x"])
        assert axes.get_title() == f"{arm}\n(trial 1: RMSE {MAP_RMSE[arm][1]:.3g} m)"
    assert "trial 1 in every panel" in figure._suptitle.get_text()


def test_without_a_trial_common_to_every_cell_each_panel_draws_its_first_and_says_so(tmp_path):
    cells = {"bbbbbbbbbbb1": ("A", [0, 1]), "bbbbbbbbbbb2": ("B", [2, 3])}
    result = _map_folder(tmp_path / "run", cells)
    frame = result.steps.assign(_cell=result.cell_names(result.steps))
    assert shared_trial(frame, ["A", "B"]) is None and shared_trial(frame, ["B"]) == 2
    figure = trajectory_map(result)
    assert [axes.get_title().splitlines()[1] for axes in figure.axes] == ["(trial 0: RMSE 1 m)", "(trial 2: RMSE 1 m)"]
    assert "no trial traced in every cell" in figure._suptitle.get_text()


# -- 4. posterior_marginals and posterior_pairs: the true value ------------------------------------

ESTIMATION_CELLS = {"ccccccccccc1": "bootstrap", "ccccccccccc2": "guided"}
TRUTH = {"mu": 1.0, "noise_variance": 50.0}      # the second parameter's column is named in the config


def _estimation_folder(path, *, data: bool = False, sweep: dict | None = None, labels=None) -> ResultFolder:
    """A PMMH folder: chains.csv of 2 chains x 30 iterations per cell (the first 10 warm-up),
    and config.yaml with the model that simulated the data (or a ``data:`` section)."""
    rng = np.random.default_rng(5)
    labels = labels or {cell: {"arm": arm} for cell, arm in ESTIMATION_CELLS.items()}
    rows = []
    for cell, cell_labels in labels.items():
        for chain in range(2):
            for iteration in range(31):
                rows.append({"cell": cell, **cell_labels, "chain": chain, "iteration": iteration,
                             "warm_up": iteration <= 10, "mu": 1.2 + 0.1 * rng.normal(),
                             "noise_variance": 45.0 + 3.0 * rng.normal(), "log_likelihood": -100 + rng.normal(),
                             "log_prior": 0.0, "accepted": True})
    config = {"name": "fixes", "seed": 1,
              "model": {"kind": "plugin_model", "mu": TRUTH["mu"],
                        "measurement_noise": {"family": "gaussian", "variance": TRUTH["noise_variance"]}},
              "sweep": sweep or {},
              "estimation": {"method": "pmmh", "parameters": {
                  "model.mu": {"prior": {"law": "flat"}, "name": None},
                  "model.measurement_noise.variance": {"prior": {"law": "flat"}, "name": "noise_variance"}}}}
    manifest = _manifest(labels, estimation={"method": "pmmh", "iterations": 30, "chains": 2})
    if data:
        config["data"] = {"measurements": "nile.csv"}
        manifest["recorded_data"] = True
    _write_manifest(path, manifest)
    write_csv(pd.DataFrame(rows), path / "chains.csv")
    (path / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    return ResultFolder(path)


def _true_lines(axes) -> list[float]:
    """The x of the panel's dash-dotted vertical lines."""
    return sorted(float(line.get_xdata()[0]) for line in axes.get_lines() if line.get_linestyle() == "-.")


def _legend_texts(figure) -> list[str]:
    return [text.get_text() for legend in figure.legends for text in legend.get_texts()]


def test_posterior_marginals_mark_the_value_that_simulated_the_data(tmp_path):
    result = _estimation_folder(tmp_path / "run")
    assert true_parameter_values(result) == {cell: TRUTH for cell in ESTIMATION_CELLS}
    figure = posterior_marginals(result)
    assert [axes.get_xlabel() for axes in figure.axes] == list(TRUTH)
    for axes, value in zip(figure.axes, TRUTH.values()):
        assert _true_lines(axes) == [value]                   # one line: the cells share the truth
        assert axes.get_xlim()[0] <= value <= axes.get_xlim()[1]
    assert "true value" in _legend_texts(figure)


def test_posterior_pairs_star_the_true_point(tmp_path):
    figure = posterior_pairs(_estimation_folder(tmp_path / "run"))
    grid = np.array(figure.axes).reshape(2, 2)
    stars = [c for c in grid[1, 0].collections if isinstance(c, PathCollection) and len(c.get_offsets()) == 1]
    assert [list(star.get_offsets()[0]) for star in stars] == [[TRUTH["mu"], TRUTH["noise_variance"]]]
    assert _true_lines(grid[0, 0]) == [TRUTH["mu"]] and _true_lines(grid[1, 1]) == [TRUTH["noise_variance"]]
    assert "true value" in _legend_texts(figure)


def test_recorded_data_get_no_true_value(tmp_path):
    result = _estimation_folder(tmp_path / "run", data=True)
    assert true_parameter_values(result) == {}
    marginals = posterior_marginals(result)
    assert all(_true_lines(axes) == [] for axes in marginals.axes)
    assert "true value" not in _legend_texts(marginals)
    pairs = posterior_pairs(result)
    assert "true value" not in _legend_texts(pairs) and all(_true_lines(axes) == [] for axes in pairs.axes)


def test_a_swept_parameter_takes_each_cell_s_value_and_a_swept_mapping_none(tmp_path):
    labels = {"ccccccccccc1": {"arm": "bootstrap", "model_mu": 1.0}, "ccccccccccc2": {"arm": "bootstrap", "model_mu": 2.0}}
    result = _estimation_folder(tmp_path / "mu", sweep={"model.mu": [1.0, 2.0]}, labels=labels)
    assert true_parameter_values(result) == {"ccccccccccc1": TRUTH, "ccccccccccc2": {**TRUTH, "mu": 2.0}}
    figure = posterior_marginals(result)
    assert _true_lines(figure.axes[0]) == [1.0, 2.0]              # a line per cell, in its colour
    colours = {line.get_color() for line in figure.axes[0].get_lines() if line.get_linestyle() == "-."}
    assert colours == {"C0", "C1"}
    swept_noise = _estimation_folder(tmp_path / "noise", sweep={"model.measurement_noise": [{"variance": 1.0}]})
    assert true_parameter_values(swept_noise) == {cell: {"mu": 1.0} for cell in ESTIMATION_CELLS}


def test_a_real_run_s_config_gives_the_truth(tmp_path):
    """A PMMH run of the Kalman filter on data pfx simulated: config.yaml as the run writes it."""
    import pfx

    config = {
        "name": "truth", "seed": 3,
        "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                  "names": ["level"], "steps": 20, "process_noise": {"variance": 4.0},
                  "measurement_noise": {"variance": 9.0}, "initial": {"kind": "gaussian", "mean": [0.0],
                                                                      "covariance": 10.0}},
        "filter": {"kind": "kf"},
        "estimation": {"method": "pmmh", "chains": 2, "iterations": 30, "warm_up": 10, "parameters": {
            "model.measurement_noise.variance": {"prior": {"law": "flat", "lower": 0}, "start": 5.0},
            "model.process_noise.variance": {"prior": {"law": "flat", "lower": 0}, "start": 5.0,
                                             "name": "q"}}},
        "outputs": {"figures": []},
    }
    out = pfx.run(config, out=tmp_path / "run").folder
    result = ResultFolder(out)
    (cell,) = result.manifest["cells"]
    assert true_parameter_values(result) == {cell["cell"]: {"measurement_noise.variance": 9.0, "q": 4.0}}
    figure = posterior_marginals(result)
    assert [_true_lines(axes) for axes in figure.axes] == [[9.0], [4.0]]
