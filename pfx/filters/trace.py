r"""What every filter kind returns: per-trial, per-step estimates and diagnostics.

A step whose measurement is missing (recorded data with a blank row, :mod:`pfx.config.data`)
is predict-only in every kind: no weight update, a log-likelihood increment of 0, and NIS NaN
at that step (empty in the CSV).

The log-likelihood estimate is a sum over the steps, :math:`\log \hat p(z_{1:T}) = \sum_k L_k`
with :math:`L_k = \log \hat p(z_k \mid z_{1:k-1})`; every kind also keeps the increments
:math:`L_k` themselves (``log_likelihood_increments``: steps.csv's ``log_likelihood_increment``),
where a user finds the step at which the model and the data disagree. The total is the kind's
own running sum, as it always was; the increments add up to it to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Optional

import numpy as np


@dataclass
class Predictive:
    r"""The one-step-ahead predictive distribution of the measurement, :math:`p(z_k \mid z_{1:k-1})`,
    and its proper scores against the :math:`z_k` that came (:mod:`pfx.numerics.proper_scores`),
    per trial and step; NaN at a step without a measurement.

    ``mean``, ``sd``, ``crps``, ``pit``: (trials, T, m), per measurement component; ``energy_score``
    (trials, T) of the whole vector (None for a scalar measurement, whose energy score is its
    CRPS, or where the kind does not compute it); ``log_score`` (trials, T), minus the
    log-likelihood increment (None where the weighting is not the likelihood: the increment is
    then not a predictive density).
    """

    mean: np.ndarray
    sd: np.ndarray
    crps: np.ndarray
    pit: np.ndarray
    energy_score: Optional[np.ndarray] = None
    log_score: Optional[np.ndarray] = None

    @classmethod
    def empty(cls, trials: int, steps: int, dimension: int, energy: bool) -> "Predictive":
        def blank(*shape):
            return np.full(shape, np.nan)

        return cls(mean=blank(trials, steps, dimension), sd=blank(trials, steps, dimension),
                   crps=blank(trials, steps, dimension), pit=blank(trials, steps, dimension),
                   energy_score=blank(trials, steps) if energy else None, log_score=blank(trials, steps))


@dataclass(frozen=True, eq=False)
class Snapshot:
    """One kept particle cloud (``outputs.particles``, particles.csv): the rows of the batch a
    :class:`~pfx.filters.particle.recorders.SnapshotRequest` names, at one stage of one step.

    ``stage``: ``prior`` (step 0), ``predicted``, ``weighted`` or ``resampled``; ``rows`` (r,) the
    batch rows; ``state`` (r, N, d) and ``weights`` (r, N) (float64 on the jax backend at either
    precision; the NumPy engine's own arrays, copied).
    """

    stage: str
    step: int
    rows: np.ndarray
    state: np.ndarray
    weights: np.ndarray


class WeightedCloud(NamedTuple):
    """The weighted cloud (after the weight update, before resampling) of a forecast request's
    rows at one origin step, float64: what :mod:`pfx.filters.particle.forecasting` forecasts from."""

    state: np.ndarray          # (r, N, d)
    log_weights: np.ndarray    # (r, N), normalised


@dataclass
class FilterTrace:
    """A filter run over a batch of trials and steps 1..T (shapes: ``trials`` first).

    Fields that do not apply to a filter kind (ESS for a Kalman filter) hold NaN, and become
    empty fields in the CSV; ``covariances`` and ``nis`` are None where not computed.
    """

    estimates: np.ndarray            # (trials, T, d) posterior mean (PF: weighted mean before resampling)
    ess: np.ndarray                  # (trials, T) effective sample size before resampling
    resampled: np.ndarray            # (trials, T) bool
    degenerate: np.ndarray           # (trials, T) bool: every weight underflowed
    spread: np.ndarray               # (trials, T) RMS distance of the position from its mean
    log_likelihood: np.ndarray       # (trials,) estimate of log p(z_1:T)
    lost_particles: np.ndarray       # (trials,) particles whose state became non-finite
    within_radius: Optional[np.ndarray] = None  # (trials, T) share of particles within the radius
    covariances: Optional[np.ndarray] = None    # (trials, T, d, d) posterior covariance
    nis: Optional[np.ndarray] = None            # (trials, T) normalised innovation squared
    grid_lost_mass: Optional[np.ndarray] = None  # (trials, T) grid filter: probability mass leaving the grid
    # (trials, T, d) posterior standard deviation of each component, where a kind records it
    # apart from ``covariances`` (the particle filter: weighted, before resampling, for the
    # traced trials only; NaN in the rows not recorded)
    standard_deviations: Optional[np.ndarray] = None
    move_acceptance: Optional[np.ndarray] = None  # (trials,) filter.move mcmc: mean acceptance rate (NaN: never moved)
    # particle filters: (trials, T) the particles the step's cloud was weighted with (N, or the
    # adaptive count, pfx.filters.particle.adaptive), and the particles injected at its
    # resampling (pfx.filters.particle.injection; None: no injection)
    particle_counts: Optional[np.ndarray] = None
    injected: Optional[np.ndarray] = None
    # particle filters, when asked for (the genealogy): (trials, T, N) the index of each particle's
    # ancestor in the previous step's weighted cloud (-1: injected from the prior; step 1: the prior)
    ancestors: Optional[np.ndarray] = None
    # particle filters, when asked for (the history the smoothers run on): (trials, T, N, d) each
    # step's cloud and (trials, T, N) its normalised log-weights, both before resampling
    particles: Optional[np.ndarray] = None
    log_weights: Optional[np.ndarray] = None
    # the smoothers' results, by label (``ffbs``, ``rts``, ...): each with ``means`` and
    # ``standard_deviations``, (trials, T, d) (pfx.filters.smoothers)
    smoothed: dict = field(default_factory=dict)
    # (trials, T) each step's log-likelihood increment L_k = log p^(z_k | z_1:k-1) (module
    # docstring): 0 at a step without a measurement; None from a kind that does not record it
    log_likelihood_increments: Optional[np.ndarray] = None
    # the one-step-ahead predictive distribution of the measurement and its scores, when asked for
    # (``metrics.scores``; :class:`Predictive`); None otherwise
    predictive: Optional["Predictive"] = None
    # forecasts from the weighted clouds, when asked for (pfx.filters.particle.forecasting): columns
    # of equal length, one row per forecast trial, origin and horizon; None otherwise
    forecasts: Optional[dict] = None
    # particle filters, when asked for: the kept particle clouds (a SnapshotRequest, outputs.particles),
    # a list of :class:`Snapshot` in the order recorded (the prior's, then each step's stages in
    # their order); the weighted clouds to forecast from (a ForecastRequest), origin step ->
    # :class:`WeightedCloud`, and the forecasts' weighted samples made from them (a list of
    # pfx.filters.particle.forecasting.ForecastSample, by origin then horizon). None otherwise
    snapshots: Optional[list] = None
    forecast_clouds: Optional[dict] = None
    forecast_samples: Optional[list] = None
    # the seconds this run spent compiling its program (the jax backend's first run of a shape;
    # 0 where a program was reused, and on numpy): trials.csv's compile_time_s, apart from run_time_s
    compile_time_s: float = 0.0

    def posterior_standard_deviations(self) -> Optional[np.ndarray]:
        """(trials, T, d): the recorded standard deviations, else the square root of the
        covariance diagonal (Gaussian filters, the histogram filter), else None."""
        if self.standard_deviations is not None:
            return self.standard_deviations
        if self.covariances is not None:
            variances = np.diagonal(self.covariances, axis1=-2, axis2=-1)
            with np.errstate(invalid="ignore"):      # round-off may leave a variance at -1e-300
                return np.sqrt(np.clip(variances, 0.0, None))
        return None

    @classmethod
    def for_gaussian_filter(cls, estimates, covariances, nis, log_likelihood, position,
                            log_likelihood_increments=None) -> "FilterTrace":
        """A trace for filters that carry a mean and a covariance (KF, EKF, UKF, grid)."""
        trials, steps = estimates.shape[:2]
        position_covariance = covariances[..., position, :][..., :, position]
        return cls(estimates=estimates, ess=np.full((trials, steps), np.nan),
                   resampled=np.zeros((trials, steps), dtype=bool),
                   degenerate=np.zeros((trials, steps), dtype=bool),
                   spread=np.sqrt(np.trace(position_covariance, axis1=-2, axis2=-1)),
                   log_likelihood=log_likelihood, lost_particles=np.zeros(trials, dtype=np.int64),
                   covariances=covariances, nis=nis, log_likelihood_increments=log_likelihood_increments)
