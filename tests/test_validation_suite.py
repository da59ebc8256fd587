"""The particle filter against exact answers on a linear-Gaussian model (Kalman filter).

1. The Monte Carlo error of the PF posterior mean falls as N^-1/2: the fitted log-log slope of
   the RMS difference to the Kalman mean over N = 100..10000 lies within -0.5 +- 0.15.
2. The PF likelihood estimate is unbiased: E[p_hat(z_1:T)] = p(z_1:T) (Del Moral 2004), so the
   mean of p_hat / p over independent filter runs on one measurement sequence is 1 within its
   standard error. (log p_hat is biased downwards by Jensen's inequality: the test uses the
   ratio, not the log.)
"""

from __future__ import annotations

import numpy as np

import pfx
from pfx.laws.initial import GaussianLaw
from pfx.models.base import bind_law
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams

A = [[0.9, 0.2], [0.0, 0.8]]
H = [[1.0, 0.0]]


def _model(steps: int) -> LinearGaussian:
    return LinearGaussian(transition_matrix=A, measurement_matrix=H, steps=steps,
                          process_noise={"variance": [0.5, 0.2]}, measurement_noise={"variance": 1.0},
                          initial={"kind": "gaussian", "mean": [0.0, 0.0], "covariance": [1.0, 1.0]})


def kalman(model: LinearGaussian, measurements: np.ndarray):
    """Textbook Kalman filter, one trial: posterior means (T, d) and log p(z_1:T)."""
    a, h = np.asarray(A), np.asarray(H)
    q, r = model.process_noise.covariance(), model.measurement_noise.covariance()
    mean, covariance = np.zeros(2), np.eye(2)
    means, log_likelihood = [], 0.0
    for z in measurements:
        mean, covariance = a @ mean, a @ covariance @ a.T + q
        innovation = z - h @ mean
        s = h @ covariance @ h.T + r
        log_likelihood += -0.5 * (innovation @ np.linalg.solve(s, innovation) + np.log(np.linalg.det(2 * np.pi * s)))
        gain = covariance @ h.T @ np.linalg.inv(s)
        mean = mean + gain @ innovation
        covariance = (np.eye(2) - gain @ h) @ covariance
        means.append(mean)
    return np.array(means), log_likelihood


def _particle_filter(model, measurements, particles, seeds):
    prior = bind_law(GaussianLaw(mean=[0.0, 0.0], covariance=[1.0, 1.0]), 2, "initial")
    return pfx.particle_filter(model, prior=prior, particles=particles, resampler="systematic", ess_threshold=1.0)(measurements, seeds=seeds).trace


def test_error_against_kalman_mean_falls_as_inverse_square_root_of_n():
    """RMS over 20 trials x 20 steps of (PF mean - KF mean) for N = 100 .. 10000.

    The Monte Carlo error of a weighted mean is O(N^-1/2) (central limit theorem for SMC);
    +-0.15 on the slope covers the sampling noise of 400 error terms per N.
    """
    model = _model(20)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds(range(1000, 1020)))
    exact = np.stack([kalman(model, z)[0] for z in measurements])
    counts = np.array([100, 300, 1000, 3000, 10000])
    errors = []
    for n in counts:
        trace = _particle_filter(model, measurements, int(n), range(2000, 2020))
        errors.append(np.sqrt(np.mean((trace.estimates - exact) ** 2)))
    slope, _ = np.polyfit(np.log(counts), np.log(errors), 1)
    assert -0.65 <= slope <= -0.35, (slope, errors)


def test_likelihood_estimate_is_unbiased():
    """Mean of p_hat / p over 2000 independent runs of N = 200 particles on one sequence of
    T = 10 measurements is 1 within 4 standard errors (the SE estimated from the same runs)."""
    model = _model(10)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([77]))
    _, exact = kalman(model, measurements[0])
    runs = 2000
    trace = _particle_filter(model, np.repeat(measurements, runs, axis=0), 200, range(5000, 5000 + runs))
    ratio = np.exp(trace.log_likelihood - exact)
    standard_error = ratio.std(ddof=1) / np.sqrt(runs)
    assert abs(ratio.mean() - 1.0) < 4 * standard_error, (ratio.mean(), standard_error)
    # and the log of the estimate is biased low (Jensen), which is why the ratio is tested
    assert np.mean(trace.log_likelihood) < exact
