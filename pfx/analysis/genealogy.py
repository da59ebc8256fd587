"""The genealogy of a particle filter's last particles: how many distinct ancestors remain, step by step.

``ancestors[k - 1, i]`` is the index, among step k-1's particles, of the parent of particle i of
step k (row 0, step 1: the prior's own particles). Following the parents back from the last
step, the surviving lineages coalesce: at step k only a few of step k's particles are ancestors
of any last-step particle (path degeneracy).
"""

from __future__ import annotations

import numpy as np


def distinct_ancestor_counts(ancestors: np.ndarray) -> np.ndarray:
    """(T,): at each step k, the number of distinct particles of step k that are ancestors of
    the last step's particles (N at the last step when every particle survives its own step),
    from ``ancestors`` (T, N)."""
    steps, count = ancestors.shape
    counts = np.empty(steps, dtype=np.int64)
    alive = np.unique(np.arange(count))
    for k in range(steps, 0, -1):
        counts[k - 1] = alive.size
        parents = ancestors[k - 1, alive]
        alive = np.unique(parents[parents >= 0])
    return counts
