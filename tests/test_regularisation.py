r"""The regularised particle filter's move (``move: regularise``, pfx.filters.particle.moves): the
unbiased weighted covariance and its fallback for degenerate weights, the two jitter forms
(every particle, Musso et al.; the duplicates only, DAPPER's), the bandwidth scale and Scott's
bandwidth (DAPPER's reg), the recovery of a collapsed cloud without process noise, the cell keys
of configs that do not use the new settings, and the ``move`` column of trials.csv.

The jitter's covariance against h^2 Sigma (both kernels) is checked statistically in
tests/test_moves.py. Seeds are fixed; tolerances are standard errors derived from theory.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pfx.config.plan import build_plan
from pfx.config.schema import config_schema
from pfx.errors import ConfigError
from pfx.filters.particle.bound import bind_particle_filter
from pfx.filters.particle.engine import ParticleFilter
from pfx.filters.particle.moves import (
    DEGENERATE_WEIGHTS,
    MoveContext,
    Regularisation,
    shared_parents,
    unbiased_weighted_covariance,
    weighted_covariance,
)
from pfx.models import MODELS
from pfx.numerics.seeding import TrialStreams

Z_LIMIT = 4.0          # standard errors: a two-sided miss probability of 6e-5 per check


def reliability_covariance(weights: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """sum_j w_j (x_j - m)(x_j - m)' / (1 - sum_j w_j^2) for one trial, written out term by term."""
    mean = sum(w * x for w, x in zip(weights, cloud))
    total = sum(w * np.outer(x - mean, x - mean) for w, x in zip(weights, cloud))
    return total / (1.0 - sum(w * w for w in weights))


def everyone(weights: np.ndarray) -> np.ndarray:
    return np.ones_like(weights, dtype=bool)


# -- the covariance -------------------------------------------------------------------------------

def test_unbiased_weighted_covariance_is_the_reliability_weights_formula():
    """Random weights and clouds, three trials: the estimator equals the formula summed term by
    term; with equal weights it is numpy's N - 1 sample covariance."""
    setup = np.random.default_rng(31)
    trials, particles, d = 3, 7, 3
    cloud = setup.standard_normal((trials, particles, d)) * [1.0, 3.0, 0.5]
    weights = setup.uniform(size=(trials, particles))
    weights /= weights.sum(axis=-1, keepdims=True)
    estimated = unbiased_weighted_covariance(weights, cloud, everyone(weights))
    for trial in range(trials):
        assert np.allclose(estimated[trial], reliability_covariance(weights[trial], cloud[trial]), rtol=1e-12)

    equal = np.full((trials, particles), 1.0 / particles)
    estimated = unbiased_weighted_covariance(equal, cloud, everyone(equal))
    for trial in range(trials):
        assert np.allclose(estimated[trial], np.cov(cloud[trial].T, ddof=1), rtol=1e-12)


def test_one_weight_holding_the_mass_falls_back_to_the_unweighted_covariance():
    """w = (1, 0, ..., 0): the weighted covariance is 0; the estimator is the cloud's unweighted
    N - 1 covariance instead. The threshold is 1 - max w < 1e-10: just below it the fallback,
    above it the formula (finite, and nothing like the unweighted covariance here)."""
    setup = np.random.default_rng(32)
    particles, d = 9, 2
    cloud = setup.standard_normal((1, particles, d))
    unweighted = np.cov(cloud[0].T, ddof=1)
    one_hot = np.zeros((1, particles))
    one_hot[0, 4] = 1.0
    assert np.all(weighted_covariance(one_hot, cloud) == 0.0)       # what the move used before
    assert np.allclose(unbiased_weighted_covariance(one_hot, cloud, everyone(one_hot))[0], unweighted)

    for rest, falls_back in ((0.5 * DEGENERATE_WEIGHTS, True), (100 * DEGENERATE_WEIGHTS, False)):
        weights = np.full((1, particles), rest / (particles - 1))
        weights[0, 4] = 1.0 - rest
        estimated = unbiased_weighted_covariance(weights, cloud, everyone(weights))[0]
        if falls_back:
            assert np.allclose(estimated, unweighted)
        else:
            assert np.allclose(estimated, reliability_covariance(weights[0], cloud[0]), rtol=1e-5)


def test_the_fallback_uses_the_members_only():
    """Lost or inactive particles (log-weight -inf; their states parked, here at 100) are left
    out of the unweighted covariance; a trial with one member has nothing to estimate: 0."""
    setup = np.random.default_rng(33)
    cloud = setup.standard_normal((2, 8, 2))
    cloud[:, 5:] = 100.0
    members = np.ones((2, 8), dtype=bool)
    members[:, 5:] = False
    members[1, 1:] = False
    weights = np.zeros((2, 8))
    weights[:, 0] = 1.0
    estimated = unbiased_weighted_covariance(weights, cloud, members)
    assert np.allclose(estimated[0], np.cov(cloud[0, :5].T, ddof=1))
    assert np.all(estimated[1] == 0.0)


# -- the move -------------------------------------------------------------------------------------

def context_for(cloud: np.ndarray, weights: np.ndarray, indices: np.ndarray, log_weights=None) -> MoveContext:
    resampled = np.take_along_axis(cloud, indices[..., None], axis=1)
    if log_weights is None:
        with np.errstate(divide="ignore"):
            log_weights = np.log(weights)
    return MoveContext(model=None, step=1, resampled=resampled, cloud=cloud, weights=weights,
                       measurement=np.zeros((cloud.shape[0], 1)), parents=None, indices=indices,
                       log_weights=log_weights)


def test_shared_parents_marks_every_copy_of_a_parent_drawn_twice_or_more():
    """In any order (multinomial resampling does not sort): parents 3 and 0 have several copies."""
    indices = np.array([[3, 0, 1, 3, 5, 0, 3, 2], [0, 1, 2, 3, 4, 5, 6, 7]])
    assert shared_parents(indices).tolist() == [[True, True, False, True, False, True, True, False], [False] * 8]


def test_duplicates_moves_every_copy_of_a_shared_parent_and_no_sole_offspring():
    """jitter: duplicates (DAPPER's nuj) leaves each particle whose parent was drawn once exactly
    where it was, and moves every copy of a parent drawn more than once; with the same stream it
    moves them by the same draws as jitter: all, which moves every particle."""
    setup = np.random.default_rng(34)
    cloud = setup.standard_normal((2, 8, 3))
    weights = setup.uniform(size=(2, 8))
    weights /= weights.sum(axis=-1, keepdims=True)
    indices = np.array([[3, 0, 1, 3, 5, 0, 3, 2], [7, 7, 7, 7, 7, 7, 7, 7]])
    context = context_for(cloud, weights, indices)
    only, _ = Regularisation(jitter="duplicates").apply(context, TrialStreams.from_seeds([1, 2]))
    every, _ = Regularisation().apply(context, TrialStreams.from_seeds([1, 2]))
    unmoved = np.all(only == context.resampled, axis=-1)
    assert unmoved.tolist() == [[False, False, True, False, True, False, False, True], [False] * 8]
    assert not np.any(np.all(every == context.resampled, axis=-1))
    shared = ~unmoved
    assert np.array_equal(only[shared], every[shared])
    # one copy of every parent is NOT kept in place: all three copies of parent 3 moved apart
    assert len({tuple(row) for row in only[0, [0, 3, 6]]}) == 3


def test_bandwidth_scale_multiplies_h_and_scott_is_dappers_bandwidth():
    """h = c h_0. DAPPER's auto_bandw(N, d) = N^(-1/(d+4)) is `scott`; pfx's `optimal` for the
    Gaussian kernel is (4/(d+2))^(1/(d+4)) times it. On the moved cloud, the same draws: the
    displacement scales by c exactly."""
    n, d = 100, 3
    assert Regularisation(bandwidth="scott").bandwidth_for(n, d) == pytest.approx(n ** (-1 / 7))
    assert Regularisation(bandwidth="scott", bandwidth_scale=2.4).bandwidth_for(n, d) == pytest.approx(2.4 * n ** (-1 / 7))
    optimal = Regularisation().bandwidth_for(n, d)
    assert optimal == pytest.approx((4 / 5) ** (1 / 7) * n ** (-1 / 7))
    assert Regularisation(bandwidth_scale=0.9).bandwidth_for(n, d) == pytest.approx(0.9 * optimal)
    assert Regularisation(kernel="epanechnikov", bandwidth_scale=3.0).bandwidth_for(n, d) == pytest.approx(
        3.0 * Regularisation(kernel="epanechnikov").bandwidth_for(n, d))
    assert Regularisation(bandwidth=0.2, bandwidth_scale=0.5).bandwidth_for(n, d) == pytest.approx(0.1)

    setup = np.random.default_rng(35)
    cloud = setup.standard_normal((1, n, d))
    weights = np.full((1, n), 1.0 / n)
    context = context_for(cloud, weights, setup.integers(0, n, size=(1, n)))
    plain, _ = Regularisation().apply(context, TrialStreams.from_seeds([4]))
    scaled, _ = Regularisation(bandwidth_scale=2.5).apply(context, TrialStreams.from_seeds([4]))
    assert np.allclose(scaled - context.resampled, 2.5 * (plain - context.resampled), rtol=1e-12)


def test_a_cloud_with_all_the_weight_on_one_particle_is_spread_again():
    """All the weight on one particle (the others' log-weights -1e5: finite, their weights 0 in
    floating point), every resampled particle its copy: the move used to spread them with the
    weighted covariance, 0, so they stayed equal. Now they spread with h^2 times the cloud's
    unweighted covariance S: the mean square displacement along a direction a is h^2 a' S a
    with standard error h^2 a' S a sqrt(2 / n) (Gaussian kernel)."""
    setup = np.random.default_rng(36)
    n, d = 20_000, 2
    cloud = setup.standard_normal((1, n, d)) @ np.array([[2.0, 0.0], [0.7, 0.5]]).T
    log_weights = np.full((1, n), -1e5)
    log_weights[0, 17] = 0.0
    context = context_for(cloud, np.exp(log_weights), np.full((1, n), 17), log_weights)
    moved, _ = Regularisation().apply(context, TrialStreams.from_seeds([6]))
    assert len(np.unique(moved[0], axis=0)) == n
    h = Regularisation().bandwidth_for(n, d)
    sample = np.cov(cloud[0].T, ddof=1)
    displacement = moved[0] - cloud[0, 17]
    for direction in (np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([1.0, -1.0]) / math.sqrt(2)):
        expected = h * h * direction @ sample @ direction
        assert abs(np.mean((displacement @ direction) ** 2) - expected) < Z_LIMIT * expected * math.sqrt(2 / n)


def rotation_without_process_noise():
    """x_k = A x_(k-1), A a rotation by 0.3 rad, no process noise; z = x + v, v ~ N(0, 1e-6 I):
    so precise that after one step a single particle holds the weight to round-off."""
    angle = 0.3
    rotation = [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]]
    return MODELS["linear_gaussian"](
        kind="linear_gaussian", steps=3, transition_matrix=rotation, measurement_matrix=[[1.0, 0.0], [0.0, 1.0]],
        process_noise={"variance": 0.0}, measurement_noise={"variance": 1e-6},
        initial={"kind": "gaussian", "mean": [0.0, 0.0], "covariance": [[1.0, 0.0], [0.0, 1.0]]})


def first_step(move: str, trials: int, particles: int):
    """Step 1 of the particle filter on the rotation, stage by stage: (the predicted cloud, its
    weights, the cloud after resampling and the move)."""
    model = rotation_without_process_noise()
    settings = config_schema().FilterConfig(particles=particles, move=move)
    bound = bind_particle_filter("particle", model, settings, model.default_prior())
    measurements = np.tile(np.array([0.4, -0.3]), (trials, model.steps, 1))
    run = ParticleFilter(bound, measurements, TrialStreams.from_seeds(range(trials)))
    run.keeps_stages = True                 # hand back the step's clouds, stage by stage
    _, _, clouds = run.step(run.start(run.state, trials), run.step_inputs(1), run.random)
    return clouds.predicted, clouds.weights, clouds.resampled, bound.move


def test_a_deterministic_model_recovers_from_a_collapse_with_the_regulariser():
    """The Lorenz case in small: without process noise the filter's cloud only spreads by the
    move. At step 1 the measurement is so precise that one particle holds the weight (1 - max w
    below the threshold), so resampling makes N copies of it. Without a move they stay one point
    (and a deterministic model keeps them one point for ever). With the regulariser they spread
    by h D eps, D D' the unweighted N - 1 covariance S of the predicted cloud: along a direction
    a the mean square displacement from the copied particle is h^2 a' S a, with standard error
    h^2 a' S a sqrt(2 / n) per trial (n particles, Gaussian kernel), checked on the mean of the
    trials' standardised ratios (standard error sqrt(2 / (n trials)))."""
    trials, particles = 6, 400
    predicted, weights, collapsed, _ = first_step("none", trials, particles)
    assert np.all(1.0 - weights.max(axis=-1) < DEGENERATE_WEIGHTS)
    assert all(len(np.unique(cloud, axis=0)) == 1 for cloud in collapsed)

    predicted, weights, moved, move = first_step("regularise", trials, particles)
    assert np.all(1.0 - weights.max(axis=-1) < DEGENERATE_WEIGHTS)
    assert all(len(np.unique(cloud, axis=0)) == particles for cloud in moved)
    h = move.bandwidth_for(particles, 2)
    heaviest = predicted[np.arange(trials), weights.argmax(axis=-1)]
    displacement = moved - heaviest[:, None, :]
    for direction in (np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([1.0, 1.0]) / math.sqrt(2)):
        ratios = [np.mean((displacement[t] @ direction) ** 2)
                  / (h * h * direction @ np.cov(predicted[t].T, ddof=1) @ direction) for t in range(trials)]
        assert abs(np.mean(ratios) - 1.0) < Z_LIMIT * math.sqrt(2.0 / (particles * trials))


# -- configs: refusals, cell keys, the move column ------------------------------------------------

def _config(filter_settings: dict, **extra) -> dict:
    return {"name": "regularise", "seed": 3, "trials": 2, "model": {"kind": "growth", "steps": 8},
            "filter": {"particles": 50, **filter_settings}, **extra}


def test_scott_with_the_epanechnikov_kernel_is_refused_in_one_line():
    with pytest.raises(ConfigError) as caught:
        build_plan(_config({"move": {"kind": "regularise", "kernel": "epanechnikov", "bandwidth": "scott"}}), "r.yaml")
    assert str(caught.value).splitlines() == [
        "r.yaml: filter.move.bandwidth: scott (h = N^(-1/(d+4)), Scott's rule of thumb) is a bandwidth for the "
        "gaussian kernel; with kernel: epanechnikov use optimal or a number"]


def test_new_settings_change_the_cell_key_only_when_set():
    """bandwidth_scale: 1 and jitter: all are the defaults: written out, they keep the key of the
    config that does not name them; set to another value, they make another cell."""
    def key(move):
        return build_plan(_config({"move": move}), "r.yaml").cells[0].key

    plain = key({"kind": "regularise"})
    assert key({"kind": "regularise", "bandwidth_scale": 1.0, "jitter": "all"}) == plain
    assert key({"kind": "regularise", "bandwidth_scale": 2.0}) != plain
    assert key({"kind": "regularise", "jitter": "duplicates"}) != plain


def test_trials_csv_records_the_move(tmp_path):
    """The move column holds the move's kind for particle arms (none, regularise, mcmc), beside
    diffusion, and is empty for a Kalman filter."""
    import pfx

    config = _config({}, arms={"PF": {}, "RPF": {"move": {"kind": "regularise", "jitter": "duplicates"}},
                              "RM": {"move": "mcmc"}, "EKF": {"kind": "ekf"}},
                     outputs={"figures": [], "trace_trials": 0})
    trials = pfx.run(config, out=tmp_path / "run").trials
    columns = list(trials.columns)
    assert columns.index("move") == columns.index("diffusion") + 1
    moves = trials.groupby("arm")["move"].agg(lambda values: set(values.fillna("")))
    assert moves.to_dict() == {"PF": {"none"}, "RPF": {"regularise"}, "RM": {"mcmc"}, "EKF": {""}}
