r"""The plain vectorised NumPy bootstrap filter the benchmark compares pfx with.

The classic one-trial loop, as it is written in textbooks and tutorials: propagate every
particle, weight by the likelihood (log domain, shifted by the maximum), normalise, take the
weighted mean, and resample systematically by a binary search of the cumulative weights.
:func:`reference_run` also sums the log-likelihood increments, :math:`\log \hat p(z_t \mid
z_{1:t-1}) = \max_i \log w_i + \log \sum_i e^{\log w_i - \max} - \log N + c` (``c`` the
Gaussian's constant, :attr:`FallingBodyProblem.log_likelihood_constant`), which the plain JAX
filter (:mod:`pfx.bench.jax_reference`) is checked against.
"""

from __future__ import annotations

import numpy as np

from pfx.bench.problem import FallingBodyProblem


def reference_filter(problem: FallingBodyProblem, measurements: np.ndarray, particles: int,
                     random: np.random.Generator) -> np.ndarray:
    """Weighted-mean estimates (T, 3) of one trial; ``measurements`` has shape (T, 1)."""
    return reference_run(problem, measurements, particles, random)[0]


def reference_run(problem: FallingBodyProblem, measurements: np.ndarray, particles: int,
                  random: np.random.Generator) -> tuple[np.ndarray, float]:
    """The estimates (T, 3) and the log-likelihood estimate of one trial (module docstring)."""
    n = particles
    x = problem.sample_prior(random, n)
    estimates = np.empty((len(measurements), 3))
    log_likelihood = len(measurements) * (problem.log_likelihood_constant - np.log(n))
    for t, z in enumerate(measurements[:, 0]):
        x = problem.propagate(x) + problem.process_noise(random, n)
        log_w = problem.log_likelihood(z, x)
        top = log_w.max()
        w = np.exp(log_w - top)
        total = w.sum()
        log_likelihood += top + np.log(total)
        w /= total
        estimates[t] = w @ x
        cumulative = np.cumsum(w)
        cumulative[-1] = 1.0
        x = x[np.searchsorted(cumulative, (np.arange(n) + random.random()) / n)]
    return estimates, float(log_likelihood)
