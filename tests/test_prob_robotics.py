"""prob-robotics: the textbook studies against exact theory, the PF-vs-grid gap, figures and the report."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import integrate, stats

import pfx.papers  # noqa: F401  (registers the reports)
from pfx.analysis.reference_gap import slope_summary, step_gaps, trial_gaps, trial_slopes
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.papers.base import REPORTS, VERDICTS, PaperResults
from pfx.papers.gallery import render_section
from pfx.run.runner import run_plan
from pfx.studies.importance_sampling import ImportanceSampling
from pfx.studies.kalman_1d_steps import KalmanSteps, gaussian_density, kalman_predict, kalman_update
from pfx.studies.nonlinear_transform import NonlinearTransform, chi_square

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "papers" / "prob-robotics"


# -- Fig. 3.2: the Kalman filter in 1-D --------------------------------------------------------

def test_kalman_update_is_the_gaussian_product():
    """prior(x) p(z | x) = N(z; c mu, c^2 s^2 + Q) N(x; mu', s'^2) for every x: the update is exact."""
    mean, variance, c, q, z = 3.0, 2.5, 0.7, 1.3, 4.2
    new_mean, new_variance, gain = kalman_update(mean, variance, z, c=c, measurement_variance=q)
    x = np.linspace(-10, 15, 41)
    product = gaussian_density(x, mean, variance) * gaussian_density(z - c * x, 0.0, q)
    evidence = gaussian_density(np.array(z), c * mean, c * c * variance + q)
    np.testing.assert_allclose(product, evidence * gaussian_density(x, new_mean, new_variance), rtol=1e-12)
    # and the information form: 1/s'^2 = 1/s^2 + c^2/Q
    assert math.isclose(1 / new_variance, 1 / variance + c * c / q, rel_tol=1e-14)
    assert math.isclose(gain, variance * c / (c * c * variance + q), rel_tol=1e-15)


def test_kalman_prediction_is_the_convolution():
    mean, variance = kalman_predict(2.0, 3.0, 5.0, a=0.8, b=1.5, motion_variance=0.6)
    assert (mean, variance) == pytest.approx((0.8 * 2.0 + 1.5 * 5.0, 0.64 * 3.0 + 0.6), rel=1e-15)


def test_kalman_study_agrees_with_bayes_on_the_grid():
    study = KalmanSteps(a=0.9, b=2.0, c=0.5, control=6.0, measurements=[3.0, 9.0])
    steps = study.tables(np.random.default_rng(0))["steps"].set_index("curve")
    # Midpoint sums over Gaussians many cells wide are exact to rounding (Poisson summation).
    np.testing.assert_allclose(steps["grid_mean"], steps["mean"], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(steps["grid_variance"], steps["variance"], rtol=1e-9)
    assert (steps["max_density_difference"] < 1e-9).all()
    # The book's qualitative picture: updates shrink and move, motion widens.
    assert steps.loc["posterior_1", "variance"] < min(steps.loc["prior", "variance"],
                                                      steps.loc["measurement_1", "variance"])
    assert steps.loc["predicted", "variance"] > steps.loc["posterior_1", "variance"]
    assert list(steps["panel"]) == list("abcdef")


def test_kalman_study_refuses_a_blind_sensor():
    with pytest.raises(ConfigError, match="study.c"):
        build_plan({"name": "k", "study": {"kind": "kalman_1d_steps", "c": 0.0}}, "k.yaml")


# -- Fig. 4.2: importance sampling -------------------------------------------------------------

def test_importance_weighted_moments_match_the_target_within_standard_error():
    study = ImportanceSampling()
    moments = study.tables(np.random.default_rng(42))["moments"].set_index("quantity")
    # two z-scores, each |z| < 3.5 with probability 0.9995 if the standard error is right
    assert (moments["z_score"].abs() < 3.5).all()
    # without the weights the draws describe g, not f: far more than 3.5 standard errors off
    off = (moments["unweighted_estimate"] - moments["exact"]).abs() / moments["standard_error"]
    assert (off > 10).all()


def test_importance_sampling_standard_error_is_calibrated():
    """Over 300 independent runs the z-scores have mean square 1 (the standard error is right)."""
    study = ImportanceSampling(samples=2000, shown_samples=10)
    random = np.random.default_rng(7)
    tables = [study.tables(random)["moments"] for _ in range(300)]
    z = np.array([m["z_score"].to_numpy() for m in tables])
    # mean of z^2 over 300 draws: 1 +- 3 sqrt(2/300) = 1 +- 0.25 if z ~ N(0, 1); mean 0 +- 3/sqrt(300)
    for column in range(2):
        assert abs(np.mean(z[:, column] ** 2) - 1.0) < 0.25
        assert abs(np.mean(z[:, column])) < 3 / math.sqrt(300)
    # the ESS rule of thumb is conservative here (wider), never too narrow
    z_ess = np.array([((m["weighted_estimate"] - m["exact"]) / m["ess_standard_error"]).to_numpy() for m in tables])
    assert (np.mean(z_ess ** 2, axis=0) < 1.0).all()


def test_importance_target_moments_are_exact():
    study = ImportanceSampling(target_weights=[0.2, 0.5, 0.3], target_means=[-1.0, 2.0, 4.0],
                               target_stds=[0.5, 1.0, 0.3])
    mean, variance = study.target_moments()
    first = integrate.quad(lambda x: x * study.target_density(np.array([x]))[0], -20, 20, limit=200)[0]
    second = integrate.quad(lambda x: (x - mean) ** 2 * study.target_density(np.array([x]))[0], -20, 20,
                            limit=200)[0]
    assert mean == pytest.approx(first, abs=1e-9)
    assert variance == pytest.approx(second, abs=1e-8)


def test_importance_sampling_checks_its_mixture():
    with pytest.raises(ConfigError, match="sum to 1"):
        build_plan({"name": "i", "study": {"kind": "importance_sampling", "target_weights": [0.5, 0.6]}}, "i.yaml")
    with pytest.raises(ConfigError, match="one entry per mixture component"):
        build_plan({"name": "i", "study": {"kind": "importance_sampling", "target_means": [1.0]}}, "i.yaml")


# -- Fig. 4.3: a Gaussian through a nonlinear function ----------------------------------------

def test_nonlinear_exact_law_matches_closed_forms():
    study = NonlinearTransform(input_mean=0.5, input_std=0.6, coefficients=[0.0, 1.0, 0.0, 1.0])
    mu, s = 0.5, 0.6
    mean, variance = study.exact_moments()
    assert mean == pytest.approx(mu + mu ** 3 + 3 * mu * s ** 2, rel=1e-12)      # E[X + X^3]
    # Var by direct moments of the Gaussian: E[Y^2] = E[X^2 + 2 X^4 + X^6]
    m = [stats.norm(mu, s).moment(k) for k in range(7)]
    assert variance == pytest.approx(m[2] + 2 * m[4] + m[6] - mean ** 2, rel=1e-10)
    # g is increasing: the CDF is Phi(g^-1(y)); the density integrates to it
    y = np.array([-2.0, 0.3, 1.0, 4.0])
    inverse = np.array([np.roots([1.0, 0.0, 1.0, -v])[np.abs(np.roots([1.0, 0.0, 1.0, -v]).imag) < 1e-9].real[0]
                        for v in y])
    np.testing.assert_allclose(study.exact_cdf(y), stats.norm.cdf(inverse, mu, s), rtol=1e-10)
    area = integrate.quad(lambda v: study.exact_density(np.array([v]))[0], -2.0, 4.0, limit=200)[0]
    assert area == pytest.approx(study.exact_cdf(np.array([4.0]))[0] - study.exact_cdf(np.array([-2.0]))[0],
                                 abs=1e-8)


def test_nonlinear_exact_law_of_a_non_monotone_function():
    """y = x^2 with x ~ N(1, 0.5^2): y / 0.25 is noncentral chi-square (1 dof, noncentrality 4)."""
    study = NonlinearTransform(input_mean=1.0, input_std=0.5, coefficients=[0.0, 0.0, 1.0])
    y = np.array([0.05, 0.5, 1.0, 2.5])
    law = stats.ncx2(df=1, nc=4.0, scale=0.25)
    np.testing.assert_allclose(study.exact_cdf(y), law.cdf(y), rtol=1e-9)
    np.testing.assert_allclose(study.exact_density(y), law.pdf(y), rtol=1e-9)


def test_particle_histogram_fits_the_exact_law_and_the_linearisation_does_not():
    study = NonlinearTransform()
    tables = study.tables(np.random.default_rng(43))
    fit = tables["fit"].set_index("method")
    # Pearson's test at the 0.1 % level on a fixed seed; the Gaussian is rejected by far
    assert fit.loc["particles", "p_value"] > 1e-3
    assert fit.loc["linearised", "p_value"] < 1e-10
    assert fit.loc["linearised", "total_variation"] > 5 * fit.loc["particles", "total_variation"]
    moments = tables["moments"].set_index("quantity")
    z = (moments.loc["mean", "particles"] - moments.loc["mean", "exact"]) / moments.loc["mean",
                                                                                        "particle_standard_error"]
    assert abs(z) < 3.5
    histogram = tables["histogram"]
    assert histogram["exact_probability"].sum() == pytest.approx(0.998, abs=1e-9)


def test_chi_square_merges_small_bins():
    result = chi_square(np.array([3, 10, 40, 40, 7]), np.array([0.02, 0.1, 0.4, 0.4, 0.08]))
    assert result["degrees_of_freedom"] == 3          # [3+10], 40, 40, [7] -> 4 groups
    assert result["chi_square"] == pytest.approx((13 - 12) ** 2 / 12 + 0 + 0 + (7 - 8) ** 2 / 8)


def test_nonlinear_study_refuses_a_flat_linearisation():
    with pytest.raises(ConfigError, match="degenerate"):
        build_plan({"name": "n", "study": {"kind": "nonlinear_transform", "input_mean": 0.0,
                                           "coefficients": [0.0, 0.0, 1.0]}}, "n.yaml")


# -- the particle filter against the grid ------------------------------------------------------

def _synthetic_steps(counts=(100, 400, 1600), trials=3, steps=4):
    """A reference cell and PF cells whose estimates sit exactly 1/sqrt(N) from it (known slope -1/2)."""
    rows = []
    for trial in range(trials):
        for step in range(1, steps + 1):
            truth = np.sin(trial + step)
            rows.append({"cell": "grid", "arm": "grid", "filter": "histogram", "n_particles": np.nan,
                         "trial": trial, "step": step, "truth_x": truth, "estimate_x": truth + 0.1})
            for n in counts:
                sign = 1 if (step + trial) % 2 else -1
                rows.append({"cell": f"pf{n}", "arm": f"PF-{n}", "filter": "particle", "n_particles": n,
                             "trial": trial, "step": step, "truth_x": truth,
                             "estimate_x": truth + 0.1 + sign * (trial + 1) / math.sqrt(n)})
    return pd.DataFrame(rows)


def test_reference_gap_and_slope_on_a_known_rate():
    steps = _synthetic_steps()
    labels = ["arm", "filter", "n_particles"]
    gaps = step_gaps(steps, labels)
    assert set(gaps["cell"]) == {"pf100", "pf400", "pf1600"}
    per_trial = trial_gaps(steps, labels)
    row = per_trial[(per_trial["cell"] == "pf400") & (per_trial["trial"] == 2)].iloc[0]
    assert row["rms_gap"] == pytest.approx(3 / 20)
    slopes = trial_slopes(per_trial, labels)
    np.testing.assert_allclose(slopes["slope"], -0.5, rtol=1e-12)
    summary = slope_summary(slopes, labels).iloc[0]
    assert summary["n"] == 3 and summary["mean"] == pytest.approx(-0.5)


def test_reference_gap_needs_exactly_one_reference():
    steps = _synthetic_steps()
    twice = pd.concat([steps, steps[steps["cell"] == "grid"].assign(cell="grid2")])
    with pytest.raises(ValueError, match="exactly one"):
        step_gaps(twice, ["arm", "filter", "n_particles"])


# -- the configs, figures and the report -------------------------------------------------------

def _small(name: str) -> dict:
    """The paper's config, shrunk to run in a moment."""
    raw = yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())
    if name == "histogram-reference":
        raw["trials"] = 4
        raw["model"]["steps"] = 8
        raw["outputs"]["trace_trials"] = 4
        raw["arms"] = {"grid": {"kind": "histogram", "grid": {"cells": 300}},
                       "PF-50": {"particles": 50}, "PF-200": {"particles": 200}, "PF-800": {"particles": 800}}
    elif name == "fig-4.2-importance-sampling":
        raw["study"]["samples"] = 4000
    elif name == "fig-4.3-nonlinear-transform":
        raw["study"]["samples"] = 3000
    return raw


@pytest.fixture(scope="module")
def paper_results(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("results") / "prob-robotics"
    # this part's experiments (the motion-model figures and Table 4.2 are tested in
    # tests/test_prob_robotics_motion.py)
    for name in ("fig-3.2-kalman", "fig-4.2-importance-sampling", "fig-4.3-nonlinear-transform",
                 "histogram-reference"):
        config = CONFIGS / f"{name}.yaml"
        plan = build_plan(_small(config.stem), str(config))
        run_plan(plan, root / plan.experiment.name)
    shutil.copy(CONFIGS / "paper.yaml", root / "paper.yaml")
    return root


def test_every_figure_is_drawn_from_csv(paper_results):
    drawn = {p.parent.parent.name: p.name for p in paper_results.glob("*/figures/*.png")}
    assert drawn == {"fig-3.2-kalman": "kalman_steps.png",
                     "fig-4.2-importance-sampling": "importance_weights.png",
                     "fig-4.3-nonlinear-transform": "nonlinear_particles.png",
                     "histogram-reference": "reference_gap_vs_particles.png"}


def test_report_section_has_a_verdict_per_claim(paper_results):
    results = PaperResults(paper_results)
    section = REPORTS["prob-robotics"](results)
    assert len(section.verdicts) == 5
    assert all(v.verdict in VERDICTS for v in section.verdicts)
    assert section.verdicts[0].verdict == "reproduced"          # exact mathematics, whatever the sizes
    text = render_section(section, results, paper_results.parent)
    assert "kalman_steps.png" in text and "missing" not in text
    assert "| particles N |" in text


def test_report_skips_the_parts_without_results(paper_results, tmp_path):
    partial = tmp_path / "prob-robotics"
    shutil.copytree(paper_results / "fig-3.2-kalman", partial / "fig-3.2-kalman")
    section = REPORTS["prob-robotics"](PaperResults(partial))
    assert len(section.verdicts) == 1
    assert [item.experiment for item in section.items if hasattr(item, "experiment")] == ["fig-3.2-kalman"]
