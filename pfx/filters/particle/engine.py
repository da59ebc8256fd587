r"""The particle filter on the NumPy backend: the kernel's step in a Python loop.

:class:`ParticleFilter` runs one batch of trials (arrays of shape (trials, N, d)) of a filter
bound once (:class:`~pfx.filters.particle.bound.BoundParticleFilter`): the prior's cloud, then
:meth:`~pfx.filters.particle.kernel.ParticleKernel.step` for k = 1..T (:mod:`pfx.filters.particle.kernel`
states the algorithm, written once for both backends). This module holds the loop and the NumPy
primitives the step calls:

* **rows, not masks**: only the trials the ESS rule picks resample, draw and move
  (:class:`Rows`); each trial's stream is its own, so no trial's draws depend on another's;
* **the model's host methods**: the transition (or a guided proposal) by the step number, or a
  model's compiled step, which does the transition and the likelihood in one pass for the bootstrap
  filter with the likelihood as weight (:meth:`pfx.models.base.Model.compiled_step`);
* **fast paths**: one sum finds whether any particle left the model's domain, and the weights'
  log-sum-exp (:func:`pfx.numerics.log_weights.normalise_rows`) takes its masks only where a row
  needs them;
* **raise at the failing step**: a trial that loses every particle, a NaN or +inf log-likelihood
  of a finite particle, a non-finite estimate raise :class:`~pfx.errors.ModelNumericalError`
  naming the model and the step (:func:`~pfx.filters.particle.kernel.first_failure`'s messages).

A particle whose state becomes NaN or infinite has left the model's domain (the falling body's
drag equation blows up in finite time for a negative ballistic coefficient): it gets weight zero,
its state is parked at 0 until resampling replaces it, and it is counted per trial. A missing
measurement (NaN in a trial's row) makes the step predict-only for that trial.

Diagnostics (particle snapshots, NEES/NIS, the spread, the genealogy) are recorders
(:mod:`pfx.filters.particle.recorders`) called after each step with the step's clouds, stage by
stage; they only read.
"""

from __future__ import annotations

import functools
from typing import Optional

import numpy as np

from pfx.errors import ModelContractError, ModelNumericalError, note_step
from pfx.filters.particle.cloud import active_uniform, resample_rows
from pfx.filters.particle.kernel import ParticleKernel, RowSelection, StepInputs, failure_error
from pfx.filters.particle.likelihood_failure import bad_log_likelihood_message
from pfx.filters.particle.predictive import PredictiveRecorder
from pfx.filters.particle.recorders import Recording, recorders_for
from pfx.filters.trace import FilterTrace
from pfx.numerics.log_weights import normalise_rows
from pfx.numerics.seeding import TrialStreams


class ParticleFilter(ParticleKernel):
    """One batch of trials of a bound particle filter on NumPy: :meth:`run` is the loop, the other
    methods the kernel's primitives (module docstring)."""

    count_dtype, index_dtype = np.int64, np.intp
    skips_unobserved = True        # a step without any measurement does not call the weighting

    def __init__(self, bound, measurements: np.ndarray, random: TrialStreams,
                 recording: Recording = Recording()):
        super().__init__(bound)
        self.measurements, self.random = measurements, random
        self.trials, self.steps, _ = measurements.shape
        self.resampler = bound.resampling.resampler
        self.tracks_ancestors = recording.genealogy
        self.recorders = recorders_for(bound.model, recording)
        if recording.scores:         # the predictive law's scores (its log score needs to know the weighting)
            self.recorders.append(PredictiveRecorder(bound.model, bound.weighting.is_likelihood))
        self.keeps_stages = bool(self.recorders)
        # (trials, T) True where a trial's measurement is missing; None when every one is there
        missing = np.isnan(measurements).any(axis=-1)
        self.missing: Optional[np.ndarray] = missing if missing.any() else None
        self.compiled_step = bound.model.compiled_step() if bound.uses_compiled_step else None
        particles = self.particles
        self.trace = FilterTrace(
            estimates=np.empty((self.trials, self.steps, bound.model.state_dimension)),
            ess=np.empty((self.trials, self.steps)), resampled=np.zeros((self.trials, self.steps), dtype=bool),
            degenerate=np.zeros((self.trials, self.steps), dtype=bool), spread=np.full((self.trials, self.steps), np.nan),
            log_likelihood=np.zeros(self.trials), log_likelihood_increments=np.zeros((self.trials, self.steps)),
            lost_particles=np.zeros(self.trials, dtype=np.int64),
            particle_counts=np.full((self.trials, self.steps), particles),
            injected=None if bound.injection is None else np.zeros((self.trials, self.steps), dtype=np.int64))
        # what the recorders read, as of the stage they are called after
        self.state = bound.prior.sample(random, (particles,))
        self.log_weights = np.full((self.trials, particles), -np.log(particles))
        self.weights = np.full((self.trials, particles), 1.0 / particles)
        self.active = None if bound.adaptive is None else np.full(self.trials, particles)
        self.ancestors = self.weight_adjustment = None

    def run(self) -> FilterTrace:
        # Overflow, NaN and log(0) are the step's to handle (lost particles, degenerate steps,
        # ModelNumericalError), not NumPy's to warn about: one setting for the whole run.
        k = 0
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
                cloud = self.start(self.state, self.trials)
                self.record("prior", 0)
                for k in range(1, self.steps + 1):
                    cloud, outputs, clouds = self.step(cloud, self.step_inputs(k), self.random)
                    self.keep(k, outputs, clouds)
                    self.state, self.log_weights, self.weights = cloud.particles, cloud.log_weights, cloud.weights
        except Exception as error:        # where it happened, for the one-line report
            note_step(error, k, "filter")
            raise
        self.trace.log_likelihood = cloud.log_likelihood
        self.trace.lost_particles = cloud.lost_particles
        if cloud.after.acceptance_sum is not None:
            with np.errstate(invalid="ignore", divide="ignore"):     # never moved: NaN, an empty field
                self.trace.move_acceptance = cloud.after.acceptance_sum / cloud.after.moved_steps
        return self.trace

    def step_inputs(self, k: int) -> StepInputs:
        """What step k reads: the measurements (NaN where missing) and which trials have one."""
        observed = None if self.missing is None or not self.missing[:, k - 1].any() else ~self.missing[:, k - 1]
        return StepInputs(step=k, measurement=self.measurements[:, k - 1], observed=observed)

    def keep(self, k: int, outputs, clouds) -> None:
        """Step k's columns into the trace, then the recorders, stage by stage."""
        t, trace = k - 1, self.trace
        trace.estimates[:, t], trace.ess[:, t] = outputs.estimate, outputs.ess
        trace.log_likelihood_increments[:, t] = outputs.increment
        trace.resampled[:, t] = outputs.resampled
        if outputs.degenerate is not None:
            trace.degenerate[:, t] = outputs.degenerate
        if outputs.particle_counts is not None:
            trace.particle_counts[:, t] = outputs.particle_counts
        if outputs.injected is not None:
            trace.injected[:, t] = outputs.injected
        if clouds is not None:
            self.record_stages(k, outputs, clouds)

    def record_stages(self, k: int, outputs, clouds) -> None:
        """The recorders after each stage of step k, reading the stage's cloud."""
        self.state, self.log_weights, self.weights = clouds.predicted, clouds.predicted_log_weights, clouds.predicted_weights
        # a copy: the genealogy recorder starts the next step's from i -> i in place
        self.weight_adjustment = clouds.adjustment
        self.ancestors = None if outputs.ancestors is None else np.array(outputs.ancestors)
        self.record("predicted", k)
        self.log_weights, self.weights = clouds.log_weights, clouds.weights
        self.record("weighted", k)
        self.state, self.log_weights, self.weights = clouds.resampled, clouds.resampled_log_weights, clouds.resampled_weights
        self.active = clouds.active
        self.record("resampled", k)

    def record(self, stage: str, step: int) -> None:
        for recorder in self.recorders:
            recorder.record(stage, step, self)

    def observed(self, k: int) -> Optional[np.ndarray]:
        """The trials with a measurement at step k (None: all of them; the recorders ask)."""
        return None if self.missing is None else ~self.missing[:, k - 1]

    # -- the primitives (pfx.filters.particle.kernel) ------------------------------------------

    def carried_weights(self, weights):
        return weights             # the normalisation's own exponentials, not exp(log w) again

    def weights_before(self, log_weights, cloud, lost):
        self.log_weights = log_weights
        return cloud.weights if lost is None else np.where(lost, 0.0, cloud.weights)

    def picks(self, ess, active):
        return self.bound.resampling.rows(ess, self.particles, active)

    def select(self, picks) -> Optional["Rows"]:
        return None if picks is None or picks.size == 0 else Rows(picks, self.trials)

    def transition(self, cloud, inputs: StepInputs, random):
        """x_k ~ p(x_k | x_k-1, u_k) by the model's host transition, or its compiled step (which
        also gives log p(z_k | x_k)); (state, likelihood or None, None)."""
        model, k, likelihood = self.model, inputs.step, None
        if self.compiled_step is not None:         # the model's fused transition and likelihood
            noise = model.process_noise.sample(random, cloud.particles.shape[1:-1])
            state, likelihood = self.compiled_step(cloud.particles, model.control(k), noise, inputs.measurement)
        else:
            state = model.transition(cloud.particles, k, random)    # non-finite values: find_lost
        self.state = state
        if state.shape != cloud.particles.shape:
            source = "compiled_step" if self.compiled_step is not None else \
                f"the transition ({model.transition_method()})"
            self._check_cloud(source, state, cloud.particles.shape, k)
        return state, likelihood, None

    def propose(self, cloud, inputs: StepInputs, random):
        state, correction = self.bound.proposal.propose(cloud.particles, inputs.step, inputs.measurement,
                                                        inputs.observed, random)
        self._check_cloud("the proposal", state, cloud.particles.shape, inputs.step)
        self.state = state
        return state, correction, None

    def _check_cloud(self, source: str, state, expected: tuple, k: int) -> None:
        if state.shape != expected:       # a tuple comparison: the contract, at the run's size
            raise ModelContractError(f"model {self.model.kind}: {source} returned shape {state.shape} at step {k} of "
                                     f"the filter, for {self.trials} trials x {self.particles} particles; "
                                     f"expected {expected}")

    def find_lost(self, state):
        # NaN and inf survive a sum: one fast pass, and the per-particle mask only if needed.
        if np.isfinite(state.sum()):
            return state, None
        finite = np.isfinite(state).all(axis=-1)
        return state, None if finite.all() else ~finite

    def mean_prediction(self, parents, inputs: StepInputs):
        return self.model.mean_transition(parents, inputs.step)

    def look_ahead_weights(self, previous, inputs: StepInputs):
        measurement = inputs.measurement[:, None, :]
        if inputs.observed is not None:
            measurement = np.where(inputs.observed[:, None, None], measurement, 0.0)
        return self.model.look_ahead_log_weight(previous, inputs.step, measurement)

    def measured(self, inputs: StepInputs):
        return inputs.measurement         # NaN where missing, as recorded

    def check_weights_shape(self, likelihood, expected: tuple, k: int):
        if np.shape(likelihood) != expected:      # would broadcast silently
            raise ModelContractError(
                f"model {self.model.kind}: the weighting {getattr(self.bound.weighting, 'kind', '')} (log_likelihood) "
                f"returned shape {np.shape(likelihood)} at step {k} of the filter, for {self.trials} trials x "
                f"{self.particles} particles; expected {expected}")
        return likelihood

    def normalise(self, log_weights, increment, lost, active, k: int):
        """log-sum-exp of log w + increment by rows, its fast path first; a row whose every weight
        underflows is degenerate and restarts uniform; a NaN or +inf normaliser raises."""
        if lost is not None:
            increment[lost] = -np.inf
        updated = log_weights + increment
        normalised, weights, normaliser = normalise_rows(updated)
        degenerate = None
        if not np.isfinite(normaliser).all():          # rare: one check in the common case
            if not np.isfinite(normaliser[~np.isneginf(normaliser)]).all():
                # A zero-weight particle stays at zero weight whatever its likelihood evaluates to
                # (-inf + NaN would be NaN); only if that does not help is it the model's error.
                updated = np.where(np.isneginf(log_weights), -np.inf, updated)
                normalised, weights, normaliser = normalise_rows(updated)
            if np.isnan(normaliser).any() or np.isposinf(normaliser).any():
                bad = "NaN" if np.isnan(normaliser).any() else "an infinite"
                raise ModelNumericalError(bad_log_likelihood_message(self.model, k, bad))
            degenerate = np.isneginf(normaliser)
            normalised[degenerate] = -np.log(self.particles)
            weights[degenerate] = 1.0 / self.particles
            if active is not None:            # uniform over the active particles only
                normalised[degenerate], weights[degenerate] = active_uniform(active[degenerate], self.particles)
        self.log_weights = normalised
        return normalised, weights, normaliser, degenerate, None

    def non_finite_rows(self, values):
        return None if np.isfinite(values).all() else ~np.isfinite(values).all(axis=-1)

    def flag(self, failures, condition, bit: int, step):
        if condition is not None and condition.any():
            raise failure_error(self.model, bit, step)
        return None

    def accumulate(self, total, first, increment):
        return (total if first is None else total + first) + increment     # L1_k first, as it happens

    def gather(self, state, rows: "Rows", indices):
        return resample_rows(state, rows.rows, indices)

    def uniforms(self, streams, shape):
        return streams.uniform(shape)

    def as_state(self, values):
        return values

    def as_measurement(self, values):
        return values

    def park(self, state, lost):
        state[lost] = 0.0                # the transition's own new array
        return state

    def put(self, mask, new, old):
        out = old.copy(order="K")        # the state's memory layout, as the transition made it
        out[mask] = new[mask]
        return out


@functools.lru_cache(maxsize=8)
def uniform_rows(shape: tuple, value: float, dtype) -> np.ndarray:
    """A read-only (R, N) array of one value: the uniform weights every resampled trial takes,
    made once per run rather than at every step (no stage writes into a cloud's weights: each
    makes its own)."""
    rows = np.full(shape, value, dtype=dtype)
    rows.flags.writeable = False
    return rows


class Rows(RowSelection):
    """The rows a stage acts on, as indices into the batch's ``total`` rows: only they are
    taken, draw and are written back (a copy: the step's earlier clouds stay as they were)."""

    def __init__(self, rows: np.ndarray, total: int):
        self.rows, self.total = rows, total
        self.every = rows.size == total

    def take(self, values):
        return values if self.every else values[self.rows]

    def streams(self, random):
        return random if self.every else random.subset(self.rows)

    def indices(self, drawn):
        return drawn

    def merge(self, new, old):
        if self.every:
            if type(new) is np.ndarray and new.shape == old.shape:
                return new
            return uniform_rows(old.shape, new, old.dtype) if np.ndim(new) == 0 else np.full(old.shape, new, old.dtype)
        out = old.copy(order="K")
        out[self.rows] = new
        return out

    def scatter(self, values, fill):
        if self.every:
            return values
        out = np.full((self.total,) + np.shape(values)[1:], fill, dtype=np.asarray(values).dtype)
        out[self.rows] = values
        return out

    def mask(self):
        if self.every:
            return np.ones(self.total, dtype=bool)
        out = np.zeros(self.total, dtype=bool)
        out[self.rows] = True
        return out

    def within(self, condition):
        inner = np.flatnonzero(condition)
        return Rows(inner, len(condition)) if inner.size else None
