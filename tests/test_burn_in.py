"""Burn-in, the RMS error over the components (DAPPER's score), and each step's log-likelihood
increment (pfx/analysis/metrics.py, pfx/filters/trace.py, docs/output-files.md).

* ``metrics.burn_in``: the step-aggregating metrics of trials.csv equal a hand computation from
  steps.csv (every trial traced) over exactly the steps with time > burn_in; the others (final
  error, log-likelihood) and the filter's random stream are untouched; a burn-in that leaves no
  step is a located config error (exit 2); a config without it keeps its cell keys (those of
  the committed results/).
* ``rms_error_mean``: the hand formula, an angle's error wrapped.
* ``log_likelihood_increment``: sums to the trial's log-likelihood for the particle filter
  (bootstrap and auxiliary), the Kalman filters and the histogram filter; 0 at a step without a
  measurement; the Kalman filter's increments are log p(z_k | z_1:k-1) of the exact joint
  Gaussian law of the measurements; steps.csv and steps_summary.csv carry them.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import tiny_config_dict
from scipy import stats

import pfx
from pfx.analysis.metrics import MetricInputs, MetricsConfig, rms_error_metrics, rmse_metrics, scored_steps
from pfx.analysis.step_summary import merge_step_summaries
from pfx.config.plan import build_plan
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams
from pfx.run.batch import steps_columns
from pfx.run.runner import run_plan

REPO_ROOT = Path(__file__).resolve().parents[1]

# A 2-D constant-velocity target observed in position, dt = 0.5: steps 1..12 at times 0.5..6.
MODEL = {"kind": "linear_gaussian", "steps": 12, "dt": 0.5, "transition_matrix": [[1.0, 0.5], [0.0, 1.0]],
         "measurement_matrix": [[1.0, 0.0]], "names": ["position", "velocity"], "position": [0],
         "process_noise": {"variance": [0.05, 0.05]}, "measurement_noise": {"variance": 0.5},
         "initial": {"kind": "gaussian", "mean": [0.0, 1.0], "covariance": [1.0, 0.1]}}
BURN_IN = 2.0          # steps 1-4 (times 0.5, 1, 1.5 and exactly 2) are not scored
TRIALS = 7


def _config(burn_in=None) -> dict:
    metrics = {"consistency": True, "convergence": {"criterion": "truth", "radius": 1.0}}
    if burn_in is not None:
        metrics["burn_in"] = burn_in
    return tiny_config_dict(name="burn-in", model=MODEL, trials=TRIALS,
                            filter={"particles": 60, "ess_threshold": 0.5},
                            arms={"pf": {}, "apf": {"auxiliary": True},
                                  "kf": {"kind": "kf", "smoothers": [{"kind": "rts"}]}},
                            metrics=metrics, outputs={"trace_trials": TRIALS, "figures": []})


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same config with and without the burn-in, every trial traced."""
    folder = tmp_path_factory.mktemp("burn-in")
    return {name: SimpleNamespace(path=path, trials=pd.read_csv(path / "trials.csv"),
                                  steps=pd.read_csv(path / "steps.csv"),
                                  steps_summary=pd.read_csv(path / "steps_summary.csv"))
            for name, path in (("burn_in", run_plan(build_plan(_config(BURN_IN), "burn-in.yaml"), folder / "with")),
                               ("none", run_plan(build_plan(_config(), "none.yaml"), folder / "without")))}


def _by_trial(steps: pd.DataFrame, trials: pd.DataFrame, values: pd.Series, how) -> np.ndarray:
    """``how`` of ``values`` (rows of steps.csv) per (cell, trial), in the order of trials.csv's rows."""
    table = steps.assign(_value=values).groupby(["cell", "trial"])["_value"].agg(how)
    return table.loc[list(zip(trials["cell"], trials["trial"]))].to_numpy(dtype=float)


def test_burn_in_scores_exactly_the_steps_after_it(runs):
    trials, steps = runs["burn_in"].trials, runs["burn_in"].steps
    scored_rows = steps[steps["time"] > BURN_IN]
    assert sorted(scored_rows["step"].unique()) == list(range(5, 13))       # 2.0 itself is burnt in

    def hand(values, how="mean", rows=scored_rows):
        return _by_trial(rows, trials, values, how)

    error = {name: scored_rows[f"estimate_{name}"] - scored_rows[f"truth_{name}"] for name in ("position", "velocity")}
    close = {"rtol": 1e-12, "atol": 0.0}
    for name in ("position", "velocity"):
        np.testing.assert_allclose(trials[f"rmse_{name}"], np.sqrt(hand(error[name] ** 2)), **close)
    np.testing.assert_allclose(trials["error_distance_mean"], hand(scored_rows["error_distance"]), **close)
    np.testing.assert_allclose(trials["rms_error_mean"],
                               hand(np.sqrt((error["position"] ** 2 + error["velocity"] ** 2) / 2)), **close)
    particle = trials["filter"] == "particle"
    np.testing.assert_allclose(trials["ess_mean"][particle], hand(scored_rows["ess"])[particle], **close)
    np.testing.assert_array_equal(trials["resample_count"], hand(scored_rows["resampled"].astype(float), "sum"))
    np.testing.assert_array_equal(trials["degenerate_steps"], hand(scored_rows["degenerate"].astype(float), "sum"))
    np.testing.assert_allclose(trials["particles_mean"][particle], hand(scored_rows["particles"])[particle], **close)
    np.testing.assert_allclose(trials["nees_mean"], hand(scored_rows["nees"]), **close)
    np.testing.assert_allclose(trials["nis_mean"], hand(scored_rows["nis"]), **close)
    kf = trials["filter"] == "kf"
    smoothed = scored_rows["smoothed_rts_position"] - scored_rows["truth_position"]
    np.testing.assert_allclose(trials["rmse_rts_position"][kf], np.sqrt(hand(smoothed ** 2))[kf], **close)
    smoothed_velocity = scored_rows["smoothed_rts_velocity"] - scored_rows["truth_velocity"]
    np.testing.assert_allclose(trials["rms_error_rts_mean"][kf],
                               hand(np.sqrt((smoothed ** 2 + smoothed_velocity ** 2) / 2))[kf], **close)
    # Not step averages: over the whole run (the last step; every increment).
    final = steps[steps["step"] == 12]
    np.testing.assert_allclose(trials["error_distance_final"], hand(final["error_distance"], "first", final), **close)
    np.testing.assert_allclose(trials["log_likelihood"], hand(steps["log_likelihood_increment"], "sum", steps),
                               rtol=0.0, atol=1e-9)


def test_burn_in_changes_no_filtering_only_what_is_scored(runs):
    with_burn_in, without = runs["burn_in"], runs["none"]
    trials_a, trials_b = with_burn_in.trials, without.trials
    assert (trials_a["cell"] != trials_b["cell"]).all()              # a metric setting: another cell
    assert list(trials_a["filter_seed"]) == list(trials_b["filter_seed"])     # ... on the same stream
    for column in ("log_likelihood", "error_distance_final", "convergence_step", "lost_particles"):
        np.testing.assert_array_equal(trials_a[column], trials_b[column], err_msg=column)
    traced = [c for c in without.steps.columns if c != "cell"]
    pd.testing.assert_frame_equal(with_burn_in.steps[traced], without.steps[traced])
    per_step = [c for c in without.steps_summary.columns if c != "cell"]
    pd.testing.assert_frame_equal(with_burn_in.steps_summary[per_step], without.steps_summary[per_step])
    # Without a burn-in every step is scored.
    assert (trials_b["resample_count"] == _by_trial(without.steps, trials_b, without.steps["resampled"], "sum")).all()
    assert not np.array_equal(trials_a["rmse_position"], trials_b["rmse_position"])


def test_the_summary_has_the_new_columns_after_the_old_ones(runs):
    summary = pd.read_csv(runs["none"].path / "summary.csv")
    columns = list(summary.columns)
    assert columns.index("rms_error_mean_mean") > columns.index("move_acceptance_mean")
    assert columns.index("rms_error_rts_mean_mean") > columns.index("rms_error_mean_mean")
    trials = runs["none"].trials
    means = trials.groupby("cell", sort=False)["rms_error_mean"].mean()
    np.testing.assert_allclose(summary["rms_error_mean_mean"], means.to_numpy(), rtol=1e-12)


def test_scored_steps_is_every_step_without_a_burn_in_whatever_the_times():
    times = np.array([-1.0, 0.0, 1.0, 2.0])                   # recorded data may start before 0
    assert scored_steps(times, 0.0) == slice(None)
    np.testing.assert_array_equal(scored_steps(times, 1.0), [False, False, False, True])


class _Model(SimpleNamespace):
    def times(self):
        return self.dt * np.arange(1, self.steps + 1)


def test_rms_error_mean_is_the_rms_over_components_averaged_over_the_scored_steps():
    random = np.random.default_rng(28)
    trials, steps = 3, 6
    truth = random.normal(size=(trials, steps, 3))
    estimates = truth + random.normal(size=(trials, steps, 3))
    estimates[0, 2, 2] = truth[0, 2, 2] + 2 * np.pi - 0.1       # a heading error of -0.1, once wrapped
    model = _Model(state_names=["x", "y", "heading"], angular_components=[2], full_turn=2 * np.pi,
                   position_components=[0, 1], dt=0.25, steps=steps)
    trace = SimpleNamespace(estimates=estimates, smoothed={})
    for burn_in, first_scored in ((0.0, 0), (0.5, 2), (1.4, 5)):
        columns = rms_error_metrics(MetricInputs(truth=truth, trace=trace, model=model,
                                                 config=MetricsConfig(burn_in=burn_in)))
        for r in range(trials):
            per_step = []
            for k in range(first_scored, steps):
                errors = [estimates[r, k, j] - truth[r, k, j] for j in range(3)]
                errors[2] = (errors[2] + np.pi) % (2 * np.pi) - np.pi
                per_step.append(np.sqrt(sum(e * e for e in errors) / 3))
            assert columns["rms_error_mean"][r] == pytest.approx(sum(per_step) / len(per_step), rel=1e-13)
    # Without the truth: empty.
    empty = rms_error_metrics(MetricInputs(truth=None, trace=trace, model=model, config=MetricsConfig()))
    assert np.isnan(empty["rms_error_mean"]).all()
    # rmse_position is the other quantity: sqrt(mean_k |e_k|^2) over the position's components.
    rmse = rmse_metrics(MetricInputs(truth=truth, trace=trace, model=model, config=MetricsConfig()))
    distance = np.linalg.norm(estimates[..., :2] - truth[..., :2], axis=-1)
    np.testing.assert_allclose(rmse["rmse_position"], np.sqrt(np.mean(distance ** 2, axis=1)), rtol=1e-13)


# -- the per-step log-likelihood increment ------------------------------------------------------

RANDOM_WALK = {"kind": "linear_gaussian", "steps": 15, "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
               "process_noise": {"variance": 0.3}, "measurement_noise": {"variance": 0.8},
               "initial": {"kind": "gaussian", "mean": [0.5], "covariance": [2.0]}}
FILTERS = {"bootstrap": {"particles": 200},
           "bootstrap, ESS rule": {"particles": 200, "ess_threshold": 0.5},
           "auxiliary": {"particles": 200, "auxiliary": True},
           "auxiliary, ESS rule": {"particles": 200, "auxiliary": True, "ess_threshold": 0.5},
           "kf": {"kind": "kf"}, "ekf": {"kind": "ekf"}, "ukf": {"kind": "ukf"},
           "histogram": {"kind": "histogram"}}


def _measurements(model, trials: int, seed: int = 11) -> np.ndarray:
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(seed, seed + trials)))
    return measurements


@pytest.mark.parametrize("name", list(FILTERS))
def test_the_increments_sum_to_the_log_likelihood(name):
    model = pfx.model(**RANDOM_WALK)
    measurements = _measurements(model, 4)
    measurements[1, 6] = np.nan                   # a missing measurement: a predict-only step
    result = pfx.particle_filter(model, **FILTERS[name])(measurements, seed=3)
    increments = result.trace.log_likelihood_increments
    assert increments.shape == (4, 15) and np.isfinite(increments).all()
    np.testing.assert_allclose(increments.sum(axis=1), result.log_likelihood, rtol=0.0, atol=1e-9)
    assert increments[1, 6] == 0.0
    assert (increments[[0, 2, 3], 6] != 0.0).all()


def _joint_measurement_law(model) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of (z_1, ..., z_T) stacked, for x_k = A x_{k-1} + w_k, z_k = H x_k + v_k,
    from the moments of the states: E x_k = A^k m_0, Cov(x_j, x_k) = A^(j-i) Var(x_i) A^(k-i)'
    with i = min(j, k), Var(x_k) = A Var(x_{k-1}) A' + Q."""
    A, H = np.array(model.transition_matrix), np.array(model.measurement_matrix)
    Q, R = model.process_noise.covariance(), model.measurement_noise.covariance()
    steps, m = model.steps, H.shape[0]
    means, variances = [np.asarray(model.initial.mean_vector(), dtype=float)], [model.initial.covariance_matrix()]
    for _ in range(steps):
        means.append(A @ means[-1])
        variances.append(A @ variances[-1] @ A.T + Q)
    mean = np.concatenate([H @ means[k] for k in range(1, steps + 1)])
    covariance = np.zeros((steps * m, steps * m))
    for j in range(1, steps + 1):
        for k in range(1, steps + 1):
            i = min(j, k)
            block = (np.linalg.matrix_power(A, j - i) @ variances[i] @ np.linalg.matrix_power(A, k - i).T)
            covariance[(j - 1) * m:j * m, (k - 1) * m:k * m] = H @ block @ H.T + (R if j == k else 0.0)
    return mean, covariance


def test_the_kalman_increments_are_the_exact_conditional_log_densities():
    """log p(z_k | z_1:k-1) = log p(z_1:k) - log p(z_1:k-1), each a marginal of the joint
    Gaussian law of the measurements: no recursion in the reference."""
    section = {**MODEL, "steps": 8, "measurement_matrix": [[1.0, 0.0], [0.5, 1.0]],
               "measurement_noise": {"variance": [0.5, 0.3]}}
    model = pfx.model(**section)
    measurements = _measurements(model, 3)
    increments = pfx.particle_filter(model, kind="kf")(measurements).trace.log_likelihood_increments
    mean, covariance = _joint_measurement_law(model)
    m = 2
    for r in range(3):
        z = measurements[r].ravel()
        marginal = [0.0] + [stats.multivariate_normal(mean[:k * m], covariance[:k * m, :k * m]).logpdf(z[:k * m])
                            for k in range(1, model.steps + 1)]
        np.testing.assert_allclose(increments[r], np.diff(marginal), rtol=0.0, atol=1e-9)


def test_steps_csv_and_steps_summary_carry_the_increments(runs):
    steps, summary = runs["none"].steps, runs["none"].steps_summary
    for cell in build_plan(_config(), "none.yaml").cells:      # after a cell's own columns, before the measurements
        columns = steps_columns(cell)
        measured = [f"measurement_{name}" for name in cell.truth_model.measurement_names]
        assert columns[-len(measured) - 1:] == ["log_likelihood_increment", *measured]
    columns = list(summary.columns)       # after a cell's own columns (a smoother's come from its cell)
    start = columns.index("rms_error_velocity") + 1
    assert columns[start:start + 4] == [f"log_likelihood_increment_{s}" for s in ("mean", "std", "ci95_low",
                                                                                  "ci95_high")]
    by_step = steps.groupby(["cell", "step"], sort=False)["log_likelihood_increment"]
    np.testing.assert_allclose(summary["log_likelihood_increment_mean"], by_step.mean().to_numpy(), rtol=1e-12)
    np.testing.assert_allclose(summary["log_likelihood_increment_std"], by_step.std().to_numpy(), rtol=1e-10)
    # The interval is the t-interval, not cut at zero (the increments are mostly negative here).
    half = stats.t.ppf(0.975, TRIALS - 1) * summary["log_likelihood_increment_std"] / np.sqrt(TRIALS)
    np.testing.assert_allclose(summary["log_likelihood_increment_ci95_low"],
                               summary["log_likelihood_increment_mean"] - half, rtol=1e-12)
    assert (summary["log_likelihood_increment_ci95_high"] < 0).any()


def test_a_summary_from_before_the_increments_merges_into_an_empty_column(runs):
    summary = runs["none"].steps_summary
    cell = summary[summary["cell"] == summary["cell"].iloc[0]]          # the particle filter's: no smoother
    cell = cell.drop(columns=[c for c in cell.columns if c.startswith("rms_error_rts_")])
    old = cell.drop(columns=[c for c in cell.columns if c.startswith("log_likelihood_increment")])
    merged = merge_step_summaries(old, cell)
    assert list(merged.columns) == list(cell.columns)
    assert merged["log_likelihood_increment_mean"].isna().all()
    both = merge_step_summaries(cell, cell)
    np.testing.assert_allclose(both["log_likelihood_increment_mean"], cell["log_likelihood_increment_mean"],
                               rtol=1e-12)


# -- the configuration: a burn-in that leaves nothing, and the cell keys ------------------------

@pytest.mark.parametrize("swept", [False, True])
def test_a_burn_in_that_leaves_no_step_is_a_located_error(swept, write_config, pfx_in_process, tmp_path):
    config = tiny_config_dict(model={**MODEL}, outputs={"figures": []})
    if swept:
        config["sweep"] = {"metrics.burn_in": [1.0, 6.0]}           # 6.0: the last step's time
    else:
        config["metrics"] = {"burn_in": 6.0}
    path = write_config(config)
    code, out, err = pfx_in_process("run", path, "--out", tmp_path / "out")
    assert code == 2, out + err
    message = (out + err).strip()
    assert "Traceback" not in message and len(message.splitlines()) == 1
    assert ("sweep.metrics.burn_in" if swept else "metrics.burn_in") in message
    assert "the last step is at time 6" in message and path.name in message


def test_a_config_without_burn_in_keeps_its_cell_keys():
    """The keys of the committed results (results/, made before burn_in existed), and the key
    of an explicit burn_in of 0; a burn-in set is another cell on the same filter stream."""
    config_file = REPO_ROOT / "configs" / "papers" / "han-lee" / "resamplers.yaml"
    committed = pd.read_csv(REPO_ROOT / "results" / "han-lee" / "resamplers" / "summary.csv")
    import yaml

    raw = yaml.safe_load(config_file.read_text())
    plan = build_plan(raw, str(config_file))
    assert [cell.key for cell in plan.cells] == list(committed["cell"])
    explicit = build_plan({**raw, "metrics": {**raw.get("metrics", {}), "burn_in": 0.0}}, str(config_file))
    assert [cell.key for cell in explicit.cells] == list(committed["cell"])
    burnt = build_plan({**raw, "metrics": {**raw.get("metrics", {}), "burn_in": 1.0}}, str(config_file))
    assert not set(cell.key for cell in burnt.cells) & set(committed["cell"])
    assert [cell.filter_key for cell in burnt.cells] == [cell.filter_key for cell in plan.cells]
    assert MetricsConfig().identity() == {key: value for key, value in MetricsConfig().model_dump(mode="json").items()
                                          if key not in ("burn_in", "scores")}
    assert MetricsConfig(scores=True).identity()["scores"] is True          # asked for: another cell


# -- the figure --------------------------------------------------------------------------------

def test_the_increment_figure_finds_a_miscoded_measurement(tmp_path):
    """A random walk recorded at times 1901..1940 with one value miscoded (x10): the figure rings
    that year in every cell and names it in its title; a folder without the increments draws nothing."""
    from pfx.figures.log_likelihood import log_likelihood_increment_over_time
    from pfx.result_folder import ResultFolder

    random = np.random.default_rng(5)
    level = 100.0 + np.cumsum(random.normal(0.0, 3.0, 40))
    flow = level + random.normal(0.0, 5.0, 40)
    flow[22] *= 10                                          # 1923
    data = tmp_path / "record.csv"
    pd.DataFrame({"time": np.arange(1901, 1941), "z1": flow}).to_csv(data, index=False)
    config = tiny_config_dict(
        name="miscoded", trials=6, data={"measurements": str(data)},
        model={"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
               "process_noise": {"variance": 9.0}, "measurement_noise": {"variance": 25.0},
               "initial": {"kind": "gaussian", "mean": [100.0], "covariance": [400.0]}},
        filter={"particles": 300}, arms={"KF": {"kind": "kf"}, "PF": {}},
        outputs={"figures": ["log_likelihood_increment_over_time"], "trace_trials": 0})
    folder = run_plan(build_plan(config, str(tmp_path / "miscoded.yaml")), tmp_path / "run")
    assert (folder / "figures" / "log_likelihood_increment_over_time.png").exists()
    summary = pd.read_csv(folder / "steps_summary.csv")
    lowest = summary.loc[summary.groupby("cell")["log_likelihood_increment_mean"].idxmin(), "time"]
    assert set(lowest) == {1923.0}
    figure = log_likelihood_increment_over_time(ResultFolder(folder))
    assert "lowest: t = 1923" in figure._suptitle.get_text()
    rings = [line for axes in figure.axes for line in axes.lines if line.get_marker() == "o"]
    assert sorted(float(ring.get_xdata()[0]) for ring in rings) == [1923.0, 1923.0]
    # A folder written before the increments: nothing to draw.
    summary.drop(columns=[c for c in summary.columns if c.startswith("log_likelihood_increment")]).to_csv(
        folder / "steps_summary.csv", index=False)
    assert log_likelihood_increment_over_time(ResultFolder(folder)) is None
