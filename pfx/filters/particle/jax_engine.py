r"""The particle filter on the JAX backend: the kernel's step, scanned over the steps, compiled once.

The algorithm is :mod:`pfx.filters.particle.kernel`'s, written once for both backends. Here it
runs as a function of explicit values, so that XLA can compile the whole run, on a CPU or a GPU:
:meth:`JaxParticleFilter.traced_run` draws the prior's cloud and scans
:meth:`JaxParticleFilter.scan_step` over the steps.

* the cloud (:class:`~pfx.filters.particle.kernel.Cloud`) is everything carried from step to
  step: the particles, their log-weights, each trial's log-likelihood so far, its lost
  particles, the ancestors and the post-resampling stage's running values;
* the step's inputs (:class:`~pfx.filters.particle.kernel.StepInputs`) are arrays indexed by the
  step, prepared on the host before the run (:meth:`JaxParticleFilter.step_inputs`): k, the
  measurements (trials, m), which trials have one, the control u_k and the substep times;
* the random numbers come from the trials' threefry keys folded with k
  (:class:`~pfx.numerics.key_streams.KeyStreams`): nothing random is carried;
* the step's outputs are the trace's columns at step k, and what a
  :class:`~pfx.filters.particle.recorders.Recording` asks for (static flags: a diagnostic not
  asked for is not computed; :mod:`pfx.filters.particle.jax_diagnostics` computes them from the
  step's clouds and makes the trace's fields of them).

The JAX primitives the kernel calls differ in form from NumPy's, not in what they compute:

* **masks, not subsets** (:class:`Mask`): every trial draws its resampling points and is
  resampled, moved and injected; the trials whose ESS is above the threshold keep their
  particles by a select;
* **error flags, not exceptions**: a trial whose particles all left the model's domain, a NaN
  or +inf log-likelihood, a non-finite estimate set a bit in the step's ``failures``, and a law's
  parameter out of its domain in the transition (a negative Poisson rate:
  :mod:`pfx.numerics.parameter_checks`) the code of the rule it broke; after the scan the first
  one is raised as the NumPy driver raises it (same message, same step);
* **the transition from arrays**: the model's substeps scanned over the control and substep
  times of the step's inputs (the NumPy driver asks the model by the step number);
* **precision**: ``float32`` keeps the particles, the process noise and the weights in single
  precision: what is stored and carried from step to step, hence the memory traffic that bounds
  a GPU. A model's arithmetic follows JAX's promotion rules: a constant held as a NumPy float64
  array promotes its expression to float64 (the result is stored as float32 again), a Python
  float does not. The resamplers' cumulative sums and the log-likelihood's running sum stay
  float64 (:mod:`pfx.filters.particle.jax_resampling` says why).

The NumPy and JAX backends draw from different generators, so their results agree in
distribution, not number for number (tests/test_jax_backend.py checks that they do); served the
same draws, they agree to rounding (tests/test_kernel_replay.py).
"""

from __future__ import annotations

import time
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from pfx.errors import ModelContractError
from pfx.filters.particle.cloud import active_uniform
from pfx.filters.particle.jax_diagnostics import Flags, by_trial, fill_trace, step_diagnostics
from pfx.filters.particle.jax_resampling import JAX_RESAMPLERS
from pfx.filters.particle.kernel import (
    BROKEN_RULE_SHIFT,
    Cloud,
    ParticleKernel,
    RowSelection,
    StepInputs,
    StepOutputs,
    first_failure,
)
from pfx.filters.particle.predictive import predictive_step
from pfx.filters.trace import FilterTrace
from pfx.numerics.key_streams import KeyStreams
from pfx.numerics.parameter_checks import collecting, merge_codes
from pfx.numerics.seeding import SCORE_STREAM


class JaxParticleFilter(ParticleKernel):
    """A bound particle filter (:class:`~pfx.filters.particle.bound.BoundParticleFilter`) as a JAX
    program: :meth:`run` filters a batch of trials; the program is compiled once per shape of
    the batch and per set of diagnostics asked for, and reused. The other methods are the
    kernel's primitives (:mod:`pfx.filters.particle.kernel`) on JAX arrays."""

    xp, count_dtype, index_dtype = jnp, jnp.int32, jnp.int32

    def __init__(self, bound):
        super().__init__(bound)
        self.dtype = jnp.float32 if bound.precision == "float32" else jnp.float64
        self.resampler = JAX_RESAMPLERS[bound.resampling.resampler.function.__name__]
        self.threshold = bound.resampling.threshold
        self.own_look_ahead = _overrides(bound.model, "look_ahead_log_weight")
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
        if self.bound.auxiliary is not None and self.own_look_ahead:
            self._check_look_ahead()

    def _check_look_ahead(self) -> None:
        """Trace the model's own ``look_ahead_log_weight`` once on a tiny batch (nothing
        computed), with a traced step: one written for the host is refused at plan time."""
        model = self.model
        with jax.enable_x64(True):
            state = jax.ShapeDtypeStruct((2, 3, model.state_dimension), self.dtype)
            step = jax.ShapeDtypeStruct((), jnp.int32)
            measurement = jax.ShapeDtypeStruct((2, 1, model.measurement_dimension), self.dtype)
            try:
                jax.eval_shape(model.look_ahead_log_weight, state, step, measurement)
            except Exception as error:      # any failure to trace: the method is NumPy-only
                reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
                raise ValueError(
                    f"@auxiliary: model {model.kind}'s look_ahead_log_weight does not run on the jax backend "
                    f"({reason[:160]}); write it against the array namespace with the step as an array, "
                    "or set backend: numpy") from None

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
        compile_seconds = 0.0
        with jax.enable_x64(True):
            keys = KeyStreams.from_seeds(random.seeds).keys
            inputs = self.step_inputs(measurements)
            # compiled ahead of the call, so that its time is known apart from the run's (a
            # program per set of flags and input shapes, as jax.jit would cache it)
            signature = (flags, jax.tree_util.tree_map(lambda value: (np.shape(value), jnp.result_type(value).str),
                                                       (keys, inputs)))
            program = self._programs.get(signature)
            if program is None:
                started = time.perf_counter()
                program = jax.jit(lambda keys, inputs: self.traced_run(keys, inputs, flags)).lower(keys, inputs).compile()
                self._programs[signature] = program
                compile_seconds = time.perf_counter() - started
            cloud, outputs = program(keys, inputs)
            cloud, outputs = jax.device_get((cloud, outputs))
        _raise_first_failure(self.model, np.asarray(outputs.failures))
        trace = self._trace(cloud, outputs, recording, trials, steps, inputs.observed.T)
        trace.compile_time_s = compile_seconds
        return trace

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
        if outputs.injected is not None:
            trace.injected = by_trial(outputs.injected).astype(np.int64)
        if cloud.after.acceptance_sum is not None:     # the move's mean acceptance per trial (NaN: never moved)
            with np.errstate(invalid="ignore", divide="ignore"):
                trace.move_acceptance = np.asarray(cloud.after.acceptance_sum, dtype=float) / np.asarray(
                    cloud.after.moved_steps, dtype=float)
        return trace

    # -- compiled: the run and its step --------------------------------------------------------

    def traced_run(self, keys, inputs: StepInputs, flags: "Flags"):
        """The run as a traceable function: the prior's cloud, then :meth:`scan_step` scanned over the
        steps; (the last cloud, the steps' :class:`StepOutputs`). :meth:`run` compiles it per
        set of ``flags``; estimation traces it inside its own programs, at parameter arrays."""
        random = KeyStreams(keys, self.dtype, count_draws=self.bound.count_draws)
        trials, count = keys.shape[0], self.particles
        state = jnp.asarray(self.bound.prior.sample(random.at(0), (count,)), self.dtype)
        _check_shape(self.model, "the filter's prior (initial law)", state, (trials, count, self.model.state_dimension))
        cloud = self.start(state, trials)
        scores = random.derived(SCORE_STREAM) if flags.scores else None
        cloud, outputs = jax.lax.scan(lambda carried, at_step: self.scan_step(carried, at_step, random, flags, scores),
                                      cloud, inputs)
        if "prior" in flags.snapshot_stages:         # the prior's cloud is kept once, not per step
            outputs = outputs._replace(prior_snapshot=state[np.asarray(flags.snapshot_rows)])
        return cloud, outputs

    def scan_step(self, cloud: Cloud, inputs: StepInputs, random: KeyStreams, flags: Flags,
                  scores: Optional[KeyStreams] = None):
        """Step k of the scan: the kernel's step from the trials' keys folded with k, then the
        diagnostics ``flags`` ask for; with ``scores`` (the trials' score streams), the
        predictive law of z_k and its scores."""
        cloud, outputs, clouds = self.step(cloud, inputs, random.at(inputs.step))
        predictive = None
        if scores is not None:
            predictive = self.predictive(clouds.predicted, _carried_weights(clouds.predicted_log_weights,
                                                                            clouds.adjustment),
                                         inputs, scores.at(inputs.step))
            predictive = {**predictive, "log_score": -outputs.increment}
        outputs = outputs._replace(failures=outputs.failures.astype(jnp.int16), predictive=predictive,
                                   ancestors=outputs.ancestors if flags.genealogy else None,
                                   **step_diagnostics(self.model, flags, clouds, inputs))
        return cloud, outputs

    # -- the primitives (pfx.filters.particle.kernel) ------------------------------------------

    def carried_weights(self, weights):
        return None                # recomputed from the log-weights: less to carry through the scan

    def weights_before(self, log_weights, cloud, lost):
        return jnp.exp(log_weights)

    def picks(self, ess, active=None):
        """The ESS rule: which trials resample (R,) bool, every one at threshold 1; None at
        threshold 0 (none ever does, so none need draw). The threshold is a share of the
        ``active`` count with an adaptive count, as on numpy."""
        if self.threshold <= 0.0:
            return None
        count = self.particles if active is None else active
        return jnp.ones(ess.shape, bool) if self.threshold >= 1.0 else ess < self.threshold * count

    def select(self, picks) -> Optional["Mask"]:
        return None if picks is None else Mask(picks, self.particles)

    def transition(self, cloud, inputs: StepInputs, random: KeyStreams, model=None):
        r"""x_k ~ p(x_k | x_{k-1}, u_k): the accumulators reset, then the model's substeps
        (:meth:`pfx.models.base.Model.sample_substep`, by default propagate with fresh process
        noise), scanned when there are several, each substep's draws from keys of its own; a law's
        parameter out of its domain is a failure code. ``model``: the filter's model unless given
        (IF2 gives the one at each particle's parameters). (state, None, failures)."""
        model, state = self.model if model is None else model, cloud.particles
        control = None if inputs.control is None else inputs.control.astype(self.dtype)
        substeps = inputs.times.shape[0]
        with collecting(len(random)) as checks:
            if _overrides(model, "sample_transition"):          # a transition that is not a sequence of substeps
                state = model.sample_transition(state, control, inputs.times, random)
            elif substeps == 1:
                state = model.sample_substep(model.reset_accumulators(state), control, inputs.times[0], random)
            else:
                def substep(current, place):
                    index, time = place
                    with collecting(len(random)) as substep_checks:      # a scan's body is traced apart
                        moved = model.sample_substep(current, control, time, random.at(index))
                    return jnp.asarray(moved, current.dtype), substep_checks.codes

                state, codes = jax.lax.scan(substep, model.reset_accumulators(state),
                                            (jnp.arange(substeps), inputs.times))
                merge_codes(codes)
        state = jnp.asarray(state)
        _check_shape(model, f"the transition ({model.transition_method()})", state, cloud.particles.shape)
        return state, None, self._broken_rules(checks, len(random))

    def propose(self, cloud, inputs: StepInputs, random: KeyStreams):
        """x_k from the guided proposal around the predictions made from the compiled step's
        control and substep times (a trial without a measurement draws from the transition,
        adjustment 0): (x_k, the adjustment log p(x_k | x_k-1) - log q, failures)."""
        predicted = self.mean_prediction(cloud.particles, inputs)
        with collecting(len(random)) as checks:
            state, adjustment = self.bound.proposal.propose_from(
                predicted, inputs.measurement.astype(self.dtype), inputs.observed, random)
        _check_shape(self.model, "the proposal", state, cloud.particles.shape)
        return jnp.asarray(state), jnp.asarray(adjustment, self.dtype), self._broken_rules(checks, len(random))

    @staticmethod
    def _broken_rules(checks, trials: int):
        """The failure codes of the laws' broken rules (none where the transition checks no law)."""
        if checks.recorded:
            return checks.codes << BROKEN_RULE_SHIFT
        return jnp.zeros(trials, jnp.int32)

    def find_lost(self, state):
        state = state.astype(self.dtype)
        return state, ~jnp.all(jnp.isfinite(state), axis=-1)

    def park(self, state, lost):
        return jnp.where(lost[..., None], 0.0, state)

    def mean_prediction(self, parents, inputs: StepInputs):
        r""":math:`\\bar f_k(x_{k-1})` of each parent (:meth:`pfx.models.base.Model.mean_transition`'s
        substeps without noise), from the compiled step's control and substep times, which the
        model's method reads on the host by the step number."""
        model = self.model
        control = None if inputs.control is None else inputs.control.astype(self.dtype)
        state = model.reset_accumulators(parents)
        zeros = jnp.zeros(parents.shape[:-1] + (model.process_noise_dimension,), parents.dtype)
        for substep in range(inputs.times.shape[0]):
            state = model.propagate_at(state, control, zeros, inputs.times[substep])
        return jnp.asarray(state, parents.dtype)

    def look_ahead_weights(self, previous, inputs: StepInputs):
        """g (R, N) of the particles ``previous`` of step k-1, as the model evaluates it (NaN where
        a prediction left its domain); a missing measurement's stand-in is 0."""
        measurement = inputs.measurement.astype(self.dtype)[:, None, :]
        if self.own_look_ahead:
            return jnp.asarray(self.model.look_ahead_log_weight(previous, inputs.step, measurement))
        return jnp.asarray(self.model.log_likelihood(measurement, self.mean_prediction(previous, inputs)))

    def measured(self, inputs: StepInputs):
        # NaN where a measurement is missing, as the NumPy driver hands a move its row
        return jnp.where(inputs.observed[:, None], inputs.measurement.astype(self.dtype), jnp.nan)

    def check_weights_shape(self, likelihood, expected: tuple, k):
        likelihood = jnp.asarray(likelihood)
        _check_shape(self.model, "log_likelihood", likelihood, expected)
        return likelihood.astype(self.dtype)

    def normalise(self, log_weights, increment, lost, active, k):
        """log-sum-exp of log w + increment by rows, as selects (a zero-weight particle stays at
        zero whatever its likelihood evaluates to); a row whose weights all underflow is degenerate
        and restarts uniform (over its ``active`` particles with an adaptive count); a NaN or +inf
        normaliser is a flag."""
        count = self.particles
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
        return normalised, weights, normaliser, degenerate, bad

    def non_finite_rows(self, values):
        return ~jnp.all(jnp.isfinite(values), axis=-1)

    def flag(self, failures, condition, bit: int, step):
        return failures | jnp.where(condition, bit, 0)

    def accumulate(self, total, first, increment):
        increment = increment.astype(jnp.float64)
        return total + (increment if first is None else first + increment)

    def gather(self, state, rows: "Mask", indices):
        return jnp.take_along_axis(state, indices[..., None], axis=1)

    def uniforms(self, streams, shape):
        return streams.uniform(shape, jnp.float64)

    def as_state(self, values):
        return jnp.asarray(values, self.dtype)

    def as_measurement(self, values):
        return values.astype(self.dtype)

    def put(self, mask, new, old):
        return jnp.where(mask[..., None], new, old)

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


class Mask(RowSelection):
    """The rows a stage acts on, as a mask (R,): every row is computed, a select keeps the
    unselected rows as they were."""

    def __init__(self, mask, particles: int):
        self.selected, self.particles = mask, particles

    def _rows(self, values):
        return self.selected.reshape(self.selected.shape + (1,) * (jnp.ndim(values) - 1))

    def take(self, values):
        return values

    def streams(self, random):
        return random

    def indices(self, drawn):
        identity = jnp.arange(self.particles, dtype=drawn.dtype)
        return jnp.where(self.selected[:, None], drawn, identity)

    def merge(self, new, old):
        return jnp.where(self._rows(old), new, old).astype(old.dtype)

    def scatter(self, values, fill):
        return jnp.where(self._rows(values), values, fill)

    def mask(self):
        return self.selected

    def within(self, condition):
        return Mask(self.selected & condition, self.particles)
