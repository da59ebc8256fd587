"""Particle smoothers (pfx/filters/particle/smoothing.py): checked against exact laws.

* The rejection form of FFBS draws from the same law as the O(N^2) form: on a fixed filter
  history, the backward step's index has an exact distribution (computed here in O(N^2)), and
  both samplers' frequencies pass a chi-square test of it, also when the rejection rounds run
  out and the exact draw takes over.
* Every particle smoother's smoothed means and variances on a linear-Gaussian model match the
  Rauch-Tung-Striebel smoother's (the exact ones) within their Monte Carlo error over trials.
* The genealogy smoother is the fixed-lag smoother with a lag of T; the distinct ancestors fall
  back in time; refusals are one line.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy import stats

import pfx
from pfx.filters.particle.smoothing import (
    BackwardSampling,
    FilterHistory,
    RejectionBackwardSampling,
    transition_log_densities,
)
from pfx.models.simulation import simulate_truth
from pfx.numerics.log_weights import normalise_rows
from pfx.numerics.seeding import TrialStreams

SIGNIFICANCE = 1e-3          # a chi-square test at this level fails a correct sampler once in a thousand seeds


def _walk(steps: int = 20, process: float = 0.5, measurement: float = 1.0):
    return pfx.model("linear_gaussian", steps=steps, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                     process_noise={"variance": process}, measurement_noise={"variance": measurement},
                     initial={"kind": "gaussian", "mean": [0.0], "covariance": 2.0})


def _history(model, particles: int, seed: int) -> FilterHistory:
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([seed]))
    bound = pfx.particle_filter(model, particles=particles).planned.bound
    from pfx.filters.particle.recorders import Recording

    trace = bound.run(measurements, TrialStreams.from_seeds([seed + 1]), Recording(history=True, genealogy=True))
    return FilterHistory(trace.particles, trace.log_weights, trace.ancestors)


def _exact_backward_law(model, history: FilterHistory, step: int) -> np.ndarray:
    """P(b_k = i) for the step k = ``step`` - 1 (0-based index ``step - 2``), b_{k+1} ~ w_{k+1}:
    sum_j w_{k+1}^j w_k^i p(x_{k+1}^j | x_k^i) / sum_i' (...)."""
    t = step - 2
    following, current = history.particles[:, t + 1], history.particles[:, t]
    logits = history.log_weights[:, t][:, None, :] + transition_log_densities(model, following, current, step)
    _, conditional, _ = normalise_rows(logits[0])                      # (N following, N current)
    return np.exp(history.log_weights[0, t + 1]) @ conditional


@pytest.mark.parametrize("sampler", [BackwardSampling(trajectories=20_000),
                                     RejectionBackwardSampling(trajectories=20_000),
                                     RejectionBackwardSampling(trajectories=20_000, rounds=1)],
                         ids=["ffbs", "ffbs_rejection", "ffbs_rejection, exact after one round"])
def test_backward_samplers_draw_the_exact_law(sampler):
    """The index drawn at step T-1 by either form, over M trajectories, against its exact law."""
    model = _walk(steps=6)
    history = _history(model, particles=40, seed=11)
    steps = history.particles.shape[1]
    exact = _exact_backward_law(model, history, steps)
    random = TrialStreams.from_seeds([5])
    start = np.sort(random.uniform((sampler.trajectories,)), axis=-1)
    from pfx.filters.particle.resampling import inverse_cdf

    last = inverse_cdf(np.exp(history.log_weights[:, -1]), start)
    following = np.take_along_axis(history.particles[:, -1], last[..., None], axis=1)
    drawn = sampler.step_back(model, following, history.particles[:, -2], history.log_weights[:, -2], steps, random)
    counts = np.bincount(drawn[0], minlength=exact.size)
    expected = exact * sampler.trajectories
    kept = expected >= 5                           # the chi-square approximation's rule of thumb
    observed = np.append(counts[kept], counts[~kept].sum())
    expectation = np.append(expected[kept], expected[~kept].sum())
    statistic = ((observed - expectation) ** 2 / np.where(expectation > 0, expectation, 1)).sum()
    p_value = stats.chi2.sf(statistic, df=len(observed) - 1)
    assert p_value > SIGNIFICANCE, (p_value, statistic)


def test_genealogy_is_the_fixed_lag_smoother_with_a_lag_of_t():
    model = _walk(steps=15)
    history = _history(model, particles=100, seed=3)
    from pfx.filters.particle.smoothing import FixedLagSmoother, GenealogySmoother

    whole = GenealogySmoother().smooth(history, model, None)
    lagged = FixedLagSmoother(lag=15).smooth(history, model, None)
    np.testing.assert_allclose(whole.means, lagged.means, rtol=1e-12)
    np.testing.assert_allclose(whole.standard_deviations, lagged.standard_deviations, rtol=1e-9, atol=1e-12)
    # a lag of 1 uses the next step's weights: different from the filter and from the whole path
    one = FixedLagSmoother(lag=1).smooth(history, model, None)
    assert not np.allclose(one.means, whole.means)


def test_distinct_ancestors_fall_back_in_time_and_are_n_at_the_end():
    from pfx.analysis.genealogy import distinct_ancestor_counts

    model = _walk(steps=40)
    history = _history(model, particles=200, seed=8)
    counts = distinct_ancestor_counts(history.ancestors[0])
    assert counts[-1] == 200 and (np.diff(counts) >= 0).all() and counts[0] < 20


@pytest.mark.parametrize("settings, words", [
    ({"kind": "sis", "smoothers": ["ffbs"], "move": "regularise"}, "sis never resamples"),
    ({"smoothers": ["genealogy"], "move": "regularise"}, "filter.move (regularise) changes particles"),
    ({"smoothers": ["fixed_lag", "fixed_lag"]}, "fixed_lag appears twice"),
    ({"kind": "histogram", "smoothers": ["ffbs"]}, "no smoother runs after the histogram filter"),
    ({"kind": "ekf", "smoothers": ["ffbs"]}, "the ffbs smoother runs after a particle or sis filter, not ekf"),
])
def test_smoothers_that_cannot_run_are_refused_in_one_line(settings, words):
    model = _walk()
    kind = settings.pop("kind", "particle")
    with pytest.raises(pfx.ConfigError, match=re.escape(words)):
        pfx.particle_filter(model, kind=kind, **settings)


def test_a_model_without_a_transition_density_is_refused_for_backward_sampling():
    robot = pfx.model("planar_robot", steps=5)
    with pytest.raises(pfx.ConfigError, match="ffbs smoother weighs the backward step by the transition density"):
        pfx.particle_filter(robot, smoothers=["ffbs"])


# -- against the exact smoother ------------------------------------------------------------------------

TRIALS, STEPS, PARTICLES = 60, 15, 400
Z_LIMIT = 4.5        # |z| of a mean over trials; 15 steps x 2 moments: P(any |z| > 4.5 | exact) ~ 2e-4


def _rts(model, measurements):
    """The exact smoothed means and variances (R, T, 1): the Kalman filter and its RTS smoother."""
    result = pfx.filter(model, measurements, kind="kf", smoothers=["rts"])
    smoothed = result.smoothed["rts"]
    return smoothed.means, smoothed.standard_deviations ** 2


def _z_scores(estimates: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """Per step: the mean over trials of estimate - exact, in standard errors of that mean."""
    difference = (estimates - exact)[..., 0]
    return difference.mean(axis=0) / (difference.std(axis=0, ddof=1) / np.sqrt(len(difference)))


@pytest.fixture(scope="module", params=["numpy", "jax"])
def linear_runs(request):
    """Each smoother after the filter of each backend (on jax the scan records the clouds and the
    ancestors the smoothers read)."""
    if request.param == "jax":
        pytest.importorskip("jax")
    model = _walk(steps=STEPS)
    truth, measurements = simulate_truth(model, TrialStreams.from_seeds(range(100, 100 + TRIALS)))
    smoothers = [{"kind": "ffbs", "trajectories": 200}, {"kind": "ffbs_rejection", "trajectories": 200},
                 {"kind": "fixed_lag", "lag": 3}, "genealogy"]
    result = pfx.filter(model, measurements, seeds=range(500, 500 + TRIALS), particles=PARTICLES, smoothers=smoothers,
                        backend=request.param)
    return model, measurements, result


@pytest.mark.parametrize("kind", ["ffbs", "ffbs_rejection"])
def test_backward_sampling_matches_the_rts_smoother(linear_runs, kind):
    """Means and variances, every step, within their Monte Carlo error over the trials (each trial
    its own data, its own filter and smoother; the exact smoother on the same data)."""
    model, measurements, result = linear_runs
    means, variances = _rts(model, measurements)
    smoothed = result.smoothed[kind]
    assert np.abs(_z_scores(smoothed.means, means)).max() < Z_LIMIT
    assert np.abs(_z_scores(smoothed.standard_deviations ** 2, variances)).max() < Z_LIMIT


def test_the_fixed_lag_smoother_matches_the_exact_fixed_lag_posterior(linear_runs):
    """A lag of L estimates p(x_k | z_1:k+L): the RTS smoother of the record cut at k + L, exactly."""
    model, measurements, result = linear_runs
    lag, smoothed = 3, result.smoothed["fixed_lag"]
    means, variances = np.empty_like(smoothed.means), np.empty_like(smoothed.means)
    for k in range(1, STEPS + 1):
        end = min(k + lag, STEPS)
        cut = model.model_copy(update={"steps": end})
        cut_means, cut_variances = _rts(cut, measurements[:, :end])
        means[:, k - 1], variances[:, k - 1] = cut_means[:, k - 1], cut_variances[:, k - 1]
    assert np.abs(_z_scores(smoothed.means, means)).max() < Z_LIMIT
    assert np.abs(_z_scores(smoothed.standard_deviations ** 2, variances)).max() < Z_LIMIT


def test_the_genealogy_smoothers_means_match_the_exact_smoother(linear_runs):
    """On a short record (few coalesced lineages) the ancestral paths estimate the smoothed means
    within their Monte Carlo error."""
    model, measurements, result = linear_runs
    means, _ = _rts(model, measurements)
    assert np.abs(_z_scores(result.smoothed["genealogy"].means, means)).max() < Z_LIMIT


def test_on_a_long_record_the_genealogy_collapses_and_backward_sampling_does_not():
    """Path degeneracy: after 150 steps of 100 particles the last particles descend from one or a
    few particles of step 1, so the genealogy smoother's variance there is nearly zero, while
    backward sampling still matches the exact smoothed variance within its Monte Carlo error."""
    model = _walk(steps=150)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(30)))
    result = pfx.filter(model, measurements, seeds=range(900, 930), particles=100,
                        smoothers=["genealogy", {"kind": "ffbs", "trajectories": 200}], genealogy=True)
    _, variances = _rts(model, measurements)
    from pfx.analysis.genealogy import distinct_ancestor_counts

    assert max(distinct_ancestor_counts(row)[0] for row in result.ancestors) <= 5
    genealogy = (result.smoothed["genealogy"].standard_deviations[:, 0, 0] ** 2).mean()
    assert genealogy < 0.2 * variances[0, 0, 0], (genealogy, variances[0, 0, 0])
    ffbs = result.smoothed["ffbs"].standard_deviations[:, :1] ** 2
    assert abs(_z_scores(ffbs, variances[:, :1])[0]) < Z_LIMIT
