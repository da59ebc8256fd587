"""The oracle of the particle-filter refactor (issue 48): a frozen copy of the NumPy engine.

:class:`OracleParticleFilter` is ``pfx.filters.particle.engine.ParticleFilter`` copied verbatim
(renamed, nothing else changed) as of the commit that added it, and :func:`oracle_run` is
``BoundParticleFilter.run`` (pfx/filters/particle/bound.py) of that commit with this copy in place
of the engine: the smoothers on the recorded history, then the forecasts.

It is used only by tests/test_kernel_oracle.py, which runs each bound filter of its feature matrix
through pfx's current code path and through this copy, from identically seeded streams, and
requires every output to be identical. While the two engines are rewritten as one kernel with
two drivers, that test pins the numbers and the order of the random draws at every commit.
Delete this module (and that test, or its oracle half) once the refactor is done.

It imports from pfx only what the copied code imports (the cloud helpers, the move context, the
recorders, the log-weight helpers, the errors, the trace, the forecasts and the smoothers'
history), never ``pfx.filters.particle.engine``: the helpers are shared, the engine's stage
order and bookkeeping are frozen here.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Optional

import numpy as np

from pfx.errors import ModelContractError, ModelNumericalError, note_step
from pfx.filters.particle.cloud import active_uniform, posterior_mean, resample_rows
from pfx.filters.particle.forecasting import forecast_table
from pfx.filters.particle.moves import MoveContext
from pfx.filters.particle.predictive import PredictiveRecorder
from pfx.filters.particle.recorders import Recording, recorders_for
from pfx.filters.particle.smoothing import FilterHistory
from pfx.filters.trace import FilterTrace
from pfx.numerics.log_weights import effective_sample_size, normalise_rows
from pfx.numerics.seeding import TrialStreams


def oracle_run(bound, measurements: np.ndarray, random: TrialStreams,
               recording: Recording = Recording()) -> FilterTrace:
    """``BoundParticleFilter.run`` as of this copy, with :class:`OracleParticleFilter` as the
    engine (the NumPy backend only: a bound filter compiled for JAX has no oracle here)."""
    if bound.compiled is not None:
        raise ValueError("the oracle is the NumPy engine; this bound filter runs on the jax backend")
    if bound.smoothers:          # what they run on is recorded too
        recording = replace(recording, history=recording.history or any(s.needs_history for s in bound.smoothers),
                            genealogy=recording.genealogy or any(s.needs_genealogy for s in bound.smoothers))
    trace = OracleParticleFilter(bound, measurements, random, recording).run()
    if bound.smoothers:
        history = FilterHistory(trace.particles, trace.log_weights, trace.ancestors)
        for smoother in bound.smoothers:     # after the filter's draws, from the same streams
            trace.smoothed[smoother.label] = smoother.smooth(history, bound.model, random)
    if recording.forecast is not None:      # from the kept clouds, on the forecast streams
        trace.forecasts = forecast_table(bound.model, recording.forecast, measurements, random)
    return trace


class OracleParticleFilter:
    """One batch of trials of a bound particle filter (``bound``, a
    :class:`~pfx.filters.particle.bound.BoundParticleFilter`), advanced step by step in named stages.

    :meth:`step` is the algorithm; each stage is a method, and the points where a variant plugs
    in are the bound filter's objects (``self.filter``): the proposal, the weighting, the
    resampling, the move, the adaptive count, the diffusion and the injection.
    """

    def __init__(self, bound, measurements: np.ndarray, random: TrialStreams,
                 recording: Recording = Recording()):
        self.filter, self.model, self.measurements, self.random = bound, bound.model, measurements, random
        self.trials, self.steps, _ = measurements.shape
        particles = self.particles = bound.particles         # with an adaptive count: the maximum
        self.recorders = recorders_for(bound.model, recording)
        if recording.scores:         # the predictive law's scores (its log score needs to know the weighting)
            self.recorders.append(PredictiveRecorder(bound.model, bound.weighting.is_likelihood))
        self.weight_adjustment: Optional[np.ndarray] = None   # log p(x|x_prev) - log q - g_a, per particle
        self.previous_state: Optional[np.ndarray] = None      # x_{k-1}, kept only for a move that needs parents
        self.keep_previous = bound.move is not None and bound.move.needs_parents
        # the adaptive count: active particles per trial (None: all N)
        self.active: Optional[np.ndarray] = None if bound.adaptive is None else np.full(self.trials, particles)
        # particle injection's running averages, or None
        self.injection = None if bound.injection is None else bound.injection.start(self.trials)
        self.uniform_log_weight = -np.log(particles)
        self.state = bound.prior.sample(random, (particles,))
        self.cloud_shape = self.state.shape             # (trials, N, d), at every step
        self.log_weights = np.full((self.trials, particles), self.uniform_log_weight)
        self.weights = np.full((self.trials, particles), 1.0 / particles)    # always exp(log_weights)
        self.lost: Optional[np.ndarray] = None            # this step's particles that left the domain
        # (trials, T) True where a trial's measurement is missing (predict-only steps); None when
        # every measurement is there, so that simulated runs never look at it again
        missing = np.isnan(measurements).any(axis=-1)
        self.missing: Optional[np.ndarray] = missing if missing.any() else None
        self.trace = FilterTrace(
            estimates=np.empty((self.trials, self.steps, self.state.shape[-1])),
            ess=np.empty((self.trials, self.steps)), resampled=np.zeros((self.trials, self.steps), dtype=bool),
            degenerate=np.zeros((self.trials, self.steps), dtype=bool), spread=np.full((self.trials, self.steps), np.nan),
            log_likelihood=np.zeros(self.trials), log_likelihood_increments=np.zeros((self.trials, self.steps)),
            lost_particles=np.zeros(self.trials, dtype=np.int64),
            particle_counts=np.full((self.trials, self.steps), particles),
            injected=None if bound.injection is None else np.zeros((self.trials, self.steps), dtype=np.int64))
        # each particle's ancestor at the previous step (the genealogy), only when recorded
        self.ancestors: Optional[np.ndarray] = None
        if recording.genealogy:
            self.ancestors = np.broadcast_to(np.arange(particles), (self.trials, particles)).copy()
        # per trial: the sum of the move's acceptance rates over the steps it moved, and their count
        self.acceptance_tally = np.zeros((2, self.trials)) \
            if bound.move is not None and bound.move.reports_acceptance else None
        self.compiled_step = bound.model.compiled_step() if bound.uses_compiled_step else None
        self.log_likelihood: Optional[np.ndarray] = None     # this step's log p(z_k | x_k), from compiled_step

    def run(self) -> FilterTrace:
        # Overflow, NaN and log(0) are the engine's to handle (lost particles, degenerate steps,
        # ModelNumericalError), not NumPy's to warn about: one setting for the whole run, not one
        # per stage and step (each costs microseconds).
        k = 0
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
                self.record("prior", 0)
                for k in range(1, self.steps + 1):
                    self.step(k)
        except Exception as error:        # where it happened, for the one-line report
            note_step(error, k, "filter")
            raise
        if self.acceptance_tally is not None:
            with np.errstate(invalid="ignore", divide="ignore"):     # never moved: NaN, an empty field
                self.trace.move_acceptance = self.acceptance_tally[0] / self.acceptance_tally[1]
        return self.trace

    def step(self, k: int) -> None:
        """Step k: the stages in their order (module docstring), each followed by its recorders."""
        self.look_ahead(k)
        self.predict(k)
        self.record("predicted", k)
        self.update_weights(k)
        self.estimate(k)
        self.record("weighted", k)
        self.resample_and_move(k)
        self.record("resampled", k)

    def record(self, stage: str, step: int) -> None:
        for recorder in self.recorders:
            recorder.record(stage, step, self)

    def observed(self, k: int) -> Optional[np.ndarray]:
        """The trials with a measurement at step k (None: all of them)."""
        return None if self.missing is None else ~self.missing[:, k - 1]

    def look_ahead(self, k: int) -> None:
        """The auxiliary filter's first stage: weights lambda from the look-ahead, whose
        normaliser joins the log-likelihood; the trials the ESS rule picks resample by them; the
        ancestors' look-ahead g_a is kept for the second stage's weights."""
        self.weight_adjustment = None
        if self.filter.auxiliary is None:
            return
        log_first, first, increment, look_ahead = self.filter.auxiliary.weights(
            self.model, self.log_weights, self.state, k, self.measurements[:, k - 1], self.observed(k))
        self.trace.log_likelihood += increment
        self.trace.log_likelihood_increments[:, k - 1] += increment      # L1_k; update_weights adds L2_k
        self.log_weights, self.weights = log_first, first
        rows = self.filter.resampling.rows(effective_sample_size(first), self.particles, self.active)
        if rows.size:
            indices, selected = self.resample(rows, k)
            look_ahead[selected] = np.take_along_axis(look_ahead[selected], indices, axis=-1)
        self.weight_adjustment = -look_ahead

    def predict(self, k: int) -> None:
        """Propose x_k: from the transition (the bootstrap proposal), or from a guided proposal
        (:mod:`pfx.filters.particle.proposals`); park particles that left the model's domain at
        weight zero."""
        if self.keep_previous:
            self.previous_state = self.state
        proposal = self.filter.proposal
        if proposal is not None:
            self.state, correction = proposal.propose(self.state, k, self.measurements[:, k - 1], self.observed(k),
                                                      self.random)
            self.weight_adjustment = correction if self.weight_adjustment is None else \
                correction + self.weight_adjustment
        elif self.compiled_step is not None:         # the model's fused transition and likelihood
            noise = self.model.process_noise.sample(self.random, self.state.shape[1:-1])
            self.state, self.log_likelihood = self.compiled_step(self.state, self.model.control(k), noise,
                                                                 self.measurements[:, k - 1])
        else:
            self.state = self.model.transition(self.state, k, self.random)    # non-finite values: below
        if self.state.shape != self.cloud_shape:       # a tuple comparison: the contract, at the run's size
            source = "the proposal" if proposal is not None else \
                "compiled_step" if self.compiled_step is not None else \
                f"the transition ({self.model.transition_method()})"
            raise ModelContractError(f"model {self.model.kind}: {source} returned shape {self.state.shape} at step "
                                     f"{k} of the filter, for {self.trials} trials x {self.particles} particles; "
                                     f"expected {self.cloud_shape}")
        # NaN and inf survive a sum: one fast pass, and the per-particle mask only if needed.
        suspect = not np.isfinite(self.state.sum())
        self.lost = None
        if suspect:
            finite = np.isfinite(self.state).all(axis=-1)
            if not finite.all():
                self.lost = lost = ~finite
                self.trace.lost_particles += lost.sum(axis=-1)
                if (lost | np.isneginf(self.log_weights)).all(axis=-1).any():
                    raise ModelNumericalError(f"model {self.model.kind}: every particle of a trial became NaN or "
                                              f"infinite at step {k} of the filter (check the prior and the noise)")
                self.state[lost] = 0.0
                self.log_weights[lost] = -np.inf
                self.weights[lost] = 0.0

    def update_weights(self, k: int) -> None:
        """log w_k = log w_{k-1} + log l_k(x_k), normalised by log-sum-exp; the normaliser adds to
        the log-likelihood estimate; a trial whose weights all underflow is degenerate."""
        t = k - 1
        skipped = None if self.missing is None or not self.missing[:, t].any() else self.missing[:, t]
        if skipped is not None and skipped.all():
            increment = np.zeros_like(self.log_weights)       # no measurement anywhere: nothing to weigh
        else:
            if self.log_likelihood is not None:      # computed with the transition (compiled_step)
                increment = self.log_likelihood
            else:
                increment = self.filter.weighting.log_weights(self.model, self.measurements[:, t, None, :],
                                                              self.state, self.weights)
            if increment.shape != self.log_weights.shape:      # would broadcast silently
                raise ModelContractError(
                    f"model {self.model.kind}: the weighting {getattr(self.filter.weighting, 'kind', '')} (log_likelihood) "
                    f"returned shape {np.shape(increment)} at step {k} of the filter, for {self.trials} trials x "
                    f"{self.particles} particles; expected {self.log_weights.shape}")
            if skipped is not None:
                increment[skipped] = 0.0
        if self.weight_adjustment is not None:     # a guided proposal's or the auxiliary filter's terms
            increment += self.weight_adjustment
        if self.lost is not None:
            increment[self.lost] = -np.inf
        updated = self.log_weights + increment
        normalised, new_weights, normaliser = normalise_rows(updated)
        if not np.isfinite(normaliser).all():          # rare: one check in the common case
            if not np.isfinite(normaliser[~np.isneginf(normaliser)]).all():
                # A zero-weight particle stays at zero weight whatever its likelihood evaluates to
                # (-inf + NaN would be NaN); only if that does not help is it the model's error.
                updated = np.where(np.isneginf(self.log_weights), -np.inf, updated)
                normalised, new_weights, normaliser = normalise_rows(updated)
            if np.isnan(normaliser).any() or np.isposinf(normaliser).any():
                bad = "NaN" if np.isnan(normaliser).any() else "an infinite"
                raise ModelNumericalError(
                    f"model {self.model.kind} gave {bad} log-likelihood at step {k} of the filter "
                    "(did particles leave the model's domain? check the prior and the noise)")
            underflow = np.isneginf(normaliser)
            self.trace.degenerate[underflow, t] = True
            normalised[underflow] = self.uniform_log_weight
            new_weights[underflow] = 1.0 / self.particles
            if self.active is not None:            # uniform over the active particles only
                normalised[underflow], new_weights[underflow] = active_uniform(self.active[underflow], self.particles)
        self.log_weights = normalised
        if skipped is not None:
            # A predict-only step adds nothing: its normaliser is only the mass of the particles
            # lost to the model's domain (they were renormalised away above).
            normaliser = np.where(skipped, 0.0, normaliser)
        self.trace.log_likelihood += normaliser
        self.trace.log_likelihood_increments[:, t] += normaliser     # after the auxiliary filter's L1_k, if any
        if self.injection is not None:              # w_avg = exp(L_k), the weighted mean likelihood
            self.injection.observe(normaliser, None if skipped is None else ~skipped)
        self.weights = new_weights

    def estimate(self, k: int) -> None:
        """The ESS before resampling, and the estimate: the weighted (circular) mean."""
        t = k - 1
        self.trace.ess[:, t] = effective_sample_size(self.weights)
        self.trace.estimates[:, t] = posterior_mean(self.model, self.weights, self.state)
        if not np.isfinite(self.trace.estimates[:, t]).all():
            raise ModelNumericalError(f"model {self.model.kind} produced NaN or infinite particles at step {k} "
                                      "of the filter (check the prior and the noise)")

    def resample_and_move(self, k: int) -> None:
        """Resample the trials whose ESS fell below the threshold, then move their particles
        (:meth:`resample`); the auxiliary filter resamples in its next first stage instead."""
        if self.active is not None:                  # the count this step's cloud was weighted with
            self.trace.particle_counts[:, k - 1] = self.active
        if self.filter.auxiliary is not None:
            return
        rows = self.filter.resampling.rows(self.trace.ess[:, k - 1], self.particles, self.active)
        if rows.size:
            self.resample(rows, k)

    def resample(self, rows: np.ndarray, k: int):
        """Resample the trials ``rows`` (not empty) at step k and apply, to their resampled
        particles, the move, the adaptive count, the diffusion and the injection; their weights
        become uniform. Returns the ancestor indices (len(rows), N) and the rows' selector."""
        bound, t = self.filter, k - 1
        every = rows.size == self.trials
        selected = slice(None) if every else rows      # a slice spares fancy-index copies
        streams = self.random if every else self.random.subset(rows)
        indices = bound.resampling.indices(self.weights[selected], streams)
        ancestors = indices
        resampled = resample_rows(self.state, rows, indices)
        if bound.move is not None:                   # filter.move, on the parents' resampled order
            resampled = self.move(k, rows, selected, indices, resampled, streams)
        if bound.adaptive is not None:               # KLD: keep the first n of a random order
            resampled, counts, order = bound.adaptive.apply(resampled, streams)
            ancestors = np.take_along_axis(indices, order, axis=1)
        moved = bound.diffusion.apply(resampled, streams)
        if self.injection is not None:               # augmented MCL: replace some by prior draws
            # fixed in both (2026-11-29): the count this resampling keeps, KLD's new one (it took the
            # previous one, so a prior draw could land on a particle the new count leaves inactive)
            active = counts if bound.adaptive is not None else np.full(rows.size, self.particles)
            replaced = self.injection.inject(moved, active, rows, streams, bound.prior)
            self.trace.injected[rows, t] = replaced.sum(axis=1)
            ancestors = np.where(replaced, -1, ancestors)          # a prior draw has no ancestor
        if every:
            self.state = moved
        else:
            self.state[rows] = moved
        if bound.adaptive is not None:
            self.active[rows] = counts
            self.log_weights[selected], self.weights[selected] = active_uniform(counts, self.particles)
        else:
            self.log_weights[selected] = self.uniform_log_weight
            self.weights[selected] = 1.0 / self.particles
        self.trace.resampled[selected, t] = True
        if self.ancestors is not None:
            self.ancestors[selected] = ancestors
        return indices, selected

    def move(self, k: int, rows: np.ndarray, selected, indices: np.ndarray, resampled: np.ndarray,
             streams: TrialStreams) -> np.ndarray:
        """Apply ``filter.move`` to the resampled trials, giving it the cloud and weights before
        resampling, the measurement and (if it needs them) the parents' previous states; tally
        its acceptance rate."""
        parents = resample_rows(self.previous_state, rows, indices) if self.keep_previous else None
        context = MoveContext(model=self.model, step=k, resampled=resampled, cloud=self.state[selected],
                              weights=self.weights[selected], measurement=self.measurements[selected, k - 1],
                              parents=parents, indices=indices, log_weights=self.log_weights[selected])
        moved, acceptance = self.filter.move.apply(context, streams)
        if self.acceptance_tally is not None:
            self.acceptance_tally[0, selected] += acceptance
            self.acceptance_tally[1, selected] += 1
        return moved
