r"""The particle filter's step, written once: both backends run it.

A particle filter is a Feynman-Kac model: at step k a Markov kernel :math:`M_k` moves each
particle and a potential :math:`G_k` weighs it. :meth:`ParticleKernel.step` is one step over an
explicit :class:`Cloud`:

1. **look-ahead** (the auxiliary filter only, ``filter.auxiliary``): first-stage weights
   :math:`\lambda \propto w_{k-1}\, e^{g}` (:mod:`pfx.filters.particle.auxiliary`), whose
   normaliser :math:`L^{(1)}_k` joins the log-likelihood; the trials the ESS rule picks resample by
   them, and :math:`-g_{a_i}` joins the weight adjustment;
2. **predict**, :math:`M_k`: the transition (the bootstrap filter) or a guided proposal
   (:mod:`pfx.filters.particle.proposals`), whose importance correction
   :math:`\log p(x_k \mid x_{k-1}) - \log q` is the step's *weight adjustment*; a particle that left
   the model's domain (NaN or inf) is parked at 0 with weight zero and counted
   (``lost_particles``);
3. **update**, :math:`G_k`: :math:`\log w_k = \log w_{k-1} + \log \ell_k(x_k) + \text{adjustment}`
   with the configured weighting :math:`\ell`, normalised by log-sum-exp; the normaliser
   :math:`L_k` is the step's log-likelihood increment (0 where the measurement is missing); a trial
   whose weights all underflow is *degenerate* and restarts from uniform weights;
4. **estimate** the weighted (circular) mean and :math:`\mathrm{ESS}_k = 1/\sum_i w_{k,i}^2`;
5. **resample** the trials whose ESS is below the threshold (not for the auxiliary filter, which
   resamples at its next look-ahead), then, on their resampled particles, the move
   (:mod:`pfx.filters.particle.moves`), the adaptive count (:mod:`pfx.filters.particle.adaptive`),
   the diffusion and the injection (:mod:`pfx.filters.particle.injection`), in that order; their
   weights become uniform.

What differs between the backends is not the algorithm but a few primitives, which each driver
defines beside its loop: :class:`~pfx.filters.particle.engine.ParticleFilter` (NumPy, a Python loop
that raises at the failing step) and :class:`~pfx.filters.particle.jax_engine.JaxParticleFilter`
(JAX, a ``lax.scan`` that flags failures and raises after):

==================  ============================================  ==========================================
primitive           NumPy                                         JAX
==================  ============================================  ==========================================
``select(picks)``   the rows the ESS rule picked, as a            a mask: every row draws, a ``where``
                    :class:`~pfx.filters.particle.engine.Rows`:   keeps the rows not picked
                    only they draw (each trial's stream is its
                    own, so no other trial's draws move)
``transition``,     the model's host methods by step number;      the substeps scanned over the compiled
``propose``         a model's fused compiled step                 step's control and times
``find_lost``,      one sum first, the mask only if it is not     the mask; a select
``park``            finite; parked in place
``normalise``       log-sum-exp with a fast path, raising on a    the same arithmetic with selects, the
                    NaN likelihood                                failure as a flag
``flag``            raise the failure now                         set its bit in the step's ``failures``
``resampler``,      the merged inverse-CDF walk (numba) and a     float64 cumulative sums, ``searchsorted``,
``gather``          compiled gather                               ``take_along_axis``
==================  ============================================  ==========================================

Both backends consume their streams in the same order of calls (resampler, move, adaptive count,
diffusion, injection), so a stream that served both would give both the same draws.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Optional

import numpy as np

from pfx.errors import ModelContractError, ModelNumericalError
from pfx.filters.particle.cloud import active_uniform, posterior_mean
from pfx.filters.particle.injection import injection_probability, observed_averages
from pfx.filters.particle.likelihood_failure import bad_log_likelihood_message
from pfx.filters.particle.moves import MoveContext
from pfx.numerics.log_weights import effective_sample_size
from pfx.numerics.parameter_checks import broken_rule_message

# the bits of a step's ``failures``, per trial; above them, the code of the first rule of a law's
# parameters the trial's transition broke (pfx.numerics.parameter_checks: a negative Poisson rate)
EVERY_PARTICLE_LOST, BAD_LIKELIHOOD, NON_FINITE_ESTIMATE = 1, 2, 4
BROKEN_RULE_SHIFT = 3


class Carried(NamedTuple):
    """The post-resampling stage's running values, per trial; None where the filter has no such stage."""

    log_slow: Any = None          # (R,) log w_slow, float64 (injection)
    log_fast: Any = None          # (R,) log w_fast
    acceptance_sum: Any = None    # (R,) the sum of the move's acceptance rates over the steps it moved
    moved_steps: Any = None       # (R,) their count
    active: Any = None            # (R,) the adaptive count: the cloud's active particles (filter.adaptive)


class Cloud(NamedTuple):
    """What one step hands the next."""

    particles: Any            # (R, N, d)
    log_weights: Any          # (R, N), normalised
    weights: Any              # (R, N) their exponentials as the normalisation made them (NumPy); None on JAX
    log_likelihood: Any       # (R,), float64
    lost_particles: Any       # (R,), int
    ancestors: Any            # (R, N): each particle's index in the previous step's weighted cloud
    after: Carried = Carried()


class StepInputs(NamedTuple):
    """What step k reads."""

    step: Any                 # k = 1..T
    measurement: Any          # (R, m); on JAX a missing one holds 0, on NumPy NaN
    observed: Any             # (R,) bool; None: every trial has its measurement (NumPy)
    control: Any = None       # (c,) u_k, or None (JAX; NumPy reads it by the step number)
    times: Any = None         # (s,) the substeps' start times (JAX)


class StepOutputs(NamedTuple):
    """The trace's columns at step k; None where not computed. The JAX driver adds the diagnostics
    its flags ask for (:mod:`pfx.filters.particle.jax_diagnostics`)."""

    estimate: Any             # (R, d)
    ess: Any                  # (R,)
    resampled: Any            # (R,) bool
    degenerate: Any           # (R,) bool
    increment: Any            # (R,) L_k
    failures: Any             # (R,) bits (JAX); None on NumPy, which raised
    spread: Any = None        # (R,) weighted RMS distance of the positions from their mean
    within_radius: Any = None  # (R,) the spread criterion's share within its radius
    standard_deviations: Any = None   # (R, d)
    ancestors: Any = None     # (R, N) the genealogy: those that made this step's particles
    particles: Any = None     # (R, N, d) the weighted cloud (the history the smoothers read)
    log_weights: Any = None   # (R, N)
    predictive: Any = None    # the predictive law's moments and scores (pfx.filters.particle.predictive)
    forecast_particles: Any = None     # (r, N, d) the forecast rows' weighted cloud
    forecast_log_weights: Any = None   # (r, N)
    covariance: Any = None    # (R, d, d) the weighted posterior covariance before resampling, float64
    nis: Any = None           # (R,) the predicted cloud's NIS, float64
    snapshots: Any = None     # {stage: ((r, N, d), (r, N))} the snapshot rows' clouds and weights
    prior_snapshot: Any = None    # (r, N, d) the snapshot rows' prior cloud: set once, after the scan
    injected: Any = None      # (R,) the particles replaced by prior draws (filter.injection)
    particle_counts: Any = None   # (R,) the active count the step's cloud was weighted with (filter.adaptive)


class StageClouds(NamedTuple):
    """One step's clouds at the stages diagnostics read: after the prediction ("predicted"), the
    weight update ("weighted") and resampling ("resampled")."""

    predicted: Any                # (R, N, d) after the transition (lost particles at 0)
    predicted_log_weights: Any    # (R, N) the previous weights, lost particles at -inf
    predicted_weights: Any        # (R, N) their exponentials (NumPy: carried; None on JAX)
    adjustment: Any               # (R, N) the weight adjustment, or None
    log_weights: Any              # (R, N) after the weight update, normalised
    weights: Any                  # (R, N) their exponentials
    estimate: Any                 # (R, d)
    resampled: Any                # (R, N, d) after resampling and what follows it
    resampled_log_weights: Any    # (R, N)
    resampled_weights: Any        # (R, N)
    active: Any                   # (R,) the adaptive count after resampling, or None


class Prediction(NamedTuple):
    """M_k's result: the cloud to weigh."""

    state: Any                # (R, N, d), lost particles parked at 0
    log_weights: Any          # (R, N) the previous weights, lost particles at -inf
    weights: Any              # (R, N) their exponentials
    adjustment: Any           # (R, N) log p(x_k | x_k-1) - log q - g_a, or None
    likelihood: Any           # (R, N) log p(z_k | x_k) from a fused compiled step, or None
    lost: Any                 # (R, N) bool, or None where nothing was lost (NumPy)
    failures: Any             # (R,) bits so far (JAX), or None


class Weighted(NamedTuple):
    """G_k's result."""

    log_weights: Any          # (R, N) normalised
    weights: Any              # (R, N)
    increment: Any            # (R,) L_k, 0 where the measurement is missing
    degenerate: Any           # (R,) bool: every weight underflowed (NumPy: None where none did)
    failures: Any             # (R,) bits so far (JAX), or None


class Resampled(NamedTuple):
    """The resampling stage's result."""

    state: Any
    log_weights: Any
    weights: Any
    ancestors: Any            # (R, N): the resampled rows' ancestors, i -> i elsewhere (None: not tracked)
    indices: Any              # the resampler's draws (NumPy: the picked rows'; JAX: i -> i where not picked)
    resampled: Any            # (R,) bool
    after: Carried
    injected: Any             # (R,) particles replaced by prior draws, or None


class ParticleKernel:
    """The step of a bound particle filter (``bound``, a
    :class:`~pfx.filters.particle.bound.BoundParticleFilter`), written once against the array
    namespace; a driver subclass supplies the primitives (module docstring) and the loop."""

    xp: Any = np                  # the driver's array namespace
    dtype: Any = np.float64
    tracks_ancestors = True
    keeps_stages = True           # whether the step hands back its stages' clouds (StageClouds)
    skips_unobserved = False

    def __init__(self, bound):
        self.bound, self.model, self.particles = bound, bound.model, bound.particles
        self.uniform_log_weight = float(-np.log(bound.particles))

    def start(self, state, trials: int) -> Cloud:
        """The cloud before step 1: the prior's particles, uniform weights, nothing counted."""
        count, xp = self.particles, self.xp
        bound = self.bound
        never = xp.full(trials, -np.inf, dtype=np.float64) if bound.injection is not None else None
        tally = xp.zeros(trials, dtype=np.float64) if bound.move is not None and bound.move.reports_acceptance else None
        active = xp.full(trials, count, dtype=self.count_dtype) if bound.adaptive is not None else None
        weights = self.carried_weights(xp.full((trials, count), 1.0 / count, dtype=self.dtype))
        return Cloud(particles=state, log_weights=xp.full((trials, count), -np.log(count), dtype=self.dtype),
                     weights=weights, log_likelihood=xp.zeros(trials, dtype=np.float64),
                     lost_particles=xp.zeros(trials, dtype=self.count_dtype), ancestors=self.identity(trials, xp),
                     after=Carried(log_slow=never, log_fast=never, acceptance_sum=tally, moved_steps=tally,
                                   active=active))

    def step(self, cloud: Cloud, inputs: StepInputs, random) -> tuple[Cloud, StepOutputs, Optional[StageClouds]]:
        """Step k (module docstring): the next cloud, the trace's columns and the stages' clouds
        (None where the driver keeps none)."""
        first = None
        if self.bound.auxiliary is not None:         # resample by the look-ahead before moving
            cloud, first = self.look_ahead(cloud, inputs, random)
        prediction = self.predict(cloud, inputs, random, None if first is None else first.adjustment)
        weighted = self.update_weights(prediction, inputs, cloud.after.active)
        estimate, ess, failures = self.estimate(prediction.state, weighted, inputs.step)
        after = self.observe_likelihood(cloud.after, weighted.increment, inputs.observed)
        if first is None:
            result = self.resample(prediction.state, weighted.log_weights, weighted.weights,
                                   self.picks(ess, cloud.after.active), random, cloud.particles, after, inputs)
        else:                # the auxiliary filter resamples at its next look-ahead, not here
            result = Resampled(prediction.state, weighted.log_weights, weighted.weights, first.ancestors, None,
                               first.resampled, after, None)
        return self.advance(cloud, first, prediction, weighted, estimate, ess, failures, result)

    def advance(self, cloud: Cloud, first, prediction: "Prediction", weighted: "Weighted", estimate, ess, failures,
                result: "Resampled") -> tuple[Cloud, StepOutputs, StageClouds]:
        """The step's results: the cloud carried to the next step (the log-likelihood and the lost
        particles counted), the trace's columns and the stages' clouds."""
        xp = self.xp
        increment = weighted.increment
        log_likelihood = self.accumulate(cloud.log_likelihood, None if first is None else first.increment, increment)
        if first is not None:           # L_k = L1_k + L2_k
            increment = first.increment + increment.astype(np.float64)
        lost_particles = cloud.lost_particles
        if prediction.lost is not None:
            lost_particles = lost_particles + xp.sum(prediction.lost, axis=-1, dtype=self.count_dtype)
        carried = Cloud(particles=result.state, log_weights=result.log_weights,
                        weights=self.carried_weights(result.weights), log_likelihood=log_likelihood,
                        lost_particles=lost_particles, ancestors=result.ancestors, after=result.after)
        outputs = StepOutputs(estimate=estimate, ess=ess, resampled=result.resampled, degenerate=weighted.degenerate,
                              increment=increment, failures=failures,
                              ancestors=cloud.ancestors if first is None else first.ancestors,
                              injected=result.injected, particle_counts=cloud.after.active)
        if not self.keeps_stages:         # no diagnostic reads them
            return carried, outputs, None
        clouds = StageClouds(predicted=prediction.state, predicted_log_weights=prediction.log_weights,
                             predicted_weights=prediction.weights, adjustment=prediction.adjustment,
                             log_weights=weighted.log_weights, weights=weighted.weights, estimate=estimate,
                             resampled=result.state, resampled_log_weights=result.log_weights,
                             resampled_weights=result.weights, active=result.after.active)
        return carried, outputs, clouds

    # -- the stages ------------------------------------------------------------------------------

    def look_ahead(self, cloud: Cloud, inputs: StepInputs, random) -> tuple[Cloud, "FirstStage"]:
        """The auxiliary filter's first stage on the cloud of step k-1: (the cloud to predict from,
        the :class:`FirstStage`)."""
        log_first, first, increment, look_ahead = self.bound.auxiliary.first_stage(
            cloud.log_weights, self.look_ahead_weights(cloud.particles, inputs), inputs.observed)
        log_first = log_first.astype(cloud.log_weights.dtype)
        rows = self.select(self.picks(effective_sample_size(first), cloud.after.active))
        if rows is None:            # no trial resamples: lambda are the weights the second stage starts from
            xp = self.xp
            return cloud._replace(log_weights=log_first, weights=self.carried_weights(first)), FirstStage(
                increment=increment.astype(np.float64), adjustment=-look_ahead.astype(self.dtype),
                resampled=xp.zeros(len(first), dtype=bool), ancestors=self.identity(len(first), xp))
        # no move, count or injection combines with the auxiliary filter: the ancestors are the draws
        result = self.resample(cloud.particles, log_first, first, rows, random, None, cloud.after, inputs)
        xp = self.xp
        look_ahead = rows.merge(xp.take_along_axis(rows.take(look_ahead), result.indices, axis=1), look_ahead)
        return Cloud(particles=result.state, log_weights=result.log_weights, weights=self.carried_weights(result.weights),
                     log_likelihood=cloud.log_likelihood, lost_particles=cloud.lost_particles,
                     ancestors=cloud.ancestors, after=result.after), FirstStage(
            increment=increment.astype(np.float64), adjustment=-look_ahead.astype(self.dtype),
            resampled=result.resampled, ancestors=result.ancestors)

    def predict(self, cloud: Cloud, inputs: StepInputs, random, adjustment) -> Prediction:
        """M_k: x_k from the transition or the guided proposal (its correction joins the weight
        adjustment); particles that left the model's domain parked at weight zero."""
        likelihood, failures = None, None
        if self.bound.proposal is not None:
            state, correction, failures = self.propose(cloud, inputs, random)
            adjustment = correction if adjustment is None else correction + adjustment
        else:
            state, likelihood, failures = self.transition(cloud, inputs, random)
        state, lost = self.find_lost(state)
        log_weights = cloud.log_weights
        if lost is not None:
            xp = self.xp
            log_weights = xp.where(lost, -np.inf, log_weights)
            failures = self.flag(failures, xp.all(xp.isneginf(log_weights), axis=-1), EVERY_PARTICLE_LOST, inputs.step)
            state = self.park(state, lost)        # at 0 until resampling replaces it
        weights = self.weights_before(log_weights, cloud, lost)
        return Prediction(state=state, log_weights=log_weights, weights=weights, adjustment=adjustment,
                          likelihood=likelihood, lost=lost, failures=failures)

    def update_weights(self, prediction: Prediction, inputs: StepInputs, active) -> "Weighted":
        r"""G_k: log w_k = log w_{k-1} + log l_k(x_k) (+ the adjustment), normalised; the normaliser
        L_k (0 where the measurement is missing)."""
        xp = self.xp
        observed = inputs.observed
        if observed is not None and self.skips_unobserved and not observed.any():
            likelihood = xp.zeros_like(prediction.log_weights)   # no measurement anywhere: nothing to weigh
        else:
            likelihood = prediction.likelihood
            if likelihood is None:
                measurement = self.as_measurement(inputs.measurement)[:, None, :]
                likelihood = self.bound.weighting.log_weights(self.model, measurement, prediction.state,
                                                              prediction.weights)
            likelihood = self.check_weights_shape(likelihood, prediction.log_weights.shape, inputs.step)
        if prediction.adjustment is not None:      # a guided proposal's or the auxiliary filter's terms
            likelihood = likelihood + prediction.adjustment
        if observed is not None:        # (the adjustment is 0 there: the proposal is the transition, g = 0)
            likelihood = xp.where(observed[:, None], likelihood, 0.0)
        log_weights, weights, normaliser, degenerate, bad = self.normalise(prediction.log_weights, likelihood,
                                                                           prediction.lost, active, inputs.step)
        failures = self.flag(prediction.failures, bad, BAD_LIKELIHOOD, inputs.step)
        if observed is not None:    # a predict-only step adds nothing (its normaliser is only the lost mass)
            normaliser = xp.where(observed, normaliser, 0.0)
        return Weighted(log_weights, weights, normaliser, degenerate, failures)

    def estimate(self, state, weighted: "Weighted", step):
        """The weighted (circular) mean and the ESS before resampling; a non-finite estimate is a failure."""
        estimate = posterior_mean(self.model, weighted.weights, state)
        failures = self.flag(weighted.failures, self.non_finite_rows(estimate), NON_FINITE_ESTIMATE, step)
        return estimate, effective_sample_size(weighted.weights), failures

    def resample(self, state, log_weights, weights, picks, random, previous, after: Carried,
                 inputs: StepInputs) -> Resampled:
        """The trials ``picks`` selects (the ESS rule's; or a selection already made) take their
        resampled particles, then the move, the adaptive count, the diffusion and the injection,
        and uniform weights; the others keep theirs."""
        bound, count = self.bound, self.particles
        rows = picks if isinstance(picks, RowSelection) else self.select(picks)
        xp = self.xp
        trials = len(log_weights)
        if rows is None:              # no trial resamples (sis, or none below the threshold)
            return Resampled(state, log_weights, weights, self.identity(trials, xp) if self.tracks_ancestors else None,
                             None, xp.zeros(trials, dtype=bool), after,
                             xp.zeros(trials, dtype=self.count_dtype) if bound.injection is not None else None)
        streams = rows.streams(random)
        indices = rows.indices(self.resampler(rows.take(weights), streams))
        offspring = self.gather(state, rows, indices)
        ancestors = indices
        if bound.move is not None:
            offspring, after = self.move(rows, offspring, indices, previous, state, log_weights, weights, inputs,
                                         streams, after)
        if bound.adaptive is not None:            # KLD: the first n of a random order
            offspring, counts, order = bound.adaptive.apply(offspring, streams)
            ancestors = xp.take_along_axis(indices, order.astype(indices.dtype), axis=1)
            after = after._replace(active=rows.merge(counts.astype(after.active.dtype), after.active))
        if bound.diffusion.kind != "none":        # moves the resampled particles apart
            offspring = self.as_state(bound.diffusion.apply(offspring, streams))
        injected = None
        if bound.injection is not None:
            offspring, ancestors, injected = self.inject(rows, offspring, ancestors, after, streams)
        uniform_log, uniform = self.uniform_log_weight, 1.0 / count
        if bound.adaptive is not None:            # uniform over the active particles only
            uniform_log, uniform = active_uniform(rows.take(after.active), count)
        return Resampled(
            state=rows.merge(offspring, state), log_weights=rows.merge(uniform_log, log_weights),
            weights=rows.merge(uniform, weights),
            ancestors=rows.merge(ancestors, self.identity(trials, xp)) if self.tracks_ancestors else None,
            indices=indices, resampled=rows.mask(), after=after, injected=injected)

    def move(self, rows, offspring, indices, previous, state, log_weights, weights, inputs, streams, after):
        """``filter.move`` on the resampled rows, given the cloud and weights before resampling, the
        measurement and (if it needs them) the parents and their noise-free predictions; the
        acceptance rate tallied per trial."""
        move, parents, parent_means = self.bound.move, None, None
        if move.needs_parents:
            parents = self.gather(previous, rows, indices)
            parent_means = self.mean_prediction(parents, inputs)
        context = MoveContext(model=self.model, step=inputs.step, resampled=offspring, cloud=rows.take(state),
                              weights=rows.take(weights), measurement=rows.take(self.measured(inputs)),
                              parents=parents, indices=indices, log_weights=rows.take(log_weights),
                              parent_means=parent_means)
        moved, acceptance = move.apply(context, streams)
        if acceptance is not None and after.acceptance_sum is not None:
            after = after._replace(acceptance_sum=after.acceptance_sum + rows.scatter(acceptance.astype(np.float64), 0.0),
                                   moved_steps=after.moved_steps + rows.mask())
        return self.as_state(moved), after

    def inject(self, rows, offspring, ancestors, after: Carried, streams):
        """Augmented MCL: each active resampled particle replaced, with probability
        max(0, 1 - w_fast/w_slow), by a draw from the filter's prior; only the rows with a positive
        probability draw. (offspring, ancestors (-1: a prior draw), the count replaced per trial)."""
        count = offspring.shape[1]
        xp = self.xp
        probability = injection_probability(rows.take(after.log_slow), rows.take(after.log_fast))
        drawing = rows.within(probability > 0.0)
        if drawing is None:
            replaced = xp.zeros(offspring.shape[:2], dtype=bool)
        else:
            draws = drawing.streams(streams)
            replaced = self.uniforms(draws, (count,)) < drawing.take(probability)[:, None]
            active = rows.take(after.active) if after.active is not None else None
            if active is not None:                      # an inactive particle stays parked
                replaced = replaced & (xp.arange(count) < drawing.take(active)[:, None])
            fresh = drawing.merge(self.as_state(self.bound.prior.sample(draws, (count,))), offspring)
            replaced = drawing.scatter(replaced, False)
            offspring = self.put(replaced, fresh, offspring)
            ancestors = xp.where(replaced, -1, ancestors)       # a prior draw has no ancestor
        return offspring, ancestors, rows.scatter(xp.sum(replaced, axis=-1, dtype=self.count_dtype), 0)

    def observe_likelihood(self, after: Carried, increment, observed) -> Carried:
        """The injection's averages after the step's normaliser (unchanged where no measurement)."""
        if self.bound.injection is None:
            return after
        slow, fast = observed_averages(self.bound.injection, after.log_slow, after.log_fast,
                                       increment.astype(np.float64), observed)
        return after._replace(log_slow=slow, log_fast=fast)

    def identity(self, trials: int, xp):
        """i -> i for every trial: the ancestors of a step that did not resample."""
        return xp.broadcast_to(xp.arange(self.particles, dtype=self.index_dtype), (trials, self.particles))


class FirstStage(NamedTuple):
    """What the auxiliary filter's first stage of step k hands the rest of the step."""

    increment: Any            # (R,) L1_k, float64; 0 where the measurement is missing
    adjustment: Any           # (R, N) -g_{a_i}, the second stage's weight adjustment
    resampled: Any            # (R,) bool: the trials the ESS rule picked
    ancestors: Any            # (R, N) the resampled trials' ancestors; i -> i for the others


class RowSelection:
    """The trials a stage acts on (the ``select`` primitive's result): NumPy's rows, JAX's mask."""

    def take(self, values):
        """The selected rows' values (JAX: every row's)."""
        raise NotImplementedError

    def streams(self, random):
        """The selected rows' streams."""
        raise NotImplementedError

    def indices(self, drawn):
        """The resampler's draws as the gather takes them."""
        raise NotImplementedError

    def merge(self, new, old):
        """``old`` with the selected rows replaced by ``new`` (the selected rows' values, or a scalar)."""
        raise NotImplementedError

    def scatter(self, values, fill):
        """Every row: ``values`` at the selected rows, ``fill`` elsewhere."""
        raise NotImplementedError

    def mask(self):
        """(R,) bool: which rows are selected."""
        raise NotImplementedError

    def within(self, condition):
        """The selected rows where ``condition`` (over the selected rows) holds, as a selection of
        their own over the selected rows' arrays; None where none does (NumPy)."""
        raise NotImplementedError


def failure_error(model, bit: int, step) -> Exception:
    """The error of a failure ``bit`` at ``step``, as both drivers raise it."""
    if bit & EVERY_PARTICLE_LOST:
        return ModelNumericalError(f"model {model.kind}: every particle of a trial became NaN or infinite at step "
                                   f"{step} of the filter (check the prior and the noise)")
    if bit & BAD_LIKELIHOOD:
        return ModelNumericalError(bad_log_likelihood_message(model, step, "NaN or an infinite"))
    return ModelNumericalError(f"model {model.kind} produced NaN or infinite particles at step {step} of the filter "
                               "(check the prior and the noise)")


def first_failure(model, failures) -> Optional[Exception]:
    """The error the NumPy driver raises for a run's failure bits (T, R), at the first step with
    one; None when no bit is set. A law's parameter out of its domain comes first, as NumPy raises
    it in the transition, before the weights."""
    failures = np.asarray(failures)
    flagged = np.argwhere(failures != 0)        # (step, trial) pairs, in step order
    if flagged.size == 0:
        return None
    index = int(flagged[0, 0])
    step = index + 1
    codes = failures[index].astype(np.int64) >> BROKEN_RULE_SHIFT
    if codes.any():
        return ModelContractError(f"model {model.kind}: {model.transition_method()} raised ValueError: "
                                  f"{broken_rule_message(int(codes[codes != 0][0]))} (step {step} of the filter)")
    bits = int(np.bitwise_or.reduce(failures[index]))
    for bit in (EVERY_PARTICLE_LOST, BAD_LIKELIHOOD):
        if bits & bit:
            return failure_error(model, bit, step)
    return failure_error(model, NON_FINITE_ESTIMATE, step)
