"""``outputs.forecasts``: which forecasts a run writes to forecasts.csv, and their plan-time checks.

A forecast starts from a particle filter's weighted cloud at an *origin* (a step of the record,
named by its time in the model's unit, or ``all`` of them) and runs the model's transition
``horizons`` steps ahead without updates (:mod:`pfx.filters.particle.forecasting`). The first
``trials`` trials of every particle-filter cell are forecast; cells of other kinds (kf, the grid)
have no cloud and write none, which the docs say (docs/forecasts.md). After PMMH, ``trials`` is
the number of posterior draws to forecast from (:mod:`pfx.estimation.posterior_forecasts`).

Nothing asked for is dropped without a word. What cannot be made is refused at plan time, by its
key (:func:`check_forecasts`): an empty list of origins, a horizon that passes the record's last
step from every origin, more posterior draws than the chains keep. What can be made in part is
made, and the run says in one line what it left out (:func:`forecast_notes`): the forecasts of
a horizon from the origins too close to the end (``origins: all`` always has some), forecast
trials beyond the run's trials.
"""

from __future__ import annotations

from typing import Annotated, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt

from pfx.errors import ConfigError

TIME_TOLERANCE = 1e-9          # relative: an origin's time matches a step's time within this


class ForecastOutputs(BaseModel):
    """Forecasts from the filter's cloud, k steps ahead (forecasts.csv; docs/forecasts.md)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    horizons: list[Annotated[StrictInt, Field(ge=1, le=100_000)]] = Field(
        default_factory=list, description="steps ahead to forecast (e.g. [1, 4, 12]); empty (the default): no forecasts")
    origins: Union[str, list[Union[StrictInt, StrictFloat]]] = Field(
        "all", description="the times (the model's time unit, steps.csv's `time`) to forecast from, after their "
                           "measurement; `all`: every step")
    trials: StrictInt = Field(1, ge=1, le=10_000, description="how many trials per cell (the first ones) to forecast; after PMMH, how "
                                                                     "many posterior draws")
    quantiles: list[Annotated[float, Field(gt=0.0, lt=1.0)]] = Field(
        default_factory=lambda: [0.05, 0.25, 0.5, 0.75, 0.95],
        description="the quantiles of every forecast state and measurement component")

    @property
    def requested(self) -> bool:
        return bool(self.horizons)


def origin_steps(forecasts: ForecastOutputs, times: np.ndarray) -> frozenset:
    """The steps k (1..T) whose times are the requested origins (all of them for ``all``)."""
    if forecasts.origins == "all":
        return frozenset(range(1, len(times) + 1))
    steps = set()
    for origin in forecasts.origins:
        close = np.isclose(times, float(origin), rtol=TIME_TOLERANCE, atol=TIME_TOLERANCE)
        steps.update((np.flatnonzero(close) + 1).tolist())
    return frozenset(steps)


def check_forecasts(experiment, cells, file: str) -> None:
    """Refuse, by key, forecasts that cannot be made: none of the cells carries particles, no
    origin or one that is no step's time, a horizon past the record's end from every origin,
    IF2 (its estimates are points), more posterior draws than PMMH's chains keep."""
    forecasts = experiment.outputs.forecasts
    if not forecasts.requested:
        return
    key = "outputs.forecasts"
    if experiment.estimation is not None and experiment.estimation.method != "pmmh":
        raise ConfigError("after estimation, forecasts come from PMMH's posterior draws (method: pmmh); IF2 gives "
                          "point estimates: forecast from them with a filter run at those values", file=file, key=key)
    if not any(cell.filter.uses_particles for cell in cells):
        raise ConfigError("forecasts start from a particle filter's cloud, and no cell runs one (kind particle or sis)",
                          file=file, key=key)
    if isinstance(forecasts.origins, str) and forecasts.origins != "all":
        raise ConfigError(f"origins must be `all` or a list of times, not {forecasts.origins!r}", file=file,
                          key=f"{key}.origins")
    if forecasts.origins == []:
        raise ConfigError("an empty list names no origin, so no forecast would be made: list the times to forecast "
                          "from, or write `all`", file=file, key=f"{key}.origins")
    if forecasts.origins != "all":
        times = np.asarray(cells[0].truth_model.times(), dtype=float)
        for index, origin in enumerate(forecasts.origins):
            if not origin_steps(forecasts.model_copy(update={"origins": [origin]}), times):
                raise ConfigError(f"no step is at time {origin} (the steps run from {times[0]:g} to {times[-1]:g}, "
                                  f"steps.csv's `time`)", file=file, key=f"{key}.origins[{index}]")
    _check_horizons(forecasts, cells, file)
    if experiment.estimation is not None:
        _check_posterior_draws(forecasts, experiment.estimation, file)


def _records(forecasts: ForecastOutputs, cells) -> list[tuple[np.ndarray, frozenset]]:
    """Each distinct record the particle cells forecast in: its times and its origin steps."""
    records: dict[tuple, tuple[np.ndarray, frozenset]] = {}
    for cell in cells:
        if cell.filter.uses_particles:
            times = np.asarray(cell.truth_model.times(), dtype=float)
            records.setdefault(tuple(times), (times, origin_steps(forecasts, times)))
    return list(records.values())


def _check_horizons(forecasts: ForecastOutputs, cells, file: str) -> None:
    """A horizon that reaches past the record's last step from every origin of every particle
    cell would write nothing (the model's time axis ends with the record)."""
    # the record whose first origin leaves the most steps after it
    times, origins = max(_records(forecasts, cells), key=lambda record: len(record[0]) - min(record[1]))
    first = min(origins)
    room = len(times) - first
    before = f"is {room} step(s) before it" if room else "is the last step"
    for index, horizon in enumerate(forecasts.horizons):
        if horizon > room:
            raise ConfigError(f"horizon {horizon} reaches past the record's last step (time {times[-1]:g}) from every "
                              f"origin: the first origin, time {times[first - 1]:g}, {before}; drop the horizon, or "
                              "forecast from an earlier origin", file=file, key=f"outputs.forecasts.horizons[{index}]")


def kept_posterior_draws(estimation) -> int:
    """How many iterations PMMH's chains keep after their warm-up: what posterior draws are drawn from."""
    return estimation.chains * (estimation.iterations - estimation.warm_up)


def _check_posterior_draws(forecasts: ForecastOutputs, estimation, file: str) -> None:
    """After PMMH, ``trials`` posterior draws are spread over the chains' kept iterations; there
    are no more draws than those."""
    kept = kept_posterior_draws(estimation)
    if forecasts.trials > kept:
        raise ConfigError(f"{forecasts.trials} posterior draws asked, and the chains keep {kept} ({estimation.chains} "
                          f"chain(s) x ({estimation.iterations} iterations - {estimation.warm_up} warm-up)); ask for "
                          f"at most {kept}, or run more iterations", file=file, key="outputs.forecasts.trials")


def forecast_notes(experiment, cells) -> list[str]:
    """What a run with forecasts leaves out of what ``outputs.forecasts`` asks, one line each
    (the runner prints them; ``--quiet`` silences them): the forecasts of a horizon from origins
    too close to the record's end, and forecast trials beyond the run's trials."""
    forecasts = experiment.outputs.forecasts
    if not forecasts.requested:
        return []
    notes = []
    records = _records(forecasts, cells)
    cut = []
    for horizon in sorted(set(forecasts.horizons)):
        past = sum(sum(1 for origin in origins if origin + horizon > len(times)) for times, origins in records)
        if past:
            total = sum(len(origins) for _, origins in records)
            cut.append(f"horizon {horizon} from {past} of {total} origins")
    if cut:
        ends = ", ".join(sorted({f"{times[-1]:g}" for times, _ in records}))
        notes.append(f"outputs.forecasts: a forecast past the record's last step (time {ends}) is left out: "
                     f"{', '.join(cut)}")
    if experiment.estimation is None and forecasts.trials > experiment.trials:
        notes.append(f"outputs.forecasts.trials: {forecasts.trials} forecast trials asked, and the run has "
                     f"{experiment.trials} trials per cell: all {experiment.trials} are forecast")
    return notes
