r"""An adaptive particle count: KLD-sampling (Fox 2003).

Fox, "Adapting the sample size in particle filters through KLD-sampling" (IJRR 22(12), 2003):
draw particles from the posterior one at a time, binning each drawn state into a histogram;
with :math:`k` bins occupied so far, stop once the count :math:`n` reaches

.. math:: n(k) = \frac{k-1}{2\epsilon}\left[1 - \frac{2}{9(k-1)}
          + \sqrt{\frac{2}{9(k-1)}}\; z_{1-\delta}\right]^3,

the number of draws for which, with probability :math:`1-\delta`, the Kullback-Leibler distance
between the sample's histogram and the true posterior's stays below :math:`\epsilon` (the
Wilson-Hilferty approximation of the :math:`\chi^2_{k-1}` quantile; :math:`z_{1-\delta}` the
standard normal quantile). :math:`n(1) = 0`: one occupied bin asks for nothing beyond
``min_particles``.

**Batched.** The arrays stay sized to the maximum :math:`N` (``filter.particles``), with an
*active count* :math:`n_r \le N` per trial: particles :math:`n_r..N-1` are inactive (log-weight
-inf, weight 0, state parked on a copy of particle 0, so that the transition keeps them in the
model's domain and a roughening's ranges do not see them). The resampler draws :math:`N`
indices; the active count is the smallest :math:`n` with :math:`n \ge n(k(n))` and
:math:`n \ge` ``min_particles`` (at most :math:`N`), :math:`k(n)` the bins occupied by the first
:math:`n` draws, and those first :math:`n` become the new cloud.

**Which "first n".** Every resampler here returns its draws sorted by particle index (the
inverse CDF at sorted points). A prefix of a sorted draw is not a sample of the posterior: it
holds only the particles of low index, i.e. an arbitrary part of the state space, and the bins
it occupies say nothing about the posterior's spread. So the :math:`N` draws are first put in
a uniformly random order (a permutation from the trial's own stream, by sorting uniforms):
the first :math:`n` of a random order of the :math:`N` draws are a sample without
replacement from them, so each particle's expected number of copies among them is
:math:`n w_j` for every unbiased resampler (multinomial: the prefix is then exactly :math:`n`
iid draws, Fox's setting). The stopping rule looks only at the draws before it, as in Fox.

The histogram bins are boxes of side ``bin_size`` (one value, or one per state component)
over the resampled states (before the move), as in Fox's and AMCL's implementations.

**Both backends.** The rule is written once against the array namespace
(:func:`pfx.numerics.arrays.namespace`): the bound, the count and the random order run on NumPy
or JAX arrays alike, with fixed shapes (an active count per trial, never a subset). Only the
bins' first occurrences take two forms: NumPy combines each state's bin coordinates into one
integer (mixed radix over the batch's range, a shape known only from the values); JAX sorts the
coordinates lexicographically, draw position last, so equal bins are compared coordinate by
coordinate (exact, no hash) and the first of each run is the draw that first occupies the bin.
"""

from __future__ import annotations

from statistics import NormalDist
from typing import Annotated, ClassVar, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt

from pfx.filters.backends import BOTH, Backends
from pfx.numerics.arrays import namespace
from pfx.numerics.seeding import TrialStreams


def kld_bound(occupied_bins: np.ndarray, epsilon: float, delta: float) -> np.ndarray:
    r"""Fox's bound n(k) = (k-1)/(2 eps) [1 - 2/(9(k-1)) + sqrt(2/(9(k-1))) z_{1-delta}]^3
    (0 for k <= 1), elementwise over ``occupied_bins``."""
    xp = namespace(occupied_bins)
    k = xp.asarray(occupied_bins, dtype=float)
    z = NormalDist().inv_cdf(1.0 - delta)
    degrees = xp.maximum(k - 1.0, 1.0)          # k = 1 is masked below; avoids 0 / 0
    ratio = 2.0 / (9.0 * degrees)
    bound = degrees / (2.0 * epsilon) * (1.0 - ratio + xp.sqrt(ratio) * z) ** 3
    return xp.where(k > 1.0, bound, 0.0)


def occupied_bins_by_prefix(states: np.ndarray, bin_size) -> np.ndarray:
    """k(n) for n = 1..N per row: the number of distinct histogram bins among the first n
    states of the row. (R, N, d) -> (R, N) integers.

    Bin indices floor(x / size) per component are combined exactly into one integer per state
    (mixed radix over the row's range of each component); a stable sort puts the draws of each
    bin in draw order, so the first of each run is the draw that first occupies the bin.
    """
    if namespace(states) is not np:
        return _occupied_bins_by_sorting(states, bin_size)
    rows, count, _ = states.shape
    cells = np.floor(states / np.asarray(bin_size, dtype=float)).astype(np.int64)
    cells -= cells.min(axis=1, keepdims=True)
    spans = cells.max(axis=(0, 1)) + 1
    keys = np.zeros((rows, count), dtype=np.int64)
    for component, span in enumerate(spans):
        keys = keys * int(span) + cells[..., component]
    order = np.argsort(keys, axis=1, kind="stable")
    ordered = np.take_along_axis(keys, order, axis=1)
    first = np.ones((rows, count), dtype=bool)
    first[:, 1:] = ordered[:, 1:] != ordered[:, :-1]
    new_bin = np.zeros((rows, count), dtype=bool)
    np.put_along_axis(new_bin, order, first, axis=1)
    return np.cumsum(new_bin, axis=1)


def _occupied_bins_by_sorting(states, bin_size):
    """k(n) with fixed shapes (JAX): a lexicographic sort of the bin coordinates, the draw
    position as the last tie-break, marks the first draw of each bin; the marks go back to the
    draw positions and their running sum counts the bins."""
    xp = namespace(states)
    rows, count, dimension = states.shape
    cells = xp.floor(states / xp.asarray(bin_size, dtype=states.dtype)).astype(xp.int64)
    positions = xp.broadcast_to(xp.arange(count), (rows, count))
    # lexsort's last key is the primary one: the coordinates, then the position among equals
    order = xp.lexsort((positions, *(cells[..., c] for c in reversed(range(dimension)))), axis=-1)
    ordered = xp.take_along_axis(cells, order[..., None], axis=1)
    changed = xp.any(ordered[:, 1:] != ordered[:, :-1], axis=-1)
    first = xp.concatenate([xp.ones((rows, 1), bool), changed], axis=1)
    new_bin = xp.zeros((rows, count), xp.int32).at[xp.arange(rows)[:, None], order].set(first.astype(xp.int32))
    return xp.cumsum(new_bin, axis=1)


def kld_count(occupied: np.ndarray, epsilon: float, delta: float, min_particles: int) -> np.ndarray:
    """The active count per row: the smallest n (1-based) with n >= n(k(n)) and n >= min_particles,
    else the maximum N (which wins over min_particles too). ``occupied`` is k(n), (R, N)."""
    xp = namespace(occupied)
    count = occupied.shape[1]
    drawn = xp.arange(1, count + 1)
    enough = (drawn >= kld_bound(occupied, epsilon, delta)) & (drawn >= min_particles)
    return xp.where(enough.any(axis=1), xp.argmax(enough, axis=1) + 1, count)


def random_order(random: TrialStreams, count: int):
    """A uniformly random permutation of 0..count-1 per row, from each trial's stream (NumPy
    Generators or JAX keys: the namespace of the uniforms drawn)."""
    uniforms = random.uniform((count,))
    return namespace(uniforms).argsort(uniforms, axis=1)


class KLDSampling(BaseModel):
    """KLD-sampling (Fox 2003): as many particles as the histogram bound asks, at most filter.particles."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    backends: ClassVar[Backends] = Backends(BOTH)
    kind: Literal["kld"] = "kld"
    epsilon: StrictFloat = Field(0.05, gt=0, description="KL-distance bound epsilon (Fox: 0.05)")
    delta: StrictFloat = Field(0.01, gt=0, lt=1, description="the bound holds with probability 1 - delta (Fox: 0.01)")
    bin_size: Union[Annotated[StrictFloat, Field(gt=0)], list[Annotated[StrictFloat, Field(gt=0)]]] = Field(
        description="histogram bin side per state component (one value, or one per component; no default)")
    min_particles: StrictInt = Field(
        10, ge=1, description="never fewer particles than this (but never more than filter.particles, "
                              "the maximum, which wins)")

    def check(self, dimension: int, maximum: int) -> None:
        """Raise ValueError('@key: reason') if the settings do not fit the state."""
        if isinstance(self.bin_size, list) and len(self.bin_size) != dimension:
            raise ValueError(f"@adaptive.bin_size: give one value or one per state component ({dimension}), "
                             f"got {len(self.bin_size)}")

    def select(self, resampled: np.ndarray, random: TrialStreams) -> tuple[np.ndarray, np.ndarray]:
        """(order, counts): a random order of the N resampled particles of each row, and the
        active count, the KLD stopping point over that order."""
        xp = namespace(resampled)
        order = random_order(random, resampled.shape[1])
        ordered = xp.take_along_axis(resampled, order[..., None], axis=1)
        counts = kld_count(occupied_bins_by_prefix(ordered, self.bin_size), self.epsilon, self.delta,
                           self.min_particles)
        return order, counts

    def apply(self, resampled: np.ndarray, random: TrialStreams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cloud, counts, order): the resampled clouds (R, N, d) in a random order, the KLD
        count of each, and the order (for the genealogy); particles past the count are parked
        on particle 0 (inactive)."""
        xp = namespace(resampled)
        order, counts = self.select(resampled, random)
        ordered = xp.take_along_axis(resampled, order[..., None], axis=1)
        inactive = xp.arange(resampled.shape[1]) >= counts[:, None]
        return xp.where(inactive[..., None], ordered[:, :1], ordered), counts, order


AdaptiveCount = Optional[KLDSampling]
