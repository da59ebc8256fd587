"""The plain vectorised NumPy bootstrap filter the benchmark compares pfx with.

The classic one-trial loop, as it is written in textbooks and tutorials: propagate every
particle, weight by the likelihood (log domain, shifted by the maximum), normalise, take the
weighted mean, and resample systematically by a binary search of the cumulative weights.
"""

from __future__ import annotations

import numpy as np

from pfx.bench.problem import FallingBodyProblem


def reference_filter(problem: FallingBodyProblem, measurements: np.ndarray, particles: int,
                     random: np.random.Generator) -> np.ndarray:
    """Weighted-mean estimates (T, 3) of one trial; ``measurements`` has shape (T, 1)."""
    n = particles
    x = problem.sample_prior(random, n)
    estimates = np.empty((len(measurements), 3))
    for t, z in enumerate(measurements[:, 0]):
        x = problem.propagate(x) + problem.process_noise(random, n)
        log_w = problem.log_likelihood(z, x)
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        estimates[t] = w @ x
        cumulative = np.cumsum(w)
        cumulative[-1] = 1.0
        x = x[np.searchsorted(cumulative, (np.arange(n) + random.random()) / n)]
    return estimates
