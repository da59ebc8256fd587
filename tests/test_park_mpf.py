"""park-mpf: the Mahalanobis-distance study against exact theory, the comparison helpers, the
configs, the figures and the report (on a small generated result folder)."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pfx.analysis.paired_statistics import diverged, relative_change_interval
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.numerics.seeding import study_generator
from pfx.papers.base import REPORTS, VERDICTS, PaperResults, Table
from pfx.papers.gallery import write_gallery
from pfx.papers.park_mpf_extended import claim_verdict
from pfx.run.runner import run_plan
from pfx.safe_yaml import load_config_file
from pfx.studies.mahalanobis_distances import MahalanobisDistances, sample_moments

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs" / "papers" / "park-mpf"
SIGMA = np.array([[1.0, 0.9], [0.9, 1.0]])
POINTS = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])


# -- the study -----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_study():
    """n = 200 samples, 3000 replications: the sampling moments are known exactly (below)."""
    study = MahalanobisDistances(samples=200, replications=3000)
    return study.tables(study_generator(2021))


def test_exact_distances_are_the_closed_forms():
    tables = MahalanobisDistances(replications=0).tables(study_generator(1))
    distances = tables["distances"]
    np.testing.assert_allclose(distances["euclidean_exact"], 2.0, rtol=1e-14)
    # Sigma^-1 = [[1, -.9], [-.9, 1]] / 0.19: (1, 1) -> 0.2 / 0.19, (1, -1) -> 3.8 / 0.19
    np.testing.assert_allclose(distances["mahalanobis_exact"], [0.2 / 0.19, 20.0, 20.0, 0.2 / 0.19], rtol=1e-12)
    assert len(tables["samples"]) == 1000
    assert distances["euclidean_sampling_sd"].isna().all()


def test_sample_distances_are_recomputed_from_the_written_sample():
    tables = MahalanobisDistances(replications=0).tables(study_generator(2))
    draw = tables["samples"][["x", "y"]].to_numpy()
    mean = draw.mean(axis=0)
    covariance = np.cov(draw, rowvar=False)                      # divisor n - 1
    offsets = POINTS - mean
    distances = tables["distances"]
    np.testing.assert_allclose(distances["euclidean_sample"], np.sum(offsets ** 2, axis=1), rtol=1e-12)
    np.testing.assert_allclose(distances["mahalanobis_sample"],
                               np.einsum("kd,de,ke->k", offsets, np.linalg.inv(covariance), offsets), rtol=1e-10)


def test_sampling_moments_of_the_euclidean_distance_match_theory(small_study):
    # With Sigma = sum_i lambda_i e_i e_i' and m = sum_i sqrt(lambda_i / n) g_i e_i (g_i iid N(0, 1)),
    # |p - m|^2 = |p|^2 + sum_i [A_i g_i + B_i g_i^2], A_i = -2 (p'e_i) sqrt(lambda_i / n), B_i = lambda_i / n:
    # a sum of independent terms. Mean |p|^2 + tr(Sigma) / n; each term has variance A^2 + 2 B^2 and
    # fourth central moment 3 A^4 + 60 A^2 B^2 + 60 B^4, so the kurtosis kappa is exact too, and the
    # sample sd over R replications has standard error sd sqrt((kappa - 1) / (4 R)).
    n, replications = 200, 3000
    distances = small_study["distances"]
    eigenvalues, eigenvectors = np.linalg.eigh(SIGMA)
    a = -2 * (POINTS @ eigenvectors) * np.sqrt(eigenvalues / n)
    b = eigenvalues / n
    term_variance = a ** 2 + 2 * b ** 2
    variance = term_variance.sum(axis=1)
    cumulant4 = (3 * a ** 4 + 60 * a ** 2 * b ** 2 + 60 * b ** 4 - 3 * term_variance ** 2).sum(axis=1)
    kurtosis = 3 + cumulant4 / variance ** 2
    sd = np.sqrt(variance)
    mean = np.sum(POINTS ** 2, axis=1) + np.trace(SIGMA) / n
    z_mean = (distances["euclidean_sampling_mean"] - mean) / (sd / math.sqrt(replications))
    z_sd = (distances["euclidean_sampling_sd"] - sd) / (sd * np.sqrt((kurtosis - 1) / (4 * replications)))
    assert (np.abs(z_mean) < 4).all(), z_mean
    assert (np.abs(z_sd) < 4).all(), z_sd


def test_sampling_mean_of_the_mahalanobis_distance_matches_theory(small_study):
    # Sample mean and covariance of a Gaussian sample are independent; (n - 1) C ~ Wishart(Sigma, n - 1),
    # so E[C^-1] = (n - 1) / (n - d - 2) Sigma^-1 and
    # E[(p - m)' C^-1 (p - m)] = (n - 1) / (n - d - 2) (p' Sigma^-1 p + d / n).
    n, d, replications = 200, 2, 3000
    distances = small_study["distances"]
    expected = (n - 1) / (n - d - 2) * (np.einsum("kd,de,ke->k", POINTS, np.linalg.inv(SIGMA), POINTS) + d / n)
    standard_error = distances["mahalanobis_sampling_sd"] / math.sqrt(replications)
    z = (distances["mahalanobis_sampling_mean"] - expected) / standard_error
    assert (np.abs(z) < 4).all(), z


def test_sample_moments_use_the_unbiased_covariance():
    draw = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])
    mean, covariance = sample_moments(draw)
    np.testing.assert_allclose(mean, [1.0, 1.0])
    np.testing.assert_allclose(covariance, np.eye(2) * 4 / 3)


@pytest.mark.parametrize("change, key", [
    ({"covariance": [[1.0, 1.0], [1.0, 1.0]]}, "study.covariance"),
    ({"covariance": [[1.0, 2.0], [2.0, 1.0]]}, "study.covariance"),
    ({"points": [[1.0, 1.0], [1.0]]}, "study.points[1]"),
])
def test_study_errors_name_the_key(change, key):
    raw = {"name": "t1", "study": {"kind": "mahalanobis_distances", **change}}
    with pytest.raises(ConfigError) as error:
        build_plan(raw, "t1.yaml")
    assert str(error.value).startswith(f"t1.yaml: {key}:"), str(error.value)


# -- comparison helpers ----------------------------------------------------------------------------

def test_relative_change_interval_exact_ratio_and_exclusions():
    base = np.array([1.0, 2.0, 3.0, 4.0, np.inf])
    estimate, low, high = relative_change_interval(base, 0.8 * base)
    assert math.isclose(estimate, -0.2) and math.isclose(low, -0.2) and math.isclose(high, -0.2)
    assert all(math.isnan(v) for v in relative_change_interval(np.array([1.0]), np.array([2.0])))


def test_relative_change_interval_covers_the_true_ratio_at_its_level():
    # 600 experiments of 40 pairs with E[v] / E[b] = 0.75: coverage 0.95 +- 4 binomial sd (0.036)
    random = np.random.default_rng(20210323)
    covered = 0
    experiments = 600
    for _ in range(experiments):
        base = random.gamma(4.0, 25.0, size=40)                 # mean 100, skewed like RMSEs
        value = 0.75 * base + random.normal(0.0, 15.0, size=40)
        _, low, high = relative_change_interval(base, value)
        covered += low <= -0.25 <= high
    assert abs(covered / experiments - 0.95) < 4 * math.sqrt(0.95 * 0.05 / experiments)


def test_diverged_flags_infinite_missing_and_astronomical_values():
    reference = np.array([100.0, 120.0, 90.0])
    values = np.array([150.0, np.inf, np.nan, 2e5, 9e4])
    assert diverged(values, reference).tolist() == [False, True, True, True, False]


def _row(change, low, high, diverged_count=0, trials=100):
    return pd.Series({"trials": trials, "diverged": diverged_count, "relative_change": change,
                      "relative_low": low, "relative_high": high, "pairs": trials - diverged_count})


@pytest.mark.parametrize("row, verdict", [
    (_row(-0.25, -0.30, -0.18), "reproduced"),
    (_row(-0.05, -0.09, -0.01), "partly reproduced"),
    (_row(-0.02, -0.09, 0.04), "not reproduced"),
    (_row(0.10, 0.02, 0.18), "not reproduced"),
    (_row(math.nan, math.nan, math.nan, diverged_count=100), "not reproduced"),
    (_row(-0.25, -0.30, -0.18, diverged_count=3), "partly reproduced"),
])
def test_claim_verdict_rules(row, verdict):
    found, evidence = claim_verdict(-0.22, row, "MPF-x", "altitude")
    assert found == verdict
    assert evidence


# -- configs ------------------------------------------------------------------------------------

def test_filter_configs_share_model_filter_arms_and_seed():
    configs = {name: load_config_file(CONFIGS / f"{name}.yaml") for name in ("one-run", "ten-runs", "extended")}
    for name in ("ten-runs", "extended"):
        for key in ("seed", "model", "filter", "metrics"):
            assert configs[name][key] == configs["one-run"][key], (name, key)
        for arm, settings in configs["one-run"]["arms"].items():
            assert configs[name]["arms"][arm] == settings
    assert configs["ten-runs"]["trials"] == 10 and configs["extended"]["trials"] >= 100
    forms = {a.get("weighting", {}).get("form") for a in configs["extended"]["arms"].values()
             if isinstance(a.get("weighting"), dict)}
    assert forms == {"paper", "innovation"}
    for path in CONFIGS.glob("*.yaml"):
        if path.name != "paper.yaml":
            build_plan(load_config_file(path), str(path))      # every config validates


# -- a small generated result folder: figures and report -------------------------------------------

SMALL = {"one-run": None, "ten-runs": 3, "extended": 6}


@pytest.fixture(scope="module")
def small_results(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    paper = root / "park-mpf"
    for name, trials in SMALL.items():
        raw = load_config_file(CONFIGS / f"{name}.yaml")
        raw["filter"]["particles"] = 150
        raw["model"]["substeps"] = 2
        run_plan(build_plan(raw, name, trials=trials), paper / name)
    raw = load_config_file(CONFIGS / "table1.yaml")
    raw["study"]["replications"] = 200
    run_plan(build_plan(raw, "table1"), paper / "table1")
    # as `pfx reproduce` does: read with pfx's YAML rules, written back by the YAML writer
    (paper / "paper.yaml").write_text(yaml.safe_dump(load_config_file(CONFIGS / "paper.yaml"), sort_keys=False))
    return root


def test_figures_are_rendered_from_csv(small_results):
    paper = small_results / "park-mpf"
    for experiment, figure in (("table1", "mahalanobis_scatter"), ("one-run", "state_error_over_time"),
                               ("ten-runs", "state_error_over_time"), ("extended", "relative_change_by_state")):
        path = paper / experiment / "figures" / f"{figure}.png"
        assert path.stat().st_size > 20_000, path


def test_report_has_every_table_figure_and_allowed_verdicts(small_results):
    results = PaperResults(small_results / "park-mpf")
    section = REPORTS["park-mpf"](results)
    assert section.verdicts and all(v.verdict in VERDICTS for v in section.verdicts)
    claims = " ".join(v.claim for v in section.verdicts)
    for needle in ("Table 1", "22% lower", "31% lower", "MPF-paper", "MPF-innovation", "absolute RMSE"):
        assert needle in claims, needle
    by_claim = {v.claim: v for v in section.verdicts}
    assert next(v for c, v in by_claim.items() if c.startswith("absolute")).verdict == "not comparable"
    titles = " ".join(item.title for item in section.items if isinstance(item, Table))
    for needle in ("Table 1", "Table 2", "Table 3 (altitude)", "Table 3 (velocity)", "Extended"):
        assert needle in titles, needle
    table2 = next(item for item in section.items if isinstance(item, Table) and item.title.startswith("Table 2"))
    assert "0.0188" in table2.markdown and "no unit" in table2.markdown
    gallery = write_gallery(small_results).read_text()
    for figure in ("mahalanobis_scatter.png", "state_error_over_time.png", "relative_change_by_state.png"):
        assert figure in gallery
    assert "missing" not in gallery


def test_report_verdicts_follow_the_csv(small_results):
    """With every MPF-innovation RMSE set to twice the PF's, its claims must read 'not reproduced'."""
    paper = small_results / "park-mpf"
    copy = small_results.parent / "changed" / "park-mpf"
    shutil.copytree(paper, copy)
    trials = pd.read_csv(copy / "extended" / "trials.csv")
    innovation = trials["weighting"] == "mahalanobis-innovation"
    baseline = trials[trials["weighting"] == "gaussian"].set_index("trial")
    for column in ("rmse_altitude", "rmse_velocity", "rmse_ballistic_coefficient"):
        trials.loc[innovation, column] = 2.0 * trials.loc[innovation, "trial"].map(baseline[column]).to_numpy()
    trials.to_csv(copy / "extended" / "trials.csv", index=False)
    section = REPORTS["park-mpf"](PaperResults(copy))
    innovation_claims = [v for v in section.verdicts if "lower with MPF" in v.claim and v.claim.endswith("MPF-innovation")]
    assert len(innovation_claims) == 3
    assert all(v.verdict == "not reproduced" for v in innovation_claims), [v.evidence for v in innovation_claims]
