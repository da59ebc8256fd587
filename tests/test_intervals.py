"""The 95% intervals of summary.csv and steps_summary.csv stay inside the metric's range, and
there is none from too few values (pfx/analysis/summary.py, step_summary.py).

Expectations from theory: the cut t-interval covers the true mean exactly when the t-interval
does (the true mean lies in the range); Wilson's interval has a closed form (and for k = n the
lower end n / (n + z^2)); the minimum count is the smallest n with 1 - 2 * 2^-n >= 0.95.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from pfx.analysis.paired_statistics import relative_change_interval
from pfx.analysis.step_summary import merge_step_summaries, summarize_steps
from pfx.analysis.summary import MINIMUM_VALUES, describe, summarize
from pfx.analysis.value_ranges import ANY_VALUE, NONNEGATIVE, SHARE, metric_range

Z = float(stats.norm.ppf(0.975))


def _t_interval(values: np.ndarray) -> tuple[float, float]:
    half = float(stats.t.ppf(0.975, values.size - 1)) * (values.std(ddof=1) / math.sqrt(values.size))
    return values.mean() - half, values.mean() + half


def test_a_nonnegative_metric_keeps_its_t_interval_cut_at_zero():
    skewed = np.array([0.4, 0.3, 0.5, 0.2, 0.6, 0.3, 30.0])       # one diverging trial
    low, high = _t_interval(skewed)
    assert low < 0                                                 # what the t-interval alone says
    result = describe(skewed, NONNEGATIVE)
    assert (result["ci95_low"], result["ci95_high"]) == (0.0, high)
    inside = np.array([1.0, 1.2, 0.9, 1.1, 1.05, 0.95])
    result = describe(inside, NONNEGATIVE)
    assert (result["ci95_low"], result["ci95_high"]) == _t_interval(inside)        # unchanged, to the bit
    assert describe(skewed, ANY_VALUE)["ci95_low"] == low                          # a log-likelihood's: as is


def test_the_cut_interval_covers_the_true_mean_exactly_when_the_t_interval_does():
    """Exponential errors (mean 1, heavily skewed) in samples of 6: the t-interval often reaches
    below 0, and cutting it there changes no coverage decision."""
    random = np.random.default_rng(20231)
    cut_covers, t_covers, reached_below = [], [], 0
    for _ in range(4000):
        values = random.exponential(1.0, size=6)
        low, high = _t_interval(values)
        reached_below += low < 0
        result = describe(values, NONNEGATIVE)
        assert result["ci95_low"] >= 0
        t_covers.append(low <= 1.0 <= high)
        cut_covers.append(result["ci95_low"] <= 1.0 <= result["ci95_high"])
    assert reached_below > 400
    assert cut_covers == t_covers


def test_a_share_gets_the_wilson_score_interval():
    converged = np.ones(20)
    result = describe(converged, SHARE)
    # k = n: the Wilson interval is [n / (n + z^2), 1], where the t-interval would be [1, 1].
    assert result["ci95_low"] == pytest.approx(20 / (20 + Z ** 2), rel=1e-12)
    assert result["ci95_high"] == pytest.approx(1.0, rel=1e-12)
    some = np.array([1.0] * 7 + [0.0] * 13)
    p, n = 7 / 20, 20
    centre = (p + Z ** 2 / (2 * n)) / (1 + Z ** 2 / n)
    spread = Z / (1 + Z ** 2 / n) * math.sqrt(p * (1 - p) / n + Z ** 2 / (4 * n ** 2))
    result = describe(some, SHARE)
    assert (result["ci95_low"], result["ci95_high"]) == pytest.approx((centre - spread, centre + spread), rel=1e-12)
    assert metric_range("converged") == SHARE and metric_range("rmse_x") == NONNEGATIVE
    assert metric_range("log_likelihood") == ANY_VALUE


def test_fewer_than_six_values_have_no_interval():
    assert 1 - 2 * 0.5 ** 5 < 0.95 <= 1 - 2 * 0.5 ** 6 and MINIMUM_VALUES == 6
    values = np.array([2.0, 3.0, 2.5, 3.5, 2.2, 2.8])
    assert math.isnan(describe(values[:5], NONNEGATIVE)["ci95_low"])
    assert math.isnan(describe(values[:5], SHARE)["ci95_high"])
    assert np.isfinite(describe(values, NONNEGATIVE)["ci95_low"])
    assert describe(values[:5], NONNEGATIVE)["sem"] > 0                 # the other statistics stay


def test_summary_csv_intervals_respect_each_metric_s_range():
    trials = pd.DataFrame({
        "cell": ["a"] * 8 + ["b"] * 3, "arm": ["a"] * 8 + ["b"] * 3, "trial": list(range(8)) + list(range(3)),
        "error_distance_final": [40.0, 2.0, 1.0, 3.0, 2.5, 250.0, 1.5, 2.0, 40.0, 280.0, 1.0],
        "converged": [True] * 8 + [True, False, True],
        "log_likelihood": [-10.0, -12.0, -11.0, -13.0, -10.5, -300.0, -11.5, -12.0, -1.0, -2.0, -3.0]})
    summary = summarize(trials, ["arm"]).set_index("cell")
    assert summary.loc["a", "error_distance_final_ci95_low"] == 0.0
    assert summary.loc["a", "converged_ci95_low"] == pytest.approx(8 / (8 + Z ** 2), rel=1e-12)
    assert summary.loc["a", "log_likelihood_ci95_low"] == _t_interval(trials["log_likelihood"][:8].to_numpy())[0]
    assert summary.loc["b"].filter(like="ci95").isna().all()            # 3 trials: none


def test_steps_summary_intervals_are_cut_at_zero_and_nees_counts_its_values():
    random = np.random.default_rng(5)
    trials, steps = 8, 5
    values = {name: random.exponential(1.0, size=(trials, steps)) for name in ("error_distance", "ess", "nis")}
    values["nees"] = random.exponential(0.3, size=(trials, steps))
    values["nees"][:3, 1] = 40.0                       # skewed: the t-interval reaches below 0
    values["nees"][[0, 4, 6], 2] = np.nan              # three covariances that could not be inverted
    values["squared_error_x"] = random.exponential(1.0, size=(trials, steps))
    whole = summarize_steps(values, ["x"], {"cell": "c"}, np.arange(1.0, steps + 1))
    assert list(whole["nees_n"]) == [8, 8, 5, 8, 8]
    kept = values["nees"][~np.isnan(values["nees"][:, 2]), 2]
    assert whole["nees_mean"][2] == pytest.approx(kept.mean(), rel=1e-14)
    assert whole["nees_ci95_low"][1] == 0.0
    for quantity in ("error_distance", "ess", "nees", "nis"):
        assert (whole[f"{quantity}_ci95_low"].dropna() >= 0).all()
    # Extending the run (3 + 5 trials) gives the same table to rounding, counts included.
    first = summarize_steps({k: v[:3] for k, v in values.items()}, ["x"], {"cell": "c"}, np.arange(1.0, steps + 1))
    second = summarize_steps({k: v[3:] for k, v in values.items()}, ["x"], {"cell": "c"}, np.arange(1.0, steps + 1))
    merged = merge_step_summaries(first, second)
    assert list(merged.columns) == list(whole.columns)
    pd.testing.assert_frame_equal(merged, whole, rtol=1e-12, check_dtype=False)
    # Fewer than six values at a step: no interval there (5 NEES at step 3, 3 trials in ``first``).
    assert math.isnan(first["error_distance_ci95_low"][0]) and math.isnan(whole["nees_ci95_low"][2])


def test_a_relative_change_of_a_nonnegative_metric_never_falls_below_minus_100_percent():
    """park-mpf's ten runs gave the ballistic coefficient's RMSE change [-153.9%, +462.0%]: the
    ratio of two nonnegative means is at least 0, so the change is at least -100%."""
    base = np.array([1.0, 1.1, 0.9, 1.0, 1.2, 0.8])
    value = np.array([0.1, 0.1, 0.1, 0.1, 0.1, 9.0])
    change, low, high = relative_change_interval(base, value)
    assert low < -1.0
    cut = relative_change_interval(base, value, value_range=NONNEGATIVE)
    assert cut == (change, -1.0, high)
