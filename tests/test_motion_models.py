"""Probabilistic Robotics' motion models (pfx.motion): samplers, densities and their agreement.

Statistical tests use fixed seeds. Moments are checked within 4 standard errors computed from
the distribution's own kurtosis; distributions by Kolmogorov-Smirnov tests that must not reject
at level 0.001 (scipy.stats.kstest against the CDF of the density the model claims).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from pfx.motion import (
    OdometryAlphas,
    VelocityAlphas,
    executed_velocities,
    motion_model_odometry,
    motion_model_velocity,
    prob,
    prob_normal,
    prob_triangular,
    relative_motion,
    sample,
    sample_motion_model_odometry,
    sample_motion_model_velocity,
    sample_normal,
    sample_triangular,
    wrap_to_pi,
)
from pfx.motion.odometry import move_by_odometry
from pfx.motion.velocity import move_on_arc
from pfx.numerics.seeding import TrialStreams

KS_LEVEL = 1e-3
# Excess-free kurtosis E[x^4]/sigma^4: the sum of 12 uniforms (Irwin-Hall: 3 - 6/(5*12)) and the
# triangular distribution (2.4).
KURTOSIS = {"normal": 3.0 - 6.0 / 60.0, "triangular": 2.4}
SAMPLERS = {"normal": sample_normal, "triangular": sample_triangular}


def reference_distribution(noise: str, variance: float):
    """scipy's distribution of the given variance: the CDF a density test compares against."""
    std = math.sqrt(variance)
    if noise == "normal":
        return stats.norm(scale=std)
    half_width = math.sqrt(6.0) * std
    return stats.triang(c=0.5, loc=-half_width, scale=2.0 * half_width)


# -- Tables 5.2 and 5.4: prob and sample ------------------------------------------------------------

@pytest.mark.parametrize("noise", ["normal", "triangular"])
def test_samplers_have_the_requested_variance_and_zero_mean(noise):
    n, std = 200_000, 2.0
    draws = SAMPLERS[noise](np.full(n, std), np.random.default_rng(11))
    variance = std ** 2
    mean_se = std / math.sqrt(n)
    variance_se = variance * math.sqrt((KURTOSIS[noise] - 1.0) / n)
    assert abs(draws.mean()) < 4 * mean_se
    assert abs(draws.var() - variance) < 4 * variance_se


@pytest.mark.parametrize("noise", ["normal", "triangular"])
def test_sample_takes_a_variance_and_each_entry_its_own(noise):
    variances = np.array([0.25, 4.0, 9.0])
    n = 100_000
    draws = sample(np.broadcast_to(variances, (n, 3)), np.random.default_rng(5), noise)
    se = variances * math.sqrt((KURTOSIS[noise] - 1.0) / n)
    assert np.all(np.abs(draws.var(axis=0) - variances) < 4 * se)


def test_triangular_samples_follow_prob_triangular():
    draws = sample_triangular(np.full(200_000, 1.5), np.random.default_rng(3))
    reference = reference_distribution("triangular", 1.5 ** 2)
    assert stats.kstest(draws, reference.cdf).pvalue > KS_LEVEL
    # and prob_triangular is that distribution's density
    grid = np.linspace(-5.0, 5.0, 101)
    assert np.allclose(prob_triangular(grid, 1.5 ** 2), reference.pdf(grid), atol=1e-12)


def test_sample_normal_is_close_to_the_normal_distribution():
    # The sum of 12 uniforms is within 0.0024 of the normal CDF everywhere; with 20,000 draws the
    # KS critical value at level 0.001 is 1.95/sqrt(n) = 0.014, so the test cannot see the difference
    # but would see a wrong scale (a variance passed as a standard deviation) at once.
    draws = sample_normal(np.full(20_000, 0.5), np.random.default_rng(4))
    assert stats.kstest(draws, reference_distribution("normal", 0.25).cdf).pvalue > KS_LEVEL
    assert np.abs(draws).max() <= 6 * 0.5


def test_prob_matches_table_5_2():
    a = np.array([-3.0, -0.5, 0.0, 0.2, 2.0, 7.0])
    b = 1.7
    assert np.allclose(prob_normal(a, b), np.exp(-a ** 2 / (2 * b)) / np.sqrt(2 * np.pi * b), rtol=1e-12)
    assert np.allclose(prob_triangular(a, b), np.maximum(0.0, 1 / np.sqrt(6 * b) - np.abs(a) / (6 * b)),
                       rtol=1e-12, atol=1e-15)


def test_zero_variance_is_a_point_mass_and_negative_variance_an_error():
    random = np.random.default_rng(0)
    assert np.all(sample(np.zeros(5), random) == 0.0)
    assert np.all(sample(np.zeros(5), random, "triangular") == 0.0)
    assert prob(0.0, 0.0) == np.inf and prob(0.1, 0.0) == 0.0
    assert prob_triangular(0.0, 0.0) == np.inf and prob_triangular(-0.1, 0.0) == 0.0
    with pytest.raises(ValueError, match="variance"):
        sample(-1.0, random)
    with pytest.raises(ValueError, match="variance"):
        prob(0.0, -1.0)


def test_trial_streams_draw_each_trial_from_its_own_generator():
    seeds = [7, 8, 9]
    pose = np.zeros((3, 50, 3))
    batched = sample_motion_model_velocity([1.0, 0.3], pose, 1.0, [0.1] * 6, "normal",
                                           TrialStreams.from_seeds(seeds))
    for row, seed in enumerate(seeds):
        alone = sample_motion_model_velocity([1.0, 0.3], pose[row:row + 1], 1.0, [0.1] * 6, "normal",
                                             TrialStreams.from_seeds([seed]))
        assert np.array_equal(alone[0], batched[row])
    with pytest.raises(ValueError, match="trial axis"):
        sample(np.ones(4), TrialStreams.from_seeds(seeds))


def test_wrap_angle():
    values = np.array([np.pi, -np.pi, 3 * np.pi, 0.0, 2 * np.pi, -0.5, 7.0])
    wrapped = wrap_to_pi(values)
    assert np.allclose(wrapped, [np.pi, np.pi, np.pi, 0.0, 0.0, -0.5, 7.0 - 2 * np.pi])
    assert np.all((wrapped > -np.pi) & (wrapped <= np.pi))


def test_alphas_from_a_list_or_a_mapping():
    assert VelocityAlphas.of([1, 2, 3, 4, 5, 6]) == VelocityAlphas(
        alpha1=1.0, alpha2=2.0, alpha3=3.0, alpha4=4.0, alpha5=5.0, alpha6=6.0)
    assert OdometryAlphas.of((0.1, 0.2, 0.3, 0.4)).alpha4 == 0.4
    with pytest.raises(ValueError, match="6 values"):
        VelocityAlphas.of([1.0, 2.0])
    with pytest.raises(ValueError):
        OdometryAlphas.of([0.1, -0.2, 0.3, 0.4])
    variances = VelocityAlphas.of([1, 2, 3, 4, 5, 6]).variances(2.0, 0.5)
    assert variances == (1 * 4 + 2 * 0.25, 3 * 4 + 4 * 0.25, 5 * 4 + 6 * 0.25)


# -- Tables 5.1 and 5.3: the velocity model ----------------------------------------------------------

def book_arc(pose, v, w, gamma, dt):
    """Table 5.3, lines 5-7, as printed (w != 0)."""
    x, y, theta = pose[..., 0], pose[..., 1], pose[..., 2]
    radius = v / w
    return np.stack([x - radius * np.sin(theta) + radius * np.sin(theta + w * dt),
                     y + radius * np.cos(theta) - radius * np.cos(theta + w * dt),
                     theta + w * dt + gamma * dt], axis=-1)


def book_table_5_1_velocities(before, now, dt):
    """Table 5.1, lines 2-8, as printed: (v^, w^, g^)."""
    x, y, theta = before
    x1, y1, theta1 = now
    mu = 0.5 * ((x - x1) * np.cos(theta) + (y - y1) * np.sin(theta)) / \
        ((y - y1) * np.cos(theta) - (x - x1) * np.sin(theta))
    x_star, y_star = (x + x1) / 2 + mu * (y - y1), (y + y1) / 2 + mu * (x1 - x)
    r_star = np.hypot(x - x_star, y - y_star)
    turn = wrap_to_pi(np.arctan2(y1 - y_star, x1 - x_star) - np.arctan2(y - y_star, x - x_star))
    return turn / dt * r_star, turn / dt, (theta1 - theta) / dt - turn / dt


def test_arc_equals_the_books_formula_and_its_straight_line_limit():
    rng = np.random.default_rng(2)
    n = 10_000
    pose = np.column_stack([rng.normal(size=n), rng.normal(size=n), rng.uniform(-np.pi, np.pi, n)])
    v, w, gamma, dt = rng.uniform(-2, 2, n), rng.uniform(-3, 3, n), rng.normal(size=n), 0.7
    ours, book = move_on_arc(pose, v, w, gamma, dt), book_arc(pose, v, w, gamma, dt)
    assert np.allclose(ours[:, :2], book[:, :2], atol=1e-9)
    assert np.allclose(wrap_to_pi(ours[:, 2] - book[:, 2]), 0.0, atol=1e-12)
    # w = 0 is the straight line, and w -> 0 approaches it continuously
    straight = move_on_arc(pose, v, 0.0, 0.0, dt)
    assert np.array_equal(straight[:, 0], pose[:, 0] + v * dt * np.cos(pose[:, 2]))
    assert np.array_equal(straight[:, 1], pose[:, 1] + v * dt * np.sin(pose[:, 2]))
    for tiny in (1e-12, -1e-9, 1e-6):
        assert np.allclose(move_on_arc(pose, v, tiny, 0.0, dt)[:, :2], straight[:, :2], atol=3 * abs(tiny))


def test_executed_velocities_invert_the_arc_forward_and_backward():
    rng = np.random.default_rng(3)
    n = 10_000
    pose = np.column_stack([rng.normal(size=n), rng.normal(size=n), rng.uniform(-np.pi, np.pi, n)])
    v, w, gamma, dt = rng.uniform(0.01, 2, n), rng.uniform(-6, 6, n), rng.normal(size=n), 0.9
    forward = executed_velocities(pose, move_on_arc(pose, v, w, gamma, dt), dt, +1)
    backward = executed_velocities(pose, move_on_arc(pose, -v, w, gamma, dt), dt, -1)
    for recovered, expected_v in ((forward, v), (backward, -v)):
        assert np.allclose(recovered[0], expected_v, atol=1e-9)
        assert np.allclose(recovered[1], w, atol=1e-9)
        assert np.allclose(wrap_to_pi((recovered[2] - gamma) * dt), 0.0, atol=1e-9)
    # straight ahead: w^ = 0 and v^ = distance / dt, exactly
    v_hat, w_hat, _ = executed_velocities([1.0, 2.0, 0.0], [4.0, 2.0, 0.0], 2.0)
    assert (v_hat, w_hat) == (1.5, 0.0)


def test_printed_table_5_1_gives_right_turns_the_wrong_sign_and_ours_does_not():
    before = np.array([0.5, -1.0, 0.3])
    for w in (0.5, -0.5):
        now = move_on_arc(before, 1.0, w, 0.0, 1.0)
        book_v, book_w, _ = book_table_5_1_velocities(before, now, 1.0)
        ours_v, ours_w, _ = executed_velocities(before, now, 1.0)
        assert math.isclose(ours_v, 1.0, rel_tol=1e-9) and math.isclose(ours_w, w, rel_tol=1e-9)
        assert math.isclose(book_w, w, rel_tol=1e-9)
        assert math.isclose(book_v, math.copysign(1.0, w), rel_tol=1e-9)     # -1 for the right turn


VELOCITY_ALPHAS = [0.04, 0.02, 0.03, 0.05, 0.01, 0.02]     # all different: a swapped term would show


@pytest.mark.parametrize("noise", ["normal", "triangular"])
@pytest.mark.parametrize("control", [(1.0, 0.5), (1.2, -0.8)], ids=["left", "right"])
def test_velocity_sampler_agrees_with_its_density(noise, control):
    """Recover (v^, w^, g^) from sampled poses with the density's own inversion; each must follow
    the prob() term the density multiplies, and the density must be that product."""
    n, dt = 50_000, 0.5
    before = np.array([1.0, -2.0, 3.0])          # heading near pi: the motion crosses the seam
    poses = sample_motion_model_velocity(control, np.broadcast_to(before, (n, 3)), dt, VELOCITY_ALPHAS, noise,
                                         np.random.default_rng(17))
    v, w = control
    a1, a2, a3, a4, a5, a6 = VELOCITY_ALPHAS         # the variance terms of Table 5.3, written out
    variance_v, variance_w, variance_gamma = a1 * v ** 2 + a2 * w ** 2, a3 * v ** 2 + a4 * w ** 2, \
        a5 * v ** 2 + a6 * w ** 2
    v_hat, w_hat, gamma_hat = executed_velocities(before, poses, dt, +1)
    for errors, variance in ((v - v_hat, variance_v), (w - w_hat, variance_w), (gamma_hat, variance_gamma)):
        assert stats.kstest(errors, reference_distribution(noise, variance).cdf).pvalue > KS_LEVEL
    density = motion_model_velocity(poses, control, before, dt, VELOCITY_ALPHAS, noise)
    product = prob(v - v_hat, variance_v, noise) * prob(w - w_hat, variance_w, noise) \
        * prob(gamma_hat, variance_gamma, noise)
    assert np.all(density > 0)
    assert np.allclose(density, product, rtol=1e-9)


def test_velocity_density_is_continuous_through_straight_motion():
    before = np.array([0.0, 0.0, 0.2])
    now = np.array([np.cos(0.2) * 1.01, np.sin(0.2) * 1.01 + 0.004, 0.203])
    alphas = VELOCITY_ALPHAS
    at_zero = motion_model_velocity(now, [1.0, 0.0], before, 1.0, alphas)
    assert np.isfinite(at_zero) and at_zero > 0
    for w in (1e-12, -1e-9, 1e-7, -1e-7):
        assert math.isclose(motion_model_velocity(now, [1.0, w], before, 1.0, alphas), at_zero, rel_tol=1e-5)
    # and the hypothesis exactly on the straight line has a finite density too
    on_line = np.array([np.cos(0.2), np.sin(0.2), 0.2])
    assert np.isfinite(motion_model_velocity(on_line, [1.0, 0.0], before, 1.0, alphas))


def test_velocity_density_at_rest_is_a_point_mass():
    pose = np.array([1.0, 1.0, 0.5])
    assert motion_model_velocity(pose, [0.0, 0.0], pose, 1.0, VELOCITY_ALPHAS) == np.inf
    assert motion_model_velocity(pose + [0.1, 0.0, 0.0], [0.0, 0.0], pose, 1.0, VELOCITY_ALPHAS) == 0.0
    resting = sample_motion_model_velocity([0.0, 0.0], np.broadcast_to(pose, (10, 3)), 1.0, VELOCITY_ALPHAS,
                                           "normal", np.random.default_rng(0))
    assert np.array_equal(resting, np.broadcast_to(pose, (10, 3)))


# -- Tables 5.5 and 5.6: the odometry model ----------------------------------------------------------

ODOMETRY_ALPHAS = [0.05, 0.01, 0.03, 0.02]


@pytest.mark.parametrize("noise", ["normal", "triangular"])
def test_odometry_sampler_agrees_with_its_density(noise):
    n = 50_000
    reading_before = np.array([1.0, 2.0, 0.3])
    reading_after = move_by_odometry(reading_before, 0.4, 1.5, -0.2)
    before = np.array([-3.0, 0.5, 2.9])          # heading 2.9 + rot1 0.4 crosses pi
    poses = sample_motion_model_odometry(reading_before, reading_after, np.broadcast_to(before, (n, 3)),
                                         ODOMETRY_ALPHAS, noise, np.random.default_rng(23))
    rotation1, translation, rotation2 = relative_motion(reading_before, reading_after)
    assert np.allclose([rotation1, translation, rotation2], [0.4, 1.5, -0.2])
    a1, a2, a3, a4 = ODOMETRY_ALPHAS                 # the corrected variance terms of Table 5.6
    variance1 = a1 * rotation1 ** 2 + a2 * translation ** 2
    variance_trans = a3 * translation ** 2 + a4 * rotation1 ** 2 + a4 * rotation2 ** 2
    variance2 = a1 * rotation2 ** 2 + a2 * translation ** 2
    rotation1_hat, translation_hat, rotation2_hat = relative_motion(before, poses)
    errors = (wrap_to_pi(rotation1 - rotation1_hat), translation - translation_hat,
              wrap_to_pi(rotation2 - rotation2_hat))
    for error, variance in zip(errors, (variance1, variance_trans, variance2)):
        assert stats.kstest(error, reference_distribution(noise, variance).cdf).pvalue > KS_LEVEL
    density = motion_model_odometry(poses, reading_before, reading_after, before, ODOMETRY_ALPHAS, noise)
    product = prob(errors[0], variance1, noise) * prob(errors[1], variance_trans, noise) \
        * prob(errors[2], variance2, noise)
    assert np.all(density > 0)
    assert np.allclose(density, product, rtol=1e-9)


def test_odometry_turn_on_the_spot_puts_the_whole_turn_in_rot2():
    rotation1, translation, rotation2 = relative_motion([2.0, 3.0, 1.0], [2.0, 3.0, 1.5])
    assert (rotation1, translation) == (0.0, 0.0) and math.isclose(rotation2, 0.5)
    # a turn on the spot with rotation noise only: the position never moves
    poses = sample_motion_model_odometry([0.0, 0.0, 0.0], [0.0, 0.0, 0.5], np.zeros((100, 3)),
                                         [0.1, 0.0, 0.0, 0.0], "normal", np.random.default_rng(1))
    assert np.all(poses[:, :2] == 0.0) and np.std(poses[:, 2]) > 0


def test_noise_free_models_follow_the_control_exactly():
    rng = np.random.default_rng(9)
    pose = np.array([0.3, -0.4, 3.0])
    velocity = sample_motion_model_velocity([0.8, 0.6], pose, 1.5, [0.0] * 6, "normal", rng)
    assert np.allclose(velocity, book_arc(pose, 0.8, 0.6, 0.0, 1.5) - [0, 0, 2 * np.pi])
    after = move_by_odometry([5.0, 5.0, 0.0], 0.3, 2.0, 0.1)
    odometry = sample_motion_model_odometry([5.0, 5.0, 0.0], after, pose, [0.0] * 4, "triangular", rng)
    assert np.allclose(odometry, [0.3 + 2.0 * np.cos(3.3), -0.4 + 2.0 * np.sin(3.3), 3.4 - 2 * np.pi])
