"""Shared layout of the figures over time: axis labels, small multiples, legends outside the data.

Three things every figure of a quantity over time needs, decided here once:

* **Axis labels from the model.** The time axis reads ``time [s]`` in the model's time unit, or
  in the config's ``time_unit`` where it sets one (``time [day]``), or ``step`` / ``action``
  when that unit counts steps or actions (``units.time`` in manifest.json,
  :mod:`pfx.config.time_units`); the error axis names
  what the error distance measures: ``|error| of x`` when the position is one state component
  (with its unit if it has one), ``position error distance [m]`` when it is several.
* **Small multiples for sweeps.** Up to :data:`MOST_LINES_IN_ONE_PANEL` cells share one panel.
  More cells get one panel per combination of all legend columns but one, and that one (the
  column with the fewest values, the earlier on a tie) tells the lines in a panel apart: a
  sweep of 4 resamplers x 2 particle counts is 4 panels (one per resampler) of 2 lines (N = 100,
  N = 1000). A line value keeps its colour in every panel, the panels share their axes, and a
  single legend below the panels lists the line values. One legend column with many values
  gets one panel per value.
* **A panel per cell** (:func:`panel_per_cell`) for figures whose lines in a panel are
  something else (a filter and its smoothers): the cells' panels share their axes.
* **A colour per cell** (:func:`one_colour_per_cell`) for figures whose panels are something
  else (one per estimated parameter): every cell in every panel, told apart by colour.
* **Legends outside the axes.** :func:`legend_outside` puts one figure legend below every
  panel (constrained layout makes room for it), so no legend ever hides data.

A figure asks :func:`small_multiples` for its panels, draws each cell into
``layout.axes_for(cell)`` with ``layout.lines[cell].colour`` and ``.label``, then calls
``layout.finish(...)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pfx.result_folder import ResultFolder

MOST_LINES_IN_ONE_PANEL = 4           # more cells than this are split into small multiples
COUNTED_TIME_UNITS = ("step", "action")   # a time axis in these units counts steps, not seconds
LEGEND_FONT_SIZE = 8
OFF_SCALE_FACTOR = 100.0              # a line whose peak exceeds 100x the smallest peak is drawn clipped
CHARACTERS_PER_INCH = 14              # of legend text at LEGEND_FONT_SIZE, with room to spare


# -- axis labels --------------------------------------------------------------------------------

def time_axis(result: ResultFolder) -> tuple[str, str]:
    """The column of the time axis and its label: ("time", "time [s]") in the folder's time unit
    (manifest.json's ``units.time``: the model's, or the config's ``time_unit``), or ("step", "action")."""
    unit = result.units.get("time", "s")
    if unit in COUNTED_TIME_UNITS:
        return "step", unit
    return "time", f"time [{unit}]" if unit else "time"


def time_text(value: float, result: ResultFolder) -> str:
    """A moment in words for notes on a figure: "t = 9 s", "step 9", "action 9"."""
    unit = result.units.get("time", "s")
    if unit in COUNTED_TIME_UNITS:
        return f"{unit} {value:g}"
    return f"t = {value:g} {unit}".rstrip()


def with_unit(text: str, unit: str) -> str:
    """``text [unit]``, or the text alone for a quantity without unit."""
    return f"{text} [{unit}]" if unit else text


def state_text(state: str) -> str:
    """A state component's name as words: ``ballistic_coefficient`` -> ``ballistic coefficient``."""
    return state.replace("_", " ")


@dataclass(frozen=True)
class ErrorQuantity:
    """What the column ``error_distance`` measures for this model, in words."""

    axis_label: str        # e.g. "|error| of altitude [ft]", "position error distance [m]"
    title: str             # e.g. "|error| of altitude", "position error"


def error_quantity(result: ResultFolder) -> ErrorQuantity:
    """The error distance named after the model's position: one state component, or several."""
    states = result.position_states
    unit = result.units.get("position", "")
    if len(states) == 1:
        name = state_text(states[0])
        unit = result.units.get(f"state_{states[0]}", unit)
        return ErrorQuantity(with_unit(f"|error| of {name}", unit), f"|error| of {name}")
    if states:
        return ErrorQuantity(with_unit("position error distance", unit), "position error")
    return ErrorQuantity(with_unit("error distance", unit), "error distance")   # a manifest without position_states


# -- which cell goes into which panel -----------------------------------------------------------

def value_text(column: str, value) -> str:
    """One legend column's value as a label: the arm by its name, others as ``column=value``."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)              # a column with empty fields reads as floats: 100.0 -> 100
    elif isinstance(value, float) and math.isnan(value):
        value = "none"                  # e.g. n_particles of a Kalman filter arm
    return str(value) if column == "arm" else f"{column}={value}"


def legend_columns_of(result: ResultFolder, table) -> list[str]:
    """The manifest's legend columns present in ``table``; the arm when there are none."""
    columns = [c for c in result.manifest.get("legend_columns", []) if c in table]
    return columns if columns or "arm" not in table else ["arm"]


def cell_labels(cells, legend_columns: list[str]) -> list[str]:
    """A label per row of ``cells`` (one per cell): its legend columns' values, joined."""
    labels = []
    for _, cell in cells.iterrows():
        parts = [value_text(column, cell[column]) for column in legend_columns]
        labels.append(", ".join(parts) or str(cell["cell"]))      # no legend column: the key
    return labels


@dataclass(frozen=True)
class CellLine:
    """Where and how one cell is drawn."""

    cell: str              # the cell's key
    panel: int             # index of its panel
    label: str             # its legend label
    colour: str            # a matplotlib colour ("C0", "C1", ...)


def plan_panels(cells, legend_columns: list[str]) -> tuple[list[str], list[CellLine]]:
    """Assign every cell a panel, a label and a colour (the rule is in the module docstring).

    ``cells`` holds one row per cell: its key in ``cell`` and its legend columns. Returns the
    panel titles (one untitled panel for few cells) and one :class:`CellLine` per cell, in the
    order of ``cells``.
    """
    texts = {column: [value_text(column, value) for value in cells[column]] for column in legend_columns}
    varying = [column for column in legend_columns if len(set(texts[column])) > 1]
    keys = list(cells["cell"])
    if len(keys) <= MOST_LINES_IN_ONE_PANEL or not varying:
        labels = cell_labels(cells, legend_columns)
        return [""], [CellLine(key, 0, label, f"C{row % 10}") for row, (key, label) in enumerate(zip(keys, labels))]
    if len(varying) == 1:               # one column, many values: a panel per value
        line_column, panel_columns = None, varying
    else:                               # the fewest values tell the lines apart; the rest, the panels
        line_column = min(varying, key=lambda column: len(set(texts[column])))
        panel_columns = [column for column in varying if column != line_column]
    panel_titles: list[str] = []
    line_values: list[str] = []
    lines = []
    for row, key in enumerate(keys):
        title = ", ".join(texts[column][row] for column in panel_columns)
        if title not in panel_titles:
            panel_titles.append(title)
        label = texts[line_column][row] if line_column else title
        if label not in line_values:
            line_values.append(label)
        lines.append(CellLine(key, panel_titles.index(title), label, f"C{line_values.index(label) % 10}"))
    return panel_titles, lines


# -- the figure ---------------------------------------------------------------------------------

@dataclass
class SmallMultiples:
    """A figure of one or more panels with shared axes, and where each cell is drawn in it."""

    figure: object                 # matplotlib Figure
    panels: list                   # matplotlib Axes, one per panel title
    panel_titles: list[str]
    lines: dict[str, CellLine]     # cell key -> its line
    notes: dict[int, list[str]] = field(default_factory=dict)    # panel index -> notes above it

    def axes_for(self, cell: str):
        return self.panels[self.lines[cell].panel]

    def note(self, cell: str, text: str) -> None:
        """A remark written above the cell's panel (e.g. that its line leaves the axes)."""
        self.notes.setdefault(self.lines[cell].panel, []).append(text)

    def finish(self, title: str, x_label: str, y_label: str, extra_handles=()) -> None:
        """Titles, axis labels on the outer panels, grids, and the one legend below the panels.

        ``extra_handles`` (artists with a label, e.g. a reference line's) end the legend.
        """
        columns = grid_columns(len(self.panels))
        for index, (axes, panel_title) in enumerate(zip(self.panels, self.panel_titles)):
            notes = self.notes.get(index) or []
            if notes:                   # above the data, in red, left; the panel's title above it
                axes.set_title("\n".join(notes), loc="left", fontsize=8, color="C3")
            if panel_title:
                # One empty line per note under the title lifts it above them: the axes' titles
                # share one offset, so a larger pad for this one would move the notes too.
                axes.set_title(panel_title + "\n" * len(notes), fontsize=9)
            if index % columns == 0:
                axes.set_ylabel(y_label)
            if index + columns >= len(self.panels):          # nothing below it: the bottom of a column
                axes.set_xlabel(x_label)
                axes.xaxis.set_tick_params(labelbottom=True)
            axes.grid(alpha=0.3)
        self.figure.suptitle(title, fontsize=11)
        legend_outside(self.figure, extra_handles)


def grid_columns(panels: int) -> int:
    """Columns of the panel grid: at most 3 (4 beyond 9 panels), the rows as full as possible."""
    most = 3 if panels <= 9 else 4
    return math.ceil(panels / math.ceil(panels / most))


def small_multiples(result: ResultFolder, table, single_size=(7.5, 4.3), panel_size=(4.0, 2.7),
                    log_y: bool = False) -> SmallMultiples:
    """The panels for the cells of ``table`` (any table with ``cell`` and the legend columns)."""
    cells = table.drop_duplicates("cell")
    titles, lines = plan_panels(cells, legend_columns_of(result, table))
    figure, panels = _panel_grid(len(titles), single_size, panel_size, log_y)
    return SmallMultiples(figure, panels, titles, {line.cell: line for line in lines})


def panel_per_cell(result: ResultFolder, table, single_size=(7.5, 4.3), panel_size=(4.0, 2.7),
                   log_y: bool = False) -> SmallMultiples:
    """One panel per cell of ``table``, titled by its label (a single cell's panel untitled:
    the figure's title names the run), for figures whose lines within a panel are something
    other than cells (e.g. a filter and its smoothers). Every cell's line colour is "C0"."""
    cells = table.drop_duplicates("cell")
    labels = cell_labels(cells, legend_columns_of(result, table))
    titles = labels if len(labels) > 1 else [""]
    figure, panels = _panel_grid(len(titles), single_size, panel_size, log_y)
    lines = {key: CellLine(key, index if len(labels) > 1 else 0, label, "C0")
             for index, (key, label) in enumerate(zip(cells["cell"], labels))}
    return SmallMultiples(figure, panels, titles, lines)


def one_colour_per_cell(result: ResultFolder, table) -> dict[str, CellLine]:
    """Each cell of ``table`` with its label and a colour of its own, all in panel 0: for
    figures whose panels are something other than cells (one per estimated parameter), where
    every cell is drawn in every panel and a colour must name one cell throughout (beyond ten
    cells the colours repeat)."""
    cells = table.drop_duplicates("cell")
    labels = cell_labels(cells, legend_columns_of(result, table))
    return {key: CellLine(key, 0, label, f"C{index % 10}")
            for index, (key, label) in enumerate(zip(cells["cell"], labels))}


def _panel_grid(count: int, single_size, panel_size, log_y: bool):
    """A figure of ``count`` panels sharing their axes, in rows as full as possible."""
    import matplotlib.pyplot as plt

    columns = grid_columns(count)
    rows = math.ceil(count / columns)
    size = single_size if count == 1 else (panel_size[0] * columns + 1.0, panel_size[1] * rows + 1.4)
    figure, grid = plt.subplots(rows, columns, figsize=size, sharex=True, sharey=True, squeeze=False,
                                layout="constrained")
    panels = list(grid.flat)
    for unused in panels[count:]:       # the grid's empty places at the end of the last row
        figure.delaxes(unused)
    panels = panels[:count]
    if log_y:
        panels[0].set_yscale("log")     # shared with every other panel
    return figure, panels


def legend_outside(figure, extra_handles=()) -> object:
    """One legend for the whole figure, below its panels, each label once; None for a single line.

    ``extra_handles`` come last (reference lines after the cells' lines). The legend has as
    many columns as fit the figure's width, so long labels take more rows rather than
    widening the figure.
    """
    last = [handle.get_label() for handle in extra_handles]
    handles, labels = [], []
    for axes in figure.axes:
        for handle, label in zip(*axes.get_legend_handles_labels()):
            if label not in labels and label not in last:
                handles.append(handle)
                labels.append(label)
    if len(handles) <= 1 and not last:
        return None                     # one cell: nothing to tell apart, the title names the run
    handles += list(extra_handles)
    labels += last
    width = figure.get_figwidth() * CHARACTERS_PER_INCH
    columns = max(1, min(len(labels), int(width // (max(len(label) for label in labels) + 6))))
    return figure.legend(handles, labels, loc="outside lower center", ncols=columns, fontsize=LEGEND_FONT_SIZE)


# -- lines that leave the axes -------------------------------------------------------------------

def off_scale_limit(peaks: dict) -> tuple[float, list]:
    """An axis limit that keeps the ordinary lines readable when one diverges; and those lines.

    ``peaks`` maps each line to its largest absolute value. A line whose peak exceeds
    :data:`OFF_SCALE_FACTOR` times the smallest peak (or is infinite) would flatten the others
    to zero: it is left out of the limit, 1.15 times the largest peak of the rest.
    """
    finite = [peak for peak in peaks.values() if np.isfinite(peak)]
    smallest = max(min(finite), 1e-300) if finite else 1.0
    in_scale = [name for name, peak in peaks.items() if np.isfinite(peak) and peak <= OFF_SCALE_FACTOR * smallest]
    limit = 1.15 * max(peaks[name] for name in in_scale) if in_scale else 1.0
    return (limit if limit > 0 else 1.0), in_scale


def plot_within(axes, x, values, limit: float, colour: str, label: str, low=None, high=None):
    """Plot ``values`` (and a band ``low``..``high``) up to where |value| first exceeds ``limit``.

    The line stops where it leaves the axes and a triangle on the edge it crossed marks the
    place. Returns the index of that first point outside, or None if the line stays inside.
    """
    x = np.asarray(x, dtype=float)
    values = np.asarray(values, dtype=float)
    if np.isfinite(limit):
        outside = ~(np.abs(values) <= limit)          # a NaN error (inf - inf) has left the axes too
    else:
        outside = np.zeros(values.shape, dtype=bool)  # no limit: nothing to clip
    gone = np.cumsum(outside) > 0                     # from the first point outside on
    axes.plot(x, np.where(gone, np.nan, values), color=colour, label=label, linewidth=1.5)
    if low is not None and np.isfinite(low).any():
        axes.fill_between(x, np.where(gone, np.nan, np.maximum(low, -limit)),
                          np.where(gone, np.nan, np.minimum(high, limit)), color=colour, alpha=0.2, linewidth=0)
    if not outside.any():
        return None
    first = int(np.argmax(outside))
    upward = not values[first] < 0
    axes.plot([x[first]], [0.985 * limit if upward else -0.985 * limit], marker="^" if upward else "v",
              color=colour, markersize=9, clip_on=False)
    return first


def peak_text(peak: float, unit: str) -> str:
    """A diverged line's largest value for a note: "1.2e+27 ft", "∞ ft"."""
    return f"{'∞' if not np.isfinite(peak) else f'{peak:.1e}'} {unit}".rstrip()


def auxiliary_note(result: ResultFolder, table) -> str:
    """For an ESS figure: which of the drawn cells run the auxiliary particle filter, and what
    their ESS is ("" if none). It is the ESS of the second-stage weights: at a step whose first
    stage resampled by the look-ahead they hold only what the look-ahead did not foresee, so
    they are flatter than another filter's weights would be (the ESS runs higher, up to about
    0.98 N, for the same data), not a measure of the same degeneracy."""
    cells = table[table["cell"].isin(result.auxiliary_cells)].drop_duplicates("cell")
    if cells.empty:
        return ""
    names = ", ".join(cell_labels(cells, legend_columns_of(result, cells)))
    return (f"{names}: the auxiliary filter's ESS is that of its second-stage weights, which its\n"
            "first-stage (look-ahead) resampling leaves flatter: not comparable with other filters' ESS")


def trials_text(summary, covers_every_trial: bool) -> str:
    """How many trials a per-step statistic is over: "30 trials", "10-30 trials", "3 traced trials"."""
    counts = summary["trials"].dropna().astype(int)
    low, high = int(counts.min()), int(counts.max())
    number = f"{low}" if low == high else f"{low}-{high}"
    noun = "trial" if high == 1 else "trials"
    return f"{number} {noun}" if covers_every_trial else f"{number} traced {noun}"
