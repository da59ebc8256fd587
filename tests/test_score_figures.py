"""The figures of forecasts and predictive scores, read back from their artists.

* ``forecast_fan`` (pfx/figures/forecasts.py): the bands and the median of each drawn origin
  are forecasts.csv's quantiles, starting at the origin's measurement; the points are steps.csv's
  measurements; at most six origins, spaced so that the fans stay apart.
* ``pit_histogram`` and ``score_over_time`` (pfx/figures/scores.py): the bars are a density
  histogram of steps.csv's PIT values (area 1), the band is Binomial(n, 1/10)'s central 95%, the
  title's p-value is scipy's KS test; the lines are steps.csv's means per step.

One small real run (a 15-step linear-Gaussian model measured in both components, a Kalman and
a particle arm, scores and forecasts on) feeds every figure; a run without them gives None.
"""

from __future__ import annotations

import json
import re
import shutil

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from scipy.stats import binom, kstest

import pfx
from pfx.figures import FIGURES, render_figures
from pfx.figures.forecasts import MOST_ORIGINS, band_pairs, forecast_fan, quantile_probability, shown_origins
from pfx.figures.scores import PIT_BINS, pit_histogram, score_over_time, uniform_bar_band
from pfx.result_folder import ResultFolder

matplotlib.use("Agg")                  # no screen: draw into memory

CONFIG = {
    "name": "score-figures", "seed": 5, "trials": 6,
    "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
              "measurement_matrix": [[1.0, 0.0], [0.0, 1.0]], "names": ["position", "velocity"], "steps": 15,
              "process_noise": {"variance": [0.05, 0.05]}, "measurement_noise": {"variance": [1.0, 0.5]},
              "initial": {"kind": "gaussian", "mean": [0.0, 1.0], "covariance": [1.0, 0.1]}},
    "filter": {"particles": 300},
    "arms": {"kf": {"kind": "kf"}, "pf": {}},
    "metrics": {"scores": True},
    "outputs": {"figures": [], "trace_trials": 6,
                "forecasts": {"horizons": [1, 2, 3, 4], "origins": "all", "trials": 2}},
}
HORIZON = 4


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    """The result folder of the run with scores and forecasts."""
    out = tmp_path_factory.mktemp("scored") / "out"
    pfx.run(CONFIG, out=out)
    return out


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """The same experiment without scores or forecasts."""
    out = tmp_path_factory.mktemp("plain") / "out"
    config = {**CONFIG, "trials": 2, "metrics": {}, "outputs": {"figures": [], "trace_trials": 2}}
    pfx.run(config, out=out)
    return out


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def _panel(figure, title_start: str):
    return next(axes for axes in figure.axes if axes.get_title().startswith(title_start))


def _by_gid(axes, gid: str):
    return next(artist for artist in axes.get_children() if artist.get_gid() == gid)


def _label(axes, label: str):
    return next(line for line in axes.get_lines() if line.get_label() == label)


# -- forecast_fan -------------------------------------------------------------------------------

def test_shown_origins_keep_the_fans_apart():
    assert shown_origins([3, 9], horizon=10) == [3, 9]                # few: every one the config asked for
    assert shown_origins(range(1, 15), horizon=4) == [1, 5, 10, 14]   # 14 origins, fans of 4 steps: 4 fit
    many = shown_origins(range(1, 101), horizon=10)
    assert len(many) == MOST_ORIGINS and many[0] == 1 and many[-1] == 100
    assert np.diff(many).min() >= 10
    assert shown_origins(range(1, 11), horizon=50) == [1, 10]          # never fewer than two


def test_quantile_labels_and_their_pairs():
    assert quantile_probability("05") == 0.05 and quantile_probability("02_5") == 0.025
    assert band_pairs([0.5, 0.95, 0.05, 0.75, 0.25]) == [(0.05, 0.95), (0.25, 0.75)]


def test_forecast_fan_draws_the_quantiles_of_forecasts_csv(scored):
    figure = forecast_fan(ResultFolder(scored))
    forecasts = pd.read_csv(scored / "forecasts.csv")
    steps = pd.read_csv(scored / "steps.csv")
    first = forecasts[(forecasts["trial"] == 0) & (forecasts["arm"] == "pf")]
    measured = steps[(steps["arm"] == "pf") & (steps["trial"] == 0)].set_index("step")
    origins = sorted(first["origin_step"].unique())
    shown = shown_origins(origins, HORIZON)
    assert "trial 0" in figure._suptitle.get_text()
    assert f"{len(shown)} of {len(origins)} (evenly spaced" in figure._suptitle.get_text()
    assert "no forecasts (no particle cloud) for: kf" in figure._suptitle.get_text()
    for component in ("z1", "z2"):
        axes = _panel(figure, f"pf, {component}")
        points = _label(axes, "measurement")
        assert np.allclose(points.get_ydata(), measured[f"measurement_{component}"].to_numpy())
        drawn = {int(re.match(r"origin (\d+): median", artist.get_gid()).group(1))
                 for artist in axes.get_children() if (artist.get_gid() or "").endswith("median")}
        assert sorted(drawn) == shown
        for origin in shown:
            rows = first[first["origin_step"] == origin].sort_values("horizon")
            start = (float(origin), measured.loc[origin, f"measurement_{component}"])   # time = step here
            median = _by_gid(axes, f"origin {origin}: median")
            assert np.allclose(median.get_xdata(), [start[0], *rows["time"]])
            assert np.allclose(median.get_ydata(), [start[1], *rows[f"measurement_q50_{component}"]])
            for low, high in (("05", "95"), ("25", "75")):
                corners = _by_gid(axes, f"origin {origin}: {int(low)}-{int(high)}%").get_paths()[0].vertices
                expected = [start] + [(time, value) for quantile in (low, high)
                                      for time, value in zip(rows["time"], rows[f"measurement_q{quantile}_{component}"])]
                for point in expected:
                    assert np.isclose(corners, point).all(axis=1).any(), (origin, low, high, point)


def test_forecast_fan_falls_back_on_the_observed_values(scored, tmp_path):
    """Without steps.csv's trace of the trial the points are forecasts.csv's observed values,
    and a fan whose origin's measurement is unknown starts at its first horizon."""
    copy = tmp_path / "copy"
    shutil.copytree(scored, copy)
    (copy / "steps.csv").unlink()
    figure = forecast_fan(ResultFolder(copy))
    forecasts = pd.read_csv(copy / "forecasts.csv")
    first = forecasts[(forecasts["trial"] == 0)].drop_duplicates("step").sort_values("step")
    axes = _panel(figure, "pf, z1")
    assert np.allclose(_label(axes, "measurement").get_ydata(), first["observed_z1"])
    median = _by_gid(axes, "origin 1: median")            # step 1 is no forecast's step
    assert median.get_xdata()[0] == 2.0


# -- pit_histogram ------------------------------------------------------------------------------

def test_uniform_bar_band_holds_a_bar_with_95_percent():
    for count in (30, 90, 1000):
        low, high = uniform_bar_band(count)
        low_count, high_count = round(low * count / PIT_BINS), round(high * count / PIT_BINS)
        inside = binom.cdf(high_count, count, 0.1) - binom.cdf(low_count - 1, count, 0.1)
        assert low < 1.0 < high and inside >= 0.95
        # the narrowest such band: one count less on either side holds less than 97.5% of a tail
        assert binom.cdf(high_count - 1, count, 0.1) < 0.975 and binom.cdf(low_count, count, 0.1) >= 0.025


def test_pit_histogram_is_a_density_of_the_pit_values(scored):
    figure = pit_histogram(ResultFolder(scored))
    steps = pd.read_csv(scored / "steps.csv")
    for arm in ("kf", "pf"):
        for component in ("z1", "z2"):
            axes = _panel(figure, f"{arm}, {component}")
            values = steps.loc[steps["arm"] == arm, f"pit_{component}"].dropna().to_numpy()
            assert values.size == 6 * 15
            (bars,) = axes.containers                  # the histogram's bars
            heights = np.array([bar.get_height() for bar in bars])
            widths = np.array([bar.get_width() for bar in bars])
            assert np.isclose((heights * widths).sum(), 1.0)
            expected, _ = np.histogram(values, bins=np.linspace(0, 1, PIT_BINS + 1), density=True)
            assert np.allclose(heights, expected)
            band = next(patch for patch in axes.patches if patch.get_label().startswith("95% band"))
            y = band.get_path().transformed(band.get_patch_transform()).vertices[:, 1]
            assert np.allclose([y.min(), y.max()], uniform_bar_band(values.size))
            p_value = kstest(values, "uniform").pvalue
            assert f"KS p = {p_value:.2g} (n = {values.size})" in axes.get_title()
            if arm == "kf":
                # the exact filter of the true model: its PIT is uniform, so p < 0.001 has probability 0.001
                assert p_value > 0.001


def test_pit_histogram_of_recorded_data_uses_one_trial(scored, tmp_path):
    """Every trial of recorded data filters the same measurements: the first traced trial's PITs
    are the sample (n = 15 steps), not 6 near-copies of them."""
    copy = tmp_path / "copy"
    shutil.copytree(scored, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    (copy / "manifest.json").write_text(json.dumps({**manifest, "recorded_data": True}))
    figure = pit_histogram(ResultFolder(copy))
    assert "(n = 15)" in _panel(figure, "pf, z1").get_title()
    assert "first traced trial" in figure._suptitle.get_text()


# -- score_over_time ----------------------------------------------------------------------------

def test_score_over_time_draws_the_means_over_the_traced_trials(scored):
    figure = score_over_time(ResultFolder(scored))
    steps = pd.read_csv(scored / "steps.csv")
    means = steps.groupby(["arm", "step"])[["crps_z1", "crps_z2", "log_score", "energy_score"]].mean()
    for title, column in (("CRPS of z1", "crps_z1"), ("CRPS of z2", "crps_z2"), ("log score", "log_score")):
        axes = _panel(figure, title)
        for arm in ("kf", "pf"):
            line = _label(axes, arm)
            assert np.allclose(line.get_xdata(), np.arange(1, 16))
            assert np.allclose(line.get_ydata(), means.loc[arm, column].to_numpy())
    energy = _panel(figure, "energy score")
    assert [line.get_label() for line in energy.get_lines()] == ["pf"]    # the Kalman kinds compute none
    assert "none for: kf" in energy.get_title()
    assert np.allclose(_label(energy, "pf").get_ydata(), means.loc["pf", "energy_score"].to_numpy())
    legend = figure.legends[0]
    assert [text.get_text() for text in legend.get_texts()] == ["kf", "pf"]


# -- registration and folders without the columns -----------------------------------------------

def test_registered_and_rendered_from_the_folder(scored, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(scored, copy)
    names = ["forecast_fan", "pit_histogram", "score_over_time"]
    assert all(name in FIGURES for name in names)
    written = render_figures(copy, names)
    assert sorted(path.name for path in written) == sorted(f"{name}.png" for name in names)


@pytest.mark.parametrize("figure", [forecast_fan, pit_histogram, score_over_time])
def test_nothing_drawn_without_scores_or_forecasts(plain, figure):
    assert not (plain / "forecasts.csv").exists()
    assert figure(ResultFolder(plain)) is None
