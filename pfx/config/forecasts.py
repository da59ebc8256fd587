"""``outputs.forecasts``: which forecasts a run writes to forecasts.csv, and their plan-time checks.

A forecast starts from a particle filter's weighted cloud at an *origin* (a step of the record,
named by its time in the model's unit, or ``all`` of them) and runs the model's transition
``horizons`` steps ahead without updates (:mod:`pfx.filters.particle.forecasting`). The first
``trials`` trials of every particle-filter cell are forecast; cells of other kinds (kf, the grid)
have no cloud and write none, which the docs say (docs/forecasts.md). After PMMH, ``trials`` is
the number of posterior draws to forecast from (:mod:`pfx.estimation.posterior_forecasts`).
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
    """Refuse, by key, forecasts that cannot be made: none of the cells carries particles, an
    origin that is no step's time, a run that estimates parameters."""
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
    if forecasts.origins != "all":
        times = np.asarray(cells[0].truth_model.times(), dtype=float)
        for index, origin in enumerate(forecasts.origins):
            if not origin_steps(forecasts.model_copy(update={"origins": [origin]}), times):
                raise ConfigError(f"no step is at time {origin} (the steps run from {times[0]:g} to {times[-1]:g}, "
                                  f"steps.csv's `time`)", file=file, key=f"{key}.origins[{index}]")
