r"""The particle filter on the JAX backend: one pure step, scanned over the steps, compiled once.

The algorithm is :mod:`pfx.filters.particle.engine`'s (predict, weight, normalise, estimate,
resample by the ESS rule; its docstring states each stage), written as a function of explicit
values so that XLA can compile the whole run, on a CPU or a GPU:

    step(cloud, inputs) -> (cloud, outputs)

* ``cloud`` (:class:`Cloud`) is everything carried from step to step: the particles (trials, N,
  d), their log-weights, each trial's log-likelihood so far, its lost particles, and the
  ancestors of the current particles;
* ``inputs`` (:class:`StepInputs`) is what step k reads, arrays indexed by the step and prepared
  on the host before the run: k itself, the measurements (trials, m), which trials have one,
  the control u_k and the substep times;
* the random numbers come from the trials' threefry keys folded with k
  (:class:`~pfx.numerics.key_streams.KeyStreams`): nothing random is carried;
* a guided proposal (``filter.proposal``) replaces the transition by the proposals module's
  own drawing (:meth:`JaxParticleFilter.propose`), and its weight adjustment joins the
  likelihood in the weight update;
* the auxiliary filter (``filter.auxiliary``) runs its first stage before the prediction
  (:mod:`pfx.filters.particle.jax_look_ahead`: resampling by the look-ahead weights, whose
  normaliser joins the step's increment), adds its :math:`-g_{a_i}` to the weight adjustment
  and does not resample at the end of the step;
* ``outputs`` (:class:`StepOutputs`) are the trace's columns at step k: the estimate, the ESS,
  whether the trial resampled, whether its weights underflowed, the log-likelihood increment,
  and what a :class:`~pfx.filters.particle.recorders.Recording` asks for (static flags: a
  diagnostic not asked for is not computed; :mod:`pfx.filters.particle.jax_diagnostics`
  computes them from the step's clouds and makes the trace's fields of them).

Three things differ in form from the NumPy engine, not in what they compute:

* **masks, not subsets**: every trial draws its resampling points and is resampled; the trials
  whose ESS is above the threshold keep their particles by a select. (The NumPy engine touches
  only the trials that resample.) The move, the diffusion and the injection after resampling
  are the stage of :mod:`pfx.filters.particle.jax_after_resampling`, which carries the
  injection's running averages and the move's acceptance tally in the cloud.
* **error flags, not exceptions**: a trial whose particles all left the model's domain, a NaN
  or +inf log-likelihood, a non-finite estimate set a bit in the step's ``failures``, and a law's
  parameter out of its domain in the transition (a negative Poisson rate:
  :mod:`pfx.numerics.parameter_checks`) the code of the rule it broke; after the scan the first
  one is raised as the NumPy engine raises it (:class:`~pfx.errors.ModelNumericalError`, or the
  law's refusal; same message, same step).
* **precision**: ``float32`` keeps the particles, the process noise and the weights in single
  precision: what is stored and carried from step to step, hence the memory traffic that bounds
  a GPU. A model's arithmetic follows JAX's promotion rules: a constant held as a NumPy float64
  array promotes its expression to float64 (the result is stored as float32 again), a Python
  float does not. The resamplers' cumulative sums and the log-likelihood's running sum stay
  float64 (:mod:`pfx.filters.particle.jax_resampling` says why).

The NumPy and JAX backends draw from different generators, so their results agree in
distribution, not number for number (tests/test_jax_backend.py checks that they do).
"""

from __future__ import annotations

from typing import Any, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from pfx.errors import ModelContractError, ModelNumericalError
from pfx.filters.particle.cloud import active_uniform
from pfx.filters.particle.jax_after_resampling import AfterResampling
from pfx.filters.particle.jax_diagnostics import Flags, StageClouds, by_trial, fill_trace, step_diagnostics
from pfx.filters.particle.jax_look_ahead import JaxLookAhead
from pfx.filters.particle.jax_resampling import JAX_RESAMPLERS
from pfx.filters.particle.likelihood_failure import bad_log_likelihood_message
from pfx.filters.particle.predictive import predictive_step
from pfx.filters.trace import FilterTrace
from pfx.numerics.angles import circular_mean
from pfx.numerics.key_streams import KeyStreams
from pfx.numerics.parameter_checks import broken_rule_message, collecting, merge_codes
from pfx.numerics.seeding import SCORE_STREAM

# the bits of a step's ``failures``, per trial; above them, the code of the first rule of a law's
# parameters the trial's transition broke (pfx.numerics.parameter_checks: a negative Poisson rate)
EVERY_PARTICLE_LOST, BAD_LIKELIHOOD, NON_FINITE_ESTIMATE = 1, 2, 4
BROKEN_RULE_SHIFT = 3


class Cloud(NamedTuple):
    """What one step hands the next."""

    particles: Any            # (R, N, d)
    log_weights: Any          # (R, N), normalised
    log_likelihood: Any       # (R,), float64
    lost_particles: Any       # (R,), int
    ancestors: Any            # (R, N): each particle's index in the previous step's weighted cloud
    after: Any = None         # the post-resampling stage's running values (jax_after_resampling.Carried)


class StepInputs(NamedTuple):
    """What step k reads (one slice of arrays indexed by the step)."""

    step: Any                 # k = 1..T
    measurement: Any          # (R, m); a missing one holds 0 (``observed`` says which)
    observed: Any             # (R,) bool
    control: Any              # (c,) u_k, or None
    times: Any                # (s,) the substeps' start times


class StepOutputs(NamedTuple):
    """The trace's columns at step k; None where not asked for."""

    estimate: Any             # (R, d)
    ess: Any                  # (R,)
    resampled: Any            # (R,) bool
    degenerate: Any           # (R,) bool
    increment: Any            # (R,) L_k
    failures: Any             # (R,) bits
    spread: Any = None        # (R,) weighted RMS distance of the positions from their mean
    within_radius: Any = None  # (R,) the spread criterion's share within its radius
    standard_deviations: Any = None   # (R, d)
    ancestors: Any = None     # (R, N) the genealogy
    particles: Any = None     # (R, N, d) the weighted cloud (the history the smoothers read)
    log_weights: Any = None   # (R, N)
    predictive: Any = None    # the predictive law's moments and scores (pfx.filters.particle.predictive)
    forecast_particles: Any = None     # (r, N, d) the forecast rows' weighted cloud (pfx.filters.particle.forecasting)
    forecast_log_weights: Any = None   # (r, N)
    covariance: Any = None    # (R, d, d) the weighted posterior covariance before resampling, float64
    nis: Any = None           # (R,) the predicted cloud's NIS, float64
    snapshots: Any = None     # {stage: ((r, N, d), (r, N))} the snapshot rows' clouds and weights
    prior_snapshot: Any = None    # (r, N, d) the snapshot rows' prior cloud: set once, after the scan
    injected: Any = None      # (R,) the particles replaced by prior draws (filter.injection)
    particle_counts: Any = None   # (R,) the active count the step's cloud was weighted with (filter.adaptive)


class JaxParticleFilter:
    """A bound particle filter (:class:`~pfx.filters.particle.bound.BoundParticleFilter`) as a JAX
    program: :meth:`run` filters a batch of trials; the program is compiled once per shape of
    the batch and per set of diagnostics asked for, and reused."""

    def __init__(self, bound):
        self.bound, self.model = bound, bound.model
        self.dtype = jnp.float32 if bound.precision == "float32" else jnp.float64
        self.resampler = JAX_RESAMPLERS[bound.resampling.resampler.function.__name__]
        self.threshold = bound.resampling.threshold
        self.particles = bound.particles
        self.after_resampling = AfterResampling(bound, self.dtype)
        # the auxiliary filter's first stage (filter.auxiliary), or None
        self.look_ahead = None if bound.auxiliary is None else \
            JaxLookAhead(self, own_look_ahead=_overrides(bound.model, "look_ahead_log_weight"))
        self._programs: dict = {}

    def check_model(self) -> None:
        """Trace the model's laws once on a tiny batch (2 trials x 3 particles, nothing computed):
        a model written for NumPy only (np.* on the state, a write in place) is refused here, at
        plan time, in one line naming the method, rather than deep inside a compiled run."""
        model, trials, count = self.model, 2, 3
        control = model.control(1)
        probes = (
            ("its initial law (the filter's prior)", lambda random, state: self.bound.prior.sample(random, (count,))),
            ("process_noise.sample", lambda random, state: model.process_noise.sample(random, (count,))),
            ("propagate", lambda random, state: model.propagate_at(
                model.reset_accumulators(state), None if control is None else jnp.asarray(control),
                jnp.zeros(state.shape[:-1] + (model.process_noise_dimension,), self.dtype),
                jnp.asarray(model.substep_time(1, 0)))),
            ("log_likelihood", lambda random, state: model.log_likelihood(
                jnp.zeros((trials, 1, model.measurement_dimension), self.dtype), state)),
        )
        if _overrides(model, "transition"):
            raise ValueError(f"@backend: model {model.kind} overrides transition(state, step, random), which reads its "
                             "control on the host at each step; override sample_substep(state, control, time, random) "
                             "(or sample_transition) instead to run on the jax backend (docs/plugins.md), or set "
                             "backend: numpy")
        if _overrides(model, "sample_transition"):
            probes = (probes[0], ("sample_transition", lambda random, state: model.sample_transition(
                state, None if control is None else jnp.asarray(control),
                jnp.asarray([model.substep_time(1, j) for j in range(model.propagations_per_step)]), random)),
                probes[3])
        elif _overrides(model, "sample_substep"):
            probes = (*probes, ("sample_substep", lambda random, state: model.sample_substep(
                state, None if control is None else jnp.asarray(control), jnp.asarray(model.substep_time(1, 0)),
                random)))
        move = self.bound.move
        if move is not None and move.needs_parents:          # the mcmc move evaluates p(x_k | x_k-1)
            probes = (*probes, ("transition density (for move: mcmc)",
                                lambda random, state: move.density.log_density(state, state)))
        proposal = self.bound.proposal
        if proposal is not None:      # the ekf proposal calls measurement_mean and measurement_jacobian
            probes = (*probes, (f"{proposal.settings.kind} proposal (measurement_mean, measurement_jacobian)",
                                lambda random, state: proposal.propose_from(
                                    state, jnp.zeros((trials, model.measurement_dimension), self.dtype),
                                    jnp.ones(trials, bool), random)))
        with jax.enable_x64(True):
            keys = jnp.zeros((trials, 2), jnp.uint32)
            state = jax.ShapeDtypeStruct((trials, count, model.state_dimension), self.dtype)
            for method, probe in probes:
                try:
                    jax.eval_shape(lambda k, x: probe(KeyStreams(k, self.dtype), x), keys, state)
                except Exception as error:      # any failure to trace: the method is NumPy-only
                    reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
                    raise ValueError(
                        f"@backend: model {model.kind}'s {method} does not run on the jax backend ({reason[:160]}); "
                        "write it against the array namespace, xp = pfx.namespace(state), without writing into "
                        "arrays (docs/plugins.md, 'Writing a model for both backends'), or set backend: numpy"
                    ) from None
        if self.look_ahead is not None:
            self.look_ahead.check_model()

    def __getstate__(self) -> dict:
        # compiled programs belong to this process: a copy sent to a worker compiles its own
        return {**self.__dict__, "_programs": {}}

    # -- on the host: inputs in, trace out ---------------------------------------------------

    def run(self, measurements: np.ndarray, random, recording) -> FilterTrace:
        """Filter ``measurements`` (trials, T, m); ``random`` is the batch's
        :class:`~pfx.numerics.seeding.TrialStreams`, whose seeds make the threefry keys."""
        if getattr(random, "seeds", None) is None:
            raise RuntimeError("the jax backend needs the trials' seeds (TrialStreams.from_seeds)")
        trials, steps, _ = measurements.shape
        flags = Flags.of(recording, steps)
        with jax.enable_x64(True):
            program = self._programs.get(flags)
            if program is None:
                program = self._programs[flags] = jax.jit(lambda keys, inputs: self.traced_run(keys, inputs, flags))
            keys = KeyStreams.from_seeds(random.seeds).keys
            inputs = self.step_inputs(measurements)
            cloud, outputs = program(keys, inputs)
            cloud, outputs = jax.device_get((cloud, outputs))
        _raise_first_failure(self.model, np.asarray(outputs.failures))
        return self._trace(cloud, outputs, recording, trials, steps, inputs.observed.T)

    def step_inputs(self, measurements: np.ndarray) -> StepInputs:
        """What each step reads, as arrays indexed by the step (:class:`StepInputs`), from the
        measurements (trials, T, m); estimation's compiled likelihood prepares them once."""
        model, steps = self.model, measurements.shape[1]
        missing = np.isnan(measurements).any(axis=-1)
        controls = [model.control(k) for k in range(1, steps + 1)]
        if all(control is None for control in controls):
            control = None
        else:
            control = np.stack([np.asarray(c, dtype=float) for c in controls])
        times = np.array([[model.substep_time(k, j) for j in range(model.propagations_per_step)]
                          for k in range(1, steps + 1)])
        return StepInputs(step=np.arange(1, steps + 1, dtype=np.int32),
                          measurement=np.nan_to_num(measurements, nan=0.0).swapaxes(0, 1),
                          observed=(~missing).T, control=control, times=times)

    def _trace(self, cloud: Cloud, outputs: StepOutputs, recording, trials: int, steps: int,
               observed: np.ndarray) -> FilterTrace:
        # every array the trace keeps is a copy of its own (by_trial): pfx writes into the trace
        # (here, the untraced rows; later, the metrics)
        spread = by_trial(outputs.spread)
        deviations = by_trial(outputs.standard_deviations)
        rows = recording.trace_rows
        if rows is not None and spread is not None and recording.spread_criterion is None:
            untraced = np.setdiff1d(np.arange(trials), rows)     # steps.csv shows the traced rows only
            spread[untraced] = np.nan
            if deviations is not None:
                deviations[untraced] = np.nan
        trace = FilterTrace(
            estimates=by_trial(outputs.estimate).astype(float), ess=by_trial(outputs.ess).astype(float),
            resampled=by_trial(outputs.resampled), degenerate=by_trial(outputs.degenerate),
            spread=np.full((trials, steps), np.nan) if spread is None else spread.astype(float),
            log_likelihood=np.array(cloud.log_likelihood, dtype=float),
            log_likelihood_increments=by_trial(outputs.increment).astype(float),
            lost_particles=np.array(cloud.lost_particles, dtype=np.int64),
            particle_counts=np.full((trials, steps), self.particles) if outputs.particle_counts is None
            else by_trial(outputs.particle_counts).astype(np.int64),
            within_radius=by_trial(outputs.within_radius),
            standard_deviations=None if deviations is None else deviations.astype(float),
            ancestors=by_trial(outputs.ancestors),
            particles=None if outputs.particles is None else by_trial(outputs.particles).astype(float),
            log_weights=None if outputs.log_weights is None else by_trial(outputs.log_weights).astype(float))
        fill_trace(trace, outputs, recording, observed, self.particles)
        self.after_resampling.fill_trace(trace, cloud.after, outputs.injected)
        return trace

    # -- compiled: the run and its step --------------------------------------------------------

    def traced_run(self, keys, inputs: StepInputs, flags: "Flags"):
        """The run as a traceable function: the prior's cloud, then :meth:`step` scanned over the
        steps; (the last cloud, the steps' :class:`StepOutputs`). :meth:`run` compiles it per
        set of ``flags``; estimation traces it inside its own programs, at parameter arrays."""
        random = KeyStreams(keys, self.dtype)
        trials, count = keys.shape[0], self.particles
        state = jnp.asarray(self.bound.prior.sample(random.at(0), (count,)), self.dtype)
        _check_shape(self.model, "the filter's prior (initial law)", state, (trials, count, self.model.state_dimension))
        cloud = Cloud(particles=state,
                      log_weights=jnp.full((trials, count), -np.log(count), self.dtype),
                      log_likelihood=jnp.zeros(trials, jnp.float64),
                      lost_particles=jnp.zeros(trials, jnp.int32),
                      ancestors=jnp.broadcast_to(jnp.arange(count, dtype=jnp.int32), (trials, count)),
                      after=self.after_resampling.start(trials))
        scores = random.derived(SCORE_STREAM) if flags.scores else None
        cloud, outputs = jax.lax.scan(lambda carried, at_step: self.step(carried, at_step, random, flags, scores),
                                      cloud, inputs)
        if "prior" in flags.snapshot_stages:         # the prior's cloud is kept once, not per step
            outputs = outputs._replace(prior_snapshot=state[np.asarray(flags.snapshot_rows)])
        return cloud, outputs

    def step(self, cloud: Cloud, inputs: StepInputs, random: KeyStreams, flags: "Flags",
             scores: Optional[KeyStreams] = None):
        """Step k: predict, weight and normalise, estimate, resample (module docstring); with
        ``scores`` (the trials' score streams), the predictive law of z_k and its scores."""
        random = random.at(inputs.step)
        adjustment = first = None
        if self.look_ahead is not None:      # the auxiliary filter's first stage: resample by the look-ahead
            cloud, first = self.look_ahead.apply(cloud, inputs, random)
            adjustment = first.adjustment
        with collecting(len(random)) as transition_checks:
            if self.bound.proposal is None:
                predicted, lost, predicted_log_weights = self.predict(cloud, inputs, random)
            else:
                predicted, lost, predicted_log_weights, correction = self.propose(cloud, inputs, random)
                adjustment = correction if adjustment is None else correction + adjustment
        predictive = self.predictive(predicted, _carried_weights(predicted_log_weights, adjustment), inputs,
                                     scores.at(inputs.step)) if scores is not None else None
        every_particle_lost = jnp.all(jnp.isneginf(predicted_log_weights), axis=-1)
        active = cloud.after.active          # the adaptive count (None: every particle active)
        log_weights, weights, increment, degenerate, bad_likelihood = self.update_weights(
            predicted_log_weights, predicted, inputs, adjustment, active)
        if first is not None:                # L_k = L1_k + L2_k
            increment = first.increment + increment.astype(jnp.float64)
        after = self.after_resampling.observe(cloud.after, increment, inputs.observed)
        ess = 1.0 / jnp.sum(weights * weights, axis=-1)
        estimate = self.estimate(weights, predicted)
        if first is None:
            resampled_state, resampled_log_weights, resampled_weights, ancestors, resampled, after, injected = \
                self.resample(predicted, log_weights, weights, ess, random, cloud.particles, after, inputs)
        else:                                # no resampling at the end of an auxiliary step (as on numpy)
            resampled_state, resampled_log_weights, resampled_weights, ancestors, resampled, injected = \
                predicted, log_weights, weights, first.ancestors, first.resampled, None
        failures = (jnp.where(every_particle_lost, EVERY_PARTICLE_LOST, 0) | jnp.where(bad_likelihood, BAD_LIKELIHOOD, 0)
                    | jnp.where(jnp.all(jnp.isfinite(estimate), axis=-1), 0, NON_FINITE_ESTIMATE))
        if transition_checks.recorded:          # a model whose transition checks no law adds nothing
            failures = failures | (transition_checks.codes << BROKEN_RULE_SHIFT)
        clouds = StageClouds(predicted=predicted, predicted_log_weights=predicted_log_weights, log_weights=log_weights,
                             weights=weights, estimate=estimate, resampled=resampled_state,
                             resampled_weights=resampled_weights)
        outputs = StepOutputs(
            estimate=estimate, ess=ess, resampled=resampled, degenerate=degenerate, increment=increment,
            failures=failures.astype(jnp.int16),
            # those that made this step's particles: the last resampling's, the first stage's if auxiliary
            ancestors=(cloud.ancestors if first is None else first.ancestors) if flags.genealogy else None,
            predictive=None if predictive is None else {**predictive, "log_score": -increment}, injected=injected,
            particle_counts=active,
            **step_diagnostics(self.model, flags, clouds, inputs))
        carried = Cloud(particles=resampled_state, log_weights=resampled_log_weights,
                        log_likelihood=cloud.log_likelihood + increment.astype(jnp.float64),
                        lost_particles=cloud.lost_particles + jnp.sum(lost, axis=-1, dtype=jnp.int32),
                        ancestors=ancestors, after=after)
        return carried, outputs

    def predict(self, cloud: Cloud, inputs: StepInputs, random: KeyStreams, model=None):
        r"""x_k ~ p(x_k | x_{k-1}, u_k): the accumulators reset, then the model's substeps
        (:meth:`pfx.models.base.Model.sample_substep`, by default propagate with fresh process
        noise), scanned when there are several, each substep's draws from keys of its own. A
        particle that left the model's domain (NaN or inf) is parked at 0 with weight zero.
        ``model``: the filter's model unless given (IF2 gives the one at each particle's parameters)."""
        model, state = self.model if model is None else model, cloud.particles
        control = None if inputs.control is None else inputs.control.astype(self.dtype)
        substeps = inputs.times.shape[0]
        if _overrides(model, "sample_transition"):          # a transition that is not a sequence of substeps
            state = model.sample_transition(state, control, inputs.times, random)
        elif substeps == 1:
            state = model.sample_substep(model.reset_accumulators(state), control, inputs.times[0], random)
        else:
            def substep(current, place):
                index, time = place
                with collecting(len(random)) as checks:      # a scan's body is traced apart: its own block
                    moved = model.sample_substep(current, control, time, random.at(index))
                return jnp.asarray(moved, current.dtype), checks.codes

            state, codes = jax.lax.scan(substep, model.reset_accumulators(state), (jnp.arange(substeps), inputs.times))
            merge_codes(codes)
        state = jnp.asarray(state)
        _check_shape(model, f"the transition ({model.transition_method()})", state, cloud.particles.shape)
        return self._park_lost(state, cloud.log_weights)

    def _park_lost(self, state, log_weights):
        state = state.astype(self.dtype)
        lost = ~jnp.all(jnp.isfinite(state), axis=-1)
        state = jnp.where(lost[..., None], 0.0, state)
        return state, lost, jnp.where(lost, -jnp.inf, log_weights)

    def propose(self, cloud: Cloud, inputs: StepInputs, random: KeyStreams):
        """x_k from the guided proposal (``filter.proposal``): the NumPy engine's own
        :meth:`~pfx.filters.particle.proposals.BoundGaussianProposal.propose_from`, on every trial
        (a trial without a measurement draws from the transition, adjustment 0), around the
        predictions made from the compiled step's control and substep times; (x_k, lost,
        log-weights, the weight adjustment log p(x_k | x_k-1) - log q)."""
        predicted = self.after_resampling.parent_means(cloud.particles, inputs)
        state, adjustment = self.bound.proposal.propose_from(
            predicted, inputs.measurement.astype(self.dtype), inputs.observed, random)
        _check_shape(self.model, "the proposal", state, cloud.particles.shape)
        return (*self._park_lost(jnp.asarray(state), cloud.log_weights), jnp.asarray(adjustment, self.dtype))

    def update_weights(self, log_weights, state, inputs: StepInputs, adjustment=None, active=None):
        r"""log w_k = log w_{k-1} + log p(z_k | x_k) (or the configured weighting's increment),
        normalised by log-sum-exp; L_k the normaliser
        (0 for a trial without a measurement); a trial whose weights all underflow is degenerate
        and restarts from uniform weights (over its ``active`` particles with an adaptive count);
        a zero-weight particle stays at zero whatever its
        likelihood evaluates to."""
        count = self.particles
        measurement = inputs.measurement.astype(self.dtype)[:, None, :]
        # the configured weighting (filter.weighting; the likelihood by default) reads the
        # predicted cloud's weights, as on numpy (lost particles at zero)
        likelihood = jnp.asarray(self.bound.weighting.log_weights(self.model, measurement, state, jnp.exp(log_weights)))
        _check_shape(self.model, "log_likelihood", likelihood, log_weights.shape)
        observed = inputs.observed
        likelihood = likelihood.astype(self.dtype)
        if adjustment is not None:        # a guided proposal's log p(x_k | x_k-1) - log q, 0 where unobserved
            likelihood = likelihood + adjustment
        increment = jnp.where(observed[:, None], likelihood, 0.0)
        updated = jnp.where(jnp.isneginf(log_weights), -jnp.inf, log_weights + increment)
        peak = jnp.max(updated, axis=-1, keepdims=True)
        shifted = updated - jnp.where(jnp.isfinite(peak), peak, 0.0)
        total = jnp.sum(jnp.exp(shifted), axis=-1, keepdims=True)
        normaliser = (jnp.log(total) + jnp.where(jnp.isfinite(peak), peak, 0.0))[..., 0]
        bad = jnp.isnan(normaliser) | jnp.isposinf(normaliser)
        degenerate = jnp.isneginf(normaliser)
        uniform_log, uniform = float(-np.log(count)), 1.0 / count
        if active is not None:
            uniform_log, uniform = active_uniform(active, count)
        normalised = jnp.where(degenerate[:, None], uniform_log, shifted - jnp.log(total)).astype(self.dtype)
        weights = jnp.where(degenerate[:, None], uniform, jnp.exp(shifted) / total).astype(self.dtype)
        return normalised, weights, jnp.where(observed, normaliser, 0.0), degenerate, bad

    def estimate(self, weights, state):
        """The weighted mean, the model's angular components averaged on the circle."""
        mean = jnp.einsum("rn,rnd->rd", weights, state)
        angular = list(self.model.angular_components)
        if angular:
            mean = mean.at[:, angular].set(circular_mean(weights, state[..., angular], self.model.full_turn))
        return mean

    def resample(self, state, log_weights, weights, ess, random: KeyStreams, previous, after, inputs: StepInputs,
                 resampled=None):
        """The trials whose ESS is below the threshold (every trial at 1, none at 0) take their
        resampled particles, then the move, the diffusion and the injection
        (:mod:`pfx.filters.particle.jax_after_resampling`; ``previous``: x_{k-1}, ``after``: its
        carried values), and uniform weights; the others keep theirs (a select: every trial
        drew). Returns the cloud, the ancestors, which trials resampled, ``after`` updated and
        the particles injected per trial (None without injection). ``resampled``: the trials to
        resample when the caller has applied the ESS rule (the auxiliary filter's first stage)."""
        trials, count = weights.shape
        identity = jnp.broadcast_to(jnp.arange(count, dtype=jnp.int32), (trials, count))
        if resampled is None:
            resampled = self.picks(ess, after.active)
        if resampled is None:            # sis, or a threshold of 0: never (so nothing moved or injected)
            nothing = jnp.zeros(trials, jnp.int32) if self.bound.injection is not None else None
            return state, log_weights, weights, identity, jnp.zeros(trials, bool), after, nothing
        indices = self.resampler(weights, random)
        chosen = jnp.where(resampled[:, None], indices, identity)
        offspring = jnp.take_along_axis(state, chosen[..., None], axis=1)
        offspring, ancestors, after, injected = self.after_resampling.apply(
            after, offspring, chosen, resampled, (previous, state, log_weights, weights), inputs, random)
        state = jnp.where(resampled[:, None, None], offspring, state)
        uniform_log, uniform = -np.log(count), 1.0 / count
        if after.active is not None:         # uniform over the active particles only
            uniform_log, uniform = active_uniform(after.active, count)
        log_weights = jnp.where(resampled[:, None], uniform_log, log_weights).astype(log_weights.dtype)
        weights = jnp.where(resampled[:, None], uniform, weights).astype(weights.dtype)
        return state, log_weights, weights, ancestors, resampled, after, injected

    def picks(self, ess, active=None):
        """The ESS rule: which trials resample (R,) bool, every one at threshold 1; None at
        threshold 0 (none ever does, so none need draw). The threshold is a share of the
        ``active`` count with an adaptive count, as on numpy."""
        if self.threshold <= 0.0:
            return None
        count = self.particles if active is None else active
        return jnp.ones(ess.shape, bool) if self.threshold >= 1.0 else ess < self.threshold * count

    # -- the predictive scores (a static flag; the other diagnostics: jax_diagnostics) ---------

    def predictive(self, state, log_weights, inputs: StepInputs, random: KeyStreams) -> dict:
        """The predictive law of z_k from the predicted cloud and its weights, and its scores
        (:func:`pfx.filters.particle.predictive.predictive_step`), from the score streams; NaN
        where z_k is missing is set on the host
        (:func:`~pfx.filters.particle.jax_diagnostics.fill_trace`)."""
        measurement = inputs.measurement.astype(state.dtype)
        values = predictive_step(self.model, state, log_weights, measurement, random)
        return {name: value for name, value in values.items() if value is not None}


def _carried_weights(log_weights, adjustment):
    """The log-weights the predicted particles carry (:mod:`pfx.filters.particle.predictive`):
    with the weight adjustment, where there is one; a particle at weight zero stays there."""
    if adjustment is None:
        return log_weights
    return jnp.where(jnp.isneginf(log_weights), -jnp.inf, log_weights + adjustment)


def _overrides(model, method: str) -> bool:
    """Whether the model's class (or a class between it and the contract's) defines ``method``."""
    for cls in type(model).__mro__:
        if cls.__module__ == "pfx.models.base":
            return False
        if method in vars(cls):
            return True
    return False


def _check_shape(model, source: str, value, expected: tuple) -> None:
    """The contract's shapes, checked while tracing (shapes are static): the NumPy engine's message."""
    if tuple(value.shape) != tuple(expected):
        raise ModelContractError(f"model {model.kind}: {source} returned shape {tuple(value.shape)} on the jax "
                                 f"backend; expected {tuple(expected)}")


def _raise_first_failure(model, failures: np.ndarray) -> None:
    """Raise the first step's failure as the NumPy engine would have raised it mid-run."""
    error = first_failure(model, failures)
    if error is not None:
        raise error


def first_failure(model, failures: np.ndarray) -> Optional[Exception]:
    """The error the NumPy engine would have raised for a run's failure bits (T, R), at the
    first step with one; None when no bit is set. A law's parameter out of its domain comes
    first, as NumPy raises it in the transition, before the weights."""
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
    if bits & EVERY_PARTICLE_LOST:
        return ModelNumericalError(f"model {model.kind}: every particle of a trial became NaN or infinite at step "
                                   f"{step} of the filter (check the prior and the noise)")
    if bits & BAD_LIKELIHOOD:
        return ModelNumericalError(bad_log_likelihood_message(model, step, "NaN or an infinite"))
    return ModelNumericalError(f"model {model.kind} produced NaN or infinite particles at step {step} of the filter "
                               "(check the prior and the noise)")
