"""Observation intervals: a model advancing ``substeps`` propagate calls between two measurements
(pfx/models/base.py, docs/plugins.md "Observation intervals").

The headline: a linear-Gaussian model integrated by Euler substeps, x <- A x + w per substep
with w ~ N(0, Q), observed every s = 5 substeps, is exactly the linear-Gaussian model
x_k = A^s x_(k-1) + w_k with Q_s = sum_j A^j Q A^j' between measurements. pfx's EKF and UKF on
it equal an exact Kalman filter of that model, written here; the particle filter's likelihood
estimate is unbiased for its likelihood; the truth's increment over a step has covariance Q_s.
Then: substeps: 1 changes nothing; accumulating components reset at each step; a propagate
with a ``time`` parameter sees the substeps' start times; the algorithms that need a transition
density refuse noisy substeps in one line.
"""

from __future__ import annotations

import math
import types
from typing import ClassVar, Literal

import numpy as np
import pandas as pd
import pytest
from conftest import tiny_config_dict, write_config_file
from pydantic import StrictFloat

from pfx.config.plan import build_plan
from pfx.config.schema import config_schema
from pfx.filters import run_filter
from pfx.filters.kalman.unscented import UnscentedParameters
from pfx.laws.initial import GaussianLaw, PointLaw
from pfx.laws.noise import Noise
from pfx.laws.transition_density import TransitionDensityUnavailable
from pfx.models.base import Model, bind_law
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams

PREFIX = "pfx: error: "
DRIFT = np.array([[0.0, 1.0], [-1.0, -0.2]])       # a damped oscillator, dx/dt = M x
OBSERVATION = np.array([[1.0, 0.0]])                # its position is measured


class EulerOscillator(Model):
    """x <- (I + h M) x + w per substep of h = dt / substeps, z = x_1 + v: linear and Gaussian."""

    kind: Literal["euler_oscillator"] = "euler_oscillator"
    integrates_substeps: ClassVar[bool] = True

    @property
    def state_names(self):
        return ("x", "v")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def substep_matrix(self) -> np.ndarray:
        return np.eye(2) + self.substep_duration * DRIFT

    def propagate(self, state, control, noise):
        return state @ self.substep_matrix.T + noise

    def measurement_mean(self, state):
        return state @ OBSERVATION.T

    def transition_jacobian(self, state, control):
        return np.broadcast_to(self.substep_matrix, state.shape + (2,))

    def process_noise_jacobian(self, state, control):
        return np.broadcast_to(np.eye(2), state.shape + (2,))

    def measurement_jacobian(self, state):
        return np.broadcast_to(OBSERVATION, state.shape[:-1] + OBSERVATION.shape)


def oscillator(substeps: int = 5, steps: int = 20, **changes) -> EulerOscillator:
    parameters = dict(steps=steps, dt=0.5, substeps=substeps,
                      process_noise=Noise(variance=[[0.02, 0.005], [0.005, 0.04]]),
                      measurement_noise=Noise(variance=0.1),
                      initial=GaussianLaw(mean=[1.0, 0.0], covariance=[0.3, 0.2]))
    parameters.update(changes)
    return EulerOscillator(**parameters)


def step_law(model) -> tuple[np.ndarray, np.ndarray]:
    """A^s and Q_s = sum_{j<s} A^j Q A^j': the exact law of a whole step."""
    A, Q = model.substep_matrix, model.process_noise.covariance()
    power, covariance = np.eye(2), np.zeros((2, 2))
    for _ in range(model.substeps):
        covariance = covariance + power @ Q @ power.T
        power = A @ power
    return power, covariance


def exact_kalman(measurements, A, Q, H, R, m0, P0):
    """The textbook Kalman filter, one trial at a time: (means, covariances, log-likelihoods)."""
    trials, steps, _ = measurements.shape
    means, covariances = np.empty((trials, steps, 2)), np.empty((trials, steps, 2, 2))
    log_likelihood = np.zeros(trials)
    for r in range(trials):
        m, P = np.array(m0, dtype=float), np.array(P0, dtype=float)
        for k in range(steps):
            m, P = A @ m, A @ P @ A.T + Q
            S = H @ P @ H.T + R
            gain = P @ H.T @ np.linalg.inv(S)
            innovation = measurements[r, k] - H @ m
            log_likelihood[r] -= 0.5 * (math.log(2 * math.pi) + np.linalg.slogdet(S)[1]
                                        + innovation @ np.linalg.solve(S, innovation))
            m, P = m + gain @ innovation, (np.eye(2) - gain @ H) @ P
            means[r, k], covariances[r, k] = m, P
    return means, covariances, log_likelihood


def exact_reference(model, measurements):
    A, Q = step_law(model)
    prior = model.initial
    return exact_kalman(measurements, A, Q, OBSERVATION, model.measurement_noise.covariance(),
                        prior.mean_vector(), prior.covariance_matrix())


def prior_of(model):
    return bind_law(model.default_prior(), model.state_dimension, "initial")


# -- the headline: observed every 5 substeps = the exact Kalman filter of A^5, Q_5 ----------------

def test_step_law_differs_from_one_substep():
    """The reference is not trivially the one-substep law: Q_5 is about five times Q."""
    model = oscillator()
    A, Q5 = step_law(model)
    assert np.allclose(np.diag(Q5) / np.diag(model.process_noise.covariance()), 5.0, rtol=0.2)
    assert not np.allclose(A, model.substep_matrix, atol=0.1)


@pytest.mark.parametrize("kind, settings", [
    ("ekf", types.SimpleNamespace()),
    ("ukf", types.SimpleNamespace(unscented=UnscentedParameters(alpha=1.0, beta=0.0, kappa=1.0))),
])
def test_gaussian_filters_equal_the_exact_kalman_filter(kind, settings):
    """The EKF predicts substep by substep with the analytic F = A, L = I, which is the exact
    A^5, Q_5 in another order of operations; the UKF (alpha = 1) is exact for a linear map.
    Round-off only: 1e-10 relative (measured <= 1e-15)."""
    model = oscillator()
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(30, 36)))
    means, covariances, log_likelihood = exact_reference(model, measurements)
    trace = run_filter(kind, model, measurements, None, settings=settings, prior=prior_of(model))
    np.testing.assert_allclose(trace.estimates, means, rtol=1e-10, atol=1e-10 * np.abs(means).max())
    np.testing.assert_allclose(trace.covariances, covariances, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(trace.log_likelihood, log_likelihood, rtol=1e-10)


def test_rts_smoother_after_ekf_is_the_exact_smoother():
    """The EKF's RTS smoother with the step Jacobian F = A^5 is the exact RTS smoother of the
    step law (written here on the exact filter's output)."""
    model = oscillator(steps=12)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([8, 9]))
    means, covariances, _ = exact_reference(model, measurements)
    A, Q = step_law(model)
    smoothed = means.copy()
    for k in range(means.shape[1] - 2, -1, -1):
        for r in range(len(means)):
            predicted_covariance = A @ covariances[r, k] @ A.T + Q
            gain = covariances[r, k] @ A.T @ np.linalg.inv(predicted_covariance)
            smoothed[r, k] = means[r, k] + gain @ (smoothed[r, k + 1] - A @ means[r, k])
    FilterConfig = config_schema().FilterConfig
    trace = run_filter("ekf", model, measurements, None, settings=FilterConfig(kind="ekf", smoothers=[{"kind": "rts"}]),
                       prior=prior_of(model))
    np.testing.assert_allclose(trace.smoothed["rts"].means, smoothed, rtol=1e-9, atol=1e-10)


def test_particle_filter_likelihood_is_unbiased_for_the_exact_one():
    """E[exp(log L_hat - log L)] = 1 for the bootstrap filter (Del Moral 2004): over 400 runs
    on one data set, the sample mean of the ratio is 1 within 4 standard errors (measured:
    0.997, standard error 0.015). Noise drawn once per step instead of per substep (Q instead
    of Q_5) has log L 0.72 lower on these data (measured with exact_kalman), a ratio of 0.49:
    33 standard errors away."""
    model = oscillator(steps=15)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([77]))
    _, _, exact = exact_reference(model, measurements)
    runs = 400
    FilterConfig = config_schema().FilterConfig
    trace = run_filter("particle", model, np.repeat(measurements, runs, axis=0),
                       TrialStreams.from_seeds(range(500, 500 + runs)),
                       settings=FilterConfig(kind="particle", particles=300), prior=prior_of(model))
    ratio = np.exp(trace.log_likelihood - exact[0])
    standard_error = ratio.std(ddof=1) / math.sqrt(runs)
    assert abs(ratio.mean() - 1.0) < 4.0 * standard_error, (ratio.mean(), standard_error)
    assert standard_error < 0.05                   # the test has power: the ratio is well estimated


def test_truth_increment_has_the_covariance_of_the_noise_over_the_substeps():
    """x_1 - A^5 x_0 from a fixed x_0, over 4000 trials: sample mean 0 and sample covariance
    Q_5 within 4 standard errors per entry (Var of a sample covariance entry:
    (Q_ii Q_jj + Q_ij^2) / n; of a mean: Q_ii / n)."""
    start = np.array([1.0, -0.5])
    model = oscillator(steps=1, initial=PointLaw(state=start.tolist()))
    trials = 4000
    states, _ = simulate_truth(model, TrialStreams.from_seeds(range(trials)))
    A, Q5 = step_law(model)
    increments = states[:, 1] - start @ A.T
    sample = np.cov(increments.T)
    error = np.sqrt((np.outer(np.diag(Q5), np.diag(Q5)) + Q5 ** 2) / trials)
    assert (np.abs(sample - Q5) < 4 * error).all(), (sample, Q5)
    assert (np.abs(increments.mean(axis=0)) < 4 * np.sqrt(np.diag(Q5) / trials)).all()
    once = model.process_noise.covariance()                   # one draw per step would give ~Q
    assert (np.abs(np.diag(sample) - np.diag(once)) > 10 * np.diag(error)).all()


def test_density_is_unavailable_for_noisy_substeps_and_the_mean_composes_them():
    model = oscillator()
    density = model.transition_density()
    assert isinstance(density, TransitionDensityUnavailable)
    assert "5 noisy substeps between measurements" in density.reason
    A, _ = step_law(model)
    previous = np.array([[[0.3, -1.2], [2.0, 0.5]]])
    np.testing.assert_allclose(model.mean_transition(previous, 3), previous @ A.T, rtol=1e-14)
    assert not isinstance(oscillator(substeps=1).transition_density(), ValueError)


# -- substeps: 1 changes nothing ----------------------------------------------------------------------

def test_one_substep_is_one_propagate_call_with_one_draw():
    """transition with substeps 1 draws exactly what it drew before substeps existed: one noise
    sample, then propagate (bit for bit)."""
    model = oscillator(substeps=1)
    state = np.array([[[0.3, -1.2], [2.0, 0.5], [1.0, 1.0]]])
    moved = model.transition(state, 2, TrialStreams.from_seeds([4]))
    noise = model.process_noise.sample(TrialStreams.from_seeds([4]), state.shape[1:-1])
    assert np.array_equal(moved, model.propagate(state, None, noise))


def test_substeps_one_written_out_keeps_the_cell_key_and_every_number(pfx_in_process, tmp_path):
    plain = tiny_config_dict()
    written = tiny_config_dict()
    written["model"]["substeps"] = 1
    assert build_plan(plain, "c.yaml").cells[0].key == build_plan(written, "c.yaml").cells[0].key
    outputs = {}
    for name, data in (("plain", plain), ("written", written)):
        data["outputs"] = {"trace_trials": 2, "figures": []}
        config = write_config_file(tmp_path, data, f"{name}.yaml")
        result = pfx_in_process("run", config, "--out", tmp_path / name, cwd=tmp_path)
        assert result.returncode == 0, result.output
        outputs[name] = pd.read_csv(tmp_path / name / "steps.csv")
    pd.testing.assert_frame_equal(outputs["plain"], outputs["written"])


# -- accumulating components ----------------------------------------------------------------------------

class Counter(Model):
    """x grows by rate h per substep; c accumulates x h over the substeps of each step (an
    integral of x over the interval), reset at each measurement; z = c + v."""

    kind: Literal["counter"] = "counter"
    integrates_substeps: ClassVar[bool] = True
    rate: StrictFloat = 2.0

    @property
    def state_names(self):
        return ("x", "c")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def accumulating_components(self):
        return (1,)

    def propagate(self, state, control, noise):
        h = self.substep_duration
        x, c = state[..., 0], state[..., 1]
        return np.stack([x + self.rate * h, c + x * h], axis=-1) + noise

    def measurement_mean(self, state):
        return state[..., 1:]


def counter(**changes) -> Counter:
    parameters = dict(steps=3, dt=1.0, substeps=4, process_noise=Noise(variance=0.0),
                      measurement_noise=Noise(variance=1.0), initial=PointLaw(state=[1.0, 100.0]))
    parameters.update(changes)
    return Counter(**parameters)


def test_accumulators_reset_at_each_step_and_accumulate_within_it():
    """x_k = 1 + 2 k; over step k, c = sum_j h x^(j-1), x^(j-1) = x_(k-1) + 2 h (j-1), h = 1/4:
    c_k = x_(k-1) + 2 h^2 (0 + 1 + 2 + 3) = x_(k-1) + 0.75, never carrying the 100 it started with."""
    model = counter()
    states, _ = simulate_truth(model, TrialStreams.from_seeds([1]))
    x_before = 1.0 + 2.0 * np.arange(3)
    np.testing.assert_allclose(states[0, 1:, 0], x_before + 2.0, rtol=1e-14)
    np.testing.assert_allclose(states[0, 1:, 1], x_before + 0.75, rtol=1e-14)
    np.testing.assert_allclose(model.mean_transition(states[:, :1], 1)[0, 0], [3.0, 1.75], rtol=1e-14)

    # The EKF from N([1, 100], diag(1, 50)): the reset gives N([1, 0], diag(1, 0)); four
    # substeps of F = [[1, 0], [h, 1]] give the prediction N([3, 1.75], [[1, 1], [1, 1]]), and
    # z_1 = 0 (R = 1: S = 2, K = [1/2, 1/2]) the posterior N([2.125, 0.875], [[.5, .5], [.5, .5]]).
    # Without the reset c's mean would stay near 100 and its variance near 50.
    ekf = run_filter("ekf", model, np.zeros((1, 3, 1)), None, settings=types.SimpleNamespace(),
                     prior=bind_law(GaussianLaw(mean=[1.0, 100.0], covariance=[1.0, 50.0]), 2, "initial"))
    np.testing.assert_allclose(ekf.estimates[0, 0], [2.125, 0.875], rtol=1e-8)     # F by finite differences
    np.testing.assert_allclose(ekf.covariances[0, 0], np.full((2, 2), 0.5), rtol=1e-8)
    # the UKF (exact for these linear maps) the same, from the reset rows of its square root;
    # the rank-one predicted covariances between substeps take a relative jitter of 1e-12, which
    # moves the moments by about that (measured 4e-13): 1e-10
    unscented = types.SimpleNamespace(unscented=UnscentedParameters(alpha=1.0, beta=0.0, kappa=1.0))
    ukf = run_filter("ukf", model, np.zeros((1, 3, 1)), None, settings=unscented,
                     prior=bind_law(GaussianLaw(mean=[1.0, 100.0], covariance=[1.0, 50.0]), 2, "initial"))
    np.testing.assert_allclose(ukf.estimates[0, 0], [2.125, 0.875], rtol=1e-10)
    np.testing.assert_allclose(ukf.covariances[0, 0], np.full((2, 2), 0.5), rtol=1e-10)


def test_accumulating_components_are_checked():
    class Wrong(Counter):
        @property
        def accumulating_components(self):
            return (2,)
    with pytest.raises(ValueError, match=r"accumulating_components returned \(2,\)"):
        Wrong(**counter().model_dump(exclude={"kind"})).check_contract(TrialStreams.from_seeds([1, 2]))


# -- time at the substeps' starts ------------------------------------------------------------------------

class Clock(EulerOscillator):
    """The oscillator, recording the times its propagate and transition Jacobian are given."""

    kind: Literal["clock"] = "clock"
    seen: ClassVar[list] = []
    jacobian_seen: ClassVar[list] = []

    def propagate(self, state, control, noise, time):
        Clock.seen.append(time)
        return super().propagate(state, control, noise)

    def transition_jacobian(self, state, control, time):
        Clock.jacobian_seen.append(time)
        return super().transition_jacobian(state, control)


def test_propagate_is_given_the_time_at_each_substep_start():
    model = Clock(**oscillator(substeps=4, steps=3, dt=2.0).model_dump(exclude={"kind"}))
    Clock.seen.clear()
    simulate_truth(model, TrialStreams.from_seeds([3]))
    assert Clock.seen == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5]
    substep_starts = list(Clock.seen)
    Clock.seen.clear()
    Clock.jacobian_seen.clear()
    run_filter("ekf", model, np.zeros((1, 3, 1)), None, settings=types.SimpleNamespace(), prior=prior_of(model))
    assert Clock.jacobian_seen == substep_starts and Clock.seen == substep_starts
    model.use_recorded_times(np.array([10.0, 12.0, 14.0]))      # t_0 = t_1 - dt
    assert [model.substep_time(k, 0) for k in (1, 2, 3)] == [8.0, 10.0, 12.0]
    assert model.substep_time(2, 3) == 11.5
    assert list(model.times()) == [10.0, 12.0, 14.0]


def test_a_run_with_substeps_writes_the_measurement_times(pfx_in_process, tmp_path):
    """The filters that take substeps run from a config (the auxiliary filter's look-ahead is
    the noise-free step, mean_transition); steps.csv's times are the measurement times."""
    (tmp_path / "oscillator.py").write_text(PLUGIN)
    arms = {"pf": {"kind": "particle"}, "apf": {"kind": "particle", "auxiliary": True}, "sis": {"kind": "sis"},
            "ekf": {"kind": "ekf", "smoothers": [{"kind": "rts"}]}, "ukf": {"kind": "ukf"}}
    config = write_config_file(tmp_path, plugin_config(arms=arms))
    result = pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    trials = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert len(trials) == 5 * 2 and np.isfinite(trials["rmse_position"]).all()
    steps = pd.read_csv(tmp_path / "out" / "steps.csv")
    np.testing.assert_allclose(sorted(set(steps["time"])), 0.5 * np.arange(1, 9), rtol=1e-12)


# -- refusals -----------------------------------------------------------------------------------------

PLUGIN = '''from typing import ClassVar, Literal
import numpy as np
import pfx

@pfx.register_model
class NoisyOscillator(pfx.Model):
    """An Euler-integrated damped oscillator with noise on every substep; z = x + v."""
    kind: Literal["noisy_oscillator"] = "noisy_oscillator"
    integrates_substeps: ClassVar[bool] = True

    @property
    def state_names(self): return ("x", "v")
    @property
    def measurement_dimension(self): return 1
    def propagate(self, state, control, noise):
        h = self.substep_duration
        x, v = state[..., 0], state[..., 1]
        return np.stack([x + h * v, v - h * (x + 0.2 * v)], axis=-1) + noise
    def measurement_mean(self, state): return state[..., :1]
'''


def plugin_config(arms=None, **filter_settings) -> dict:
    extra = {"arms": arms} if arms else {}
    return {**extra, "name": "noisy", "plugins": ["oscillator.py"], "trials": 2, "seed": 3,
            "model": {"kind": "noisy_oscillator", "steps": 8, "dt": 0.5, "substeps": 5,
                      "process_noise": {"variance": [0.01, 0.02]}, "measurement_noise": {"variance": 0.1},
                      "initial": {"kind": "gaussian", "mean": [1.0, 0.0], "covariance": [0.3, 0.2]}},
            "filter": {"particles": 50, **filter_settings} if filter_settings.get("kind", "particle") == "particle"
            else filter_settings, "outputs": {"trace_trials": 2, "figures": []}}


def one_error_line(result) -> str:
    assert result.returncode == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stdout + result.stderr, result.stderr
    return lines[0].removeprefix(PREFIX)


def test_builtin_model_that_does_not_integrate_substeps_is_refused(pfx_in_process, tmp_path):
    data = tiny_config_dict()
    data["model"]["substeps"] = 3
    result = pfx_in_process("run", write_config_file(tmp_path, data), "--out", tmp_path / "out", cwd=tmp_path)
    line = one_error_line(result)
    assert "model.substeps" in line and "integrates_substeps" in line, line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("settings, words", [
    ({"proposal": "locally_optimal"}, "5 noisy substeps between measurements"),
    ({"move": {"kind": "mcmc"}}, "5 noisy substeps between measurements"),
    ({"smoothers": [{"kind": "ffbs", "trajectories": 10}]}, "5 noisy substeps between measurements"),
    ({"kind": "histogram"}, "substeps"),
    ({"kind": "ukf", "smoothers": [{"kind": "rts"}]}, "substeps"),
])
def test_algorithms_needing_a_step_density_refuse_noisy_substeps(pfx_in_process, tmp_path, settings, words):
    (tmp_path / "oscillator.py").write_text(PLUGIN)
    config = write_config_file(tmp_path, plugin_config(**settings))
    line = one_error_line(pfx_in_process("run", config, "--out", tmp_path / "out", cwd=tmp_path))
    assert words in line, line


def test_linear_gaussian_substeps_refused_in_validation():
    with pytest.raises(ValueError, match="@substeps: model linear_gaussian's propagate advances a whole dt"):
        LinearGaussian(transition_matrix=[[1.0]], measurement_matrix=[[1.0]], steps=3, substeps=2)
