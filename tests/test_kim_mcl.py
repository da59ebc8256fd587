"""kim-mcl: the commanded route in the scene, the arena figure, the verdict rules, the configs, and
the report on a small generated result folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pfx.config.plan import build_plan
from pfx.figures.arena import action_groups
from pfx.figures.registry import render_figures
from pfx.papers.base import REPORTS, VERDICTS, PaperResults, Table
from pfx.papers.gallery import write_gallery
from pfx.papers.kim_mcl import (
    VARIANCE,
    _verdicts,
    accuracy_verdict,
    error_slope,
    first_trials_coincide,
    per_count_verdict,
    trend_verdict,
)
from pfx.run.runner import run_plan
from pfx.safe_yaml import load_config_file

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs" / "papers" / "kim-mcl"
EXPERIMENTS = ("arena", "one-run", "paper-runs", "extended")


# -- the scene and the arena figure ----------------------------------------------------------------

def _model(route):
    raw = load_config_file(CONFIGS / "arena.yaml")
    raw["model"]["route"] = route
    plan = build_plan(raw, "arena.yaml", trials=1)
    return plan.cells[0].truth_model


def test_scene_holds_the_walls_and_the_route_executed_exactly():
    model = _model(["turn 90", "move 20", "turn -90", "move 10"])
    scene = pd.DataFrame(model.scene())
    assert (scene["element"] == "wall").sum() == len(model.walls)
    path = scene[scene["element"] == "path"]
    # from (30, 30) facing +x: turn to +y, 20 up, turn back to +x, 10 right; no bias, no noise
    np.testing.assert_allclose(path[["x", "y"]].to_numpy(), [[30, 30], [30, 30], [30, 50], [30, 50], [40, 50]],
                               atol=1e-12)
    np.testing.assert_allclose(path["heading"], [0, 90, 90, 0, 0], atol=1e-12)
    assert path["label"].tolist() == ["0", "1", "2", "3", "4"]


def test_action_groups_share_a_label_for_actions_in_one_place():
    path = pd.DataFrame({"x": [0, 0, 0, 10, 10, 20], "y": [0, 0, 0, 0, 0, 0], "label": ["0", "1", "2", "3", "4", "5"]})
    assert action_groups(path) == [(0.0, 0.0, "1-2"), (10.0, 0.0, "3-4"), (20.0, 0.0, "5")]


# -- the verdict rules -----------------------------------------------------------------------------

def test_per_count_verdict():
    assert per_count_verdict([-3, -2], [-1, -0.5], -1) == "reproduced"
    assert per_count_verdict([-3, -2], [-1, 0.5], -1) == "partly reproduced"
    assert per_count_verdict([-3, 1], [1, 2], -1) == "not reproduced"
    assert per_count_verdict([1, 2], [3, 4], +1) == "reproduced"
    assert per_count_verdict([-1, 2], [3, 4], +1) == "partly reproduced"
    assert per_count_verdict([-1, -2], [3, 4], +1) == "not reproduced"


def test_accuracy_and_trend_verdicts():
    assert accuracy_verdict(-0.6) == "reproduced"
    assert accuracy_verdict(-0.3) == "partly reproduced"
    assert accuracy_verdict(0.1) == "not reproduced"
    assert trend_verdict(-0.01) == "reproduced"
    assert trend_verdict(0.01) == "not reproduced"


def test_error_slope_recovers_an_exact_line_and_leaves_out_missing_values():
    frame = pd.DataFrame({"n_particles": [200, 200, 300, 300, 400, 400, 400],
                          "error_at_convergence": [80.0, 80.0, 60.0, 60.0, 40.0, 40.0, np.nan]})
    slope, low, high, n = error_slope(frame)
    assert n == 6
    assert slope == pytest.approx(-0.2) and low == pytest.approx(-0.2) and high == pytest.approx(-0.2)


def _synthetic_trials(free_error: float, noisy_error_at_200: float, noisy_slope: float, time_gap: float):
    """Trials of both arms at 3 counts x 40 trials, with known differences and some trial-to-trial noise."""
    random = np.random.default_rng(7)
    rows = []
    for n in (200, 300, 400):
        for trial in range(40):
            common = random.normal(0, 5)                 # shared by both arms of trial t (the same truth)
            noisy_time = 6 + random.normal(0, 0.5)
            rows.append({"arm": "noisy", "n_particles": n, VARIANCE: 100.0, "trial": trial, "converged": True,
                         "convergence_step": noisy_time,
                         "error_at_convergence": noisy_error_at_200 + noisy_slope * (n - 200) + common
                         + random.normal(0, 2)})
            rows.append({"arm": "noise-free", "n_particles": n, VARIANCE: 100.0, "trial": trial, "converged": True,
                         "convergence_step": noisy_time - time_gap + random.normal(0, 0.5),
                         "error_at_convergence": free_error + common + random.normal(0, 2)})
    return pd.DataFrame(rows)


LABELS = ["arm", "n_particles", VARIANCE]


def test_verdicts_follow_the_numbers_when_the_finding_holds():
    # noise-free 2 actions faster, 80 cm off; noisy 30 cm at N = 200 falling 0.05 cm per particle
    verdicts = _verdicts(_synthetic_trials(80.0, 30.0, -0.05, 2.0), LABELS, 100.0)
    assert [v.verdict for v in verdicts] == ["reproduced"] * 4
    assert all("100 cm²" in v.claim for v in verdicts)


def test_verdicts_follow_the_numbers_when_the_finding_fails():
    # same speed, same error, no trend: nothing holds
    verdicts = _verdicts(_synthetic_trials(50.0, 50.0, 0.0, 0.0), LABELS, 100.0)
    assert [v.verdict for v in verdicts][1:] == ["not reproduced"] * 3
    assert verdicts[0].verdict in ("not reproduced", "partly reproduced")    # 3 intervals at 5% each


# -- the configs -----------------------------------------------------------------------------------

def test_configs_share_model_and_seed_and_paper_runs_is_extended_cut_to_ten():
    configs = {name: load_config_file(CONFIGS / f"{name}.yaml") for name in EXPERIMENTS}
    for name in EXPERIMENTS:
        assert configs[name]["model"] == configs["extended"]["model"], name
        assert configs[name]["seed"] == configs["extended"]["seed"], name
        build_plan(configs[name], f"{name}.yaml")                 # every config validates
    paper, extended = configs["paper-runs"], configs["extended"]
    assert paper["trials"] == 10 and extended["trials"] >= 100
    different = {key for key in set(paper) | set(extended) if paper.get(key) != extended.get(key)}
    assert different == {"name", "description", "trials"}
    assert extended["sweep"]["filter.model.measurement_noise.variance"] == [1.0, 100.0]
    assert extended["model"]["measurement_noise"] == {"variance": 1.0}       # the truth's sonar stays the paper's


# -- a small generated result folder: figures and report -------------------------------------------

@pytest.fixture(scope="module")
def small_results(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    paper = root / "kim-mcl"
    for name, trials in (("arena", 1), ("one-run", 1), ("paper-runs", 2), ("extended", 3)):
        raw = load_config_file(CONFIGS / f"{name}.yaml")
        raw["filter"]["particles"] = 60
        if "sweep" in raw:
            raw["sweep"]["filter.particles"] = [40, 60]
        if name == "one-run":
            raw["outputs"]["particles"]["steps"] = [0, 3, 6]
        run_plan(build_plan(raw, name, trials=trials), paper / name)
    (paper / "paper.yaml").write_text(yaml.safe_dump(load_config_file(CONFIGS / "paper.yaml"), sort_keys=False,
                                                     allow_unicode=True))
    return root


def test_figures_are_rendered_from_csv(small_results):
    paper = small_results / "kim-mcl"
    for experiment in EXPERIMENTS:
        names = load_config_file(CONFIGS / f"{experiment}.yaml")["outputs"]["figures"]
        written = render_figures(paper / experiment, names)
        assert sorted(p.stem for p in written) == sorted(names), experiment


def test_report_has_its_figures_tables_and_allowed_verdicts(small_results):
    results = PaperResults(small_results / "kim-mcl")
    section = REPORTS["kim-mcl"](results)
    assert len(section.verdicts) == 8                        # 4 parts x 2 filter sensor variances
    assert all(v.verdict in VERDICTS for v in section.verdicts)
    assert all(v.evidence for v in section.verdicts)
    tables = [item for item in section.items if isinstance(item, Table)]
    assert sum("as a table" in t.title for t in tables) == 2
    assert all("90 % of the particles within 15 cm" in t.note for t in tables if "as a table" in t.title)
    assert "1 cm²" in section.summary and "100 cm²" in section.summary
    assert any("are value for value trials 0-9" in getattr(item, "markdown", "") for item in section.items)
    gallery = write_gallery(small_results).read_text()
    assert "kim-mcl" in gallery and "arena_map.png" in gallery


def test_paper_runs_are_the_first_trials_of_extended(small_results):
    paper = PaperResults(small_results / "kim-mcl")
    ten, extended = paper.folder("paper-runs"), paper.folder("extended")
    assert first_trials_coincide(ten.trials, extended.trials, extended.label_columns)
    changed = ten.trials.copy()
    changed.loc[0, "error_at_convergence"] += 1.0
    assert not first_trials_coincide(changed, extended.trials, extended.label_columns)
