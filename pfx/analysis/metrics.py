r"""Metrics: pure functions from a trial's truth and filter trace to numbers.

All arrays carry the trial axis first; steps are numbered k = 1..T (step k is the k-th
transition + measurement, i.e. the k-th action in kim-mcl's counting).

* **RMSE** of component :math:`j`: :math:`\sqrt{\tfrac1T \sum_k (\hat x_{k,j} - x_{k,j})^2}`;
  of position: :math:`\sqrt{\tfrac1T \sum_k e_k^2}` with the error distance below (every
  mean over steps is over the scored steps only when a burn-in is set: below). The error
  of an angular component (a heading) is wrapped into half a turn either side (:mod:`pfx.numerics.angles`).
* **Error distance** :math:`e_k = \lVert \hat p_k - p_k \rVert_2` over the model's position
  components; reported time-averaged (:math:`\tfrac1T\sum_k e_k`) and final (:math:`e_T`).
* **Convergence step**, two criteria (the table using it must say which):

  - ``spread``: the first step at which at least ``fraction`` of the particles lie within
    ``radius`` of the particle mean, evaluated on the posterior cloud at the end of the step
    (after any resampling); ``weighted`` counts particles by weight and uses the weighted mean,
    otherwise each particle counts 1/N around the unweighted mean. kim-mcl's paper asks for
    every particle (fraction 1; the criteria compared: docs/reference-facts.md#convergence).
  - ``truth``: the first step from which the error distance stays below ``radius`` for
    ``hold`` consecutive steps (needs the truth: for experiments, not for a deployed filter).

  Error distance at convergence is :math:`e_k` at that step; never converging leaves both
  empty and ``converged`` false.
* **Consistency**: NEES :math:`(\hat x_k - x_k)^\top P_k^{-1} (\hat x_k - x_k)` (chi-square with d
  degrees of freedom for a consistent filter) and NIS :math:`\nu_k^\top S_k^{-1} \nu_k` (m degrees),
  averaged over the steps. A step whose covariance cannot be inverted reliably (a particle cloud
  collapsed onto a few particles: singular, or indefinite by rounding; the test is
  :mod:`pfx.numerics.quadratic_forms`) has no value: it is left out of the mean and counted
  (``nees_invalid_steps``, ``nis_invalid_steps``), never averaged in as a wrong number.
* **Mean ESS**, **resample count**, **degenerate-step count** (every weight underflowed; the
  weights are reset to uniform), **lost particles** (states that became non-finite), and the filter's **log-likelihood** estimate
  :math:`\sum_k \log \sum_i w_{k-1,i}\, \ell_k(x_{k,i})` (the marginal likelihood when the
  weighting is ``gaussian``).

Recorded data (:mod:`pfx.config.data`) may come without the truth: then every metric that
needs it (RMSE, error distance, the truth convergence criterion and the error at convergence,
NEES) is NaN, an empty field, and the others (log-likelihood, ESS, NIS, the spread criterion)
are computed as usual. Steps whose measurement is missing have no NIS: the mean NIS is taken
over the other steps.

**RMS error over the components** (``rms_error_mean``, the score of DAPPER's benchmark tables,
its ``rmse.a``): at each step the root mean square over the d state components of the
posterior mean's error, averaged over the scored steps,
:math:`\tfrac{1}{|S|} \sum_{k \in S} \sqrt{\tfrac1d \sum_j (\hat x_{k,j} - x_{k,j})^2}`. Unlike
``rmse_position`` (the root of a mean over time of a Euclidean distance, :math:`\sqrt d` larger
for errors spread evenly), it is a mean over time of an RMS over components.

**Predictive scores** (``metrics.scores``; :mod:`pfx.numerics.proper_scores`, docs/scores.md):
the mean over the scored steps that have a measurement of each component's CRPS
(``crps_<measurement>``), of the energy score of the measurement vector (``energy_score``, for
two components or more) and of the log score :math:`-L_k` (``log_score``, per step; empty where
the weighting is not the likelihood). All are negatively oriented: smaller is better.

**Burn-in** (``metrics.burn_in``, in the model's time unit): the steps whose time
(``model.times()``, steps.csv's ``time``) is at most ``burn_in`` are not scored. Every metric
that aggregates over the steps (RMSEs, mean error distance, RMS error, mean ESS, resample and
degenerate counts, NEES and NIS means and their invalid steps, the mean particle and injected
counts, the smoothers' RMSEs) is taken over the scored steps :math:`S = \{k : t_k >
\text{burn\_in}\}` only; the others keep their meaning over the whole run: the final error,
the convergence step and the error there, the log-likelihood of the whole record, the lost
particles, the largest grid mass lost in one step (a check of the grid, not a score), the
move's acceptance rate and the ancestral tree. ``burn_in: 0`` (the default) scores every step,
whatever the times. The plan refuses a burn-in that leaves no step to score.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat

from pfx.numerics.angles import wrap_difference
from pfx.numerics.quadratic_forms import normalised_squares
from pfx.registry import Registry

NEVER = -1


class ConvergenceCriterion(BaseModel):
    """Parameters of the convergence metric."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    criterion: Literal["spread", "truth"] = Field("spread", description="spread (particle cloud) or truth (error) based")
    radius: StrictFloat = Field(1.0, gt=0, description="radius in position units")
    fraction: StrictFloat = Field(0.9, gt=0, le=1, description="spread: share of particles required inside the radius")
    weighted: bool = Field(False, description="spread: weight particles (and the mean) by their weights")
    hold: int = Field(1, ge=1, description="truth: steps the error must stay below the radius")


class MetricsConfig(BaseModel):
    """Parameters of the metrics (every metric is always computed)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    convergence: ConvergenceCriterion = Field(default_factory=ConvergenceCriterion)
    consistency: bool = Field(
        False, description="NEES and NIS for particle filters too (records a weighted covariance "
                           "per step; Gaussian filters always report them)")
    burn_in: StrictFloat = Field(
        0.0, ge=0, description="steps at times <= burn_in (the model's time unit) are not scored by the "
                               "metrics that average or count over steps; 0: every step is scored")
    scores: bool = Field(
        False, description="the one-step-ahead predictive distribution of each measurement and its proper "
                           "scores (CRPS, energy score, log score, PIT; docs/scores.md) in steps.csv, their "
                           "means in trials.csv (a particle filter draws one measurement per particle and step "
                           "for them, from streams apart from its own)")

    def identity(self) -> dict:
        """The settings as they enter a cell's key: ``burn_in`` and ``scores`` only when set, so
        that the keys of configs without them are what they were before they existed."""
        dump = self.model_dump(mode="json")
        if self.burn_in == 0:
            dump.pop("burn_in")
        if not self.scores:
            dump.pop("scores")
        return dump


# -- pure functions ---------------------------------------------------------------------------

def state_error(truth: np.ndarray, estimate: np.ndarray, model) -> np.ndarray:
    """estimate - truth per component, the model's angular components wrapped into
    (-full turn / 2, full turn / 2] (:mod:`pfx.numerics.angles`); other components bit-for-bit as is."""
    error = estimate - truth
    angular = list(model.angular_components)
    if angular:
        error[..., angular] = wrap_difference(error[..., angular], model.full_turn)
    return error


def component_rmse(error: np.ndarray) -> np.ndarray:
    """RMSE over time of every state component from the errors: (trials, T, d) -> (trials, d)."""
    return np.sqrt(np.mean(error ** 2, axis=1))


def error_distance(truth: np.ndarray, estimate: np.ndarray, model) -> np.ndarray:
    """Euclidean distance between true and estimated position (the model's position
    components; an angular one's error wrapped, as in :func:`state_error`): (trials, T)."""
    position = list(model.position_components)
    difference = state_error(truth[..., position], estimate[..., position], _PositionOf(model))
    return np.sqrt(np.sum(difference * difference, axis=-1))


class _PositionOf:
    """The angular components of a model's position, numbered within the position (for
    :func:`state_error` on the position's columns alone)."""

    def __init__(self, model):
        position = list(model.position_components)
        self.angular_components = [position.index(c) for c in model.angular_components if c in position]
        self.full_turn = model.full_turn


def scored_steps(times: np.ndarray, burn_in: float):
    """The steps :math:`k` with :math:`t_k >` ``burn_in``, as an index of the step axis: a
    whole slice when ``burn_in`` is 0 (every step, whatever the times), else a boolean mask."""
    if burn_in == 0:
        return slice(None)
    return np.asarray(times, dtype=float) > burn_in


def rms_over_components(error: np.ndarray) -> np.ndarray:
    r"""The RMS over the state components at each step, :math:`\sqrt{\tfrac1d \sum_j e_{k,j}^2}`:
    (trials, T, d) -> (trials, T)."""
    return np.sqrt(np.mean(error ** 2, axis=-1))


def first_step(condition: np.ndarray) -> np.ndarray:
    """1-based index of the first True along the step axis, or NEVER."""
    found = condition.any(axis=1)
    return np.where(found, condition.argmax(axis=1) + 1, NEVER)


def spread_convergence_step(fraction_within: np.ndarray, fraction: float) -> np.ndarray:
    """First step at which at least ``fraction`` of the particles lie within the radius."""
    return first_step(fraction_within >= fraction - 1e-12)


def truth_convergence_step(distance: np.ndarray, radius: float, hold: int) -> np.ndarray:
    """First step k with distance < radius at steps k .. k + hold - 1 (all inside the run)."""
    below = distance < radius
    steps = below.shape[1]
    if hold > steps:
        return np.full(below.shape[0], NEVER)
    window = np.ones_like(below[:, : steps - hold + 1])
    for offset in range(hold):
        window &= below[:, offset: steps - hold + 1 + offset]
    return first_step(window)


def value_at_step(series: np.ndarray, step: np.ndarray) -> np.ndarray:
    """series[r, step[r] - 1], NaN where step is NEVER."""
    index = np.clip(step - 1, 0, series.shape[1] - 1)
    values = np.take_along_axis(series, index[:, None], axis=1)[:, 0]
    return np.where(step == NEVER, np.nan, values)


# -- metric families: column name -> per-trial values -----------------------------------------

@dataclass
class MetricInputs:
    """Everything a metric may read: truth at steps 1..T, the filter trace, the model."""

    truth: Optional[np.ndarray]    # (trials, T, d); None: recorded data without the truth
    trace: "object"                # pfx.filters.trace.FilterTrace
    model: "object"                # the truth model (names, position components)
    config: MetricsConfig
    observed: Optional[np.ndarray] = None   # (trials, T) False where the measurement is missing; None: all there

    @property
    def trials(self) -> int:
        return self.trace.estimates.shape[0]

    @property
    def scored(self):
        """The steps the step-aggregating metrics score (module docstring, burn-in): an index of
        the step axis, every step (a whole slice, so that the numbers without a burn-in are
        computed exactly as before it existed) or a boolean mask of the steps after the burn-in."""
        if self.config.burn_in == 0:          # nothing to exclude: the times are not needed
            return slice(None)
        return scored_steps(self.model.times(), self.config.burn_in)

    def empty(self) -> np.ndarray:
        """A metric column with nothing in it (NaN per trial): what needs the truth, without it."""
        return np.full(self.trials, np.nan)


MetricFamily = Callable[[MetricInputs], dict[str, np.ndarray]]
METRICS: Registry[MetricFamily] = Registry("metric")


def _distance(inputs: MetricInputs) -> np.ndarray:
    return error_distance(inputs.truth, inputs.trace.estimates, inputs.model)


@METRICS.register("rmse")
def rmse_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """RMSE over time per state component (rmse_<name>) and of position (rmse_position)."""
    if inputs.truth is None:
        return {f"rmse_{name}": inputs.empty() for name in (*inputs.model.state_names, "position")}
    scored = inputs.scored
    values = component_rmse(state_error(inputs.truth, inputs.trace.estimates, inputs.model)[:, scored])
    columns = {f"rmse_{name}": values[:, j] for j, name in enumerate(inputs.model.state_names)}
    columns["rmse_position"] = np.sqrt(np.mean(_distance(inputs)[:, scored] ** 2, axis=1))
    return columns


@METRICS.register("error_distance")
def error_distance_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Position error distance averaged over time (error_distance_mean) and at the end (_final)."""
    if inputs.truth is None:
        return {"error_distance_mean": inputs.empty(), "error_distance_final": inputs.empty()}
    distance = _distance(inputs)
    return {"error_distance_mean": distance[:, inputs.scored].mean(axis=1), "error_distance_final": distance[:, -1]}


@METRICS.register("convergence")
def convergence_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Convergence step (spread or truth criterion), converged flag, error distance then."""
    criterion = inputs.config.convergence
    if inputs.truth is None:
        if criterion.criterion == "truth":
            return {"convergence_step": inputs.empty(), "converged": inputs.empty(),
                    "error_at_convergence": inputs.empty()}
        distance = np.full(inputs.trace.estimates.shape[:2], np.nan)   # the error at convergence: unknown
    else:
        distance = _distance(inputs)
    if criterion.criterion == "spread" and inputs.trace.within_radius is None:
        # no cloud to measure (the Gaussian filters): the criterion does not apply, which is not
        # "never converged"; the truth criterion applies to every kind
        return {"convergence_step": inputs.empty(), "converged": inputs.empty(),
                "error_at_convergence": inputs.empty()}
    if criterion.criterion == "spread":
        step = spread_convergence_step(inputs.trace.within_radius, criterion.fraction)
    else:
        step = truth_convergence_step(distance, criterion.radius, criterion.hold)
    return {
        "convergence_step": np.where(step == NEVER, np.nan, step.astype(float)),
        "converged": step != NEVER,
        "error_at_convergence": value_at_step(distance, step),
    }


@METRICS.register("ess")
def ess_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Mean effective sample size over the steps (before resampling), in particles."""
    return {"ess_mean": inputs.trace.ess[:, inputs.scored].mean(axis=1)}


@METRICS.register("resampling")
def resampling_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Number of steps at which the trial resampled."""
    return {"resample_count": inputs.trace.resampled[:, inputs.scored].sum(axis=1)}


@METRICS.register("degeneracy")
def degeneracy_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Number of degenerate steps (every weight underflowed; weights reset to uniform)."""
    return {"degenerate_steps": inputs.trace.degenerate[:, inputs.scored].sum(axis=1)}


@METRICS.register("lost_particles")
def lost_particle_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Particles whose state became NaN or infinite (given weight zero), summed over steps."""
    return {"lost_particles": inputs.trace.lost_particles}


@METRICS.register("particle_count")
def particle_count_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Particle filters: the mean particle count and the mean number injected per step.

    particles_mean: N, or the mean adaptive count; injected_mean: 0 without injection. Empty
    for other filters."""
    trace = inputs.trace
    counts = getattr(trace, "particle_counts", None)
    if counts is None:
        return {"particles_mean": inputs.empty(), "injected_mean": inputs.empty()}
    injected = getattr(trace, "injected", None)
    scored = inputs.scored
    return {"particles_mean": counts[:, scored].mean(axis=1),
            "injected_mean": injected[:, scored].mean(axis=1) if injected is not None else np.zeros(inputs.trials)}


@METRICS.register("grid_lost_mass")
def grid_lost_mass_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Grid filter: the largest probability mass that left the grid in one step.

    Near 0 when the grid covers where the state goes; empty for other filters."""
    lost = inputs.trace.grid_lost_mass
    return {"grid_lost_mass": lost.max(axis=1) if lost is not None else inputs.empty()}


@METRICS.register("smoothing")
def smoothing_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Each smoother's RMSE over time per state component and of the position (``rmse_<smoother>_<state>``,
    ``rmse_<smoother>_position``), as the filter's ``rmse_*`` are computed (empty without the truth)."""
    columns: dict[str, np.ndarray] = {}
    model, scored = inputs.model, inputs.scored
    for label, smoothed in inputs.trace.smoothed.items():
        if inputs.truth is None:
            empty = np.full(inputs.trials, np.nan)
            columns.update({f"rmse_{label}_{name}": empty for name in model.state_names})
            columns[f"rmse_{label}_position"] = empty
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            values = component_rmse(state_error(inputs.truth, smoothed.means, model)[:, scored])
            columns.update({f"rmse_{label}_{name}": values[:, j] for j, name in enumerate(model.state_names)})
            distance = error_distance(inputs.truth, smoothed.means, model)[:, scored]
            columns[f"rmse_{label}_position"] = np.sqrt(np.mean(distance ** 2, axis=1))
    return columns


@METRICS.register("genealogy")
def genealogy_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """The size of the last particles' ancestral tree (``ancestral_tree_size``: its distinct
    nodes over every step, pfx.analysis.genealogy), where the genealogy was recorded."""
    ancestors = getattr(inputs.trace, "ancestors", None)
    if ancestors is None:
        return {}
    from pfx.analysis.genealogy import distinct_ancestor_counts

    return {"ancestral_tree_size": np.array([distinct_ancestor_counts(row).sum() for row in ancestors], dtype=float)}


@METRICS.register("consistency")
def consistency_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Mean NEES (expected d) and NIS (expected m), and the steps left out of them.

    NEES e' P^-1 e and NIS nu' S^-1 nu, averaged over the steps that have one; a step whose
    covariance cannot be inverted reliably is left out and counted (module docstring)."""
    trace, scored = inputs.trace, inputs.scored
    columns = {name: inputs.empty() for name in
               ("nees_mean", "nees_invalid_steps", "nis_mean", "nis_invalid_steps")}
    if trace.covariances is not None and inputs.truth is not None:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            errors = state_error(inputs.truth, trace.estimates, inputs.model)
            nees = normalised_squares(errors, trace.covariances)
        columns["nees_mean"], columns["nees_invalid_steps"] = _mean_over_valid_steps(nees[:, scored], None)
    if trace.nis is not None:
        observed = None if inputs.observed is None else inputs.observed[:, scored]
        columns["nis_mean"], columns["nis_invalid_steps"] = _mean_over_valid_steps(trace.nis[:, scored], observed)
    return columns


def _mean_over_valid_steps(values: np.ndarray, observed: Optional[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(mean over the steps with a value, count of the steps left out) per trial, from a
    (trials, T) array that is NaN where a covariance could not be inverted reliably.

    Steps without a measurement (``observed`` False) have no NIS by design: they are neither
    averaged nor counted. A trial with no valid step has an empty mean.
    """
    expected = np.ones(values.shape, dtype=bool) if observed is None else observed
    valid = expected & ~np.isnan(values)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        mean = np.where(valid, values, 0.0).sum(axis=1) / valid.sum(axis=1)
    return mean, (expected & ~valid).sum(axis=1).astype(float)


@METRICS.register("log_likelihood")
def log_likelihood_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """The filter's estimate of log p(z_1:T) (exact meaning only with gaussian weighting)."""
    return {"log_likelihood": inputs.trace.log_likelihood}


@METRICS.register("move_acceptance")
def move_acceptance_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """filter.move mcmc: the mean Metropolis acceptance rate over the moved steps and proposals.

    Empty for other moves and filters, and for a trial that never resampled."""
    acceptance = inputs.trace.move_acceptance
    return {"move_acceptance": acceptance if acceptance is not None else inputs.empty()}


@METRICS.register("rms_error")
def rms_error_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """The RMS over the state components of the mean's error, averaged over the scored steps
    (``rms_error_mean``, DAPPER's rmse.a; in the state's unit), and each smoother's
    (``rms_error_<smoother>_mean``); empty without the truth."""
    labels = list(inputs.trace.smoothed)
    if inputs.truth is None:
        return {f"rms_error_{prefix}mean": inputs.empty() for prefix in ("", *(f"{label}_" for label in labels))}
    scored = inputs.scored
    columns = {"rms_error_mean": rms_over_components(
        state_error(inputs.truth, inputs.trace.estimates, inputs.model))[:, scored].mean(axis=1)}
    with np.errstate(over="ignore", invalid="ignore"):
        for label in labels:
            error = state_error(inputs.truth, inputs.trace.smoothed[label].means, inputs.model)
            columns[f"rms_error_{label}_mean"] = rms_over_components(error)[:, scored].mean(axis=1)
    return columns


@METRICS.register("scores")
def score_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """With ``metrics.scores``: the mean over the scored steps with a measurement of each
    component's CRPS (``crps_<name>``), of the energy score (``energy_score``, two components or
    more) and of the log score (``log_score``); empty where the kind computes none."""
    if not inputs.config.scores:
        return {}
    names = inputs.model.measurement_names
    predictive = getattr(inputs.trace, "predictive", None)
    columns = {f"crps_{name}": inputs.empty() for name in names}
    if len(names) > 1:
        columns["energy_score"] = inputs.empty()
    columns["log_score"] = inputs.empty()
    if predictive is None:
        return columns
    scored = inputs.scored
    for j, name in enumerate(names):
        columns[f"crps_{name}"] = _mean_of_present(predictive.crps[:, scored, j])
    if len(names) > 1 and predictive.energy_score is not None:
        columns["energy_score"] = _mean_of_present(predictive.energy_score[:, scored])
    if predictive.log_score is not None:
        columns["log_score"] = _mean_of_present(predictive.log_score[:, scored])
    return columns


def _mean_of_present(values: np.ndarray) -> np.ndarray:
    """The mean over the steps of each trial's values that are not NaN (a step without a
    measurement scores nothing); NaN for a trial with none."""
    present = ~np.isnan(values)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(present, values, 0.0).sum(axis=1) / present.sum(axis=1)


def compute_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
    """Every registered metric, as column name -> (trials,) array."""
    columns: dict[str, np.ndarray] = {}
    for family in METRICS.names():
        columns.update(METRICS[family](inputs))
    return columns
