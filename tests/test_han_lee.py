"""han-lee: the paper's configs, its figures (concept, close-ups, ESS decay) and its report.

The report is exercised on a small result folder made by running the paper's own configs with
fewer trials, particles, steps and draws (the structure of every table and figure is the same).
The verdict functions are checked on inputs whose verdict is known.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pfx.config.plan import build_plan
from pfx.figures.closeups import HELD_WEIGHT, closeup_window
from pfx.figures.concept import likelihood_quadratic, offspring_stacks
from pfx.papers import han_lee
from pfx.papers.base import VERDICTS, PaperResults
from pfx.papers.gallery import write_gallery
from pfx.run.runner import run_plan
from pfx.safe_yaml import load_config_file

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "papers" / "han-lee"
SMALL = {  # experiment -> overrides that keep its structure but make it fast
    "fig1-concept": {},
    "fig2-tracking": {"model.steps": 12, "filter.particles": 200},
    "resamplers": {"trials": 6, "model.steps": 12, "filter.particles": 200},
    "degeneracy": {"trials": 4, "model.steps": 12, "filter.particles": 200, "outputs.trace_trials": 4},
    "offspring": {"study.draws": 3000},
}


def _set(config: dict, dotted: str, value) -> None:
    *parents, last = dotted.split(".")
    for key in parents:
        config = config[key]
    config[last] = value


@pytest.fixture(scope="module")
def small_results(tmp_path_factory) -> Path:
    """results/han-lee/ made by the paper's configs, shrunk (see SMALL)."""
    root = tmp_path_factory.mktemp("results")
    paper = root / "han-lee"
    for path in sorted(CONFIGS.glob("*.yaml")):
        if path.name == "paper.yaml":
            continue
        config = load_config_file(path)
        for key, value in SMALL[config["name"]].items():
            _set(config, key, value)
        if config["name"] == "fig2-tracking":
            config["outputs"]["particles"]["steps"] = [1, 2, 12]
        run_plan(build_plan(config, str(path)), paper / config["name"])
    shutil.copy(CONFIGS / "paper.yaml", paper / "paper.yaml")
    return root


def test_every_config_of_the_paper_is_valid():
    names = {load_config_file(p)["name"] for p in CONFIGS.glob("*.yaml") if p.name != "paper.yaml"}
    assert names == set(SMALL)
    for path in CONFIGS.glob("*.yaml"):
        if path.name != "paper.yaml":
            build_plan(load_config_file(path), str(path))
    facts = load_config_file(CONFIGS / "paper.yaml")["simulation"]
    assert (facts["particles"], facts["steps"], facts["diffusion_rate"]["value"]) == (1000, 80, 0.03)


def test_the_full_size_configs_use_the_papers_settings():
    fig2 = load_config_file(CONFIGS / "fig2-tracking.yaml")
    assert fig2["filter"]["particles"] == 1000 and fig2["model"]["steps"] == 80
    assert fig2["filter"]["diffusion"] == {"kind": "gaussian", "std": 0.03}
    assert fig2["model"]["region"] == {"low": [-20.0, -15.0], "high": [20.0, 25.0]}
    assert len(fig2["model"]["beacons"]) >= 4
    resamplers = load_config_file(CONFIGS / "resamplers.yaml")
    assert resamplers["trials"] >= 100
    assert set(resamplers["sweep"]["filter.resampler"]) == {"systematic", "han_lee_iv", "multinomial",
                                                             "stratified", "residual"}
    degeneracy = load_config_file(CONFIGS / "degeneracy.yaml")
    assert degeneracy["outputs"]["trace_trials"] >= 20


# -- figures ------------------------------------------------------------------------------------

def test_likelihood_quadratic_recovers_a_gaussian_and_refuses_anything_else():
    x = np.array([-3.0, -1.2, 0.1, 0.4, 2.5, 4.0])
    measurement, variance = 0.7, 2.0
    increments = -(measurement - x) ** 2 / (2 * variance) + 5.0
    a, b, _ = likelihood_quadratic(x, increments)
    assert a == pytest.approx(-1 / (2 * variance))
    assert -b / (2 * a) == pytest.approx(measurement)            # the peak is the measurement
    assert likelihood_quadratic(x, np.abs(x - measurement)) is None   # a Laplace likelihood is not quadratic
    assert likelihood_quadratic(x, (x - measurement) ** 2) is None    # opens upwards


def test_offspring_stacks_count_exact_copies():
    assert offspring_stacks(np.array([2.0, -1.0, 2.0, 2.0, 0.5])) == [(-1.0, 1), (0.5, 1), (2.0, 3)]


def test_closeup_window_holds_the_heavy_particles_and_the_truth():
    random = np.random.default_rng(3)
    x, y = random.normal(size=500), random.normal(size=500)
    weights = random.random(500)
    (x_low, x_high), (y_low, y_high) = closeup_window(x, y, weights, truth=(4.0, 0.0))
    assert x_low < 4.0 < x_high and y_low < 0.0 < y_high
    inside = (x > x_low) & (x < x_high) & (y > y_low) & (y < y_high)
    assert weights[inside].sum() / weights.sum() >= HELD_WEIGHT
    assert x_high - x_low == pytest.approx(y_high - y_low)


def test_the_papers_figures_are_rendered(small_results):
    paper = small_results / "han-lee"
    for experiment, name in [("fig1-concept", "resampling_concept.png"), ("fig2-tracking", "trajectory_map.png"),
                             ("fig2-tracking", "particle_closeups.png"), ("resamplers", "trajectory_map.png"),
                             ("offspring", "offspring_bias.png"), ("degeneracy", "ess_decay.png")]:
        assert (paper / experiment / "figures" / name).stat().st_size > 20_000, (experiment, name)


def test_ess_decay_is_on_a_log_scale_with_the_one_particle_floor(small_results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pfx.figures.degeneracy import ess_decay
    from pfx.result_folder import ResultFolder

    figure = ess_decay(ResultFolder(small_results / "han-lee" / "degeneracy"))
    axes = figure.axes[0]
    assert axes.get_yscale() == "log"
    assert any(np.allclose(line.get_ydata(), 1 / 200) for line in axes.get_lines())   # the 1/N floor
    plt.close(figure)


# -- the report and its verdicts -----------------------------------------------------------------

def test_report_section_and_gallery(small_results):
    section = han_lee.report(PaperResults(small_results / "han-lee"))
    assert len(section.verdicts) == 5
    assert {v.verdict for v in section.verdicts} <= set(VERDICTS)
    assert all(v.evidence for v in section.verdicts)
    figures = [item for item in section.items if isinstance(item, han_lee.Figure)]
    assert len(figures) == 7
    gallery = write_gallery(small_results).read_text()
    assert "han-lee" in gallery and "missing" not in gallery
    assert "Algorithm IV as printed (BIASED)" in gallery


def test_concept_offspring_follow_algorithm_ii(small_results):
    particles = pd.read_csv(small_results / "han-lee" / "fig1-concept" / "particles.csv")
    table = han_lee.concept_offspring(particles)
    assert len(table) == 10 and table["offspring"].sum() == 10
    assert table["weight"].sum() == pytest.approx(1.0)
    assert han_lee.concept_verdict(table).verdict == "reproduced"
    broken = table.copy()
    broken.loc[broken["weight"].idxmax(), "offspring"] = 0      # the heaviest particle dropped
    assert han_lee.concept_verdict(broken).verdict == "not reproduced"


def test_tracking_verdict_follows_its_criterion():
    sigma = 0.5
    good = np.full(100, 0.2) + np.linspace(-0.05, 0.05, 100)
    assert han_lee.tracking_verdict(0.3, good, sigma).verdict == "reproduced"
    assert han_lee.tracking_verdict(0.9, good, sigma).verdict == "partly reproduced"
    lost = good.copy()
    lost[:10] = 10 * sigma                                     # 10% of trials lost
    assert han_lee.tracking_verdict(0.9, lost, sigma).verdict == "not reproduced"


def test_bias_verdict_on_the_exact_expectations():
    from pfx.filters.particle.resampling import han_lee_iv_expected_counts

    weights = np.array([0.3, 0.1, 0.2, 0.15, 0.25])
    draws, n = 10_000, weights.size
    sem = 0.01
    rows = []
    for name, mean in (("systematic", n * weights), ("han_lee_iv", han_lee_iv_expected_counts(weights))):
        for j in range(n):
            rows.append({"resampler": name, "particle": j + 1, "weight": weights[j], "target_count": n * weights[j],
                         "expected_count": mean[j], "observed_mean": mean[j], "observed_sem": sem,
                         "z_score": (mean[j] - n * weights[j]) / sem, "draws": draws})
    table = pd.DataFrame(rows)
    verdict = han_lee.bias_verdict(table)
    assert verdict.verdict == "not reproduced" and "particle 5" in verdict.evidence
    unbiased = table.assign(observed_mean=table["target_count"], z_score=0.0)
    assert han_lee.bias_verdict(unbiased).verdict == "reproduced"


def test_equivalence_verdict_follows_the_margin():
    def row(low, high):
        return pd.Series({"baseline_mean": 1.0, "mean": 1.0 + (low + high) / 2, "mean_difference": (low + high) / 2,
                          "ci95_low": low, "ci95_high": high, "n_pairs": 100, "p_value": 0.5})

    assert han_lee.equivalence_verdict(row(-0.05, 0.05), "m").verdict == "reproduced"
    assert han_lee.equivalence_verdict(row(0.2, 0.3), "m").verdict == "not reproduced"
    assert han_lee.equivalence_verdict(row(-0.02, 0.15), "m").verdict == "partly reproduced"


def test_degeneracy_verdict_follows_its_criteria():
    def steps(filter_kind, arm, ess):
        return pd.DataFrame({"filter": filter_kind, "arm": arm, "trial": 0, "step": np.arange(1, len(ess) + 1),
                             "ess": ess, "n_particles": 1000})

    sis = steps("sis", "SIS", [3.0, 1.2, 1.0, 1.0])
    sir = steps("particle", "SIR", [3.0, 600.0, 700.0, 650.0])
    assert han_lee.degeneracy_verdict(pd.concat([sis, sir])).verdict == "reproduced"
    weak = steps("particle", "SIR", [3.0, 20.0, 30.0, 25.0])
    assert han_lee.degeneracy_verdict(pd.concat([sis, weak])).verdict == "partly reproduced"
    healthy_sis = steps("sis", "SIS", [3.0, 300.0, 200.0, 100.0])
    assert han_lee.degeneracy_verdict(pd.concat([healthy_sis, weak])).verdict == "not reproduced"


def test_range_sigma_reads_the_resolved_config():
    assert han_lee.range_sigma({"model": {"measurement_noise": {"variance": 0.25}}}) == pytest.approx(0.5)
    assert math.isclose(han_lee.range_sigma({"model": {"measurement_noise": {"variance": 2.0}}}), math.sqrt(2))
