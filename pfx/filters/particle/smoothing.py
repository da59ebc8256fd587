r"""Particle smoothers, run after the particle filter on its recorded clouds and genealogy.

The filter records, at every step k = 1..T, its weighted cloud before resampling
:math:`\{x_k^i, w_k^i\}` and each particle's ancestor :math:`a_k^i` among step k-1's particles
(:class:`~pfx.filters.particle.recorders.Recording`: ``history``, ``genealogy``). From them:

**Forward filtering backward sampling** (``ffbs``; Godsill, Doucet & West 2004). Each of M
trajectories starts from :math:`b_T \sim w_T` and steps back,

.. math::

    P(b_k = i \mid b_{k+1}) = \frac{w_k^i\, p(x_{k+1}^{b_{k+1}} \mid x_k^i)}
                                {\sum_j w_k^j\, p(x_{k+1}^{b_{k+1}} \mid x_k^j)},

each trajectory :math:`(x_1^{b_1}, \dots, x_T^{b_T})` a draw from the particle approximation of
:math:`p(x_{1:T} \mid z_{1:T})`. The smoothed mean and standard deviation at step k are those of
the M trajectories. Cost: the N weights of each of the M draws, O(M N) per step (the classic
O(N^2) for M = N).

**Rejection FFBS** (``ffbs_rejection``; Douc, Garivier, Moulines & Olsson 2011). The same law,
each draw by rejection: propose :math:`i \sim w_k`, accept with probability
:math:`p(x_{k+1}^{b_{k+1}} \mid x_k^i) / \rho`, :math:`\rho \ge \sup p` the transition density's
bound (its value at zero noise, for the noise families pfx has: each is symmetric and unimodal).
A proposal is accepted with probability :math:`\sum_i w_k^i p(x_{k+1} \mid x_k^i) / \rho`, so the
expected cost per draw is :math:`\rho / \hat p(x_{k+1} \mid z_{1:k})`: O(M) per step when the
predictive density is not much flatter than the transition. After ``rounds`` unsuccessful
rounds the remaining draws are made exactly (the O(N) form): the law is unchanged (Taghavi,
Lindsten, Svensson & Schön 2013's hybrid). Only for models whose transition density pfx
derives (:meth:`pfx.models.base.Model.transition_density`): a model's own
``transition_log_density`` has no bound pfx knows.

**The genealogy smoothers.** Following the ancestors back from step e, particle i of step e
descends from :math:`x_k^{a_{k:e}(i)}` at step k: the **fixed-lag** smoother (``fixed_lag``)
estimates :math:`x_k` by :math:`\sum_i w_{e}^i x_k^{a_{k:e}(i)}`, e = min(k + L, T), using the
measurements up to L steps ahead; the **genealogy** smoother (``genealogy``) is e = T for every
k, the weighted ancestral paths of the last step's particles. Going back, the paths coalesce:
few distinct ancestors remain at early steps (path degeneracy; Jacob, Murray & Rubenthaler 2015
bound the expected size of the whole ancestral tree by :math:`T + C N \log N`), which is why the
backward-sampling smoothers exist. A move, a diffusion or an injection changes particles after
their ancestor was chosen, so the recorded paths are not the filter's: refused with them.

Every random draw comes from the trial's own stream (after the filter's), a trial's draws
never depend on the other trials of its batch, and the weights stay in the log domain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional

import numpy as np
from pydantic import Field, StrictInt

from pfx.filters.particle.cloud import posterior_mean
from pfx.filters.particle.resampling import inverse_cdf
from pfx.filters.smoothers import SMOOTHERS, Smoothed, Smoother
from pfx.numerics.angles import wrap_difference
from pfx.numerics.log_weights import normalise_rows
from pfx.numerics.seeding import TrialStreams

# Elements of a (trials, trajectories, N) block of backward weights computed at once: bounds the
# smoother's temporaries (8 bytes each) whatever N and M.
BLOCK_ELEMENTS = 4_000_000


@dataclass
class FilterHistory:
    """What the particle filter recorded for the smoothers: (R, T, N, d) states, (R, T, N)
    normalised log-weights (before resampling) and ancestors (None when not recorded)."""

    particles: np.ndarray
    log_weights: np.ndarray
    ancestors: Optional[np.ndarray]


def weighted_moments(model, weights: np.ndarray, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weighted mean (circular for the model's angles) and standard deviation of states
    (R, N, d) with normalised weights (R, N)."""
    mean = posterior_mean(model, weights, states)
    centred = states - mean[:, None, :]
    angular = list(model.angular_components)
    if angular:
        centred[..., angular] = wrap_difference(centred[..., angular], model.full_turn)
    variance = np.einsum("rn,rnd->rd", weights, centred * centred)
    return mean, np.sqrt(variance)


class _PathMoments:
    def moments(self, model, paths: np.ndarray) -> Smoothed:
        """Mean and sd over the M trajectories of ``paths`` (R, T, M, d), step by step."""
        trials, steps, count, _ = paths.shape
        uniform = np.full((trials, count), 1.0 / count)
        means, deviations = _empty_moments(paths)
        for t in range(steps):
            means[:, t], deviations[:, t] = weighted_moments(model, uniform, paths[:, t])
        return Smoothed(means, deviations)


def _has_own_density(model) -> bool:
    """Whether the model's class (or a parent below pfx's base class) defines transition_log_density."""
    owner = next(cls for cls in type(model).__mro__ if "transition_log_density" in vars(cls))
    return owner.__module__ != "pfx.models.base"


# What to do instead when the backward step has no density to weigh by: the smoothers that
# follow the particles' ancestry need none.
_DENSITY_FREE_SMOOTHERS = "use the fixed_lag or genealogy smoother, which need no transition density"


def _check_density(kind: str, model) -> None:
    density = model.transition_density()
    if isinstance(density, ValueError):
        if _has_own_density(model):
            return
        raise ValueError(f"@smoothers: the {kind} smoother weighs the backward step by the transition density "
                         f"p(x_k+1 | x_k); model {model.kind} {density.reason}: {_DENSITY_FREE_SMOOTHERS}")
    if not density.has_density:
        raise ValueError(f"@smoothers: the {kind} smoother weighs the backward step by the transition density "
                         f"p(x_k+1 | x_k); model {model.kind}'s process noise covariance L Q L' is singular: "
                         f"{_DENSITY_FREE_SMOOTHERS}, or give the model a process noise of full rank "
                         "(L Q L' positive definite)")


def transition_log_densities(model, following: np.ndarray, current: np.ndarray, step: int) -> np.ndarray:
    """log p(x_{k+1} = following_j | x_k = current_i) for states following (R, M, d) and current
    (R, N, d), the step k+1 being ``step``: (R, M, N)."""
    density = model.transition_density()
    if isinstance(density, ValueError):           # the model's own density (checked at plan time)
        return model.transition_log_density(following[:, :, None, :], current[:, None, :, :], step)
    mean = model.mean_transition(current, step)
    return density.log_density(following[:, :, None, :], mean[:, None, :, :])


def draw_from_log_weights(log_weights: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One index per row of (rows, N) unnormalised log-weights, by the inverse CDF at ``uniforms`` (rows,)."""
    with np.errstate(under="ignore", over="ignore", invalid="ignore", divide="ignore"):
        _, weights, _ = normalise_rows(log_weights)
    return inverse_cdf(weights, uniforms[:, None])[:, 0]


def _start(history: FilterHistory, random: TrialStreams, count: int) -> np.ndarray:
    """b_T ~ w_T for M trajectories per trial: (R, M)."""
    weights = np.exp(history.log_weights[:, -1])
    uniforms = np.sort(random.uniform((count,)), axis=-1)
    return inverse_cdf(weights, uniforms)


def _gather(states: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """states (R, N, d) at indices (R, M): (R, M, d)."""
    return np.take_along_axis(states, indices[..., None], axis=1)


@SMOOTHERS.register_kind
class BackwardSampling(_PathMoments, Smoother):
    """Forward filtering backward sampling: M trajectories drawn backwards, O(M N) per step."""

    kind: Literal["ffbs"] = "ffbs"
    trajectories: StrictInt = Field(100, ge=1, le=100_000, description="backward trajectories M")

    def check(self, filter_kind, model, settings):
        super().check(filter_kind, model, settings)
        _check_density(self.kind, model)

    def smooth(self, history: FilterHistory, model, random: TrialStreams) -> Smoothed:
        return self.moments(model, self.paths(history, model, random))

    def paths(self, history: FilterHistory, model, random: TrialStreams) -> np.ndarray:
        """M trajectories per trial, (R, T, M, d)."""
        particles, log_weights = history.particles, history.log_weights
        trials, steps, count, dimension = particles.shape
        indices = _start(history, random, self.trajectories)
        paths = np.empty((trials, steps, self.trajectories, dimension))
        paths[:, -1] = _gather(particles[:, -1], indices)
        for t in range(steps - 2, -1, -1):
            paths[:, t] = _gather(particles[:, t], self.step_back(model, paths[:, t + 1], particles[:, t],
                                                                  log_weights[:, t], t + 2, random))
        return paths

    def step_back(self, model, following, current, log_weights, step, random) -> np.ndarray:
        """b_k for each trajectory given x_{k+1} (``following``, (R, M, d)): (R, M)."""
        trials, count = following.shape[:2]
        uniforms = random.uniform((count,))
        indices = np.empty((trials, count), dtype=np.intp)
        block = max(1, BLOCK_ELEMENTS // max(1, trials * current.shape[1]))
        for start in range(0, count, block):
            part = slice(start, start + block)
            logits = log_weights[:, None, :] + transition_log_densities(model, following[:, part], current, step)
            indices[:, part] = draw_from_log_weights(logits.reshape(-1, logits.shape[-1]),
                                                     uniforms[:, part].ravel()).reshape(trials, -1)
        return indices


@SMOOTHERS.register_kind
class RejectionBackwardSampling(BackwardSampling):
    """FFBS by rejection sampling with the transition density's bound (Douc et al. 2011): O(M) per step on average."""

    kind: Literal["ffbs_rejection"] = "ffbs_rejection"
    rounds: StrictInt = Field(10, ge=1, le=10_000,
                              description="rejection rounds per step before the remaining draws are made exactly")

    def check(self, filter_kind, model, settings):
        super().check(filter_kind, model, settings)
        if isinstance(model.transition_density(), ValueError):
            raise ValueError(f"@smoothers: the ffbs_rejection smoother needs a bound of the transition density; model "
                             f"{model.kind} gives its own transition_log_density, whose bound pfx does not know "
                             "(use ffbs)")

    def step_back(self, model, following, current, log_weights, step, random) -> np.ndarray:
        density = model.transition_density()
        dimension = following.shape[-1]
        log_bound = float(density.log_density(np.zeros(dimension), np.zeros(dimension)))
        trials, count = following.shape[:2]
        weights = np.exp(log_weights)
        indices = np.zeros((trials, count), dtype=np.intp)
        pending = np.ones((trials, count), dtype=bool)
        for _ in range(self.rounds):
            rows = np.flatnonzero(pending.any(axis=1))
            if not rows.size:
                return indices
            streams = random.subset(rows)         # each trial draws for all M while it has any pending
            candidates = inverse_cdf(weights[rows], streams.uniform((count,)))
            accept_draws = streams.uniform((count,))
            chosen = _gather(current[rows], candidates)
            mean = model.mean_transition(chosen, step)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                accepted = np.log(accept_draws) < density.log_density(following[rows], mean) - log_bound
            accepted &= pending[rows]
            block = indices[rows]
            block[accepted] = candidates[accepted]
            indices[rows] = block
            pending[rows] &= ~accepted
        rows = np.flatnonzero(pending.any(axis=1))
        if rows.size:                             # the rest exactly: the same law (module docstring)
            exact = BackwardSampling.step_back(self, model, following[rows], current[rows], log_weights[rows], step,
                                               random.subset(rows))
            block = indices[rows]
            block[pending[rows]] = exact[pending[rows]]
            indices[rows] = block
        return indices


def _check_genealogy(kind: str, settings) -> None:
    for key in ("move", "diffusion", "injection"):
        value = getattr(settings, key, None)
        if value is not None and getattr(value, "kind", "none") != "none":
            raise ValueError(f"@smoothers: the {kind} smoother follows each particle's ancestors, and filter.{key} "
                             f"({value.kind}) changes particles after their ancestor was chosen, so the recorded paths "
                             "are not the filter's (use ffbs)")


def lineage(ancestors: np.ndarray, end: int, start: int) -> np.ndarray:
    """The index at step ``start`` of the ancestor of each particle of step ``end`` (1-based
    steps, start <= end), (R, N), following ``ancestors`` (R, T, N) back."""
    trials, _, count = ancestors.shape
    indices = np.broadcast_to(np.arange(count), (trials, count))
    for step in range(end, start, -1):
        indices = np.take_along_axis(ancestors[:, step - 1], indices, axis=1)
    return indices


class _GenealogyBased(Smoother):
    needs_genealogy = True

    def check(self, filter_kind, model, settings):
        super().check(filter_kind, model, settings)
        _check_genealogy(self.kind, settings)


@SMOOTHERS.register_kind
class FixedLagSmoother(_GenealogyBased):
    """Fixed-lag smoothing from the genealogy: x_k estimated with the weights of step k + lag."""

    kind: Literal["fixed_lag"] = "fixed_lag"
    lag: StrictInt = Field(10, ge=1, le=1_000_000, description="steps of measurements used after k (L)")

    def smooth(self, history: FilterHistory, model, random: TrialStreams) -> Smoothed:
        particles, log_weights, ancestors = history.particles, history.log_weights, history.ancestors
        steps = particles.shape[1]
        means, deviations = _empty_moments(particles)
        for k in range(1, steps + 1):
            end = min(k + self.lag, steps)
            states = _gather(particles[:, k - 1], lineage(ancestors, end, k))
            means[:, k - 1], deviations[:, k - 1] = weighted_moments(model, np.exp(log_weights[:, end - 1]), states)
        return Smoothed(means, deviations)


@SMOOTHERS.register_kind
class GenealogySmoother(_GenealogyBased):
    """The genealogy (ancestral-path) smoother: the weighted ancestral paths of the last step's particles."""

    kind: Literal["genealogy"] = "genealogy"

    def smooth(self, history: FilterHistory, model, random: TrialStreams) -> Smoothed:
        particles, log_weights, ancestors = history.particles, history.log_weights, history.ancestors
        trials, steps, count, _ = particles.shape
        weights = np.exp(log_weights[:, -1])
        means, deviations = _empty_moments(particles)
        indices = np.broadcast_to(np.arange(count), (trials, count))
        for k in range(steps, 0, -1):             # one pass back: O(T N)
            means[:, k - 1], deviations[:, k - 1] = weighted_moments(model, weights, _gather(particles[:, k - 1], indices))
            indices = np.take_along_axis(ancestors[:, k - 1], indices, axis=1)
        return Smoothed(means, deviations)


def _empty_moments(particles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    shape = particles.shape[:2] + particles.shape[3:]
    return np.empty(shape), np.empty(shape)


def history_bytes(particles: int, state_dimension: int, steps: int, smoothers) -> int:
    """Memory of one trial's recorded history and the smoothers' temporaries (bytes): the clouds
    and log-weights (8 bytes each), the ancestors (4), M trajectories, and a block of backward
    weights; 0 without particle smoothers."""
    particle_smoothers = [smoother for smoother in smoothers if smoother.needs_history]
    if not particle_smoothers:
        return 0
    total = steps * particles * (8 * state_dimension + 8 + 4)
    trajectories = max([getattr(smoother, "trajectories", 0) for smoother in particle_smoothers] + [0])
    total += 8 * steps * trajectories * state_dimension + 3 * 8 * min(trajectories * particles, BLOCK_ELEMENTS)
    return int(total)
