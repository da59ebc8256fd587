r"""Forecasts from a particle filter's cloud: k steps ahead, without updates.

At an origin step :math:`k` the weighted cloud :math:`\{x_{k,i}, w_{k,i}\}` (after the weight
update, before resampling) represents :math:`p(x_k \mid z_{1:k})`. Propagating every particle
through the model's transition :math:`h` times, weights unchanged, gives a weighted sample of
the h-step forecast :math:`p(x_{k+h} \mid z_{1:k})`:

.. math::

    x_{k+j,i} \sim p(x_{k+j} \mid x_{k+j-1,i}, u_{k+j}), \qquad j = 1..h,

and one measurement draw per particle, :math:`\tilde z_{k+h,i} \sim p(z \mid x_{k+h,i})`, a
weighted sample of :math:`p(z_{k+h} \mid z_{1:k})`. :func:`forecast_table` summarises each
horizon: the weighted mean, standard deviation and quantiles of every state and measurement
component, and, where the measurement :math:`z_{k+h}` exists (in the record, not missing), its
scores (:mod:`pfx.numerics.proper_scores`): CRPS and randomised PIT per component, the energy
score of the vector, and the log score :math:`-\log \sum_i w_i\, p(z_{k+h} \mid x_{k+h,i})`,
computed in the log domain from the model's ``log_likelihood``. (At h = 1 these are the
one-step predictive scores of ``metrics.scores`` again, from other draws.)

The draws come from each trial's *forecast stream* (:meth:`~pfx.numerics.seeding.TrialStreams.derived`),
apart from the filter's, so a run with forecasts filters exactly as one without. Horizons that
reach past the record's last step are left out: the model's time axis (its controls, covariates
and substep times) ends there.

The clouds come from the engine that ran the filter: :class:`ForecastRequest` names the rows and
origin steps to keep (a description only, frozen), and the engine returns their clouds in its
trace (``FilterTrace.forecast_clouds``, origin step -> :class:`~pfx.filters.trace.WeightedCloud`).
So forecasts are the same on either backend: this module runs on the host, with NumPy, on the
model's own methods. After the run, :func:`forecast_samples` propagates the clouds (the trace
keeps the samples, ``FilterTrace.forecast_samples``: posterior forecasts pool them) and
:func:`forecast_table` summarises them (``FilterTrace.forecasts``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from pfx.filters.particle.recorders import read_only_rows
from pfx.filters.particle.resampling import inverse_cdf
from pfx.numerics.proper_scores import sample_crps, sample_energy_score, sample_pit, weighted_moments
from pfx.numerics.seeding import FORECAST_STREAM


@dataclass(frozen=True, eq=False)
class ForecastRequest:
    """Which forecasts to make: from the weighted clouds of the batch's ``rows`` at the
    ``origins`` (steps), ``horizons`` steps ahead, summarised by ``quantiles``. A description
    only: the engine returns each origin's cloud of those rows in its trace
    (``FilterTrace.forecast_clouds``)."""

    rows: np.ndarray
    origins: frozenset
    horizons: tuple
    quantiles: tuple

    def __post_init__(self):
        object.__setattr__(self, "rows", read_only_rows(self.rows))


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, probabilities) -> np.ndarray:
    r"""The weighted sample's quantiles, row by row: values (R, N), weights (R, N) normalised ->
    (R, q). The p-quantile is :math:`\min\{v_{(j)} : W_{(j)} > p\}` over the sorted values and
    their cumulative weights (the inverse CDF of :func:`pfx.filters.particle.resampling.inverse_cdf`)."""
    order = np.argsort(values, axis=-1)
    sorted_values = np.take_along_axis(values, order, axis=-1)
    sorted_weights = np.take_along_axis(weights, order, axis=-1)
    points = np.broadcast_to(np.asarray(probabilities, dtype=float), (len(values), len(probabilities)))
    return np.take_along_axis(sorted_values, inverse_cdf(sorted_weights, points), axis=-1)


def quantile_label(probability: float) -> str:
    """A quantile's column label: q05 for 0.05, q50 for 0.5, q02_5 for 0.025."""
    percent = round(100.0 * probability, 6)
    if percent == int(percent):
        return f"q{int(percent):02d}"
    whole, fraction = f"{percent:g}".split(".")
    return f"q{int(whole):02d}_{fraction}"


@dataclass
class ForecastSample:
    """The weighted sample of one forecast, for the rows of a request: the propagated states
    (r, N, d) and their weights (r, N), one measurement draw per particle (r, N, m), the
    measurement that came (r, m; NaN where missing), each particle's log-likelihood of it (r, N)
    and the draws V (r, m) of the randomised PIT."""

    origin: int
    horizon: int
    rows: np.ndarray
    state: np.ndarray
    weights: np.ndarray
    draws: np.ndarray
    observed: np.ndarray
    log_likelihood: np.ndarray
    uniform: np.ndarray


def forecast_samples(model, request: ForecastRequest, clouds: dict, measurements: np.ndarray,
                     random) -> list[ForecastSample]:
    """Every forecast of ``request`` as its weighted sample, by origin then horizon (module
    docstring), from the kept ``clouds`` (``FilterTrace.forecast_clouds``). ``measurements``
    (R, T, m) are the batch's; ``random`` the batch's streams (the forecast streams derive from them)."""
    steps = measurements.shape[1]
    streams = random.derived(FORECAST_STREAM).subset(request.rows)
    samples = []
    for origin in sorted(clouds):
        state, log_weights = clouds[origin]
        weights = np.exp(log_weights - logsumexp(log_weights, axis=-1, keepdims=True))
        reachable = [h for h in sorted(request.horizons) if origin + h <= steps]
        for horizon in range(1, max(reachable, default=0) + 1):
            state = model.transition(state, origin + horizon, streams)
            if horizon not in reachable:
                continue
            observed = measurements[request.rows, origin + horizon - 1]
            draws = np.asarray(model.simulate_measurement(state, streams), dtype=float)
            value = np.where(np.isnan(observed), 0.0, observed)
            with np.errstate(divide="ignore", invalid="ignore"):
                likelihood = np.asarray(model.log_likelihood(value[:, None, :], state), dtype=float)
            samples.append(ForecastSample(origin, horizon, request.rows, state, weights, draws, observed,
                                          likelihood, streams.uniform((draws.shape[-1],))))
    return samples


def pooled(samples: list[ForecastSample]) -> ForecastSample:
    """One forecast from several rows' samples of the same origin and horizon (each row a
    posterior draw of the parameters with its own filter): their particles side by side, each
    row's weights divided by the number of rows: the mixture of the rows' forecasts, as one row."""
    first, count = samples[0], sum(len(sample.rows) for sample in samples)

    def side_by_side(name):
        return np.concatenate([np.concatenate(list(getattr(sample, name)), axis=0) for sample in samples])[None]

    return ForecastSample(first.origin, first.horizon, np.array([0]), side_by_side("state"),
                          side_by_side("weights") / count, side_by_side("draws"), first.observed[:1],
                          side_by_side("log_likelihood"), first.uniform[:1])


def summaries(model, sample: ForecastSample, quantiles) -> dict[str, np.ndarray]:
    """One forecast's columns, a value per row: the state's and the measurement's weighted mean,
    sd and quantiles, the measurement that came, and its scores (NaN where it is missing)."""
    columns: dict[str, np.ndarray] = {}
    labels = [quantile_label(p) for p in quantiles]
    state, weights, draws = sample.state, sample.weights, sample.draws
    state_mean, state_sd = weighted_moments(state, weights)
    for j, name in enumerate(model.state_names):
        columns[f"state_mean_{name}"], columns[f"state_sd_{name}"] = state_mean[:, j], state_sd[:, j]
        for label, values in zip(labels, weighted_quantiles(state[..., j], weights, quantiles).T):
            columns[f"state_{label}_{name}"] = values
    present = ~np.isnan(sample.observed).any(axis=-1)
    value = np.where(present[:, None], sample.observed, 0.0)      # a missing one scores nothing (NaN below)
    mean, sd = weighted_moments(draws, weights)
    for j, name in enumerate(model.measurement_names):
        columns[f"measurement_mean_{name}"], columns[f"measurement_sd_{name}"] = mean[:, j], sd[:, j]
        for label, values in zip(labels, weighted_quantiles(draws[..., j], weights, quantiles).T):
            columns[f"measurement_{label}_{name}"] = values
        columns[f"observed_{name}"] = sample.observed[:, j]
        columns[f"crps_{name}"] = np.where(present, sample_crps(draws[..., j], weights, value[:, j]), np.nan)
        columns[f"pit_{name}"] = np.where(present, sample_pit(draws[..., j], weights, value[:, j],
                                                              sample.uniform[:, j]), np.nan)
    if draws.shape[-1] > 1:
        columns["energy_score"] = np.where(present, sample_energy_score(draws, weights, value), np.nan)
    with np.errstate(divide="ignore"):
        density = logsumexp(np.log(weights) + sample.log_likelihood, axis=-1)
    columns["log_score"] = np.where(present, -density, np.nan)
    return columns


def forecast_table(model, request: ForecastRequest, samples: list[ForecastSample]) -> dict[str, np.ndarray]:
    """The forecasts' ``samples`` (:func:`forecast_samples`) as columns of equal length, one row per
    forecast trial, origin and horizon, in the samples' order: ``row`` (the batch row), ``origin``,
    ``horizon``, ``step``, then :func:`summaries`'s columns (at the request's quantiles)."""
    rows = []
    for sample in samples:
        count = len(sample.rows)
        rows.append({"row": sample.rows, "origin": np.full(count, sample.origin),
                     "horizon": np.full(count, sample.horizon), "step": np.full(count, sample.origin + sample.horizon),
                     **summaries(model, sample, request.quantiles)})
    if not rows:
        return {}
    return {name: np.concatenate([row[name] for row in rows]) for name in rows[0]}
