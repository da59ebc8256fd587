r"""``predictions_over_data``: the filter's one-step-ahead prediction of each measurement against the measurement that came.

Given the measurements up to step k - 1, the filter predicts the next one: the predictive law
:math:`p(z_k \mid z_{1:k-1})`, whose mean and standard deviation steps.csv records with
``metrics.scores: true`` (``predictive_mean_<m>``, ``predictive_sd_<m>``; docs/scores.md). This
figure draws, for each measurement component m, the predictive mean as a line with the band
mean :math:`\pm 2` sd, and the measurements (``measurement_<m>``) as points: a model that
fits the data has about 95% of its points inside the band (if its predictive law is near
Gaussian; steps.csv records no quantiles of it), and a run of points outside shows where model
and data part. It is the view of R's pomp's one-step predictions, and asks nothing of the
model's form: a measurement that is no state plus noise (reported cases of an epidemic) is
drawn here, where ``filtered_over_data`` cannot place it on a state's axis.

A row of panels per measurement component and a column per cell (at most
:data:`~pfx.figures.filtered_over_data.MOST_CELLS`), each cell's first traced trial (with
recorded data every trial filters the same measurements). A step without a measurement has no
prediction drawn (the columns are empty there). It draws what ``metrics.scores`` writes, and
declares so (:func:`~pfx.figures.registry.asks_for`); cells whose kind computes no predictive
law are named in the title, and a folder without the columns draws nothing.
"""

from __future__ import annotations

import numpy as np

from pfx.figures.filtered_over_data import (
    BAND_SDS,
    MEASUREMENT_POINT_SIZE,
    draw_band,
    drawn_cells,
    first_traced_trials,
)
from pfx.figures.layout import time_axis
from pfx.figures.registry import FIGURES, asks_for
from pfx.figures.scores import cell_grid, components_with, traced_steps
from pfx.result_folder import ResultFolder


@FIGURES.register("predictions_over_data")
@asks_for("metrics.scores")
def predictions_over_data(result: ResultFolder):
    """One-step-ahead predictive mean ± 2 sd of each measurement component against the measurements that came, a panel per (component, cell).

    From steps.csv's `predictive_mean_<m>`, `predictive_sd_<m>` and `measurement_<m>` (`metrics.scores`), each cell's first traced trial; about 95% of the points inside the band for a model that fits.
    """
    steps = traced_steps(result)
    components = components_with(steps, "predictive_mean_") if not steps.empty else []
    if not components:
        return None
    rows = first_traced_trials(steps)
    cells, left_out = drawn_cells(result, rows, [f"predictive_mean_{component}" for component in components])
    x_column, x_label = time_axis(result)
    grid = cell_grid(result, cells, components)
    drawn = {component: [] for component in components}      # component -> its panels' (axes, values)
    for (component, cell), axes in grid.axes.items():
        trace = rows[rows["cell"] == cell]
        time = trace[x_column].to_numpy(dtype=float)
        mean = trace[f"predictive_mean_{component}"].to_numpy(dtype=float)
        sd = trace[f"predictive_sd_{component}"].to_numpy(dtype=float)
        observed = trace[f"measurement_{component}"].to_numpy(dtype=float)
        draw_band(axes, time, mean, sd, "C1", "predictive mean")
        axes.scatter(time, observed, s=MEASUREMENT_POINT_SIZE, color="black", zorder=5, label="measurement")
        scored = np.isfinite(mean) & np.isfinite(sd) & np.isfinite(observed)
        away = np.abs(observed[scored] - mean[scored]) > BAND_SDS * sd[scored]
        drawn[component].append((axes, observed, mean, sd))
        # the count above the panel, where it hides no point
        axes.set_title(f"{grid.labels[cell]}: {int(away.sum())} of {int(scored.sum())} outside the band", fontsize=9)
    trials = ", ".join(sorted({str(int(trial)) for trial in rows.loc[rows["cell"].isin(cells["cell"]), "trial"]}))
    title = (f"{result.manifest.get('name', '')}: one-step-ahead prediction of each measurement, "
             f"mean ± {BAND_SDS:g} sd of p(z_k | z_1:k-1), against the measurements\n"
             f"trial {trials} of each cell" + (" (recorded data: every trial filters the same measurements)"
                                               if result.recorded_data else ""))
    clipped = sum(_fit_to_data(panels) for panels in drawn.values())     # steps whose band leaves the axes
    notes = [f"the axes fit the measurements and predictive means: the band leaves them at {clipped} step(s) of "
             "the panels" if clipped else "",
             left_out]
    grid.finish(title + "".join(f"\n{note}" for note in notes if note), x_label,
                lambda component: f"measurement {component}")
    return grid.figure


def _fit_to_data(panels: list) -> int:
    """Limit the y axis of one measurement component's panels (``(axes, observed, mean, sd)``
    each) to the measurements and predictive means, with half their span either side for the
    band: the first prediction from a diffuse prior (a band thousands of times wider than the
    data) would flatten every other step. Returns the count of steps whose band leaves them."""
    values = np.concatenate([np.concatenate([observed, mean]) for _, observed, mean, _ in panels])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 0
    span = max(values.max() - values.min(), abs(values.max()) * 1e-6, 1e-12)
    low, high = values.min() - span / 2, values.max() + span / 2
    clipped = 0
    for axes, _, mean, sd in panels:
        axes.set_ylim(low, high)
        with np.errstate(invalid="ignore"):
            clipped += int(((mean - BAND_SDS * sd < low) | (mean + BAND_SDS * sd > high)).sum())
    return clipped
