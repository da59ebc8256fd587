r"""The batched particle filter: many independent trials x N particles advanced together.

Particles are an array of shape (trials, N, d); log-weights (trials, N). Each step k = 1..T:

1. **Predict**: :math:`x_{k,i} \sim p(x_k \mid x_{k-1,i}, u_k)` (the model's transition).
2. **Weight**: :math:`\log \tilde w_{k,i} = \log w_{k-1,i} + \log \ell_k(x_{k,i})`, with the
   configured weighting :math:`\ell` (the likelihood :math:`p(z_k \mid x_{k,i})` by default).
3. **Normalise** in the log domain: :math:`\log w_{k,i} = \log \tilde w_{k,i} - L_k`,
   :math:`L_k = \log \sum_i \tilde w_{k,i}` by log-sum-exp (shifted by the row maximum, so
   extreme log-weights never overflow). :math:`\sum_k L_k` estimates :math:`\log p(z_{1:T})`.
   If every weight of a trial underflows (:math:`L_k = -\infty`), the step is *degenerate*:
   the policy is to reset that trial's weights to uniform and go on (counted per trial).
4. **Estimate** :math:`\hat x_k = \sum_i w_{k,i} x_{k,i}` (weighted mean, before resampling;
   a model's angular components by the circular mean, :mod:`pfx.numerics.angles`), and
   :math:`\mathrm{ESS}_k = 1 / \sum_i w_{k,i}^2`.
5. **Resample** the trials with :math:`\mathrm{ESS}_k < \theta N` (:math:`\theta = 1`: every step;
   :math:`\theta = 0`: never, i.e. SIS), then apply the post-resampling diffusion to them.

In the code, :class:`ParticleFilter` runs these as named stages, ``predict`` (the proposal:
the transition, i.e. the bootstrap filter, or a guided proposal, :mod:`pfx.filters.particle.proposals`,
after the auxiliary filter's first stage, :mod:`pfx.filters.particle.auxiliary`; their importance
terms reach the weight update as a per-particle weight adjustment), ``update_weights``, ``estimate`` and
``resample_and_move`` (the resampler; a move given the step's context, ``filter.move``:
:mod:`pfx.filters.particle.moves`; the particle count, fixed or adaptive,
:mod:`pfx.filters.particle.adaptive`; the diffusion or roughening; particle injection,
:mod:`pfx.filters.particle.injection`). Diagnostics (particle snapshots, NEES/NIS, the spread and
the share within a radius) are :class:`Recorder` s called after each stage; they only read.
For the bootstrap filter with the likelihood as weight, a model's optional compiled step
(:meth:`pfx.models.base.Model.compiled_step`) does the transition and the likelihood in one
pass: ``predict`` then hands the likelihood to ``update_weights``.

A particle whose state becomes NaN or infinite has left the model's domain (the falling body's
drag equation, for instance, blows up in finite time for a negative ballistic coefficient): it
gets weight zero (log-weight -inf), its state is parked at 0 until resampling replaces it, and
it is counted per trial (``lost_particles``). A trial that loses every particle, a NaN or
+inf log-likelihood of a finite particle, or a non-finite truth is a model error:
:class:`ModelNumericalError` names the model and the step.

A missing measurement (NaN in a trial's row at step k: recorded data with a blank row) makes
the step predict-only for that trial: step 2 is skipped (the weights stay as they were, so
:math:`L_k = 0` adds nothing to the log-likelihood), the estimate and the ESS are taken as
usual, and the ESS rule may still resample.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from pfx.errors import ModelContractError, ModelNumericalError, note_step
from pfx.filters.particle.auxiliary import first_stage
from pfx.filters.particle.moves import MoveContext
from pfx.filters.trace import FilterTrace
from pfx.numerics.angles import circular_mean, wrap_difference
from pfx.numerics.compiled import compiled
from pfx.numerics.quadratic_forms import normalised_squares
from pfx.numerics.seeding import TrialStreams


@dataclass
class SnapshotRequest:
    """Which particle clouds to keep: trials (rows of the batch), steps, stages.

    Stages: ``prior`` (step 0), ``predicted`` (after the transition, with the previous
    weights), ``weighted`` (after the weight update, before resampling) and ``resampled``
    (after resampling and diffusion). Each kept cloud is appended to ``clouds`` as a dict with
    keys stage, step, rows, state (len(rows), N, d) and weights (len(rows), N).
    """

    rows: np.ndarray
    steps: object                 # a collection of steps, or "all"
    stages: frozenset
    clouds: list = field(default_factory=list)

    def keep(self, stage: str, step: int, state: np.ndarray, weights: np.ndarray) -> None:
        if (stage in self.stages or stage == "prior") and (self.steps == "all" or step in self.steps):
            self.clouds.append({"stage": stage, "step": step, "rows": self.rows,
                                "state": state[self.rows].copy(), "weights": weights[self.rows].copy()})


@dataclass
class SpreadCriterion:
    """Record, per step, the share of particles within ``radius`` of the particle mean."""

    radius: float
    weighted: bool


def guided_predict(run: "ParticleFilter", k: int) -> np.ndarray:
    """The predict stage with a guided proposal and/or the auxiliary filter's first stage:
    sets ``run.state`` to x_k and returns the weight adjustment (R, N) that the weight update
    adds to log p(z_k | x_k): log p(x_k | x_k-1) - log q(x_k | x_k-1, z_k) - g_a."""
    adjustment = first_stage(run, k) if run.auxiliary else None
    t = k - 1
    if run.proposal is None:
        with np.errstate(over="ignore", invalid="ignore"):
            run.state = run.model.transition(run.state, k, run.random)
        return -adjustment
    observed = None if run.missing is None else ~run.missing[:, t]
    run.state, correction = run.proposal.propose(run.model, run.state, k, run.measurements[:, t], observed,
                                                 run.random)
    return correction if adjustment is None else correction - adjustment


def log_normalise(log_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise log-sum-exp normalisation; returns (normalised log-weights, log normaliser).

    A row whose entries are all -inf has normaliser -inf and is returned unchanged.
    """
    normalised, _, normaliser = normalise_weights(log_weights)
    return normalised, normaliser


def normalise_weights(log_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Log-sum-exp normalisation, row by row: (log w, w, L).

    With :math:`m = \max_i \log \tilde w_i` and :math:`S = \sum_i e^{\log \tilde w_i - m}`:
    :math:`\log w_i = \log \tilde w_i - m - \log S`, :math:`w_i = e^{\log \tilde w_i - m} / S`
    (the exponentials are computed once, for the sum and the weights) and
    :math:`L = m + \log S`. A row whose entries are all -inf has L = -inf, log-weights
    unchanged and weights 0.
    """
    with np.errstate(under="ignore", over="ignore", invalid="ignore", divide="ignore"):
        return normalise_rows(log_weights)


def normalise_rows(log_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`normalise_weights` without its ``np.errstate`` (the engine's loop sets it once)."""
    peak = np.max(log_weights, axis=-1, keepdims=True)
    finite_peak = np.where(np.isfinite(peak), peak, 0.0)
    shifted = log_weights - finite_peak
    weights = np.exp(shifted)
    total = np.sum(weights, axis=-1, keepdims=True)
    log_total = np.log(total)
    usable = np.isfinite(log_total)
    # Subtract the shift and log(total) separately: peak + log(total) loses log(total) to
    # rounding when |peak| > ~1e16.
    shifted -= np.where(usable, log_total, 0.0)
    weights /= np.where(usable, total, 1.0)
    return shifted, weights, (log_total + finite_peak)[..., 0]


def effective_sample_size(weights: np.ndarray) -> np.ndarray:
    """ESS = 1 / sum_i w_i^2 for normalised weights, per row."""
    return 1.0 / np.einsum("rn,rn->r", weights, weights)


def weighted_mean(weights: np.ndarray, particles: np.ndarray) -> np.ndarray:
    """sum_i w_i x_i per trial: (R, N), (R, N, d) -> (R, d).

    A (1 x N) by (N x d) matrix product per trial: BLAS does it about ten times faster than
    ``einsum`` (which loops over the short last axis d).
    """
    return np.matmul(weights[:, None, :], particles)[:, 0, :]


def resample_rows(state: np.ndarray, rows: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """The resampled particles of the given trials: out[r, i] = state[rows[r], indices[r, i]].

    One compiled pass (:func:`gather_particles`): NumPy's ``take_along_axis`` on (R, N, d)
    costs several times more.
    """
    # Every trial resampled: the same memory layout as the state (models may keep each state
    # component contiguous, see Noise.sample).
    out = np.empty_like(state) if len(rows) == len(state) else np.empty((len(rows),) + state.shape[1:])
    gather_particles(state, np.asarray(rows, dtype=np.intp), indices, out)
    return out


@compiled
def gather_particles(state, rows, indices, out):
    """out[r, i, :] = state[rows[r], indices[r, i], :]."""
    dimension = state.shape[2]
    for r in range(rows.size):
        source = rows[r]
        for c in range(dimension):           # component by component: contiguous writes when
            for i in range(indices.shape[1]):    # the state keeps its components contiguous
                out[r, i, c] = state[source, indices[r, i], c]


def posterior_mean(model, weights: np.ndarray, particles: np.ndarray) -> np.ndarray:
    """The estimate: the weighted mean, with the model's angular components (if any) averaged
    on the circle (:func:`pfx.numerics.angles.circular_mean`)."""
    mean = weighted_mean(weights, particles)
    angular = list(model.angular_components)
    if angular:
        mean[:, angular] = circular_mean(weights, particles[..., angular], model.full_turn)
    return mean


def run_particle_filter(model, measurements: np.ndarray, random: TrialStreams, *, prior,
                        particles: int, resampler, ess_threshold: float, weighting, diffusion,
                        spread_criterion: Optional[SpreadCriterion] = None,
                        consistency: bool = False, snapshot: Optional[SnapshotRequest] = None,
                        trace_rows: Optional[np.ndarray] = None, move=None, adaptive=None,
                        injection=None, proposal=None, auxiliary: bool = False) -> FilterTrace:
    """Run the filter on measurements of shape (trials, T, m); see the module docstring.

    With ``consistency``, also record the weighted posterior covariance (before resampling) and
    the normalised innovation squared of the predicted cloud, for NEES and NIS. With
    ``snapshot``, keep the particle clouds it asks for (in ``snapshot.clouds``). The weighted
    posterior standard deviations are recorded for the rows ``trace_rows`` (the traced trials),
    and only for them: a second moment per step costs about what the estimate does, and only
    steps.csv shows it (None: for no row, as in ``pfx bench``, whose timings are the filter's).
    ``move`` is ``filter.move`` (:mod:`pfx.filters.particle.moves`; None or ``none``: no move).
    """
    recorders: list[Recorder] = []
    traced = trace_rows is not None and len(trace_rows) > 0
    if traced or spread_criterion is not None:      # steps.csv's spread; the spread convergence criterion
        recorders.append(SpreadRecorder(model, spread_criterion, None if spread_criterion is not None else trace_rows))
    if traced:
        recorders.append(StandardDeviationRecorder(model, trace_rows))
    if consistency:
        recorders.append(ConsistencyRecorder(model))
    if snapshot is not None:
        recorders.append(SnapshotRecorder(snapshot))
    return ParticleFilter(model, measurements, random, prior=prior, particles=particles, resampler=resampler,
                          ess_threshold=ess_threshold, weighting=weighting, move=diffusion,
                          recorders=recorders, adaptive=adaptive, injection=injection,
                          rejuvenation=move if move is not None and move.kind != "none" else None,
                          proposal=proposal, auxiliary=auxiliary).run()


class ParticleFilter:
    """One batch of trials of the particle filter, advanced step by step in named stages.

    :meth:`run` is the algorithm; each stage is a method, and the points where a variant plugs
    in are objects: the proposal, the weighting (the weight update), the resampler, the move after
    resampling (``filter.move``), the particle count (fixed, or ``filter.adaptive``), the
    diffusion and the injection. Diagnostics are
    :class:`Recorder` s: they look at the cloud after a stage and fill their part of the trace,
    so the loop holds the algorithm and nothing else.
    """

    normalise = staticmethod(normalise_weights)

    def __init__(self, model, measurements: np.ndarray, random: TrialStreams, *, prior, particles: int,
                 resampler, ess_threshold: float, weighting, move, recorders=(), adaptive=None, injection=None,
                 rejuvenation=None, proposal=None, auxiliary: bool = False):
        self.model, self.measurements, self.random = model, measurements, random
        self.resampler, self.ess_threshold, self.weighting, self.move = resampler, ess_threshold, weighting, move
        self.recorders = list(recorders)
        # a guided proposal (None: the transition) and the auxiliary filter (proposals.py, auxiliary.py)
        self.proposal, self.auxiliary = proposal, auxiliary
        self.weight_adjustment: Optional[np.ndarray] = None   # log p(x|x_prev) - log q - g_a, per particle
        # filter.move (pfx.filters.particle.moves): None when off, so that it costs nothing
        self.rejuvenation = rejuvenation
        self.previous_state: Optional[np.ndarray] = None      # x_{k-1}, kept only for a move that needs parents
        self.keep_previous = rejuvenation is not None and rejuvenation.needs_parents
        self.trials, self.steps, _ = measurements.shape
        self.particles = particles                       # the particle count (with ``adaptive``: the maximum)
        # the adaptive count (pfx.filters.particle.adaptive): active particles per trial, None: all N
        self.adaptive, self.prior = adaptive, prior
        self.active: Optional[np.ndarray] = None if adaptive is None else np.full(self.trials, particles)
        # particle injection (pfx.filters.particle.injection): its running averages, or None
        self.injection = None if injection is None else injection.start(self.trials)
        self.uniform_log_weight = -np.log(particles)
        self.state = prior.sample(random, (particles,))
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
            log_likelihood=np.zeros(self.trials), lost_particles=np.zeros(self.trials, dtype=np.int64),
            particle_counts=np.full((self.trials, self.steps), particles),
            injected=None if injection is None else np.zeros((self.trials, self.steps), dtype=np.int64))
        # per trial: the sum of the move's acceptance rates over the steps it moved, and their count
        self.acceptance_tally = np.zeros((2, self.trials)) \
            if rejuvenation is not None and rejuvenation.reports_acceptance else None
        # The model's compiled transition-and-likelihood (Model.compiled_step), where it computes
        # exactly this filter's proposal and weights: the bootstrap filter with the likelihood.
        plain = proposal is None and not auxiliary and getattr(weighting, "kind", None) == "gaussian"
        self.compiled_step = model.compiled_step() if plain else None
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
                    self.predict(k)
                    self.record("predicted", k)
                    self.update_weights(k)
                    self.estimate(k)
                    self.record("weighted", k)
                    self.resample_and_move(k)
                    self.record("resampled", k)
        except Exception as error:        # where it happened, for the one-line report
            note_step(error, k, "filter")
            raise
        if self.acceptance_tally is not None:
            with np.errstate(invalid="ignore", divide="ignore"):     # never moved: NaN, an empty field
                self.trace.move_acceptance = self.acceptance_tally[0] / self.acceptance_tally[1]
        return self.trace

    def record(self, stage: str, step: int) -> None:
        for recorder in self.recorders:
            recorder.record(stage, step, self)

    def predict(self, k: int) -> None:
        """Propose x_k: from the transition (the bootstrap proposal), or from a guided proposal
        (:mod:`pfx.filters.particle.proposals`), after the auxiliary filter's first stage if
        asked (:mod:`pfx.filters.particle.auxiliary`); park particles that left the model's
        domain at weight zero."""
        if self.keep_previous:
            self.previous_state = self.state
        if self.auxiliary or self.proposal is not None:
            self.weight_adjustment = guided_predict(self, k)
        elif self.compiled_step is not None:         # the model's fused transition and likelihood
            noise = self.model.process_noise.sample(self.random, self.state.shape[1:-1])
            self.state, self.log_likelihood = self.compiled_step(self.state, self.model.control(k), noise,
                                                                 self.measurements[:, k - 1])
        else:
            self.state = self.model.transition(self.state, k, self.random)    # non-finite values: below
        if self.state.shape != self.cloud_shape:       # a tuple comparison: the contract, at the run's size
            source = "the proposal" if self.proposal is not None else \
                "compiled_step" if self.compiled_step is not None else "the transition (propagate)"
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
                increment = self.weighting.log_weights(self.model, self.measurements[:, t, None, :],
                                                       self.state, self.weights)
            if increment.shape != self.log_weights.shape:      # would broadcast silently
                raise ModelContractError(
                    f"model {self.model.kind}: the weighting {getattr(self.weighting, 'kind', '')} (log_likelihood) "
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
        """Resample the trials whose ESS fell below the threshold, then move their particles (the
        diffusion, or ``filter.move`` with the step's context: :meth:`rejuvenate`)."""
        if self.active is not None:                  # the count this step's cloud was weighted with
            self.trace.particle_counts[:, k - 1] = self.active
        if self.auxiliary:
            return          # the auxiliary filter resamples in the next step's first stage
        rows = self.rows_to_resample(self.trace.ess[:, k - 1])
        if rows.size:
            self.resample(rows, k)

    def rows_to_resample(self, ess: np.ndarray) -> np.ndarray:
        """The trials the ESS rule resamples: ESS < threshold * N (threshold 1: all; 0: none),
        N the active count with an adaptive count."""
        if self.ess_threshold >= 1.0:
            return np.arange(self.trials)
        if self.ess_threshold > 0.0:
            count = self.particles if self.active is None else self.active
            return np.flatnonzero(ess < self.ess_threshold * count)
        return np.empty(0, dtype=np.intp)

    def resample(self, rows: np.ndarray, k: int):
        """Resample and move the trials ``rows`` (not empty) at step k; their weights become
        uniform. Returns the ancestor indices (len(rows), N) and the rows' selector."""
        t = k - 1
        every = rows.size == self.trials
        selected = slice(None) if every else rows      # a slice spares fancy-index copies
        streams = self.random if every else self.random.subset(rows)
        indices = self.resampler(self.weights[selected], streams)
        resampled = resample_rows(self.state, rows, indices)
        if self.rejuvenation is not None:            # filter.move, on the parents' resampled order
            resampled = self.rejuvenate(k, rows, selected, indices, resampled, streams)
        if self.adaptive is not None:                # KLD: keep the first n of a random order
            resampled, counts = self._adapt_count(resampled, streams)
        moved = self.move.apply(resampled, streams)
        if self.injection is not None:               # augmented MCL: replace some by prior draws
            active = np.full(rows.size, self.particles) if self.active is None else self.active[rows]
            self.trace.injected[rows, t] = self.injection.inject(moved, active, rows, streams, self.prior)
        if every:
            self.state = moved
        else:
            self.state[rows] = moved
        if self.adaptive is not None:
            self.active[rows] = counts
            self.log_weights[selected], self.weights[selected] = active_uniform(counts, self.particles)
        else:
            self.log_weights[selected] = self.uniform_log_weight
            self.weights[selected] = 1.0 / self.particles
        self.trace.resampled[selected, t] = True
        return indices, selected

    def _adapt_count(self, resampled: np.ndarray, streams: TrialStreams) -> tuple[np.ndarray, np.ndarray]:
        """The resampled clouds in a random order with the KLD count of each
        (:mod:`pfx.filters.particle.adaptive`); particles past the count are parked on particle 0."""
        order, counts = self.adaptive.select(resampled, streams)
        ordered = np.take_along_axis(resampled, order[..., None], axis=1)
        inactive = np.arange(self.particles) >= counts[:, None]
        ordered = np.where(inactive[..., None], ordered[:, :1], ordered)
        return ordered, counts

    def rejuvenate(self, k: int, rows: np.ndarray, selected, indices: np.ndarray, resampled: np.ndarray,
                   streams: TrialStreams) -> np.ndarray:
        """Apply ``filter.move`` to the resampled trials, giving it the cloud and weights before
        resampling, the measurement and (if it needs them) the parents' previous states; tally
        its acceptance rate."""
        parents = resample_rows(self.previous_state, rows, indices) if self.keep_previous else None
        context = MoveContext(model=self.model, step=k, resampled=resampled, cloud=self.state[selected],
                              weights=self.weights[selected], measurement=self.measurements[selected, k - 1],
                              parents=parents)
        moved, acceptance = self.rejuvenation.apply(context, streams)
        if self.acceptance_tally is not None:
            self.acceptance_tally[0, selected] += acceptance
            self.acceptance_tally[1, selected] += 1
        return moved


class Recorder:
    """A diagnostic attached to :class:`ParticleFilter`: after each stage ("prior",
    "predicted", "weighted", "resampled") it may read the filter's cloud and fill its part of
    the trace. Recorders never change the cloud or draw random numbers."""

    def record(self, stage: str, step: int, run: ParticleFilter) -> None:
        raise NotImplementedError


class SpreadRecorder(Recorder):
    """After each step: the weighted RMS distance of the positions from their mean (``spread``,
    a column of steps.csv: for the traced ``rows`` only, None: every row) and, for the spread
    convergence criterion, the share within its radius (every row)."""

    def __init__(self, model, criterion: Optional[SpreadCriterion], rows: Optional[np.ndarray] = None):
        position = list(model.position_components)
        if position == list(range(position[0], position[-1] + 1)):
            position = slice(position[0], position[-1] + 1)      # a view of the state, not a copy per step
        self.position, self.criterion = position, criterion
        self.rows = slice(None) if rows is None else np.asarray(rows, dtype=np.intp)

    def record(self, stage: str, step: int, run: ParticleFilter) -> None:
        if stage != "resampled":
            return
        if self.criterion is not None and run.trace.within_radius is None:
            run.trace.within_radius = np.empty((run.trials, run.steps))
        # (a diverging cloud has infinite spread: the run's np.errstate lets it be)
        run.trace.spread[self.rows, step - 1] = _spread(run.weights[self.rows], run.state[self.rows][..., self.position])
        if self.criterion is not None:
            run.trace.within_radius[:, step - 1] = _share_within(run.weights, run.state[..., self.position],
                                                                 self.criterion, run.active)


class StandardDeviationRecorder(Recorder):
    """The posterior standard deviation of each state component, weighted, before resampling
    (at the estimate's stage), for some rows of the batch (the traced trials; None: all); the others stay NaN.

    An angular component's deviations are taken from the circular mean, wrapped into half a
    turn either side, as its errors are.
    """

    def __init__(self, model, rows: Optional[np.ndarray]):
        self.rows = slice(None) if rows is None else np.asarray(rows, dtype=np.intp)   # None: every row
        self.angular = list(model.angular_components)
        self.full_turn = model.full_turn

    def record(self, stage: str, step: int, run: ParticleFilter) -> None:
        trace, t = run.trace, step - 1
        if stage == "prior":
            trace.standard_deviations = np.full((run.trials, run.steps, run.state.shape[-1]), np.nan)
        elif stage == "weighted":
            with np.errstate(over="ignore", invalid="ignore"):    # a diverging cloud: infinite spread
                centred = run.state[self.rows] - trace.estimates[self.rows, t, None, :]
                if self.angular:
                    centred[..., self.angular] = wrap_difference(centred[..., self.angular], self.full_turn)
                variances = np.einsum("rn,rnd->rd", run.weights[self.rows], centred * centred)
                trace.standard_deviations[self.rows, t] = np.sqrt(variances)


class ConsistencyRecorder(Recorder):
    """NEES and NIS for particle filters: the NIS of the predicted cloud, and the weighted
    posterior covariance (before resampling)."""

    def __init__(self, model):
        self.model = model

    def record(self, stage: str, step: int, run: ParticleFilter) -> None:
        trace, t = run.trace, step - 1
        if stage == "prior":
            dimension = run.state.shape[-1]
            trace.covariances = np.empty((run.trials, run.steps, dimension, dimension))
            trace.nis = np.empty((run.trials, run.steps))
        elif stage == "predicted":
            trace.nis[:, t] = _innovation_squared(self.model, run.measurements[:, t], run.state, run.weights)
        elif stage == "weighted":
            centred = run.state - trace.estimates[:, t, None, :]
            trace.covariances[:, t] = np.einsum("rn,rnd,rne->rde", run.weights, centred, centred)


class SnapshotRecorder(Recorder):
    """Keeps the particle clouds a :class:`SnapshotRequest` asks for."""

    def __init__(self, request: SnapshotRequest):
        self.request = request

    def record(self, stage: str, step: int, run: ParticleFilter) -> None:
        self.request.keep(stage, step, run.state, run.weights)


def _innovation_squared(model, measurement: np.ndarray, state: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """NIS of the predicted cloud: nu' S^-1 nu, nu = z - E_w[h(x)], S = Cov_w(h(x)) + R; NaN where
    S cannot be inverted reliably (:mod:`pfx.numerics.quadratic_forms`)."""
    with np.errstate(over="ignore", invalid="ignore"):
        predicted = model.measurement_mean(state)
        mean = np.einsum("rn,rnm->rm", weights, predicted)
        centred = predicted - mean[:, None, :]
        innovation_covariance = np.einsum("rn,rnm,rnk->rmk", weights, centred, centred) \
            + model.measurement_noise.covariance()
        return normalised_squares(measurement - mean, innovation_covariance)


def _spread(weights: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Weighted RMS distance of the particles' positions from their weighted mean."""
    centre = weighted_mean(weights, positions)[:, None, :]
    squared = np.sum((positions - centre) ** 2, axis=-1)
    return np.sqrt(np.einsum("rn,rn->r", weights, squared))


def _share_within(weights: np.ndarray, positions: np.ndarray, criterion: SpreadCriterion,
                  active: Optional[np.ndarray] = None) -> np.ndarray:
    """Share of particles (by weight, or by count: of the active ones) within the radius of the
    (matching) mean."""
    if not criterion.weighted:
        weights = np.full_like(weights, 1.0 / weights.shape[-1]) if active is None \
            else active_uniform(active, weights.shape[-1])[1]
    centre = weighted_mean(weights, positions)[:, None, :]
    inside = np.sum((positions - centre) ** 2, axis=-1) <= criterion.radius ** 2
    return np.sum(weights * inside, axis=-1)


def active_uniform(counts: np.ndarray, maximum: int) -> tuple[np.ndarray, np.ndarray]:
    """(log-weights, weights) uniform over the first ``counts[r]`` particles of each row
    (log 1/n, 1/n), -inf and 0 past them: an adaptive count's inactive particles."""
    active = np.arange(maximum) < counts[:, None]
    uniform = 1.0 / counts[:, None]
    return np.where(active, -np.log(counts)[:, None], -np.inf), np.where(active, uniform, 0.0)


def simulate_truth(model, random: TrialStreams) -> tuple[np.ndarray, np.ndarray]:
    """True states x_0..x_T (R, T+1, d) and measurements z_1..z_T (R, T, m) from ``model``;
    the model's truth events (a kidnapping: :meth:`truth_event`) apply here, never in a filter."""
    trials = len(random)
    state = model.initial.sample(random)
    states = np.empty((trials, model.steps + 1, state.shape[-1]))
    measurements = np.empty((trials, model.steps, model.measurement_dimension))
    states[:, 0] = state
    k = 0
    try:
        for k in range(1, model.steps + 1):
            with np.errstate(over="ignore", invalid="ignore"):   # reported just below
                state = model.transition(state, k, random)
                _check_shape(model, "the transition (propagate)", state, states.shape[::2], k)
                state = model.truth_event(state, k)
                states[:, k] = state
                measurement = model.simulate_measurement(state, random)
                _check_shape(model, "simulate_measurement", measurement, measurements.shape[::2], k)
                measurements[:, k - 1] = measurement
            if not (np.isfinite(state).all() and np.isfinite(measurements[:, k - 1]).all()):
                raise ModelNumericalError(f"model {model.kind} produced NaN or infinite values at step {k} "
                                          "of the truth")
    except Exception as error:            # where it happened, for the one-line report
        note_step(error, k, "truth")
        raise
    return states, measurements


def _check_shape(model, source: str, value, expected: tuple, k: int) -> None:
    """The truth's arrays keep their shape (R, d) / (R, m): a wrong one would broadcast silently."""
    if np.shape(value) != expected:
        raise ModelContractError(f"model {model.kind}: {source} returned shape {np.shape(value)} at step {k} of "
                                 f"the truth, for {expected[0]} trials; expected {expected}")
