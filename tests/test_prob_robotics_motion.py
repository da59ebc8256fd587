"""Probabilistic Robotics part B: motion-model studies (Figs. 5.3/5.4, 5.8/5.9), binary Bayes, report.

Statistical checks use fixed seeds; their limits are stated beside them (z limits in standard
errors, chi-square p-values). Quadrature checks state the error the midpoint rule allows.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import stats
from scipy.special import expit

from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.filters.log_odds import corridor_example
from pfx.motion import (
    arc_jacobian,
    motion_model_odometry,
    motion_model_velocity,
    pose_density_odometry,
    pose_density_velocity,
    prob,
)
from pfx.motion.odometry import move_by_odometry
from pfx.motion.velocity import executed_velocities, move_on_arc
from pfx.papers.base import VERDICTS, PaperResults, Section
from pfx.papers.gallery import render_section
from pfx.papers.prob_robotics_motion import (
    BINARY_BAYES,
    ODOMETRY_DENSITY,
    ODOMETRY_SAMPLES,
    VELOCITY_DENSITY,
    VELOCITY_SAMPLES,
    motion_sections,
)
from pfx.run.runner import run_plan
from pfx.studies.robot_motion import histogram_agreement, spread_along_across
from pfx.studies.velocity_motion import VelocityMotionDensity

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "papers" / "prob-robotics"
VELOCITY_SETTINGS = [{"name": "a", "alphas": [0.02, 0.02, 0.02, 0.02, 0.0025, 0.0025]},
                     {"name": "b", "alphas": [0.08, 0.08, 0.005, 0.005, 0.0025, 0.0025]}]


def _config(name: str) -> dict:
    return yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())


# ---- the pose densities: the book's value divided by the Jacobian --------------------------------

def test_arc_jacobian_matches_finite_differences():
    v, w, dt = 0.8, 0.6, 1.3

    def pose(noise):
        return move_on_arc(np.zeros(3), noise[0], noise[1], noise[2], dt)

    step = 1e-6
    base = np.array([v, w, 0.05])
    matrix = np.column_stack([(pose(base + step * e) - pose(base - step * e)) / (2 * step) for e in np.eye(3)])
    assert abs(np.linalg.det(matrix)) == pytest.approx(float(arc_jacobian(v, w, dt)), rel=1e-6)


def test_odometry_jacobian_is_the_translation():
    rotation1, translation, rotation2 = 0.3, 1.2, -0.4
    step = 1e-6
    base = np.array([rotation1, translation, rotation2])
    matrix = np.column_stack([(move_by_odometry(np.zeros(3), *(base + step * e))
                               - move_by_odometry(np.zeros(3), *(base - step * e))) / (2 * step) for e in np.eye(3)])
    assert abs(np.linalg.det(matrix)) == pytest.approx(translation, rel=1e-6)
    pose = np.array([0.9, 0.5, 0.7])
    ratio = motion_model_odometry(pose, np.zeros(3), [1.0, 0.4, 0.8], np.zeros(3), [0.05, 0.005, 0.01, 0.01]) \
        / pose_density_odometry(pose, np.zeros(3), [1.0, 0.4, 0.8], np.zeros(3), [0.05, 0.005, 0.01, 0.01])
    assert ratio == pytest.approx(math.hypot(0.9, 0.5), rel=1e-12)


@pytest.mark.parametrize("model", ["velocity", "odometry"])
def test_pose_densities_integrate_to_one_and_the_books_values_do_not(model):
    # midpoint rule, 2 cm x 2 cm x 0.02 rad cells against standard deviations of ~0.1 m and 0.1 rad:
    # the rule's relative error is ~ (h / sigma)^2 / 24 ~ 2e-3 at worst, so 1 within 5e-3
    x = -0.3 + 0.02 * (np.arange(110) + 0.5)
    y = -0.5 + 0.02 * (np.arange(90) + 0.5)
    thetas = -0.6 + 0.02 * (np.arange(120) + 0.5) + 0.75
    xs, ys, ts = np.meshgrid(x, y, thetas, indexing="ij")
    poses = np.stack([xs, ys, ts], axis=-1)
    cell = 0.02 ** 3
    if model == "velocity":
        alphas = [0.01, 0.01, 0.01, 0.01, 0.01, 0.01]
        pose_mass = pose_density_velocity(poses, [1.0, 0.75], np.zeros(3), 1.0, alphas).sum() * cell
        book_mass = motion_model_velocity(poses, [1.0, 0.75], np.zeros(3), 1.0, alphas).sum() * cell
        jacobian_at_command = float(arc_jacobian(1.0, 0.75, 1.0))
    else:
        alphas = [0.05, 0.005, 0.01, 0.01]
        pose_mass = pose_density_odometry(poses, np.zeros(3), [1.0, 0.4, 0.8], np.zeros(3), alphas).sum() * cell
        book_mass = motion_model_odometry(poses, np.zeros(3), [1.0, 0.4, 0.8], np.zeros(3), alphas).sum() * cell
        jacobian_at_command = math.hypot(1.0, 0.4)
    assert pose_mass == pytest.approx(1.0, abs=5e-3)
    # the book's value integrates to E|J|, close to |J| at the command, not to 1
    assert book_mass == pytest.approx(jacobian_at_command, rel=0.05)
    assert abs(book_mass - 1.0) > 0.05


def test_the_sum_over_headings_is_exact_for_the_books_value():
    # sum_k prob(gamma(theta_k)) dtheta = dt exactly (up to the midpoint rule's exp(-2 pi^2 sigma^2 / h^2) error),
    # so the heading-summed Table 5.1 is dt * prob(v - v^) prob(w - w^)
    study = VelocityMotionDensity(settings=VELOCITY_SETTINGS[:1], cells=(20, 10), theta_cells=100, dt=1.0)
    setting = study.settings[0]
    summed, _ = study.marginals(setting)
    x, y, _, _ = study.grid()
    xs, ys = np.meshgrid(x, y, indexing="ij")
    poses = np.stack([xs, ys, np.zeros_like(xs)], axis=-1)
    v_hat, w_hat, _ = executed_velocities(np.zeros(3), poses, 1.0, 1)
    variance_v, variance_w, _ = setting.alphas.variances(1.0, 0.75)
    expected = prob(1.0 - v_hat, variance_v) * prob(0.75 - w_hat, variance_w)
    near = expected > 1e-6 * expected.max()
    np.testing.assert_allclose(summed[near], expected[near], rtol=1e-6)


def test_the_heading_grid_must_resolve_the_final_rotation():
    config = _config("fig-5.3-velocity-density")
    config["study"]["theta_cells"] = 20       # step 0.15 rad against a spread of 0.0625 rad
    with pytest.raises(ConfigError) as error:
        build_plan(config, "density.yaml")
    assert "theta_cells" in str(error.value) and "density.yaml" in str(error.value)
    config = _config("fig-5.3-velocity-density")
    config["study"]["cells"] = [151, 80]
    with pytest.raises(ConfigError, match="check_block"):
        build_plan(config, "density.yaml")
    config = _config("fig-5.8-odometry-density")
    config["study"]["settings"][0]["alphas"] = [0.0, 0.0, 0.01, 0.01]   # no rotation error at all
    with pytest.raises(ConfigError, match="zero variance of the final rotation"):
        build_plan(config, "density.yaml")


# ---- the check against the sampler, and the spread statistics ------------------------------------

def test_histogram_agreement_is_calibrated():
    # counts drawn from the probabilities themselves: the p-values are uniform (Kolmogorov-Smirnov
    # at 1e-3), and p < 0.05 in Binomial(300, 0.05) cases: 15 +- 4 sd (3.8); counts from shifted
    # probabilities fail
    random = np.random.default_rng(8)
    probabilities = np.append(np.full(40, 0.02), 0.2)
    p_values = np.array([histogram_agreement(random.multinomial(5000, probabilities), probabilities,
                                             random)["p_value"] for _ in range(300)])
    assert stats.kstest(p_values, "uniform").pvalue > 1e-3
    assert abs((p_values < 0.05).sum() - 15) <= 4 * math.sqrt(300 * 0.05 * 0.95)
    shifted = probabilities * np.append(np.linspace(0.8, 1.2, 40), 1.0)
    shifted /= shifted.sum()
    result = histogram_agreement(random.multinomial(5000, shifted), probabilities, random)
    assert result["p_value"] < 1e-6
    assert result["total_variation"] > result["tv_null_q99"]


def test_spread_along_and_across_with_its_standard_errors():
    random = np.random.default_rng(3)
    angle = 0.4
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    points = (random.standard_normal((40_000, 2)) * [0.3, 0.1]) @ rotation.T + [1.0, 2.0]
    row = spread_along_across(points, angle)
    # normal data: se(s^2) = sigma^2 sqrt(2 / n); each variance within 4 standard errors of the truth
    assert row["var_along_se"] == pytest.approx(0.09 * math.sqrt(2 / 40_000), rel=0.05)
    assert abs(row["var_along"] - 0.09) < 4 * row["var_along_se"]
    assert abs(row["var_across"] - 0.01) < 4 * row["var_across_se"]
    assert abs(row["correlation"]) < 4 / math.sqrt(40_000)


@pytest.mark.parametrize("kind", ["velocity_motion_samples", "odometry_motion_samples"])
def test_straight_translation_noise_only_gives_the_exact_variance_along(kind, tmp_path):
    # w = 0 and translational noise only: the robot moves straight, the position along is v^ dt
    # (trans^ for odometry) exactly, of variance alpha v^2 dt^2; across it nothing moves
    if kind.startswith("velocity"):
        study = {"kind": kind, "control": [2.0, 0.0], "dt": 0.5,
                 "settings": [{"name": "a", "alphas": [0.04, 0.0, 0.0, 0.0, 0.0, 0.0]}]}
        variance = 0.04 * 2.0 ** 2 * 0.5 ** 2
    else:
        study = {"kind": kind, "odometry_after": [1.5, 0.0, 0.0],
                 "settings": [{"name": "a", "alphas": [0.0, 0.0, 0.04, 0.0]}]}
        variance = 0.04 * 1.5 ** 2
    study.update(samples=100, extended_samples=5000)
    out = run_plan(build_plan({"name": "straight", "seed": 4, "study": study,
                               "outputs": {"figures": []}}, "straight.yaml"), tmp_path / "run")
    spread = pd.read_csv(out / "spread.csv")
    for _, row in spread.iterrows():
        assert abs(row["var_along"] - variance) < 4 * row["var_along_se"]
        assert row["var_across"] == pytest.approx(0.0, abs=1e-20)
    samples = pd.read_csv(out / "samples.csv")
    assert samples.groupby(["setting", "noise"]).size().tolist() == [100, 100]


# ---- the binary Bayes study -----------------------------------------------------------------------

def test_binary_bayes_study_against_exact_beliefs(tmp_path):
    config = _config("table-4.2-binary-bayes")
    config["study"]["runs"] = 400
    config["outputs"]["figures"] = []
    plan = build_plan(config, "binary.yaml")
    out = run_plan(plan, tmp_path / "run")
    beliefs = pd.read_csv(out / "beliefs.csv")
    final = pd.read_csv(out / "final.csv").set_index("cell")
    convergence = pd.read_csv(out / "convergence.csv")
    # the example is corridor_example with the study's generator
    from pfx.numerics.seeding import study_generator
    expected = corridor_example(study_generator(config["seed"]))
    np.testing.assert_allclose(beliefs["belief"], expected["belief"])
    # cells far before the face are seen through in every scan (a range error of 4 standard
    # deviations would be needed otherwise): belief = expit(T log(0.3/0.7)) exactly
    exact_free = expit(10 * math.log(0.3 / 0.7))
    np.testing.assert_allclose(final.loc[:20, "belief_mean"], exact_free, rtol=1e-9)
    # the face cell: each scan says occupied if |e| < 1/2 cell (p = 2 Phi(1.25) - 1), free if e > 1/2 cell,
    # nothing otherwise; its mean final belief against the exact multinomial expectation, within 4 SE
    step = math.log(0.7 / 0.3)
    p_occupied = 2 * stats.norm.cdf(1.25) - 1
    p_free = 1 - stats.norm.cdf(1.25)
    exact = 0.0
    for occupied in range(11):
        for free in range(11 - occupied):
            weight = math.comb(10, occupied) * math.comb(10 - occupied, free) * p_occupied ** occupied \
                * p_free ** free * (1 - p_occupied - p_free) ** (10 - occupied - free)
            exact += weight * expit(step * (occupied - free))
    assert abs(final.loc[24, "belief_mean"] - exact) < 4 * final.loc[24, "belief_se"]
    # error falls scan by scan; occluded far cells keep the prior exactly
    assert (np.diff(convergence["visible_error_mean"]) < 0).all()
    assert (final.loc[27:, "belief_mean"] == 0.5).all()


# ---- figures and the report from a small generated result folder ----------------------------------

SMALL = {
    VELOCITY_DENSITY: {"cells": [30, 16], "check_samples": 3000},
    ODOMETRY_DENSITY: {"cells": [24, 24], "check_samples": 3000},
    VELOCITY_SAMPLES: {"extended_samples": 2000},
    ODOMETRY_SAMPLES: {"extended_samples": 2000},
    BINARY_BAYES: {"runs": 50},
}
FILES = {
    VELOCITY_DENSITY: "fig-5.3-velocity-density", ODOMETRY_DENSITY: "fig-5.8-odometry-density",
    VELOCITY_SAMPLES: "fig-5.4-velocity-samples", ODOMETRY_SAMPLES: "fig-5.9-odometry-samples",
    BINARY_BAYES: "table-4.2-binary-bayes",
}


@pytest.fixture(scope="module")
def small_results(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("results")
    for experiment, overrides in SMALL.items():
        config = copy.deepcopy(_config(FILES[experiment]))
        assert config["name"] == experiment
        config["study"].update(overrides)
        run_plan(build_plan(config, f"{experiment}.yaml"), root / "prob-robotics" / experiment)
    return root


def test_every_figure_is_drawn_from_csv(small_results):
    for experiment in SMALL:
        folder = small_results / "prob-robotics" / experiment
        config = _config(FILES[experiment])
        for name in config["outputs"]["figures"]:
            assert (folder / "figures" / f"{name}.png").stat().st_size > 20_000, (experiment, name)


def test_the_report_gives_items_and_verdicts_from_the_csv(small_results):
    results = PaperResults(small_results / "prob-robotics")
    items, verdicts = motion_sections(results)
    assert len(verdicts) == 7           # per model: agreement, settings, noise families; binary Bayes
    assert {v.verdict for v in verdicts} <= set(VERDICTS)
    text = render_section(Section("prob-robotics", "part B", "", items, verdicts), results, small_results)
    assert "missing" not in text
    # the book's Table 5.1 leaves out the Jacobian: with (b)'s translational error the check finds it
    agreement = pd.read_csv(small_results / "prob-robotics" / VELOCITY_DENSITY / "agreement.csv")
    printed_b = agreement[(agreement["density"] == "table_5_1") & (agreement["setting"] == "b")]
    assert printed_b["p_value"].iloc[0] < 1e-3
    assert verdicts[0].verdict in ("partly reproduced", "not reproduced")


def test_the_report_skips_absent_experiments(tmp_path):
    (tmp_path / "prob-robotics").mkdir()
    assert motion_sections(PaperResults(tmp_path / "prob-robotics")) == ([], [])
