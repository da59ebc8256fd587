r"""Figures of the filter's one-step-ahead predictive scores (``metrics.scores``, steps.csv).

With ``metrics.scores: true`` every traced trial's steps.csv row carries the filter's
predictive law of the measurement :math:`z_k` given :math:`z_{1:k-1}` and how it fared against
the value that came (:mod:`pfx.numerics.proper_scores`): ``crps_<m>`` and ``pit_<m>`` per
measurement component :math:`m`, ``energy_score`` of the vector, and ``log_score``. Two
questions, two figures:

* ``pit_histogram``: *is the forecast calibrated?* The probability integral transform
  :math:`F_k(z_k)` of a calibrated forecast is uniform on (0, 1), and for one-step-ahead
  forecasts the values of successive steps are independent (Diebold, Gunther & Tay 1998), so
  every traced trial's and step's PIT pool into one sample. (With recorded data, ``data:``,
  every trial filters the same measurements and their PITs nearly repeat each other, so the
  sample is the first traced trial's alone: its steps are the independent values.) A histogram of 10 bins on [0, 1]
  on a density scale should lie flat at 1: a U shape means the forecast is too narrow (the
  values fall in its tails), a hump too wide, a slope a bias. Under uniformity a bar's count
  is Binomial(n, 1/10); the shaded band holds each bar's height with probability 95% (a band
  for one bar at a time: of 10 bars, one outside now and then is no alarm). The panel's
  title gives the Kolmogorov-Smirnov p-value of the sample against U(0, 1) (scipy).
* ``score_over_time``: *which forecast is better, and when?* The CRPS of each measurement
  component and the log score (energy score too, for two or more components), each averaged
  over the traced trials at every step, a line per cell on shared axes. Every score is
  negatively oriented: the lower line forecasts better. A step whose log score is infinite (a
  degenerate step: every weight underflowed) has no point.

Both draw the traced trials only (``outputs.trace_trials``): steps.csv holds nothing else.
Cells whose filter kind computes no scores have empty columns and no panel or line; the
title names them. Each returns None (draws nothing) for a folder without the columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pfx.figures.layout import (
    cell_labels,
    grid_columns,
    legend_columns_of,
    legend_outside,
    one_colour_per_cell,
    time_axis,
)
from pfx.figures.registry import FIGURES, asks_for
from pfx.result_folder import ResultFolder

PIT_BINS = 10                  # bins of the PIT histogram on [0, 1]
BAND_PROBABILITY = 0.95        # of a bar's height under uniformity


# -- what a folder holds ------------------------------------------------------------------------

def traced_steps(result: ResultFolder):
    """steps.csv, or an empty table for a folder without it (a study's)."""
    import pandas as pd

    return result.steps if "steps" in result.tables else pd.DataFrame()


def components_with(table, prefix: str) -> list[str]:
    """The measurement components ``<m>`` of the columns ``<prefix><m>`` that hold a value."""
    return [column.removeprefix(prefix) for column in table.columns
            if column.startswith(prefix) and table[column].notna().any()]


def cells_without(result: ResultFolder, table, drawn, what: str = "no values") -> str:
    """"no values for: kf, ..." naming the cells of ``table`` (one or more rows per cell, with
    its legend columns) not in ``drawn`` ("" if none)."""
    left_out = table[~table["cell"].isin(drawn)].drop_duplicates("cell")
    if left_out.empty:
        return ""
    names = dict.fromkeys(cell_labels(left_out, legend_columns_of(result, left_out)))   # each label once
    return f"{what} for: {', '.join(names)}"


# -- a panel per (measurement component, cell) --------------------------------------------------

@dataclass
class CellGrid:
    """Panels for every (measurement component, cell): a row per component and a column per
    cell; with one component, the cells' panels wrap into rows as full as possible
    (:func:`pfx.figures.layout.grid_columns`). Time (or the x axis) is shared by every panel,
    the y axis by the panels of one component."""

    figure: object                        # matplotlib Figure
    axes: dict                            # (component, cell) -> matplotlib Axes
    labels: dict                          # cell -> its label (the legend columns' values)

    def finish(self, title: str, x_label: str, y_label) -> None:
        """The figure's title, ``x_label`` under each column's bottom panel, ``y_label(component)``
        left of each row's first panel, grids, and one legend below the panels."""
        for (component, _), axes in self.axes.items():
            if axes.get_subplotspec().is_first_col():
                axes.set_ylabel(y_label(component))
            axes.grid(alpha=0.3)
        for axes in _bottom_of_each_column(self.axes.values()):
            axes.set_xlabel(x_label)
            axes.xaxis.set_tick_params(labelbottom=True)
        self.figure.suptitle(title, fontsize=11)
        legend_outside(self.figure)


def cell_grid(result: ResultFolder, cells, components: list[str], panel_size=(4.2, 2.9)) -> CellGrid:
    """The :class:`CellGrid` of the cells (a table with one row per cell: ``cell`` and its
    legend columns) and the measurement ``components``."""
    import matplotlib.pyplot as plt

    keys = list(cells["cell"])
    labels = dict(zip(keys, cell_labels(cells, legend_columns_of(result, cells))))
    places = [(component, cell) for component in components for cell in keys]
    columns = grid_columns(len(keys)) if len(components) == 1 else len(keys)
    rows = math.ceil(len(places) / columns)
    figure, grid = plt.subplots(rows, columns, figsize=(panel_size[0] * columns + 1.0, panel_size[1] * rows + 1.6),
                                sharex=True, sharey=True if len(components) == 1 else "row",
                                squeeze=False, layout="constrained")
    panels = list(grid.flat)
    for unused in panels[len(places):]:
        figure.delaxes(unused)
    return CellGrid(figure, dict(zip(places, panels)), labels)


def _bottom_of_each_column(panels) -> list:
    """The lowest panel of each column of the grid."""
    lowest = {}
    for axes in panels:
        spec = axes.get_subplotspec()
        column = spec.colspan.start
        if column not in lowest or spec.rowspan.start > lowest[column].get_subplotspec().rowspan.start:
            lowest[column] = axes
    return list(lowest.values())


# -- pit_histogram --------------------------------------------------------------------------------

def uniform_bar_band(count: int, bins: int = PIT_BINS, probability: float = BAND_PROBABILITY) -> tuple[float, float]:
    """The heights (density scale) between which one bar of a histogram of ``count`` uniform
    values in ``bins`` equal bins lies with ``probability``: the central quantiles of its count,
    Binomial(count, 1/bins), over count / bins (the height of a bar of the expected count is 1)."""
    from scipy.stats import binom

    tail = (1.0 - probability) / 2
    low, high = binom.ppf([tail, 1.0 - tail], count, 1.0 / bins)
    return float(low) * bins / count, float(high) * bins / count


@FIGURES.register("pit_histogram")
@asks_for("metrics.scores")
def pit_histogram(result: ResultFolder):
    """Histogram of the one-step-ahead PIT values per cell and measurement component (flat at 1 if calibrated), with the 95% band of a bar under uniformity and the KS p-value.

    From steps.csv's `pit_<m>` (`metrics.scores`): every traced trial and step, 10 bins on [0, 1], density scale; the band is each bar's central 95% under Binomial(n, 1/10). With recorded data, the first traced trial's alone (every trial filters the same measurements). A U shape: the forecast is too narrow; a hump: too wide; a slope: biased.
    """
    from scipy.stats import kstest

    steps = traced_steps(result)
    components = components_with(steps, "pit_") if not steps.empty else []
    if not components:
        return None
    if result.recorded_data:           # every trial filters the same data: one trial's values are the sample
        steps = steps[steps["trial"] == steps.groupby("cell")["trial"].transform("min")]
    has_values = steps[[f"pit_{component}" for component in components]].notna().any(axis=1)
    drawn = steps.loc[has_values, "cell"].unique()
    grid = cell_grid(result, steps[steps["cell"].isin(drawn)].drop_duplicates("cell"), components)
    edges = np.linspace(0.0, 1.0, PIT_BINS + 1)
    band_handle = None
    for (component, cell), axes in grid.axes.items():
        values = steps.loc[steps["cell"] == cell, f"pit_{component}"].dropna().to_numpy(dtype=float)
        if values.size == 0:
            axes.set_title(f"{grid.labels[cell]}, {component}: no PIT values", fontsize=9)
            continue
        low, high = uniform_bar_band(values.size)
        band_handle = axes.axhspan(low, high, color="0.55", alpha=0.25, linewidth=0,
                                   label=f"{BAND_PROBABILITY:.0%} band of a bar under uniformity")
        axes.hist(values, bins=edges, density=True, color="C0", alpha=0.8, edgecolor="white",
                  label="PIT histogram")
        for edge in (low, high):       # the band's edges over the bars, where a bar hides the shade
            axes.axhline(edge, color="0.4", linestyle=":", linewidth=0.9)
        axes.axhline(1.0, color="black", linestyle="--", linewidth=1, label="uniform density")
        p_value = kstest(values, "uniform").pvalue
        axes.set_title(f"{grid.labels[cell]}, {component}\nKS p = {p_value:.2g} (n = {values.size})", fontsize=9)
        axes.set_xlim(0.0, 1.0)
    if band_handle is None:
        return None
    grid.finish(_pit_title(result, steps, drawn), "PIT value", lambda component: f"density ({component})")
    return grid.figure


def _pit_title(result: ResultFolder, steps, drawn) -> str:
    if result.recorded_data:
        which = "the first traced trial per cell (recorded data: every trial filters the same measurements)"
    else:
        trials = steps[steps["cell"].isin(drawn)].groupby("cell")["trial"].nunique()
        which = f"{_count_text(trials)} traced trial(s) per cell"
    title = (f"{result.manifest.get('name', '')}: PIT of the one-step-ahead forecast (uniform if calibrated)\n"
             f"{which}, every step\nband: {BAND_PROBABILITY:.0%} of a bar's height under uniformity "
             f"(Binomial); KS: Kolmogorov-Smirnov test against U(0, 1)")
    missing = cells_without(result, steps, drawn)
    return title + (f"\n{missing}" if missing else "")


def _count_text(counts) -> str:
    """A count per cell in words: "4", or "2-4" when the cells differ."""
    low, high = int(counts.min()), int(counts.max())
    return f"{low}" if low == high else f"{low}-{high}"


# -- score_over_time ------------------------------------------------------------------------------

def step_means(steps, column: str, x_column: str) -> dict:
    """cell -> (x, the mean of ``column`` over the traced trials at each step), for the cells
    with a value; a step where some trial's value is infinite has an infinite mean."""
    means = {}
    for cell, rows in steps.groupby("cell", sort=False):
        if not rows[column].notna().any():
            continue
        by_step = rows.groupby("step", sort=True).agg(x=(x_column, "first"), mean=(column, "mean"))
        means[cell] = (by_step["x"].to_numpy(dtype=float), by_step["mean"].to_numpy(dtype=float))
    return means


@FIGURES.register("score_over_time")
@asks_for("metrics.scores")
def score_over_time(result: ResultFolder):
    """Mean CRPS of each measurement component and mean log score over time, a line per cell (lower is better).

    From steps.csv (`metrics.scores`): the mean over the traced trials at each step; the CRPS in the first row, a panel per component, the log score (and the energy score for two or more components) in the second.
    """
    import matplotlib.pyplot as plt

    steps = traced_steps(result)
    components = components_with(steps, "crps_") if not steps.empty else []
    if not components:
        return None
    x_column, x_label = time_axis(result)
    second_row = [column for column in ("log_score", "energy_score") if column in steps and steps[column].notna().any()]
    panels = [(f"crps_{component}", f"CRPS of {component}") for component in components]
    panels += [(column, {"log_score": "log score", "energy_score": "energy score"}[column]) for column in second_row]
    columns = max(len(components), len(second_row), 1)
    figure, grid = plt.subplots(2 if second_row else 1, columns, figsize=(4.6 * columns + 1.0, 3.0 * (1 + bool(second_row)) + 1.4),
                                sharex=True, squeeze=False, layout="constrained")
    places = [grid[0, index] for index in range(len(components))] + [grid[1, index] for index in range(len(second_row))]
    for axes in grid.flat:
        if axes not in places:
            figure.delaxes(axes)
    scored = steps[steps[[column for column, _ in panels]].notna().any(axis=1)]
    lines = one_colour_per_cell(result, scored.drop_duplicates("cell"))
    colours: dict[str, str] = {}       # by label: cells that read alike (a kf in a sweep of N) share one
    for line in lines.values():
        colours.setdefault(line.label, f"C{len(colours) % 10}")
    for axes, (column, name) in zip(places, panels):
        means = step_means(steps, column, x_column)
        for cell, (x, mean) in means.items():
            axes.plot(x, mean, color=colours[lines[cell].label], label=lines[cell].label, linewidth=1.5)
        missing = list(dict.fromkeys(line.label for cell, line in lines.items() if cell not in means))
        axes.set_title(name + (f" (none for: {', '.join(missing)})" if missing else ""), fontsize=10)
        axes.set_ylabel(f"mean {name}")
        axes.grid(alpha=0.3)
    for axes in places:                # the x axis's label under each column's lowest panel
        spec = axes.get_subplotspec()
        if not (spec.rowspan.start == 0 and spec.colspan.start < len(second_row)):
            axes.set_xlabel(x_label)
            axes.xaxis.set_tick_params(labelbottom=True)
    title = (f"{result.manifest.get('name', '')}: one-step-ahead predictive scores over time (lower is better)\n"
             f"mean over {_count_text(scored.groupby('cell')['trial'].nunique())} traced trial(s) per cell at each step")
    missing = cells_without(result, steps, list(lines))
    figure.suptitle(title + (f"\n{missing}" if missing else ""), fontsize=11)
    legend_outside(figure)
    return figure
