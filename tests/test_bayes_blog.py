"""bayes-blog: the empirical-CDF and importance-sampling studies against exact theory, their
figures, and the paper's report on small runs of its own configs."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import integrate, stats

from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.papers import REPORTS
from pfx.papers.base import VERDICTS, PaperResults, Table, Verdict
from pfx.papers.gallery import write_gallery
from pfx.run.runner import run_plan
from pfx.safe_yaml import load_config_file
from pfx.studies.empirical_cdf import KOLMOGOROV_MEAN, EmpiricalCdf, expected_ks_distance, ks_distance
from pfx.studies.importance_sampling_cdf import ImportanceSamplingCdf

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "papers" / "bayes-blog"


# -- empirical CDF ----------------------------------------------------------------------------

def test_ks_distance_is_scipys_exact_statistic():
    random = np.random.default_rng(1)
    for n in (1, 7, 300):
        sample = np.sort(random.normal(2.0, 3.0, n))
        distance, _ = ks_distance(sample, stats.norm.cdf(sample, 2.0, 3.0))
        assert distance == pytest.approx(stats.kstest(sample, "norm", args=(2.0, 3.0)).statistic, abs=1e-12)


def test_expected_ks_distance_against_closed_forms():
    # n = 1: D_1 = max(U, 1 - U), so E[D_1] = 3/4 exactly.
    assert expected_ks_distance(1) == (pytest.approx(0.75, abs=1e-9), "exact")
    # Large n: sqrt(n) E[D_n] rises towards Kolmogorov's sqrt(pi/2) ln 2 from below.
    value, method = expected_ks_distance(2000)
    assert method == "exact" and 0.86 < math.sqrt(2000) * value < KOLMOGOROV_MEAN
    value, method = expected_ks_distance(10**5)
    assert method == "asymptotic" and value == pytest.approx(KOLMOGOROV_MEAN / math.sqrt(10**5))


def test_mean_ks_distance_matches_its_exact_expectation():
    tables = EmpiricalCdf(mean=-1.0, std=0.5, sizes=[5, 50], repetitions=3000).tables(np.random.default_rng(3))
    distances = tables["ks_distance"]
    # the mean of 3000 draws lies within 4 standard errors of E[D_n] (chance of failing < 1e-4 per size)
    assert (distances["z_score"].abs() < 4).all()
    assert distances["ks_sem"].tolist() == pytest.approx((distances["ks_std"] / math.sqrt(3000)).tolist())
    ecdf = tables["ecdf"]
    for n in (5, 50):
        sample = ecdf[ecdf["size"] == n]
        assert len(sample) == n and sample["x"].is_monotonic_increasing
        assert sample["ecdf"].tolist() == pytest.approx(list(np.arange(1, n + 1) / n))
        row = distances[distances["size"] == n].iloc[0]
        assert abs(row["ks_ecdf_value"] - row["ks_true_cdf"]) == pytest.approx(row["ks_distance"])
    grid = tables["true_cdf"]
    assert grid["cdf"].tolist() == pytest.approx(stats.norm.cdf(grid["x"], -1.0, 0.5).tolist())
    assert grid["density"].tolist() == pytest.approx(stats.norm.pdf(grid["x"], -1.0, 0.5).tolist())


def test_empirical_cdf_rejects_bad_sizes():
    with pytest.raises(ConfigError) as error:
        build_plan({"name": "e", "study": {"kind": "empirical_cdf", "sizes": [10, 10]}}, "e.yaml")
    assert "study.sizes" in str(error.value)


# -- importance sampling ----------------------------------------------------------------------

def test_importance_sampling_moments_are_exact():
    study = ImportanceSamplingCdf(mean=0.5, std=1.5, proposal_low=-4.0, proposal_high=6.0, samples=100,
                                  grid_low=-3.0, grid_high=5.0)
    width = 10.0
    for x in (-3.0, 0.2, 4.0, 6.0):
        first = integrate.quad(lambda t: study.weight(t) / width, -4.0, x)[0]          # E_q[w 1{X <= x}]
        second = integrate.quad(lambda t: study.weight(t) ** 2 / width, -4.0, x)[0]    # E_q[w^2 1{X <= x}]
        assert float(study.first_moment(x)) == pytest.approx(first, rel=1e-9)
        assert float(study.second_moment(x)) == pytest.approx(second, rel=1e-9)
    assert study.expected_ess() == pytest.approx(100 * float(study.first_moment(6.0)) ** 2
                                                 / float(study.second_moment(6.0)))


def test_importance_sampling_error_matches_its_standard_error():
    repetitions = 1000
    study = ImportanceSamplingCdf(samples=200, repetitions=repetitions, grid_points=81)
    tables = study.tables(np.random.default_rng(11))
    cdf = tables["cdf"].set_index("x")
    # MSE over R independent repetitions, against SE^2: relative standard error sqrt(2/R) for
    # near-normal errors; 4 of them leave a failure chance below 1e-4 per point.
    tolerance = 4 * math.sqrt(2 / repetitions)
    for x in (-1.0, 0.0, 1.0):
        row = cdf.loc[x]
        for name in ("plain", "self_normalised"):
            ratio = row[f"rms_error_{name}"] ** 2 / row[f"standard_error_{name}"] ** 2
            assert abs(ratio - 1) < tolerance, (x, name, ratio)
            assert abs(row[f"truncation_bias_{name}"]) < 1e-6
    assert cdf["true_cdf"].tolist() == pytest.approx(stats.norm.cdf(cdf.index).tolist())
    samples = tables["samples"]
    assert samples["normalised_weight"].sum() == pytest.approx(1.0)
    assert samples["weight"].tolist() == pytest.approx((10 * stats.norm.pdf(samples["x"])).tolist())
    # the self-normalised estimate reaches 1 at the proposal's end; the plain one only on average
    summary = tables["summary"].set_index("estimator")
    assert summary.loc["self_normalised", "z_points"] <= 81


def test_importance_sampling_grid_must_lie_inside_the_proposal():
    with pytest.raises(ConfigError) as error:
        build_plan({"name": "i", "study": {"kind": "importance_sampling_cdf", "grid_low": -6.0}}, "i.yaml")
    assert "study.grid_low" in str(error.value)


# -- figures and the report on small runs of the paper's configs ------------------------------

def _small(name: str) -> dict:
    """The paper's config, made small enough for a test."""
    raw = load_config_file(CONFIGS / f"{name}.yaml")
    if name == "empirical-cdf":
        raw["study"].update(sizes=[10, 100], repetitions=50)
    elif name == "importance-sampling":
        raw["study"].update(samples=200, repetitions=20, grid_points=41)
    else:
        raw["trials"] = 3
        raw["model"]["steps"] = 8
        raw["outputs"]["particles"] = {"steps": "all", "trials": 1, "stages": ["weighted"]}
        raw["outputs"]["trace_trials"] = 2 if name == "landmark-demo" else 0
        raw["filter"]["particles"] = 30
        if name == "resamplers":
            raw["sweep"]["filter.particles"] = [10, 30]
    return raw


@pytest.fixture(scope="module")
def paper_results(tmp_path_factory) -> PaperResults:
    root = tmp_path_factory.mktemp("results")
    for name in ("empirical-cdf", "importance-sampling", "landmark-demo", "resamplers"):
        run_plan(build_plan(_small(name), f"{name}.yaml"), root / "bayes-blog" / name)
    shutil.copy(CONFIGS / "paper.yaml", root / "bayes-blog" / "paper.yaml")
    return PaperResults(root / "bayes-blog")


def test_the_paper_configs_are_valid():
    for path in sorted(CONFIGS.glob("*.yaml")):
        if path.name != "paper.yaml":
            build_plan(load_config_file(path), str(path))
    numbers = load_config_file(CONFIGS / "paper.yaml")
    assert numbers["demo"]["particles"] == 100 and numbers["demo"]["ess_threshold"] == 0.5


def test_figures_render_from_csv(paper_results):
    expected = {"empirical-cdf": ["empirical_cdf.png"], "importance-sampling": ["importance_sampling_cdf.png"],
                "landmark-demo": ["error_over_time.png", "particle_animation.gif", "particle_snapshots.png",
                                  "trajectory_map.png"],
                "resamplers": ["rmse_vs_particles.png"]}
    for experiment, files in expected.items():
        assert paper_results.figures(experiment) == files
        for name in files:
            assert (paper_results.path / experiment / "figures" / name).stat().st_size > 5_000


def test_the_report_gives_a_verdict_per_claim(paper_results):
    section = REPORTS["bayes-blog"](paper_results)
    assert [type(v) for v in section.verdicts] == [Verdict] * 5
    assert all(v.verdict in VERDICTS for v in section.verdicts)
    assert all(any(c.isdigit() for c in v.evidence) for v in section.verdicts)
    titles = [item.title for item in section.items if isinstance(item, Table)]
    assert any("Kolmogorov-Smirnov" in t for t in titles) and any("by particle count and resampler" in t
                                                                    for t in titles)
    gallery = write_gallery(paper_results.path.parent).read_text()
    assert "## bayes-blog" in gallery and "particle_animation.gif" in gallery
    assert "missing" not in gallery


def test_the_resampler_verdicts_follow_the_numbers(paper_results):
    """Doctored trials: a resampler made much better at every N must be reported as dominating."""
    folder = paper_results.path / "resamplers"
    trials = pd.read_csv(folder / "trials.csv")
    doctored = paper_results.path.parent / "doctored" / "bayes-blog"
    shutil.copytree(paper_results.path, doctored)
    # every scheme gets the same error per (N, trial), except systematic: 0.1 m less, nearly constant
    trials["rmse_position"] = trials.groupby(["n_particles", "trial"])["rmse_position"].transform("mean")
    better = trials["resampler"] == "systematic"
    trials.loc[better, "rmse_position"] -= 0.1 + 0.001 * trials.loc[better, "trial"]
    trials.to_csv(doctored / "resamplers" / "trials.csv", index=False)
    section = REPORTS["bayes-blog"](PaperResults(doctored))
    remark = next(v for v in section.verdicts if "resampling scheme" in v.claim)
    assert remark.verdict == "not reproduced" and "systematic" in remark.evidence
