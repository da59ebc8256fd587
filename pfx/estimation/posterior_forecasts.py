r"""Forecasts after PMMH: from posterior draws of the parameters, each with its own filter.

A filter at fixed parameters forecasts with its own uncertainty about the state only. After
PMMH, the parameters are uncertain too, and the posterior predictive forecast integrates over
them:

.. math::

    p(z_{k+h} \mid z_{1:k}) \approx \frac1D \sum_{d=1}^{D} \hat p(z_{k+h} \mid z_{1:k}, \theta_d),

with :math:`\theta_1..\theta_D` drawn from the chains after their warm-up. Each draw runs the
cell's particle filter on the data with its own stream, and forecasts from its cloud at the
origins (:mod:`pfx.filters.particle.forecasting`). forecasts.csv then holds, per origin and
horizon, one row per draw (``draw`` = 0..D-1, with its chain, iteration and parameter values)
and the posterior predictive forecast itself (``draw`` = ``pooled``: every draw's particles side
by side, each draw's weights divided by D, so its quantiles are those of the mixture).

The D draws are spread evenly over the kept iterations of the chains pooled in (chain,
iteration) order (``outputs.forecasts.trials`` names D); the seeds of their filters depend on
(seed, cell, draw) only. D is at most the number of kept iterations: the plan refuses more
(:func:`pfx.config.forecasts.kept_posterior_draws`), rather than this module giving fewer.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

from pfx.config.forecasts import ForecastOutputs, origin_steps
from pfx.errors import ModelNumericalError
from pfx.filters import FILTERS
from pfx.filters.particle.forecasting import ForecastRequest, pooled, summaries
from pfx.numerics.seeding import TrialStreams, posterior_forecast_seed

POOLED = "pooled"
PLACE_COLUMNS = ("row", "origin", "horizon", "step")      # forecast_table's columns that place a row


def posterior_draws(chains: pd.DataFrame, columns: list[str], count: int) -> pd.DataFrame:
    """``count`` rows of the chains after their warm-up, spread evenly in (chain, iteration) order."""
    kept = chains[~chains["warm_up"].astype(bool)].sort_values(["chain", "iteration"], kind="stable")
    if kept.empty:
        return kept
    positions = np.unique(np.linspace(0, len(kept) - 1, min(count, len(kept))).round().astype(int))
    return kept.iloc[positions][["chain", "iteration", *columns]].reset_index(drop=True)


class PosteriorForecasts(NamedTuple):
    """One PMMH cell's forecasts: forecasts.csv's rows without the cell's labels, how many
    posterior draws were asked, and why each draw left out was (a filter that failed at its
    parameters), so that the run can say so."""

    table: pd.DataFrame
    draws: int
    left_out: list[str]


def posterior_forecasts(target, chains: pd.DataFrame, forecasts: ForecastOutputs, root_seed: int,
                        cell_key: int) -> PosteriorForecasts:
    """forecasts.csv's rows of one PMMH cell (module docstring), without the cell's labels."""
    columns = target.estimation.columns
    draws = posterior_draws(chains, columns, forecasts.trials)
    settings = target.cell.filter
    origins = origin_steps(forecasts, np.asarray(target.cell.filter_model.times(), dtype=float))
    request = ForecastRequest(rows=np.array([0]), origins=origins, horizons=tuple(forecasts.horizons),
                              quantiles=tuple(forecasts.quantiles))      # the same for every draw
    by_place: dict[tuple[int, int], list] = {}
    frames = []
    left_out: list[str] = []
    for index, draw in draws.iterrows():
        model = target.model_at(draw[columns].to_numpy(dtype=float))
        if model is None:            # a draw the model refuses cannot have been accepted; kept for safety
            left_out.append(f"draw {index}: the model refuses its parameters")
            continue
        prior = target.prior_of(model)
        random = TrialStreams.from_seeds([posterior_forecast_seed(root_seed, cell_key, index)])
        try:
            planned = FILTERS[settings.kind].plan(model, settings, prior)
            trace = planned.run(model, target.measurements[None], random, settings=settings, prior=prior,
                                forecast=request)
        except ModelNumericalError as error:
            left_out.append(f"draw {index}: {error}")
            continue
        summarised = trace.forecasts            # one row per sample, in their order
        for position, sample in enumerate(trace.forecast_samples):
            by_place.setdefault((sample.origin, sample.horizon), []).append(sample)
            frames.append({"draw": str(index), "chain": int(draw["chain"]), "iteration": int(draw["iteration"]),
                           **{name: float(draw[name]) for name in columns}, **_place(sample),
                           **{name: float(values[position]) for name, values in summarised.items()
                              if name not in PLACE_COLUMNS}})
    names = target.cell.filter_model          # the mixture's column names: every draw's model has them
    for samples in by_place.values():
        mixture = pooled(samples)
        frames.append({"draw": POOLED, "chain": np.nan, "iteration": np.nan, **{name: np.nan for name in columns},
                       **_place(mixture), **_first(summaries(names, mixture, forecasts.quantiles))})
    if not frames:
        return PosteriorForecasts(pd.DataFrame(), len(draws), left_out)
    table = pd.DataFrame(frames)
    times = np.asarray(target.cell.filter_model.times(), dtype=float)
    table.insert(table.columns.get_loc("origin_step") + 1, "origin_time", times[table["origin_step"] - 1])
    table.insert(table.columns.get_loc("step") + 1, "time", times[table["step"] - 1])
    return PosteriorForecasts(table.sort_values(["origin_step", "horizon"], kind="stable", ignore_index=True),
                              len(draws), left_out)


def _place(sample) -> dict:
    return {"origin_step": sample.origin, "horizon": sample.horizon, "step": sample.origin + sample.horizon}


def _first(columns: dict) -> dict:
    """One row's values of :func:`~pfx.filters.particle.forecasting.summaries`'s columns."""
    return {name: float(values[0]) for name, values in columns.items()}
