r"""The jax engine's post-resampling stage: the move, the diffusion and the injection, as masks.

The NumPy engine (:meth:`pfx.filters.particle.engine.ParticleFilter.resample`) applies, to the
resampled particles of the trials that resample, the move (``filter.move``), the adaptive
count, the diffusion and the injection (``filter.injection``), in that order. The compiled step
(:mod:`pfx.filters.particle.jax_engine`) cannot take a subset of the trials: every trial draws
its resampling points, and this stage, for every trial:

* **move**: the move's own ``apply`` (:mod:`pfx.filters.particle.moves`: its mathematics is
  written once against the array namespace) on a :class:`~pfx.filters.particle.moves.MoveContext`
  of every trial, with the parents' predictions :math:`f(x_{k-1}^{a_i}, u_k, 0)` made here from
  the step's control and substep times (the NumPy move reads them on the host by the step
  number). The mcmc move's acceptance rate counts only at the steps a trial resampled: the
  running sum and count per trial are carried (:class:`Carried`), as the NumPy engine tallies them.
* **adaptive count** (``filter.adaptive``, KLD-sampling): the count rule's own ``apply``
  (:mod:`pfx.filters.particle.adaptive`, written once against the array namespace): a random
  order of the resampled particles from the trial's keys, the KLD count over it, the particles
  past it parked on a copy of particle 0. The active count per trial is carried
  (:class:`Carried`) and changes only where a trial resampled; the ancestors follow the order.
* **diffusion**: the diffusion's own ``apply``.
* **injection** (augmented MCL, :mod:`pfx.filters.particle.injection`): the running averages
  :math:`\log w_\text{slow}, \log w_\text{fast}` per trial are carried and updated from the
  step's log-normaliser :math:`L_k` by the injection module's function (unchanged at a step
  without a measurement); each resampled particle is replaced, with probability
  :math:`\max(0, 1 - w_\text{fast}/w_\text{slow})`, by a draw from the filter's prior (with an
  adaptive count, only the particles active after this resampling). Every
  trial draws the uniforms and the prior's particles (NumPy draws only in the trials with a
  positive probability); a trial that did not resample replaces nothing. A prior draw has
  ancestor -1 in the genealogy, as on NumPy. (The prior's ``sample`` traces on jax: the engine's
  probe of the model checks it at plan time, since the initial cloud is drawn from it too.)

Then a select keeps the trials that did not resample as they were.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from pfx.filters.particle.injection import injection_probability, observed_averages
from pfx.filters.particle.jax_diagnostics import by_trial
from pfx.filters.particle.moves import MoveContext


class Carried(NamedTuple):
    """What the stage carries from step to step, per trial; None where the filter has no such stage."""

    log_slow: Any = None          # (R,) log w_slow, float64 (injection)
    log_fast: Any = None          # (R,) log w_fast
    acceptance_sum: Any = None    # (R,) the sum of the move's acceptance rates over the steps it moved
    moved_steps: Any = None       # (R,) their count
    active: Any = None            # (R,) int32: the adaptive count, the cloud's active particles (filter.adaptive)


class AfterResampling:
    """The post-resampling stage of a bound filter (``bound``), in ``dtype``."""

    def __init__(self, bound, dtype):
        self.bound, self.model, self.dtype = bound, bound.model, dtype
        self.move, self.injection, self.adaptive = bound.move, bound.injection, bound.adaptive

    def start(self, trials: int) -> Carried:
        """The carried values before step 1: both averages at log 0, nothing tallied, every
        particle active."""
        never = jnp.full(trials, -jnp.inf, jnp.float64) if self.injection is not None else None
        tally = self.move is not None and self.move.reports_acceptance
        zeros = jnp.zeros(trials, jnp.float64) if tally else None
        active = jnp.full(trials, self.bound.particles, jnp.int32) if self.adaptive is not None else None
        return Carried(log_slow=never, log_fast=never, acceptance_sum=zeros, moved_steps=zeros, active=active)

    def observe(self, carried: Carried, increment, observed) -> Carried:
        """The injection's averages after step k's log-normaliser ``increment`` (R,), for the
        trials ``observed``; as they were without injection."""
        if self.injection is None:
            return carried
        slow, fast = observed_averages(self.injection, carried.log_slow, carried.log_fast,
                                       increment.astype(jnp.float64), observed)
        return carried._replace(log_slow=slow, log_fast=fast)

    def apply(self, carried: Carried, offspring, chosen, resampled, before, inputs, random):
        """The move, the adaptive count, the diffusion and the injection on every trial's ``offspring`` (R, N, d)
        (drawn by the indices ``chosen``, (R, N)); the trials not ``resampled`` are kept by the
        caller's select. ``before``: (the previous step's particles, the weighted cloud, its
        log-weights and weights). Returns (offspring, ancestors, carried, injected per trial)."""
        previous, cloud, log_weights, weights = before
        ancestors, injected = chosen, None
        if self.move is not None:
            offspring, carried = self._move(carried, offspring, chosen, resampled, previous, cloud, log_weights,
                                            weights, inputs, random)
        if self.adaptive is not None:                    # KLD: the first n of a random order
            offspring, counts, order = self.adaptive.apply(offspring, random)
            ancestors = jnp.take_along_axis(chosen, order.astype(chosen.dtype), axis=1)
            carried = carried._replace(active=jnp.where(resampled, counts.astype(jnp.int32), carried.active))
        if self.bound.diffusion.kind != "none":          # moves the resampled trials' particles apart
            offspring = jnp.asarray(self.bound.diffusion.apply(offspring, random), self.dtype)
        if self.injection is not None:
            probability = injection_probability(carried.log_slow, carried.log_fast)
            count = offspring.shape[1]
            uniforms = random.uniform((count,), jnp.float64)
            fresh = jnp.asarray(self.bound.prior.sample(random, (count,)), self.dtype)
            replaced = (uniforms < probability[:, None]) & resampled[:, None]
            if carried.active is not None:                           # an inactive particle stays parked
                replaced = replaced & (jnp.arange(count) < carried.active[:, None])
            offspring = jnp.where(replaced[..., None], fresh, offspring)
            ancestors = jnp.where(replaced, -1, ancestors)           # a prior draw has no ancestor
            injected = jnp.sum(replaced, axis=-1, dtype=jnp.int32)
        return offspring, ancestors, carried, injected

    def _move(self, carried, offspring, chosen, resampled, previous, cloud, log_weights, weights, inputs, random):
        """``filter.move`` on every trial, with the context the NumPy engine gives it; the
        acceptance tallied where a trial resampled."""
        parents = parent_means = None
        if self.move.needs_parents:
            parents = jnp.take_along_axis(previous, chosen[..., None], axis=1)
            parent_means = self.parent_means(parents, inputs)
        # NaN where a measurement is missing, as the NumPy engine hands the move its row
        measurement = jnp.where(inputs.observed[:, None], inputs.measurement.astype(self.dtype), jnp.nan)
        context = MoveContext(model=self.model, step=inputs.step, resampled=offspring, cloud=cloud, weights=weights,
                              measurement=measurement, parents=parents, indices=chosen, log_weights=log_weights,
                              parent_means=parent_means)
        moved, acceptance = self.move.apply(context, random)
        if acceptance is not None and carried.acceptance_sum is not None:
            carried = carried._replace(
                acceptance_sum=carried.acceptance_sum + jnp.where(resampled, acceptance.astype(jnp.float64), 0.0),
                moved_steps=carried.moved_steps + resampled)
        return jnp.asarray(moved, self.dtype), carried

    def parent_means(self, parents, inputs):
        r""":math:`\bar f_k(x_{k-1})` of each parent (:meth:`pfx.models.base.Model.mean_transition`'s
        substeps without noise), from the compiled step's control and substep times, which the
        model's method reads on the host by the step number."""
        model = self.model
        control = None if inputs.control is None else inputs.control.astype(self.dtype)
        state = model.reset_accumulators(parents)
        zeros = jnp.zeros(parents.shape[:-1] + (model.process_noise_dimension,), parents.dtype)
        for substep in range(inputs.times.shape[0]):
            state = model.propagate_at(state, control, zeros, inputs.times[substep])
        return jnp.asarray(state, parents.dtype)

    def fill_trace(self, trace, carried: Carried, injected) -> None:
        """The trace's injection counts (R, T) and the move's mean acceptance per trial (NaN:
        never moved), from the scan's outputs and its last carried values (on the host)."""
        if injected is not None:
            trace.injected = by_trial(injected).astype(np.int64)
        if carried.acceptance_sum is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                trace.move_acceptance = np.asarray(carried.acceptance_sum, dtype=float) / np.asarray(
                    carried.moved_steps, dtype=float)
