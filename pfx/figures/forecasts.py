r"""The forecast fan: k-step forecasts of the measurement from the filter's cloud (forecasts.csv).

``outputs.forecasts`` runs the model ahead from a particle filter's weighted cloud at each
*origin* step :math:`k`, without updates, and writes for every horizon :math:`h` the weighted
quantiles of the forecast measurement :math:`z_{k+h}` given :math:`z_{1:k}`
(:mod:`pfx.filters.particle.forecasting`; forecasts.csv's ``measurement_q<pp>_<m>``).
``forecast_fan`` draws them for the first forecast trial: per cell and measurement component,
the measurements as points over time (steps.csv's ``measurement_<m>``, or forecasts.csv's
``observed_<m>`` where steps.csv did not trace the trial), and from each origin a fan over its
horizons: the widest pair of quantiles (5% and 95% by default) lightest, each inner pair
darker, the median a line. A fan starts at the measurement of its origin step, where it has no
width: given :math:`z_{1:k}`, the measurement :math:`z_k` is known. (An origin whose
measurement is missing starts its fan at the first horizon.) The measurements that follow
show at a glance whether the fan holds them: about 90% of points should fall inside the 5-95%
band of a calibrated forecast, and a fan that widens too slowly or too fast with the horizon
shows a transition noise the model under- or overstates.

With ``origins: all`` and horizons ``[1..H]`` there is a fan from every step and they would
cover each other: of more than :data:`MOST_ORIGINS` origins, as many are drawn as fit without
one fan covering the next (at most that many, at least 2), evenly spaced over the trial's
origins (the first and the last among them), and the title says how many of how many. The
cells that wrote no forecasts (a Kalman filter or the grid: no particle cloud) are named.
Returns None (draws nothing) for a folder without forecasts.csv or its quantile columns.

After PMMH (an estimation folder's forecasts.csv, :mod:`pfx.estimation.posterior_forecasts`) the
fans are the posterior predictive forecast's, the rows whose ``draw`` is :data:`POOLED` (every
posterior draw's cloud side by side), and the measurements are forecasts.csv's observed values
(an estimation folder has no steps.csv).
"""

from __future__ import annotations

import re

import numpy as np

from pfx.figures.layout import time_axis
from pfx.figures.registry import FIGURES, asks_for, draws_on_estimation_from
from pfx.figures.scores import cell_grid, cells_without, traced_steps
from pfx.result_folder import ResultFolder

MOST_ORIGINS = 6               # fans drawn per panel at most, evenly spaced over the origins
FAN_COLOUR = "C0"
LIGHTEST, DARKEST = 0.18, 0.45  # the opacity of the widest and of the innermost band
POOLED = "pooled"               # the `draw` of PMMH's posterior predictive rows (pfx.estimation.posterior_forecasts)


def quantile_probability(label: str) -> float:
    """The probability of a quantile label of forecasts.csv: "05" -> 0.05, "02_5" -> 0.025
    (the inverse of :func:`pfx.filters.particle.forecasting.quantile_label` without its "q")."""
    return float(label.replace("_", ".")) / 100.0


def measurement_quantiles(forecasts, component: str) -> dict[float, str]:
    """probability -> column ``measurement_q<pp>_<component>`` of forecasts.csv, in increasing order."""
    pattern = re.compile(r"measurement_q(\d{2}(?:_\d+)?)_" + re.escape(component))
    found = {}
    for column in forecasts.columns:
        match = pattern.fullmatch(column)
        if match:
            found[quantile_probability(match.group(1))] = column
    return dict(sorted(found.items()))


def band_pairs(probabilities) -> list[tuple[float, float]]:
    """The quantiles paired outside in: the lowest with the highest (the widest band), the
    second lowest with the second highest, ...; a middle one left over is not a band."""
    ordered = sorted(probabilities)
    return [(ordered[index], ordered[-1 - index]) for index in range(len(ordered) // 2)]


def shown_origins(origins, horizon: int, most: int = MOST_ORIGINS) -> list:
    """The origins (steps) to draw a fan from: every one of at most ``most``; of more, as many
    as fit without one fan of ``horizon`` steps covering the next (at most ``most``, at least
    2), evenly spaced over them, the first and the last among them."""
    origins = sorted(origins)
    if len(origins) <= most:
        return origins
    apart = (origins[-1] - origins[0]) // max(horizon, 1) + 1
    count = min(most, max(apart, 2))
    return [origins[index] for index in np.unique(np.round(np.linspace(0, len(origins) - 1, count)).astype(int))]


def percent(probability: float) -> str:
    return f"{100 * probability:.4g}"


@FIGURES.register("forecast_fan")
@asks_for("outputs.forecasts")
@draws_on_estimation_from("forecasts")
def forecast_fan(result: ResultFolder):
    """Forecast fans of the measurement for the first forecast trial: from each origin, its quantile bands over the horizons (widest lightest, the median a line), with the measurements as points.

    From forecasts.csv (`outputs.forecasts`) and steps.csv's `measurement_<m>`; a panel per cell with forecasts and measurement component. Of more than 6 origins, as many as keep the fans apart (2 to 6), evenly spaced; the title says how many of how many. Each fan starts at its origin's measurement. After PMMH, the posterior predictive forecast (every posterior draw pooled).
    """
    forecasts = result.forecasts
    components = [column.removeprefix("observed_") for column in forecasts.columns if column.startswith("observed_")]
    components = [component for component in components if measurement_quantiles(forecasts, component)]
    if forecasts.empty or not components:
        return None
    x_column, x_label = time_axis(result)
    trial = None
    if "draw" in forecasts:           # after PMMH: the posterior draws' mixture, not a trial
        draws = forecasts.loc[forecasts["draw"].astype(str) != POOLED, "draw"].nunique()
        forecasts = forecasts[forecasts["draw"].astype(str) == POOLED]
        source = f"the posterior predictive ({draws} posterior draws pooled)"
    else:
        trial = int(forecasts["trial"].min())
        forecasts = forecasts[forecasts["trial"] == trial]
        source = f"the filter's cloud, trial {trial}"
    steps = traced_steps(result)      # none in an estimation folder
    if not steps.empty:
        steps = steps[steps["trial"] == trial]
    grid = cell_grid(result, forecasts.drop_duplicates("cell"), components, panel_size=(5.0, 3.0))
    counts = set()
    for (component, cell), axes in grid.axes.items():
        rows = forecasts[forecasts["cell"] == cell]
        measured = _measurements(steps[steps["cell"] == cell] if not steps.empty else steps, rows, component, x_column)
        origins = sorted(rows["origin_step"].unique())
        shown = shown_origins(origins, int(rows["horizon"].max()))
        counts.add((len(shown), len(origins)))
        for origin in shown:
            _draw_fan(axes, rows[rows["origin_step"] == origin].sort_values("horizon"), component, x_column,
                      measured, origin)
        axes.plot(measured["x"], measured["value"], linestyle="none", marker="o", markersize=3.5, color="black",
                  label="measurement", zorder=3)
        if len(grid.labels) > 1 or len(components) > 1:
            axes.set_title(f"{grid.labels[cell]}, {component}", fontsize=9)
    title = _title(result, forecasts, source, counts) + _without_forecasts(result, forecasts)
    grid.finish(title, x_label, lambda component: f"measurement {component}")
    return grid.figure


def _measurements(steps, forecasts, component: str, x_column: str):
    """The trial's measurements of ``component`` at each step: columns step, x, value. From
    steps.csv when it traced the trial, else forecasts.csv's values observed at forecast steps."""
    import pandas as pd

    column = f"measurement_{component}"
    if not steps.empty and column in steps:
        table = steps[["step", x_column, column]]
    else:
        table = forecasts[["step", x_column, f"observed_{component}"]].drop_duplicates("step")
    table = pd.DataFrame({"step": table.iloc[:, 0].to_numpy(), "x": table.iloc[:, 1].to_numpy(dtype=float),
                          "value": table.iloc[:, 2].to_numpy(dtype=float)})
    return table.sort_values("step", ignore_index=True)


def _draw_fan(axes, rows, component: str, x_column: str, measured, origin: int) -> None:
    """One origin's fan: its bands (outside in, lighter to darker) and its median, from the
    measurement at the origin where there is one. Each artist's gid names the origin and what
    it draws ("origin 5: 5-95%", "origin 5: median"), so that tests can find it."""
    quantiles = measurement_quantiles(rows, component)
    x = rows[x_column].to_numpy(dtype=float)
    start = measured.loc[measured["step"] == origin]
    anchored = not start.empty and np.isfinite(start["value"].iloc[0])

    def from_origin(values):
        if not anchored:
            return x, values
        return np.concatenate([[start["x"].iloc[0]], x]), np.concatenate([[start["value"].iloc[0]], values])

    pairs = band_pairs(quantiles)
    for index, (low, high) in enumerate(pairs):
        opacity = LIGHTEST + (DARKEST - LIGHTEST) * index / max(len(pairs) - 1, 1)
        band_x, lower = from_origin(rows[quantiles[low]].to_numpy(dtype=float))
        _, upper = from_origin(rows[quantiles[high]].to_numpy(dtype=float))
        band = axes.fill_between(band_x, lower, upper, color=FAN_COLOUR, alpha=opacity, linewidth=0,
                                 label=f"{percent(low)}-{percent(high)}% forecast band")
        band.set_gid(f"origin {origin}: {percent(low)}-{percent(high)}%")
        if len(x) == 1 and not anchored:   # one horizon and nothing to start from: a bar, not an area
            axes.vlines(x, lower, upper, color=FAN_COLOUR, alpha=opacity, linewidth=4)
    if 0.5 in quantiles:
        line_x, median = from_origin(rows[quantiles[0.5]].to_numpy(dtype=float))
        (line,) = axes.plot(line_x, median, color=FAN_COLOUR, linewidth=1.3, marker="." if len(line_x) < 3 else None,
                            label="forecast median")
        line.set_gid(f"origin {origin}: median")


def _without_forecasts(result: ResultFolder, forecasts) -> str:
    """A line naming the run's cells that wrote no forecasts (kinds without a particle cloud)."""
    import pandas as pd

    cells = pd.DataFrame(result.manifest.get("cells", []))
    if cells.empty or "cell" not in cells:
        return ""
    missing = cells_without(result, cells, forecasts["cell"].unique(), what="no forecasts (no particle cloud)")
    return f"\n{missing}" if missing else ""


def _title(result: ResultFolder, forecasts, source: str, counts: set) -> str:
    horizons = ", ".join(str(int(h)) for h in sorted(forecasts["horizon"].unique()))
    shown = ", ".join(f"{drawn} of {every}" for drawn, every in sorted(counts))
    spacing = " (evenly spaced, fans apart)" if any(drawn < every for drawn, every in counts) else ""
    return (f"{result.manifest.get('name', '')}: forecasts of the measurement from {source}\n"
            f"origins drawn: {shown}{spacing}; horizons {horizons} steps; each fan starts at its origin's measurement")
