"""Profile likelihood (estimation.method: profile): the Monte Carlo adjusted profile's mathematics
(pfx.estimation.profile), the config's refusals, a run's tables and figure, and its interval
against the exact profile of the Nile local level (the Kalman filter)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import optimize, stats

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.estimation.profile import monte_carlo_adjusted_profile
from pfx.papers.estimation_nile_exact import local_level_log_likelihood

ROOT = Path(__file__).resolve().parents[1]
NILE = str(ROOT / "examples" / "data" / "nile.csv")
MEASUREMENT, PROCESS = "model.measurement_noise.variance", "model.process_noise.variance"
CHI2 = stats.chi2.ppf(0.95, 1)


def profile_config(grid=(6000.0, 9000.0, 12000.0, 15000.0, 18000.0, 21000.0, 24000.0, 27000.0, 30000.0),
                   iterations=30, particles=200, **estimation):
    """The Nile local level, its measurement variance profiled, its process variance estimated."""
    config = {
        "name": "nile-profile", "seed": 7,
        "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                  "names": ["level"], "process_noise": {"variance": 1469.1},
                  "measurement_noise": {"variance": 15099.0},
                  "initial": {"kind": "gaussian", "mean": [0.0], "covariance": 1.0e7}},
        "data": {"measurements": NILE},
        "filter": {"particles": particles, "resampler": "systematic", "ess_threshold": 0.5},
        "estimation": {"method": "profile", "chains": 3, "iterations": iterations, "evaluations": 5,
                       "profile": {"parameter": MEASUREMENT, "grid": list(grid)},
                       "parameters": {PROCESS: {"prior": {"law": "flat", "lower": 0.0}, "transform": "log",
                                                "start": [500.0, 1500.0, 4000.0], "random_walk_sd": 0.1}}},
        "outputs": {"figures": []}}
    config["estimation"].update(estimation)
    return config


# -- the mathematics --------------------------------------------------------------------------------

def test_mcap_recovers_the_maximum_and_interval_of_a_quadratic_profile():
    """Points on l(x) = -(x - 2)^2 / (2 * 0.25) plus small noise: the maximum at 2, and (with
    little Monte Carlo error) the interval 2 +- 0.5 sqrt(chi2) where l is 1.92 below its top."""
    generator = np.random.default_rng(3)
    x = np.repeat(np.linspace(0.5, 3.5, 13), 4)
    noise_sd = 0.05
    y = -(x - 2.0) ** 2 / (2 * 0.25) + noise_sd * generator.standard_normal(len(x))
    fit = monte_carlo_adjusted_profile(x, y, level=0.95, span=0.75)
    half_width = 0.5 * np.sqrt(CHI2)
    assert abs(fit.maximum - 2.0) < 3 * fit.se_monte_carlo + 0.01
    assert fit.se_statistical == pytest.approx(0.5, rel=0.05)      # sqrt(1 / (2a)) with a = 2
    assert 0 < fit.se_monte_carlo < 0.05
    assert CHI2 / 2 <= fit.cutoff < CHI2 / 2 + 0.05                  # little Monte Carlo error: close to 1.92
    assert fit.lower == pytest.approx(2.0 - half_width, abs=0.03)
    assert fit.upper == pytest.approx(2.0 + half_width, abs=0.03)
    assert fit.flag == ""


def test_mcap_widens_the_cutoff_with_the_monte_carlo_error():
    """The same profile with 20 times the noise: the cutoff grows by chi2 * a * SE_mc^2, and the
    interval widens with it."""
    generator = np.random.default_rng(4)
    x = np.repeat(np.linspace(0.5, 3.5, 13), 4)
    clean = -(x - 2.0) ** 2 / (2 * 0.25)
    quiet = monte_carlo_adjusted_profile(x, clean + 0.01 * generator.standard_normal(len(x)))
    noisy = monte_carlo_adjusted_profile(x, clean + 1.0 * generator.standard_normal(len(x)))
    a = 1 / (2 * noisy.se_statistical ** 2)
    assert noisy.cutoff == pytest.approx(CHI2 * (a * noisy.se_monte_carlo ** 2 + 0.5), rel=1e-9)
    assert noisy.cutoff > quiet.cutoff + 0.1
    assert noisy.upper - noisy.lower > quiet.upper - quiet.lower


def test_mcap_flags_an_interval_that_reaches_the_grid_edge_and_a_profile_without_a_maximum():
    x = np.repeat(np.linspace(0.0, 1.0, 7), 2)
    rising = monte_carlo_adjusted_profile(x, -(x - 1.2) ** 2 + 0.001 * np.sin(7 * x))
    assert "edge" in rising.flag
    flat = monte_carlo_adjusted_profile(x, (x - 0.5) ** 2)
    assert np.isnan(flat.lower) and "not concave" in flat.flag


# -- refusals -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("change, key", [
    (lambda e: e["profile"].update(grid=[6000.0, 9000.0]), "estimation.profile.grid"),
    (lambda e: e["profile"].update(grid=[6000.0, 9000.0, 9000.0]), "estimation.profile.grid"),
    (lambda e: e["profile"].update(lower=1.0), "estimation.profile.lower"),
    (lambda e: e["profile"].update(grid=None, lower=9.0, upper=3.0, points=5), "estimation.profile.upper"),
    (lambda e: e.pop("profile"), "estimation.profile"),
    (lambda e: e.update(method="if2"), "estimation.profile"),
    (lambda e: e["parameters"].update({MEASUREMENT: {"prior": {"law": "flat", "lower": 0.0}, "start": 1.0}}),
     "estimation.profile.parameter"),
    (lambda e: e["profile"].update(parameter="model.nothing_here"), "estimation.profile.parameter"),
    (lambda e: e["profile"].update(parameter="model.dt"), "estimation.profile.parameter"),
    (lambda e: e.update(warm_up=3), "estimation.warm_up"),
])
def test_bad_profile_settings_name_their_key(change, key):
    config = profile_config()
    change(config["estimation"])
    with pytest.raises(ConfigError) as error:
        build_plan(config, "nile.yaml")
    assert error.value.key == key, str(error.value)


def test_an_evenly_spaced_grid_from_lower_upper_points():
    config = profile_config()
    config["estimation"]["profile"] = {"parameter": MEASUREMENT, "lower": 5000.0, "upper": 25000.0, "points": 5}
    plan = build_plan(config, "nile.yaml")
    assert plan.experiment.estimation.profile.values == [5000.0, 10000.0, 15000.0, 20000.0, 25000.0]


# -- a run ------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def profile_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("profile") / "run"
    config = profile_config()
    config["outputs"] = {"figures": ["profile_likelihood"], "formats": ["png"]}
    return pfx.run(config, out=out), config


def test_a_profile_run_writes_its_tables_and_figure(profile_run):
    result, config = profile_run
    folder = Path(result.folder)
    grid = config["estimation"]["profile"]["grid"]
    table = pd.read_csv(folder / "profile.csv")
    assert len(table) == len(grid) * 3
    assert list(table.columns[-6:]) == ["grid_point", "start", "measurement_noise.variance",
                                        "process_noise.variance", "log_likelihood", "log_likelihood_se"]
    assert table["measurement_noise.variance"].tolist() == [value for value in grid for _ in range(3)]
    assert table["start"].tolist() == [0, 1, 2] * len(grid)
    # the profiled parameter never moved: every IF2 pass kept each replicate at its grid value
    passes = pd.read_csv(folder / "if2.csv")
    assert np.allclose(passes["measurement_noise.variance"], np.repeat(grid, 3)[passes["replicate"]], rtol=1e-12)
    interval = pd.read_csv(folder / "profile_interval.csv").iloc[0]
    assert interval["lower"] < interval["maximum"] < interval["upper"]
    assert interval["cutoff"] >= CHI2 / 2
    smoothed = pd.read_csv(folder / "profile_smoothed.csv")
    assert len(smoothed) == 1000 and smoothed["value"].min() == grid[0] and smoothed["value"].max() == grid[-1]
    assert (folder / "figures" / "profile_likelihood.png").is_file()
    assert "profile" in result.manifest["estimation"]["method"]


def test_a_profile_run_extends_as_if2_does(tmp_path):
    """Asked for more passes, a finished profile continues its replicates: the numbers of one run."""
    small = dict(grid=(8000.0, 15000.0, 22000.0), particles=50)
    whole = pfx.run(profile_config(iterations=4, **small), out=tmp_path / "whole")
    pfx.run(profile_config(iterations=2, **small), out=tmp_path / "part")
    extended = pfx.run(profile_config(iterations=4, **small), out=tmp_path / "part")
    for name in ("profile.csv", "profile_interval.csv"):
        pd.testing.assert_frame_equal(*(pd.read_csv(Path(result.folder) / name) for result in (whole, extended)))


# -- against the exact profile -------------------------------------------------------------------------

def exact_interval(lower, upper):
    """The exact profile's maximiser and 95% interval (where the profile is within chi2/2 = 1.92
    of its maximum) over the measurement variance: the Kalman filter's exact log-likelihood,
    maximised over the process variance (on the log scale) by scipy at each value, the ends found
    by root-finding. The likelihood is the Kalman recursion written for arrays
    (pfx.papers.estimation_nile_exact, equal to pfx's ``kf`` on this model to 1e-9:
    tests/test_estimation_nile.py), which costs a fraction of a millisecond a call where a run of
    pfx's ``kf`` costs milliseconds, and this search makes about a thousand calls."""
    flows = pd.read_csv(NILE)["z1"].to_numpy(dtype=float)
    initial = profile_config()["model"]["initial"]

    def profile(measurement):
        fit = optimize.minimize_scalar(
            lambda log_q: -float(local_level_log_likelihood(flows, measurement, np.exp(log_q), initial["mean"][0],
                                                            initial["covariance"])),
            bounds=(np.log(10.0), np.log(50000.0)), method="bounded", options={"xatol": 1e-5})
        return -fit.fun
    top = optimize.minimize_scalar(lambda value: -profile(value), bounds=(lower, upper), method="bounded",
                                   options={"xatol": 1.0})
    level = -top.fun - CHI2 / 2
    ends = [optimize.brentq(lambda value: profile(value) - level, *bracket, xtol=1.0)
            for bracket in ((lower, top.x), (top.x, upper))]
    return top.x, *ends


def test_the_run_says_the_interval_and_its_flag_in_one_line(tmp_path, pfx_in_process):
    """The run prints each cell's maximum and interval as profile_interval.csv holds them; a grid
    too narrow for the interval (both ends at its edges) says so on the same line."""
    config = profile_config(grid=(14000.0, 15000.0, 16000.0), iterations=3, particles=50)
    (tmp_path / "profile.yaml").write_text(yaml.safe_dump(config))
    result = pfx_in_process("run", str(tmp_path / "profile.yaml"), "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.output
    interval = pd.read_csv(tmp_path / "out" / "profile_interval.csv").iloc[0]
    lines = [line for line in result.stderr.splitlines() if "profile of" in line]
    assert len(lines) == 1, result.stderr
    assert "Warning" not in result.stderr, result.stderr      # a fit without curvature is refused, not divided by 0
    if np.isfinite(interval["lower"]):
        assert f"[{interval['lower']:.4g}, {interval['upper']:.4g}]" in lines[0]
    assert interval["flag"] and interval["flag"] in lines[0]


def test_a_profile_runs_on_the_jax_backend_with_its_parameter_held_at_each_grid_value(tmp_path):
    """The profiled parameter walks with sd 0 inside IF2's compiled passes too: every replicate's
    estimate of it is its grid value, and the others move."""
    pytest.importorskip("jax")
    config = profile_config(grid=(8000.0, 15000.0, 22000.0), iterations=3, particles=50)
    config["filter"]["backend"] = "jax"
    table = pfx.run(config, out=tmp_path / "jax").tables["profile"]
    held = [column for column in table.columns if "measurement" in column][0]
    assert sorted(table.groupby("grid_point")[held].unique().map(tuple)) == [(8000.0,), (15000.0,), (22000.0,)]
    moved = [column for column in table.columns if "process" in column][0]
    assert not np.allclose(table[moved].to_numpy()[:3], [500.0, 1500.0, 4000.0])


def test_the_mcap_interval_covers_the_exact_profile_interval(profile_run):
    """The exact 95% interval lies inside MCAP's interval, each end within 3 SE_mc (MCAP's
    Monte Carlo standard error of the maximum's location, by which its whole interval may
    shift), and no further from it than that plus the widening MCAP's cutoff makes,
    sqrt(2 delta / a) - sqrt(chi2 / a) (a the quadratic's curvature, 1 / (2 SE_stat^2))."""
    result, _ = profile_run
    interval = pd.read_csv(Path(result.folder) / "profile_interval.csv").iloc[0]
    exact_maximum, exact_lower, exact_upper = exact_interval(6000.0, 30000.0)
    a = 1 / (2 * interval["se_statistical"] ** 2)
    widening = np.sqrt(2 * interval["cutoff"] / a) - np.sqrt(CHI2 / a)
    tolerance = 3 * interval["se_monte_carlo"]
    print(f"exact [{exact_lower:.0f}, {exact_upper:.0f}] max at {exact_maximum:.0f}; MCAP "
          f"[{interval['lower']:.0f}, {interval['upper']:.0f}] max at {interval['maximum']:.0f}, cutoff "
          f"{interval['cutoff']:.3f}, se_mc {interval['se_monte_carlo']:.0f}, se_stat {interval['se_statistical']:.0f}, "
          f"widening {widening:.0f}")
    assert interval["lower"] <= exact_lower + tolerance
    assert interval["upper"] >= exact_upper - tolerance
    assert abs(interval["lower"] - exact_lower) <= tolerance + widening
    assert abs(interval["upper"] - exact_upper) <= tolerance + widening
    assert abs(interval["maximum"] - exact_maximum) <= tolerance
