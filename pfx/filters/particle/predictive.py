r"""The particle filter's one-step-ahead predictive distribution of the measurement, and its scores.

Before the weight update at step k, the predicted particles :math:`x_{k,i}` with the weights
they carry, :math:`w_i \propto w_{k-1,i}\, e^{a_i}`, represent :math:`p(x_k \mid z_{1:k-1})`
(:math:`a_i` is a guided proposal's importance correction :math:`\log p(x_k \mid x_{k-1}) -
\log q`, or the auxiliary filter's :math:`-g`, where there is one: without it a proposal that
looked at :math:`z_k` would score its own answer). The predictive law of the measurement is then
the mixture :math:`\sum_i w_i\, p(z_k \mid x_{k,i})`; :func:`predictive_step` draws one
:math:`\tilde z_i \sim p(z \mid x_{k,i})` per particle (the model's ``simulate_measurement``)
and scores the weighted sample against :math:`z_k` (:mod:`pfx.numerics.proper_scores`): the
mean and sd of each component, its CRPS and randomised PIT, and the energy score of the vector.

The draws come from each trial's *score stream* (:meth:`~pfx.numerics.seeding.TrialStreams.derived`),
never from the filter's: a run with scores filters exactly as one without. An angular measurement
component (a bearing) is scored on the circle's cut through the value that came: each draw is
taken as :math:`y + \mathrm{wrap}(\tilde z - y)`, so a draw half a turn away is as far as it gets.

:class:`PredictiveRecorder` does this for the NumPy engine after the "predicted" stage and takes
the log score, :math:`-L_k`, after the "weighted" one; the JAX engine calls :func:`predictive_step`
inside its compiled step.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfx.filters.particle.recorders import Recorder
from pfx.filters.trace import Predictive
from pfx.numerics.angles import wrap_difference
from pfx.numerics.arrays import namespace
from pfx.numerics.proper_scores import sample_crps, sample_energy_score, sample_pit, weighted_moments
from pfx.numerics.seeding import SCORE_STREAM


def predictive_step(model, state: Any, log_weights: Any, measurement: Any, random) -> dict[str, Any]:
    """The predictive moments and scores at one step, for every trial of the batch.

    ``state`` (R, N, d) the predicted particles, ``log_weights`` (R, N) their log-weights (any
    normalisation; -inf for a particle out of the model's domain), ``measurement`` (R, m) the
    value that came, ``random`` the trials' score streams. Returns arrays ``mean``, ``sd``,
    ``crps``, ``pit`` (R, m) and ``energy_score`` (R,) (None for m = 1).
    """
    xp = namespace(state, log_weights)
    peak = xp.max(log_weights, axis=-1, keepdims=True)
    weights = xp.exp(log_weights - xp.where(xp.isfinite(peak), peak, 0.0))
    weights = weights / xp.sum(weights, axis=-1, keepdims=True)
    draws = xp.asarray(model.simulate_measurement(state, random))            # (R, N, m)
    if angular := list(model.measurement_angular_components):     # on the circle's cut through the value
        unwrapped = measurement[:, None, angular] + wrap_difference(
            draws[..., angular] - measurement[:, None, angular], model.measurement_full_turn)
        draws = _with_columns(xp, draws, angular, unwrapped)
    # a particle of weight zero (out of the model's domain, parked at 0) may draw anything, even
    # NaN: it stands at the value itself, where it adds nothing to any sum
    draws = xp.where(weights[..., None] > 0.0, draws, measurement[:, None, :])
    dimension = draws.shape[-1]
    mean, sd = weighted_moments(draws, weights)
    uniform = random.uniform((dimension,))                                     # (R, m): V of the randomised PIT
    crps = xp.stack([sample_crps(draws[..., j], weights, measurement[:, j]) for j in range(dimension)], axis=-1)
    pit = xp.stack([sample_pit(draws[..., j], weights, measurement[:, j], uniform[:, j])
                    for j in range(dimension)], axis=-1)
    energy = sample_energy_score(draws, weights, measurement) if dimension > 1 else None
    return {"mean": mean, "sd": sd, "crps": crps, "pit": pit, "energy_score": energy}


def _with_columns(xp, array, columns: list[int], values):
    """``array`` (..., m) with its ``columns`` replaced by ``values`` (..., len(columns)): a copy."""
    parts = []
    for j in range(array.shape[-1]):
        parts.append(values[..., columns.index(j):columns.index(j) + 1] if j in columns else array[..., j:j + 1])
    return xp.concatenate(parts, axis=-1)


class PredictiveRecorder(Recorder):
    """Fills ``trace.predictive`` (:class:`~pfx.filters.trace.Predictive`) for the NumPy engine:
    the moments and scores after the "predicted" stage, the log score after the "weighted" one
    (module docstring). Its draws come from the trials' score streams, not the filter's."""

    def __init__(self, model, likelihood_weighting: bool):
        self.model = model
        self.likelihood_weighting = likelihood_weighting
        self.random = None

    def record(self, stage: str, step: int, run) -> None:
        t = step - 1
        if stage == "prior":
            self.random = run.random.derived(SCORE_STREAM)
            run.trace.predictive = Predictive.empty(run.trials, run.steps, self.model.measurement_dimension,
                                                    energy=self.model.measurement_dimension > 1)
            if not self.likelihood_weighting:
                run.trace.predictive.log_score = None
            return
        predictive = run.trace.predictive
        observed = run.observed(step)
        if stage == "predicted":
            log_weights = run.log_weights if run.weight_adjustment is None else run.log_weights + run.weight_adjustment
            scores = predictive_step(self.model, run.state, log_weights, run.measurements[:, t], self.random)
            for name in ("mean", "sd", "crps", "pit", "energy_score"):
                values = scores[name]
                if values is None:
                    continue
                if observed is not None:          # no measurement: nothing to score
                    values = np.where(observed.reshape(observed.shape + (1,) * (values.ndim - 1)), values, np.nan)
                getattr(predictive, name)[:, t] = values
        elif stage == "weighted" and predictive.log_score is not None:
            score = -run.trace.log_likelihood_increments[:, t]
            predictive.log_score[:, t] = score if observed is None else np.where(observed, score, np.nan)
