r"""The genealogy of a particle filter: which particles of each step still have descendants at
the last step, and how few they become back in time (path degeneracy).

A filter that resamples gives each particle of step :math:`k` a parent among the particles of
step :math:`k-1`. Write :math:`a_k^i` for the parent's index of particle :math:`i` at step
:math:`k`, and an ``ancestors`` array of shape :math:`(T, N)` for all of them: row :math:`k`
(0-based, so row 0 is step 1) holds :math:`a_{k}^{0..N-1}`. Follow the parents back from the
:math:`N` particles of the last step: the particles met on the way are the **ancestral lines**
(:func:`ancestral_lines`), and their number at each step is the number of **distinct
ancestors** (:func:`distinct_ancestor_counts`): :math:`N` at the last step, and falling back
in time, since resampling copies some particles and drops others. A few dozen steps back they
typically all descend from one particle: a smoother that keeps the filter's paths (the
``genealogy`` smoother) has one path there, whatever :math:`N`.

Two entries are not parents:

* :data:`NO_PARENT` (-1): a particle drawn afresh from the prior (injected), whose line starts
  at its step; step 1's row is ignored (genealogy.csv writes each particle as its own parent
  there);
* :data:`NO_PARTICLE` (-2): no particle at this place, in an array padded to the largest
  particle count of a filter whose count varies by step (:func:`trial_genealogy` pads so).

The functions are pure (arrays in, arrays out): the run may count the distinct ancestors for
steps.csv with them, and the figures draw genealogy.csv's trees with them
(:mod:`pfx.figures.smoothing`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

NO_PARENT = -1        # a particle injected from the prior: its line starts at its step
NO_PARTICLE = -2      # padding: no particle at this index at this step


def ancestral_lines(ancestors: np.ndarray) -> np.ndarray:
    """Which particles lie on the ancestral line of some particle of the last step: (T, N) booleans.

    ``ancestors`` is the (T, N) array of parent indices of the module docstring. At the last
    step every particle is on its own line; at step k, a particle is on a line when some
    particle of step k+1 on a line has it as parent.
    """
    ancestors = np.asarray(ancestors)
    if ancestors.ndim != 2:
        raise ValueError(f"ancestors must be a (steps, particles) array, not of shape {ancestors.shape}")
    ancestors = ancestors.astype(np.int64, copy=False)
    steps, particles = ancestors.shape
    if ((ancestors[1:] >= particles) | (ancestors[1:] < NO_PARTICLE)).any():
        raise ValueError(f"a parent index outside 0..{particles - 1} (or {NO_PARENT}: injected, "
                         f"{NO_PARTICLE}: no particle)")
    on_line = np.zeros((steps, particles), dtype=bool)
    if steps == 0:
        return on_line
    on_line[-1] = ancestors[-1] != NO_PARTICLE
    # Back in time, one step at a time: a step's parents are indices into the step before it.
    for step in range(steps - 1, 0, -1):
        parents = ancestors[step, on_line[step]]
        on_line[step - 1, parents[parents >= 0]] = True
    return on_line


def distinct_ancestor_counts(ancestors: np.ndarray) -> np.ndarray:
    """The number of distinct ancestors of the last step's particles at each step: (T,) integers.

    The particles of the last step count themselves (N there); a step where every line was
    injected later counts 0. See :func:`ancestral_lines` for ``ancestors``.
    """
    return ancestral_lines(ancestors).sum(axis=1)


@dataclass(frozen=True)
class TrialGenealogy:
    """One trial's genealogy as arrays, one row per step and one column per particle index."""

    steps: np.ndarray          # (T,) the step numbers, 1..T
    ancestors: np.ndarray      # (T, N) parent indices; NO_PARTICLE where a step has fewer particles
    weights: np.ndarray        # (T, N) normalised weights before resampling; NaN where no particle
    states: np.ndarray         # (T, N, d) the particles' states before resampling; NaN where no particle

    @property
    def particle_counts(self) -> np.ndarray:
        """The particles at each step: (T,)."""
        return (self.ancestors != NO_PARTICLE).sum(axis=1)


def trial_genealogy(rows: pd.DataFrame, state_columns: list[str]) -> TrialGenealogy:
    """The arrays of one (cell, trial)'s rows of genealogy.csv (columns ``step``, ``particle``,
    ``ancestor``, ``weight`` and ``state_columns``), padded to the largest particle count.

    The steps must run 1, 2, ... without a gap, since each row's parent is an index into the
    step before it; otherwise a ValueError says so.
    """
    step_values = rows["step"].to_numpy(dtype=np.int64)
    particle = rows["particle"].to_numpy(dtype=np.int64)
    steps = np.unique(step_values)
    if len(steps) and not np.array_equal(steps, np.arange(1, len(steps) + 1)):
        raise ValueError(f"genealogy steps must run 1..T without a gap, not {steps.tolist()[:10]}")
    if (particle < 0).any():
        raise ValueError("genealogy particle indices must be 0 or more")
    count = int(particle.max()) + 1 if len(particle) else 0
    row = step_values - 1
    ancestors = np.full((len(steps), count), NO_PARTICLE, dtype=np.int64)
    weights = np.full((len(steps), count), np.nan)
    states = np.full((len(steps), count, len(state_columns)), np.nan)
    ancestors[row, particle] = rows["ancestor"].to_numpy(dtype=np.int64)
    weights[row, particle] = rows["weight"].to_numpy(dtype=float)
    states[row, particle] = rows[state_columns].to_numpy(dtype=float)
    return TrialGenealogy(steps, ancestors, weights, states)
