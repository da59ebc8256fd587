"""The smoothing figures and the genealogy they stand on, against hand-computed answers.

The result folders here are written by hand, to the contract of the smoothers' outputs
(docs/output-files.md): a manifest.json with the keys a run writes, steps.csv with
``smoothed_<smoother>_<state>`` and ``distinct_ancestors``, steps_summary.csv with
``rms_error_<smoother>_<state>``, and genealogy.csv. Two cells (arms ``bootstrap`` and
``auxiliary``) of a planar model (states x, y, vx, vy; position x, y in metres), N = 8
particles, T = 6 steps, 3 trials.

The first trial of the first cell has the genealogy :data:`ANCESTORS`, whose ancestral lines
were followed back by hand (:data:`LINES`): the 8 particles of step 6 descend from 6, 4, 3,
2 and finally 1 particle; one of them was drawn afresh from the prior at step 5.
"""

from __future__ import annotations

import json

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from matplotlib.collections import LineCollection

from pfx.analysis.genealogy import (
    NO_PARENT,
    NO_PARTICLE,
    ancestral_lines,
    distinct_ancestor_counts,
    trial_genealogy,
)
from pfx.figures import render_figures
from pfx.figures.smoothing import (
    distinct_ancestors,
    genealogy_tree,
    parent_edges,
    position_rms,
    smoother_kinds,
    smoothing_error_over_time,
)
from pfx.result_folder import ResultFolder, write_csv

matplotlib.use("Agg")                  # no screen: draw into memory

STATES = ["x", "y", "vx", "vy"]
POSITION = ["x", "y"]
SMOOTHERS = ["ffbs", "rts"]
PARTICLES, STEPS, TRIALS = 8, 6, 3
CELLS = {"a1b2c3d4e5f6": "bootstrap", "0123456789ab": "auxiliary"}   # the second key starts with 0 on purpose

# Row k is step k + 1; each entry the parent's index among the step before's particles.
ANCESTORS = np.array([
    [0, 1, 2, 3, 4, 5, 6, 7],                  # step 1: each particle its own
    [0, 0, 1, 2, 0, 3, 5, 7],
    [0, 1, 1, 2, 4, 4, 6, 7],
    [1, 1, 2, 2, 5, 5, 5, 7],
    [0, 0, 1, 3, 4, 5, 5, NO_PARENT],          # particle 7 drawn afresh from the prior
    [0, 1, 1, 3, 3, 4, 7, 5],
])
# Followed back by hand: step 6's parents are {0, 1, 3, 4, 5, 7}; their parents at step 4
# {0, 3, 4, 5} (7 has none); then {1, 2, 5}, {1, 4}, {0}.
LINES = [{0}, {1, 4}, {1, 2, 5}, {0, 3, 4, 5}, {0, 1, 3, 4, 5, 7}, set(range(8))]
COUNTS = [1, 2, 3, 4, 6, 8]


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


# -- the genealogy, pure functions ---------------------------------------------------------------

def test_ancestral_lines_follow_the_parents_back_from_the_last_step():
    lines = ancestral_lines(ANCESTORS)
    assert [set(np.flatnonzero(row)) for row in lines] == LINES


def test_distinct_ancestor_counts_by_hand():
    counts = distinct_ancestor_counts(ANCESTORS)
    assert counts.tolist() == COUNTS
    assert counts.shape == (STEPS,)


def test_a_line_drawn_from_the_prior_starts_at_its_step():
    """Every particle of step 2 was injected: step 1 has no ancestor left."""
    ancestors = np.array([[0, 1], [NO_PARENT, NO_PARENT]])
    assert distinct_ancestor_counts(ancestors).tolist() == [0, 2]


def test_padding_of_a_varying_particle_count_is_not_a_particle():
    """Step 2 has 2 particles of 3 places; both descend from particle 1 of step 1."""
    ancestors = np.array([[0, 1, 2], [1, 1, NO_PARTICLE]])
    assert ancestral_lines(ancestors).tolist() == [[False, True, False], [True, True, False]]
    assert distinct_ancestor_counts(ancestors).tolist() == [1, 2]


def test_one_step_and_no_step():
    assert distinct_ancestor_counts(np.array([[0, 1, 2]])).tolist() == [3]
    assert distinct_ancestor_counts(np.zeros((0, 4), dtype=int)).tolist() == []


@pytest.mark.parametrize("ancestors", [np.array([[0, 1], [2, 0]]), np.array([[0, 1], [0, -3]]), np.array([0, 1])])
def test_a_parent_outside_the_particles_is_refused(ancestors):
    with pytest.raises(ValueError):
        ancestral_lines(ancestors)


def test_trial_genealogy_reads_rows_in_any_order():
    rows = _genealogy_rows(ANCESTORS, np.random.default_rng(1)).sample(frac=1.0, random_state=3)
    tree = trial_genealogy(rows, ["x", "y"])
    np.testing.assert_array_equal(tree.steps, np.arange(1, STEPS + 1))
    np.testing.assert_array_equal(tree.ancestors, ANCESTORS)
    by_place = rows.set_index(["step", "particle"]).sort_index()
    np.testing.assert_allclose(tree.weights.ravel(), by_place["weight"])
    np.testing.assert_allclose(tree.states.reshape(-1, 2), by_place[["x", "y"]])
    assert tree.particle_counts.tolist() == [PARTICLES] * STEPS


def test_trial_genealogy_refuses_a_gap_in_the_steps():
    rows = _genealogy_rows(ANCESTORS, np.random.default_rng(1))
    with pytest.raises(ValueError, match="without a gap"):
        trial_genealogy(rows[rows["step"] != 3], ["x"])


def test_parent_edges_join_each_parent_to_its_children():
    values = np.arange(STEPS * PARTICLES, dtype=float).reshape(STEPS, PARTICLES)    # value = 8 row + column
    segments, on_line = parent_edges(np.arange(1, STEPS + 1), ANCESTORS, values)
    assert len(segments) == (STEPS - 1) * PARTICLES - 1          # the injected particle has no edge
    # Step 3's particle 5 descends from step 2's particle 4.
    assert [[2.0, 8 + 4.0], [3.0, 16 + 5.0]] in segments.tolist()
    # The edges on a line: one per particle on a line from step 2 on, minus the injected one.
    assert on_line.sum() == sum(COUNTS[1:]) - 1


def test_smoother_kinds_are_told_from_states_with_underscores():
    states = ["x", "y", "velocity_x", "velocity_y"]
    columns = ["step", "rms_error_x", "rms_error_y", "rms_error_velocity_x", "rms_error_velocity_y",
               "rms_error_ffbs_rejection_x", "rms_error_ffbs_rejection_y", "rms_error_fixed_lag_x",
               "rms_error_fixed_lag_y", "rms_error_rts_x"]        # rts lacks y: not a position error
    assert smoother_kinds(columns, ["x", "y"], states) == ["ffbs_rejection", "fixed_lag"]
    assert smoother_kinds(["rms_error_x", "rms_error_y"], ["x", "y"], states) == []


# -- a result folder written by hand ------------------------------------------------------------

def _genealogy_rows(ancestors: np.ndarray, rng) -> pd.DataFrame:
    """genealogy.csv's rows of one trial: each particle its parent's position plus a step."""
    steps, particles = ancestors.shape
    states = np.zeros((steps, particles, 2))
    states[0] = rng.normal(0.0, 1.0, (particles, 2))
    for row in range(1, steps):
        parents = np.where(ancestors[row] >= 0, ancestors[row], 0)
        fresh = rng.normal(0.0, 3.0, (particles, 2))          # a particle from the prior
        moved = states[row - 1, parents] + [1.0, 0.5] + rng.normal(0.0, 0.4, (particles, 2))
        states[row] = np.where((ancestors[row] >= 0)[:, None], moved, fresh)
    weights = rng.dirichlet(np.ones(particles), size=steps)
    return pd.DataFrame({
        "step": np.repeat(np.arange(1, steps + 1), particles), "particle": np.tile(np.arange(particles), steps),
        "ancestor": ancestors.ravel(), "weight": weights.ravel(),
        "x": states[:, :, 0].ravel(), "y": states[:, :, 1].ravel(),
    })


def _random_ancestors(rng) -> np.ndarray:
    """A multinomial resampler's genealogy: every step's parents drawn uniformly."""
    ancestors = rng.integers(0, PARTICLES, size=(STEPS, PARTICLES))
    ancestors[0] = np.arange(PARTICLES)
    return ancestors


def _cell_columns(cell: str) -> dict:
    return {"cell": cell, "arm": CELLS[cell], "model": "planar", "filter": "particle",
            "n_particles": PARTICLES, "resampler": "multinomial"}


def _manifest(figures: list[str]) -> dict:
    """The keys of a real run's manifest.json (`pfx run configs/examples/linear-gaussian.yaml`)."""
    return {
        "name": "smoothing-test", "description": "A planar target, a filter and its smoothers.\n",
        "config_file": "smoothing-test.yaml", "config_hash": "0" * 16, "results_hash": "1" * 16, "seed": 7,
        "pfx_version": "0.1.0", "git_revision": "0" * 40, "python": "3.11.7", "numpy": "2.4.6",
        "platform": "Linux", "started": "2026-01-01T00:00:00+00:00", "finished": "2026-01-01T00:00:01+00:00",
        "complete": True, "figures": figures, "formats": ["png"], "trials": TRIALS,
        "label_columns": ["arm", "model", "filter", "n_particles", "resampler"], "legend_columns": ["arm"],
        "units": {"time": "s", "position": "m", "state_x": "m", "state_y": "m", "state_vx": "m/s", "state_vy": "m/s"},
        "position_states": POSITION, "angular_states": [], "full_turn": 2 * np.pi,
        "cells": [{**_cell_columns(cell), "wall_time_s": 0.01} for cell in CELLS],
        "wall_time_s": 0.02,
    }


def write_folder(path, smoothers=SMOOTHERS, genealogy: bool = True, distinct: bool = True):
    """A finished result folder of the two cells; returns its path.

    The filter's RMS error grows 1, 2, ... m per step and state; each smoother's is a share of it.
    """
    rng = np.random.default_rng(0)
    path.mkdir(parents=True, exist_ok=True)
    step_rows, summary_rows, genealogy_frames = [], [], []
    for cell in CELLS:
        for trial in range(TRIALS):
            ancestors = ANCESTORS if (cell, trial) == (next(iter(CELLS)), 0) else _random_ancestors(rng)
            counts = distinct_ancestor_counts(ancestors)
            if genealogy and trial < 2:           # the first few trials of each cell
                genealogy_frames.append(_genealogy_rows(ancestors, rng).assign(
                    **_cell_columns(cell), trial=trial))
            for step in range(1, STEPS + 1):
                row = {**_cell_columns(cell), "trial": trial, "step": step, "time": 0.5 * step}
                for state in STATES:
                    truth = rng.normal()
                    row |= {f"truth_{state}": truth, f"estimate_{state}": truth + rng.normal(),
                            f"sd_{state}": 1.0}
                row |= {"error_distance": 1.0, "ess": 4.0, "resampled": True, "degenerate": False, "spread": 1.0,
                        "nees": np.nan, "nis": np.nan, "particles": PARTICLES}
                for smoother in smoothers:
                    for state in STATES:
                        row |= {f"smoothed_{smoother}_{state}": row[f"truth_{state}"] + 0.5 * rng.normal(),
                                f"smoothed_sd_{smoother}_{state}": 0.5}
                if distinct:
                    row["distinct_ancestors"] = counts[step - 1]
                step_rows.append(row)
        for step in range(1, STEPS + 1):
            row = {**_cell_columns(cell), "step": step, "time": 0.5 * step, "trials": TRIALS,
                   "error_distance_mean": 1.0, "ess_mean": 4.0}
            for state in STATES:
                row[f"rms_error_{state}"] = float(step)
            for share, smoother in zip((0.5, 0.25), smoothers):
                for state in STATES:
                    row[f"rms_error_{smoother}_{state}"] = share * step
            summary_rows.append(row)
    steps = pd.DataFrame(step_rows)
    if distinct == "empty":
        steps["distinct_ancestors"] = np.nan
    write_csv(steps, path / "steps.csv")
    write_csv(pd.DataFrame(summary_rows), path / "steps_summary.csv")
    if genealogy_frames:
        frame = pd.concat(genealogy_frames, ignore_index=True)
        first = ["cell", "arm", "model", "filter", "n_particles", "resampler", "trial"]
        write_csv(frame[first + [c for c in frame.columns if c not in first]], path / "genealogy.csv")
    figures = ["smoothing_error_over_time", "genealogy_tree", "distinct_ancestors"]
    (path / "manifest.json").write_text(json.dumps(_manifest(figures), indent=2))
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_folder(tmp_path_factory.mktemp("smoothing") / "run")


# -- the figures -------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["smoothing_error_over_time", "genealogy_tree", "distinct_ancestors"])
def test_each_figure_is_written_as_png(tmp_path, name):
    copy = write_folder(tmp_path / "run")
    written = render_figures(copy, [name])
    assert [path.name for path in written] == [f"{name}.png"]
    assert written[0].stat().st_size > 10_000


def test_smoothing_error_draws_the_filter_and_each_smoother_per_cell(folder):
    result = ResultFolder(folder)
    figure = smoothing_error_over_time(result)
    assert len(figure.axes) == len(CELLS)                            # a panel per cell
    assert [axes.get_title() for axes in figure.axes] == list(CELLS.values())
    steps = np.arange(1, STEPS + 1)
    for axes in figure.axes:
        lines = {line.get_label(): line for line in axes.get_lines()}
        assert set(lines) == {"filter", *SMOOTHERS}
        # sqrt(rms_x² + rms_y²) over the position states only (vx, vy left out)
        np.testing.assert_allclose(lines["filter"].get_ydata(), np.sqrt(2) * steps)
        np.testing.assert_allclose(lines["ffbs"].get_ydata(), np.sqrt(2) * 0.5 * steps)
        np.testing.assert_allclose(lines["rts"].get_ydata(), np.sqrt(2) * 0.25 * steps)
        np.testing.assert_allclose(lines["filter"].get_xdata(), 0.5 * steps)
    assert figure.axes[0].get_ylabel() == "RMS position error [m]"
    assert figure.axes[0].get_xlabel() == "time [s]"
    assert [text.get_text() for text in figure.legends[0].get_texts()] == ["filter", *SMOOTHERS]
    assert "mean" not in figure._suptitle.get_text() and "3 trials" in figure._suptitle.get_text()


def test_position_rms_is_the_root_of_the_summed_squares():
    rows = pd.DataFrame({"rms_error_ffbs_x": [3.0, np.nan], "rms_error_ffbs_y": [4.0, 1.0]})
    np.testing.assert_allclose(position_rms(rows, ["x", "y"], "ffbs"), [5.0, np.nan])


def test_genealogy_tree_draws_the_hand_computed_lines(folder):
    result = ResultFolder(folder)
    figure = genealogy_tree(result)
    axes = figure.axes[0]
    faint, dark = [c for c in axes.collections if isinstance(c, LineCollection)]
    assert len(dark.get_segments()) == sum(COUNTS[1:]) - 1
    assert len(faint.get_segments()) + len(dark.get_segments()) == (STEPS - 1) * PARTICLES - 1
    title = axes.get_title()
    assert "trial 0 (bootstrap)" in title and "N = 8, T = 6" in title
    assert "descend from 1 distinct particle of step 1" in title
    assert axes.get_xlabel() == "step" and axes.get_ylabel() == "x [m]"
    labels = [text.get_text() for text in figure.legends[0].get_texts()]
    assert "truth" in labels and any("ancestral lines" in label for label in labels)
    assert any("prior" in label for label in labels)                 # the injected particle is marked


def test_distinct_ancestors_draws_the_mean_of_the_traced_trials(folder):
    result = ResultFolder(folder)
    figure = distinct_ancestors(result)
    axes = figure.axes[0]
    assert axes.get_yscale() == "log"
    steps = result.steps
    for cell, arm in CELLS.items():
        mean = steps[steps["cell"] == cell].groupby("step")["distinct_ancestors"].mean()
        line = next(line for line in axes.get_lines() if line.get_label() == arm)
        np.testing.assert_allclose(line.get_ydata(), mean)
        assert mean.iloc[-1] == PARTICLES                            # every particle its own ancestor
    faint = [line for line in axes.get_lines() if line.get_alpha() is not None and line.get_alpha() < 1]
    assert len(faint) == len(CELLS) * TRIALS
    first = steps[(steps["cell"] == next(iter(CELLS))) & (steps["trial"] == 0)]
    assert first["distinct_ancestors"].tolist() == COUNTS
    assert any(np.allclose(line.get_ydata(), PARTICLES) for line in axes.get_lines())   # the reference N
    assert axes.get_xlabel() == "step"


def test_every_figure_is_none_without_its_input(tmp_path):
    result = ResultFolder(write_folder(tmp_path / "bare", smoothers=(), genealogy=False, distinct=False))
    assert smoothing_error_over_time(result) is None
    assert genealogy_tree(result) is None
    assert distinct_ancestors(result) is None
    assert render_figures(result.path, ["smoothing_error_over_time", "genealogy_tree", "distinct_ancestors"]) == []


def test_distinct_ancestors_is_none_when_the_column_is_empty(tmp_path):
    """The genealogy was not recorded: steps.csv has the column, every field empty."""
    result = ResultFolder(write_folder(tmp_path / "empty", distinct="empty"))
    assert result.steps["distinct_ancestors"].isna().all()
    assert distinct_ancestors(result) is None


def test_one_cell_gets_one_untitled_panel(tmp_path):
    path = write_folder(tmp_path / "one")
    summary = pd.read_csv(path / "steps_summary.csv", dtype={"cell": str})
    write_csv(summary[summary["cell"] == next(iter(CELLS))], path / "steps_summary.csv")
    figure = smoothing_error_over_time(ResultFolder(path))
    assert len(figure.axes) == 1 and figure.axes[0].get_title() == ""
    assert [text.get_text() for text in figure.legends[0].get_texts()] == ["filter", *SMOOTHERS]
