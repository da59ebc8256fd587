"""KLD-sampling (adaptive particle count), augmented MCL (particle injection) and the kidnapped robot."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import tiny_config_dict
from pydantic import ValidationError
from scipy import stats

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.filters.particle.adaptive import KLDSampling, kld_bound, kld_count, occupied_bins_by_prefix
from pfx.filters.particle.cloud import active_uniform, posterior_mean
from pfx.filters.particle.engine import ParticleFilter, Rows
from pfx.filters.particle.injection import AugmentedMCL, injection_probability, observed_averages
from pfx.filters.particle.kernel import Carried, Prediction, StageClouds, StepOutputs
from pfx.filters.particle.recorders import Recording, SpreadCriterion
from pfx.models.planar_robot import PlanarRobot
from pfx.models.simulation import simulate_truth
from pfx.models.sonar_mcl import FreeSpaceLaw, SonarMCL
from pfx.numerics.log_weights import effective_sample_size
from pfx.numerics.seeding import TrialStreams

SQUARE = [[0.0, 0.0, 100.0, 0.0], [100.0, 0.0, 100.0, 100.0], [100.0, 100.0, 0.0, 100.0], [0.0, 100.0, 0.0, 0.0]]


def _model(**changes) -> SonarMCL:
    settings = dict(walls=SQUARE, route=["move 30", "turn 90", "move 20", "turn -90"],
                    initial={"kind": "point", "state": [50.0, 50.0, 0.0]})
    settings.update(changes)
    return SonarMCL(**settings)


# -- KLD-sampling: the bound and the count ---------------------------------------------------------

def test_kld_bound_matches_hand_computed_values():
    # k = 2, epsilon 0.05, delta 0.01: z = 2.3263479, (k-1)/(2 eps) = 10,
    # [1 - 2/9 + sqrt(2/9) z]^3 = (0.7777778 + 0.4714045 * 2.3263479)^3 = 1.8744404^3 = 6.5857731
    assert kld_bound(2, 0.05, 0.01) == pytest.approx(65.857731, rel=1e-7)
    # k = 11, epsilon 0.1, delta 0.05: z = 1.6448536, 10 / 0.2 = 50,
    # [1 - 0.0222222 + 0.1490712 * 1.6448536]^3 = 1.2229781^3 = 1.8291782
    assert kld_bound(11, 0.1, 0.05) == pytest.approx(91.458910, rel=1e-6)
    assert kld_bound(1, 0.05, 0.01) == 0.0            # one occupied bin: nothing beyond min_particles
    assert kld_bound(0, 0.05, 0.01) == 0.0


def test_kld_bound_is_the_wilson_hilferty_chi_square_quantile():
    # n(k) = chi2_{k-1, 1-delta} / (2 epsilon) in Wilson-Hilferty's approximation, whose relative
    # error at the 0.99 quantile is 1.3e-3 at k - 1 = 10 and shrinks roughly as 1/(k-1)
    for k, tolerance in ((11, 2e-3), (101, 2e-4), (1001, 2e-5)):
        exact = stats.chi2.ppf(0.99, k - 1) / (2 * 0.05)
        assert kld_bound(k, 0.05, 0.01) == pytest.approx(exact, rel=tolerance)


def test_occupied_bins_by_prefix_counts_distinct_bins_in_draw_order():
    generator = np.random.default_rng(5)
    states = generator.uniform(-3.0, 3.0, size=(4, 300, 2))
    occupied = occupied_bins_by_prefix(states, [1.0, 0.5])
    for row in range(4):
        seen, expected = set(), []
        for x, y in states[row]:
            seen.add((math.floor(x / 1.0), math.floor(y / 0.5)))
            expected.append(len(seen))
        np.testing.assert_array_equal(occupied[row], expected)


@pytest.mark.parametrize("bins, minimum", [(5, 10), (40, 10), (1, 50)])
def test_kld_count_stops_at_the_bound_of_the_occupied_bins(bins, minimum):
    # draws cycle through `bins` bins: after the first `bins` draws k = bins for good, so the count
    # is the first n >= max(n(bins), min_particles, bins) (the bound is met only once every bin is seen)
    maximum = 5000
    states = (np.arange(maximum) % bins + 0.5)[None, :, None]
    count = kld_count(occupied_bins_by_prefix(states, 1.0), 0.05, 0.01, minimum)
    bound = kld_bound(bins, 0.05, 0.01)
    expected = max(math.ceil(bound), minimum)
    if bins > 1:
        # during the first `bins` draws, k(n) = n and n < n(n) for these settings
        assert all(n < kld_bound(n, 0.05, 0.01) for n in range(2, bins + 1))
    assert count[0] == expected


def test_kld_count_is_capped_at_the_maximum():
    states = np.arange(100.0)[None, :, None]               # every draw a new bin: never enough
    assert kld_count(occupied_bins_by_prefix(states, 1.0), 0.05, 0.01, 10)[0] == 100


def test_adaptive_filter_shrinks_as_the_cloud_localises():
    model = _model()
    truth, measurements = simulate_truth(model, TrialStreams.from_seeds([1, 2]))
    adaptive = KLDSampling(bin_size=[5.0, 5.0, 10.0], min_particles=50)
    trace = pfx.particle_filter(model, prior=FreeSpaceLaw(walls=SQUARE), particles=3000, resampler="systematic", ess_threshold=1.0, adaptive=adaptive)(measurements, seeds=[3, 4]).trace
    counts = trace.particle_counts
    assert (counts[:, 0] == 3000).all()                # the prior: the maximum
    assert (counts >= 50).all() and (counts <= 3000).all()
    assert (counts[:, -1] < 3000).all()


# -- inactive particles never count ----------------------------------------------------------------

def _filter(model, particles, adaptive, streams, recording=Recording()):
    measurements = np.array([[[40.0]]])
    bound = pfx.particle_filter(model, prior=FreeSpaceLaw(walls=SQUARE), particles=particles, adaptive=adaptive).planned.bound
    return ParticleFilter(bound, measurements, streams, recording)


def test_inactive_particles_never_affect_the_estimate_or_the_diagnostics():
    model = _model()
    active, maximum = 300, 1000
    cloud = FreeSpaceLaw(walls=SQUARE).sample(TrialStreams.from_seeds([9]), (active,))
    # the spread criterion (every row), the spread and the standard deviations (the one traced row)
    recording = Recording(spread_criterion=SpreadCriterion(radius=20.0, weighted=False), trace_rows=np.arange(1))
    fixed = _filter(model, active, None, TrialStreams.from_seeds([1]), recording)
    fixed.state = cloud.copy()
    adaptive = _filter(model, maximum, KLDSampling(bin_size=5.0), TrialStreams.from_seeds([1]), recording)
    adaptive.state = np.concatenate([cloud, np.full((1, maximum - active, 3), 1e6)], axis=1)  # far outside
    adaptive.active = np.array([active])
    adaptive.log_weights, adaptive.weights = active_uniform(adaptive.active, maximum)
    for run in (fixed, adaptive):        # step 1's weight update and estimate, without moving or resampling
        run.record("prior", 0)
        counts = run.active
        prediction = Prediction(state=run.state, log_weights=run.log_weights, weights=run.weights, adjustment=None,
                                likelihood=None, lost=None, failures=None)
        log_weights, weights, increment, degenerate, _ = run.update_weights(prediction, run.step_inputs(1), counts)
        outputs = StepOutputs(estimate=posterior_mean(model, weights, run.state), ess=effective_sample_size(weights),
                              resampled=np.zeros(1, dtype=bool), degenerate=degenerate, increment=increment,
                              failures=None, particle_counts=counts)
        clouds = StageClouds(predicted=run.state, predicted_log_weights=run.log_weights, predicted_weights=run.weights,
                             adjustment=None, log_weights=log_weights, weights=weights, estimate=outputs.estimate,
                             resampled=run.state, resampled_log_weights=log_weights, resampled_weights=weights,
                             active=counts)
        run.keep(1, outputs, clouds)       # the spread and the share within the radius, as after resampling
        run.trace.log_likelihood = increment
    for name in ("estimates", "ess", "log_likelihood", "spread", "within_radius", "standard_deviations"):
        np.testing.assert_allclose(getattr(adaptive.trace, name), getattr(fixed.trace, name), rtol=1e-12,
                                   err_msg=name)
    assert (adaptive.weights[0, active:] == 0.0).all()


# -- augmented MCL -------------------------------------------------------------------------------

def test_no_injection_while_the_fast_average_stays_above_the_slow_one():
    # a constant likelihood c: w_slow = c (1 - (1 - a_slow)^k) <= w_fast = c (1 - (1 - a_fast)^k)
    settings = AugmentedMCL(alpha_slow=0.05, alpha_fast=0.3)
    log_slow = log_fast = np.full(3, -np.inf)
    for log_average in np.log([1e-300, 0.2, 3.0]) * np.ones((50, 3)):
        log_slow, log_fast = observed_averages(settings, log_slow, log_fast, log_average)
        assert (injection_probability(log_slow, log_fast) == 0.0).all()


def test_no_injection_in_a_filter_with_a_constant_likelihood():
    model = _model(measurement_noise={"variance": 1e12})      # the reading says nothing: L_k ~ constant
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([1]))
    trace = pfx.particle_filter(model, prior=FreeSpaceLaw(walls=SQUARE), particles=500, resampler="systematic", ess_threshold=1.0, injection=AugmentedMCL(alpha_slow=0.1, alpha_fast=0.5))(measurements, seeds=[2]).trace
    assert (trace.injected == 0).all()


def test_injection_replaces_active_particles_at_the_stated_rate():
    # w_fast / w_slow held at 0.7: each active particle is replaced with probability 0.3
    trials, maximum, active = 40, 2000, 1500
    model = _model()
    prior = FreeSpaceLaw(walls=[[w + 1.0 for w in wall] for wall in SQUARE])   # (0, 0) is outside its free
    bound = pfx.particle_filter(model, prior=prior, particles=maximum,            # space: a replaced particle
                                injection=AugmentedMCL(alpha_slow=0.1, alpha_fast=0.5)).planned.bound   # shows
    run = ParticleFilter(bound, np.zeros((trials, 1, model.measurement_dimension)), TrialStreams.from_seeds(range(trials)))
    after = Carried(log_slow=np.zeros(trials), log_fast=np.full(trials, np.log(0.7)), active=np.full(trials, active))
    cloud, ancestors, injected = run.inject(Rows(np.arange(trials), trials), np.zeros((trials, maximum, 3)),
                                            np.broadcast_to(np.arange(maximum), (trials, maximum)), after, run.random)
    marked = ancestors == -1                               # a prior draw has no ancestor
    replaced = (cloud != 0.0).any(axis=-1)
    assert not replaced[:, active:].any()                  # inactive particles: never
    np.testing.assert_array_equal(replaced, marked)
    np.testing.assert_array_equal(injected, marked.sum(axis=1))
    rate, draws = injected.sum() / (trials * active), trials * active
    standard_error = math.sqrt(0.3 * 0.7 / draws)           # binomial
    assert abs(rate - 0.3) < 4 * standard_error


def test_alpha_slow_must_be_less_than_alpha_fast():
    with pytest.raises(ValidationError, match="alpha_slow: must be less than alpha_fast"):
        AugmentedMCL(alpha_slow=0.5, alpha_fast=0.5)


@pytest.mark.parametrize("kind, key, value", [
    ("sis", "adaptive", {"kind": "kld", "bin_size": 1.0}),
    ("sis", "injection", {"kind": "augmented", "alpha_slow": 0.01, "alpha_fast": 0.1}),
    ("kf", "adaptive", {"kind": "kld", "bin_size": 1.0}),
])
def test_adaptive_and_injection_are_refused_without_resampling(kind, key, value):
    raw = tiny_config_dict()
    raw["filter"] = {**raw.get("filter", {}), "kind": kind, key: value}
    with pytest.raises(ConfigError, match=f"{key}: the {kind} filter has no resampling stage") as error:
        build_plan(raw, "config.yaml")
    assert "\n" not in str(error.value).strip()


# -- the kidnapped robot ---------------------------------------------------------------------------

@pytest.mark.parametrize("make, to", [
    (lambda **kidnap: _model(**kidnap), [20.0, 80.0, 270.0]),
    (lambda **kidnap: PlanarRobot(**kidnap), [3.0, -2.0, 1.0]),
])
def test_kidnap_moves_the_truth_at_its_step_only(make, to):
    plain, kidnapped = make(), make(kidnap={"step": 2, "to": to})
    seeds = [11, 12, 13]
    states, readings = simulate_truth(plain, TrialStreams.from_seeds(seeds))
    moved, moved_readings = simulate_truth(kidnapped, TrialStreams.from_seeds(seeds))
    np.testing.assert_array_equal(moved[:, :2], states[:, :2])      # before: the same draws, the same truth
    np.testing.assert_allclose(moved[:, 2], np.tile(to, (3, 1)))     # at step 2: carried to `to`
    np.testing.assert_array_equal(moved_readings[:, 0], readings[:, 0])
    assert not np.allclose(moved[:, 3:], states[:, 3:])              # after: it goes on from there


def test_the_filter_is_not_told_of_the_kidnapping():
    plain, kidnapped = _model(), _model(kidnap={"step": 2, "to": [20.0, 80.0, 270.0]})
    _, measurements = simulate_truth(kidnapped, TrialStreams.from_seeds([1]))
    traces = [pfx.particle_filter(model, prior=FreeSpaceLaw(walls=SQUARE), particles=200, resampler="systematic", ess_threshold=1.0)(measurements, seeds=[2]).trace
              for model in (plain, kidnapped)]
    np.testing.assert_array_equal(traces[0].estimates, traces[1].estimates)


def test_kidnap_step_past_the_route_is_refused():
    with pytest.raises(ValidationError, match="kidnap.step: 9 is past the last step"):
        _model(kidnap={"step": 9, "to": [20.0, 80.0, 0.0]})
