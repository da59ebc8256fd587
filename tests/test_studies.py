"""Studies (pfx.studies), particle snapshots (particles.csv) and the gallery's table helpers."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pfx.config.plan import StudyPlan, build_plan
from pfx.errors import ConfigError
from pfx.filters.particle.resampling import han_lee_iv_expected_counts
from pfx.papers.base import format_number, markdown_table
from pfx.run.runner import run_plan


def _study(**parameters):
    return {"name": "offspring", "seed": 5,
            "study": {"kind": "offspring_counts", "draws": 4000, **parameters},
            "outputs": {"figures": ["offspring_bias"]}}


def test_a_study_config_is_a_study_plan():
    plan = build_plan(_study(), "study.yaml")
    assert isinstance(plan, StudyPlan)
    assert plan.cells == []
    assert plan.size_text == "study offspring_counts"


def test_study_errors_name_the_key():
    with pytest.raises(ConfigError) as error:
        build_plan(_study(weights=[0.5, 0.6]), "study.yaml")
    assert str(error.value).startswith("study.yaml: study.weights: weights must be non-negative and sum to 1")
    with pytest.raises(ConfigError) as error:
        build_plan({**_study(), "trials": 3}, "study.yaml")
    assert "trials" in str(error.value)


def test_offspring_study_writes_its_table_and_figure(tmp_path):
    out = run_plan(build_plan(_study(), "study.yaml"), tmp_path / "run")
    table = pd.read_csv(out / "offspring.csv")
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] and manifest["tables"] == ["offspring"]
    assert (out / "figures" / "offspring_bias.png").stat().st_size > 10_000
    unbiased = table[table["unbiased"]]
    # 4000 draws x 5 particles x 4 unbiased schemes: |z| < 4.5 for all 20 has probability > 0.9998
    assert (unbiased["z_score"].abs() < 4.5).all()
    biased = table[~table["unbiased"]]
    expected = han_lee_iv_expected_counts(np.array([0.3, 0.1, 0.2, 0.15, 0.25]))
    np.testing.assert_allclose(biased["expected_count"], expected)
    # Algorithm IV's observed counts match its own (biased) expectation, not N w
    z_own = (biased["observed_mean"] - biased["expected_count"]) / biased["observed_sem"]
    assert (z_own.abs() < 4.5).all()
    assert biased["z_score"].abs().max() > 10


def test_a_study_is_deterministic_given_its_seed(tmp_path):
    first = run_plan(build_plan(_study(), "study.yaml"), tmp_path / "a")
    second = run_plan(build_plan(_study(), "study.yaml"), tmp_path / "b")
    assert (first / "offspring.csv").read_text() == (second / "offspring.csv").read_text()


def test_particle_snapshots_keep_the_requested_clouds(tmp_path, tiny_config_dict):
    config = tiny_config_dict()
    config["outputs"]["particles"] = {"steps": [0, 2, 5], "trials": 2, "stages": ["weighted", "resampled"]}
    out = run_plan(build_plan(config, "tiny.yaml"), tmp_path / "run")
    particles = pd.read_csv(out / "particles.csv")
    n = config["filter"]["particles"]
    assert sorted(particles["trial"].unique()) == [0, 1]
    kept = particles.groupby(["trial", "step", "stage"]).size()
    assert set(kept.index) == {(t, s, stage) for t in (0, 1) for s in (2, 5) for stage in ("weighted", "resampled")} \
        | {(t, 0, "prior") for t in (0, 1)}
    assert (kept == n).all()
    sums = particles.groupby(["trial", "step", "stage"])["weight"].sum()
    np.testing.assert_allclose(sums, 1.0)
    # the weighted cloud's mean is the estimate written to steps.csv
    steps = pd.read_csv(out / "steps.csv")
    weighted = particles[(particles["stage"] == "weighted") & (particles["step"] == 2) & (particles["trial"] == 0)]
    estimate = steps[(steps["trial"] == 0) & (steps["step"] == 2)]["estimate_x1"].iloc[0]
    assert np.isclose((weighted["weight"] * weighted["x1"]).sum(), estimate)


def test_without_snapshots_there_is_no_particles_file(tmp_path, tiny_config_dict):
    out = run_plan(build_plan(tiny_config_dict(), "tiny.yaml"), tmp_path / "run")
    assert not (out / "particles.csv").exists()


def test_markdown_table_and_number_format():
    frame = pd.DataFrame({"name": ["a", "b"], "value": [1234567.0, float("nan")], "small": [0.5, 2e-5]})
    text = markdown_table(frame)
    assert text.splitlines()[0] == "| name | value | small |"
    assert "1.23e+06" in text and "2.00e-05" in text
    assert format_number(float("inf")) == "∞" and format_number(12.3456) == "12.3"


def test_map_figures_and_the_scene_come_from_csv(tmp_path):
    config = {
        "name": "map", "seed": 2, "trials": 2,
        "model": {"kind": "range_beacons", "beacons": [[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]], "steps": 6,
                  "path": {"kind": "lissajous", "center": [2.0, 2.0]}},
        "filter": {"particles": 30},
        "outputs": {"figures": ["trajectory_map", "particle_snapshots", "particle_animation"],
                    "particles": {"steps": "all", "trials": 1}},
    }
    out = run_plan(build_plan(config, "map.yaml"), tmp_path / "run")
    scene = pd.read_csv(out / "scene.csv")
    assert (scene["element"] == "beacon").sum() == 3 and (scene["element"] == "path").sum() == 7
    assert sorted(p.name for p in (out / "figures").iterdir()) == [
        "particle_animation.gif", "particle_snapshots.png", "trajectory_map.png"]
    with open(out / "figures" / "particle_animation.gif", "rb") as handle:
        assert handle.read(6) == b"GIF89a"
    particles = pd.read_csv(out / "particles.csv")
    assert sorted(particles["step"].unique()) == list(range(7))


def test_trajectory_map_draws_one_trial_in_every_panel_on_shared_axes_without_empty_slots(tmp_path):
    """Five cells of one world: five panels (centred, no empty slot) sharing their axes, each
    the same trial (the first traced in every cell: one true path), its RMSE in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pfx.figures.maps import trajectory_map
    from pfx.result_folder import ResultFolder

    config = {
        "name": "map", "seed": 4, "trials": 6,
        "model": {"kind": "range_beacons", "beacons": [[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]], "steps": 8,
                  "path": {"kind": "lissajous", "center": [2.0, 2.0]}},
        "filter": {"particles": 20}, "sweep": {"filter.particles": [5, 10, 20, 40, 80]},
        "outputs": {"figures": [], "trace_trials": 5},
    }
    result = ResultFolder(run_plan(build_plan(config, "map.yaml"), tmp_path / "run"))
    figure = trajectory_map(result)
    try:
        figure.canvas.draw()                                                # lay the panels out
        assert len(figure.axes) == 5 and all(axes.get_visible() for axes in figure.axes)
        first = figure.axes[0]
        assert all(first.get_shared_x_axes().joined(first, axes) and first.get_shared_y_axes().joined(first, axes)
                   for axes in figure.axes[1:])
        assert "trial 0 in every panel" in figure._suptitle.get_text()
        trials, steps = result.trials, result.steps
        for axes, (cell, rows) in zip(figure.axes, trials.groupby("cell", sort=False)):
            rmse = float(rows.loc[rows["trial"] == 0, "rmse_position"].iloc[0])
            assert f"(trial 0: RMSE {rmse:.3g} m)" in axes.get_title()
            estimated = next(line for line in axes.get_lines() if line.get_label() == "estimated path")
            path = steps[(steps["cell"] == cell) & (steps["trial"] == 0)].sort_values("step")
            np.testing.assert_array_equal(estimated.get_xdata(), path["estimate_x"])
        bottom = [axes.get_position() for axes in figure.axes[3:]]          # the last row, centred
        middle = (bottom[0].x0 + bottom[1].x1) / 2
        row_above = (figure.axes[0].get_position().x0 + figure.axes[2].get_position().x1) / 2
        assert abs(middle - row_above) < 0.02
    finally:
        plt.close(figure)


def test_sweep_figures_render_from_summary(tmp_path, tiny_config_dict):
    config = tiny_config_dict()
    config["sweep"] = {"filter.particles": [10, 20], "filter.resampler": ["multinomial", "systematic"]}
    config["outputs"]["figures"] = ["rmse_vs_particles", "convergence_vs_particles",
                                    "error_at_convergence_vs_particles", "final_error_vs_particles"]
    out = run_plan(build_plan(config, "tiny.yaml"), tmp_path / "run")
    assert sorted(p.name for p in (out / "figures").iterdir()) == sorted(
        f"{name}.png" for name in config["outputs"]["figures"])
