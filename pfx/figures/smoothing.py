r"""Figures of particle smoothing and of the genealogy it stands on.

A filter estimates the state at step :math:`k` from the measurements up to :math:`k`; a
smoother from all :math:`T` of them, so it should be closer to the truth, most of all early
on. The figures show by how much, and why the simplest smoother (keeping the filter's paths)
falls short: resampling makes the particles' ancestral lines coalesce back in time.

* ``smoothing_error_over_time`` (steps_summary.csv, every trial): per cell, the RMS position
  error at each step of the filter's estimate and of every smoother's,
  :math:`\sqrt{\sum_j \mathrm{rms}_{k,j}^2}` over the position states :math:`j` (the RMS of
  the error distance: the mean over trials of a sum of squares is the sum of the means), from
  ``rms_error_<state>`` (the filter) and ``rms_error_<smoother>_<state>``. A panel per cell,
  a line per estimator, the same colour for an estimator in every panel. Each panel has its own
  y axis (time is shared): one cell whose filter diverges would otherwise flatten every other
  cell's lines to zero. Within a panel, a line that diverges (infinite, or more than 100 times
  the smallest peak of the panel) stops at the axes' edge and a note above the panel says where
  and how far it went; the axis keeps the scale of the panel's other lines, or of the finite
  values when every line of the panel diverges.
* ``genealogy_tree`` (genealogy.csv): the classic picture of path degeneracy, for the first
  trial of the first cell: every particle at each step (area proportional to its weight) at its
  first position state, every parent-to-child edge drawn faint, and the ancestral lines of the
  last step's particles drawn dark, so the eye sees them merge into one path back in time
  (:func:`pfx.analysis.genealogy.ancestral_lines`). The truth is drawn when steps.csv traced
  that trial.
* ``distinct_ancestors`` (steps.csv's ``distinct_ancestors``, the traced trials): how many
  particles of step :math:`k` have descendants at the last step, per cell on a log axis: the
  mean over the traced trials, each trial faint, and :math:`N` for reference. It is
  :math:`N` at the last step and falls back in time; where it reaches 1, every path the
  ``genealogy`` smoother holds is the same path.

Each returns None when the folder lacks its input: no smoother column, no genealogy.csv, no
or an empty ``distinct_ancestors`` column.
"""

from __future__ import annotations

import math

import numpy as np

from pfx.analysis.genealogy import NO_PARENT, ancestral_lines, trial_genealogy
from pfx.figures.layout import (
    CellLine,
    SmallMultiples,
    cell_labels,
    grid_columns,
    legend_columns_of,
    legend_outside,
    off_scale_limit,
    peak_text,
    plot_within,
    small_multiples,
    state_text,
    time_axis,
    time_text,
    trials_text,
    with_unit,
)
from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

RMS_PREFIX = "rms_error_"
FILTER = "filter"                  # the legend's name for the filter's own estimate
FILTER_COLOUR = "black"            # the smoothers take C0, C1, ... in the order of their columns
# A particle of the mean weight 1/N is drawn with this area (points²) over sqrt(N): a few
# particles as clear dots, a cloud of thousands as specks that leave the lines visible.
MARKER_AREA_FOR_ONE_PARTICLE = 40.0
LARGEST_AREA_SHARE = 12.0          # the heaviest particles' area, at most this times the mean's


# -- the filter and its smoothers: RMS position error over time ---------------------------------

def smoother_kinds(columns, position_states: list[str], state_names: list[str],
                   prefix: str = RMS_PREFIX) -> list[str]:
    """The smoothers whose columns ``<prefix><kind>_<state>`` a table holds for every position
    state, in the order of its columns.

    A state name may hold underscores, so ``rms_error_velocity_x`` could be the filter's
    column of a state ``velocity_x`` or a smoother ``velocity``'s of ``x``: a kind that
    makes a state's name this way is the filter's column, not a smoother's.
    """
    columns = list(columns)
    first = position_states[0]
    kinds = []
    for column in columns:
        if not (column.startswith(prefix) and column.endswith(f"_{first}")):
            continue
        kind = column[len(prefix):-len(first) - 1]
        if (kind and f"{kind}_{first}" not in state_names and kind not in kinds
                and all(f"{prefix}{kind}_{state}" in columns for state in position_states)):
            kinds.append(kind)
    return kinds


def position_rms(rows, position_states: list[str], kind: str = "") -> np.ndarray:
    """The RMS position error at each of ``rows`` (of steps_summary.csv) of the filter (``kind``
    empty) or of a smoother: the square root of the sum of the states' squared RMS errors."""
    infix = f"{kind}_" if kind else ""
    squares = [rows[f"{RMS_PREFIX}{infix}{state}"].to_numpy(dtype=float) ** 2 for state in position_states]
    with np.errstate(over="ignore", invalid="ignore"):
        return np.sqrt(np.sum(squares, axis=0))


def _position_axis(result: ResultFolder, states: list[str]) -> tuple[str, str, str]:
    """The RMS error's words for the title and the axis, and its unit: one state or a position."""
    unit = result.units.get("position", "")
    if len(states) == 1:
        unit = result.units.get(f"state_{states[0]}", unit)
        what = f"RMS error of {state_text(states[0])}"
    else:
        what = "RMS position error"
    return what, with_unit(what, unit), unit


def panels_with_own_y_axes(result: ResultFolder, table, single_size=(7.5, 4.3),
                           panel_size=(4.0, 2.7)) -> SmallMultiples:
    """One panel per cell of ``table``, laid out as :func:`pfx.figures.layout.panel_per_cell`
    lays them out (titled by the cell's label, a single cell's panel untitled), but only the
    time axis is shared: each panel has a y axis of its own, so that a cell whose error grows a
    thousandfold leaves the other cells' lines readable."""
    import matplotlib.pyplot as plt

    cells = table.drop_duplicates("cell")
    labels = cell_labels(cells, legend_columns_of(result, table))
    count = len(labels)
    columns = grid_columns(count)
    rows = math.ceil(count / columns)
    size = single_size if count == 1 else (panel_size[0] * columns + 1.0, panel_size[1] * rows + 1.4)
    figure, grid = plt.subplots(rows, columns, figsize=size, sharex=True, squeeze=False, layout="constrained")
    panels = list(grid.flat)
    for unused in panels[count:]:       # the grid's empty places at the end of the last row
        figure.delaxes(unused)
    lines = {key: CellLine(key, index, label, "C0") for index, (key, label) in enumerate(zip(cells["cell"], labels))}
    return SmallMultiples(figure, panels[:count], labels if count > 1 else [""], lines)


def panel_limit(series: dict) -> tuple[float, list]:
    """The y limit of one panel and the lines it keeps whole, from ``series`` (line -> values).

    :func:`pfx.figures.layout.off_scale_limit` over the lines' peaks: a line that diverges
    (infinite, or more than 100 times the smallest peak) is left out of the limit. When every
    line of the panel diverges, the limit is that of their finite values, so the panel still
    shows where each line was before it left.
    """
    peaks = {name: float(np.nanmax(np.abs(values))) for name, values in series.items()}
    limit, in_scale = off_scale_limit(peaks)
    if not in_scale:
        finite = np.concatenate([np.abs(values[np.isfinite(values)]) for values in series.values()])
        largest = float(finite.max()) if finite.size else 0.0
        limit = 1.15 * largest if largest > 0 else 1.0
    return limit, in_scale


@FIGURES.register("smoothing_error_over_time")
def smoothing_error_over_time(result: ResultFolder):
    """RMS position error over time of the filter and of every smoother it ran, a panel per cell, each panel with its own y axis.

    From steps_summary.csv, every trial: `rms_error_<state>` (the filter) and `rms_error_<smoother>_<state>` of the position states; a line per estimator (`filter`, `ffbs`, `rts`, ...). A line that diverges (infinite, or 100 times the panel's smallest peak) stops at the edge of its panel, which says so. Needs a smoother in `outputs`.
    """
    summary = result.steps_summary
    states = result.position_states or result.state_names
    if summary.empty or not states:
        return None
    kinds = smoother_kinds(summary.columns, states, result.state_names)
    x_column, x_label = time_axis(result)
    series = {}                    # (cell, estimator) -> (x, RMS error), the estimators with a value
    for cell, rows in summary.groupby("cell", sort=False):
        for kind in ["", *kinds]:
            values = position_rms(rows, states, kind)
            if not np.isnan(values).all():
                series[(cell, kind or FILTER)] = (rows[x_column].to_numpy(dtype=float), values)
    if not any(estimator != FILTER for _, estimator in series):
        return None                # no smoother (or no truth to measure one against)
    what, y_label, unit = _position_axis(result, states)
    layout = panels_with_own_y_axes(result, summary)
    colours = {FILTER: FILTER_COLOUR} | {kind: f"C{index % 10}" for index, kind in enumerate(kinds)}
    for cell in dict.fromkeys(cell for cell, _ in series):
        panel = {estimator: values for (owner, estimator), (_, values) in series.items() if owner == cell}
        limit, in_scale = panel_limit(panel)
        axes = layout.axes_for(cell)
        for estimator, values in panel.items():
            x = series[(cell, estimator)][0]
            first_outside = plot_within(axes, x, values, limit, colours[estimator], estimator)
            if estimator not in in_scale and first_outside is not None:
                layout.note(cell, f"{estimator}: off scale from {time_text(x[first_outside], result)} "
                                  f"(up to {peak_text(float(np.nanmax(np.abs(values))), unit)})")
        axes.set_ylim(0, limit)
    title = (f"{result.manifest.get('name', '')}: {what} over time, filter and smoothers\n"
             f"RMS over {trials_text(summary, result.steps_summary_covers_every_trial)} per cell; "
             "a smoother's estimate at a step uses every measurement of the trial")
    if len(layout.panels) > 1:
        title += "\neach panel has its own y scale"
    without = summary[~summary["cell"].isin({cell for cell, estimator in series if estimator != FILTER})]
    without = without.drop_duplicates("cell")
    if not without.empty:          # say so, rather than leave the reader looking for their lines
        title += f"\nno smoother in: {', '.join(cell_labels(without, legend_columns_of(result, without)))}"
    layout.finish(title, x_label, y_label)
    return layout.figure


# -- the genealogy of one trial ----------------------------------------------------------------

def parent_edges(steps: np.ndarray, ancestors: np.ndarray, values: np.ndarray):
    """Every parent-to-child edge of a genealogy as line segments, and which lie on an ancestral line.

    ``steps`` (T,), ``ancestors`` (T, N) as in :mod:`pfx.analysis.genealogy`, ``values`` (T, N)
    the quantity drawn (a state component). Returns the segments, an (E, 2, 2) array of
    ((step - 1, parent's value), (step, child's value)), and an (E,) boolean array: True where
    the child is on an ancestral line of the last step's particles (then so is its parent).
    """
    row, child = np.nonzero(ancestors[1:] >= 0)    # step 1 has no parent; injected particles neither
    row += 1
    parent = ancestors[row, child]
    starts = np.column_stack([steps[row - 1], values[row - 1, parent]])
    ends = np.column_stack([steps[row], values[row, child]])
    return np.stack([starts, ends], axis=1).astype(float), ancestral_lines(ancestors)[row, child]


def _count_text(counts: np.ndarray) -> str:
    """A particle count per step in words: "N = 8", or "N = 50-200" when it varies."""
    low, high = int(counts.min()), int(counts.max())
    return f"N = {low}" if low == high else f"N = {low}-{high}"


@FIGURES.register("genealogy_tree")
def genealogy_tree(result: ResultFolder):
    """The particles' family tree for one trial: every parent-to-child edge faint, the last step's ancestral lines dark.

    From genealogy.csv (the first trial of its first cell) at the first position state, particles' area proportional to weight, the truth from steps.csv when traced; the title counts the distinct ancestors left at step 1 (path degeneracy). Needs the genealogy recorded.
    """
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    genealogy = result.genealogy
    if genealogy.empty:
        return None
    cell = genealogy["cell"].iloc[0]
    trial = genealogy.loc[genealogy["cell"] == cell, "trial"].min()
    rows = genealogy[(genealogy["cell"] == cell) & (genealogy["trial"] == trial)]
    drawable = [name for name in [*result.position_states, *result.state_names] if name in genealogy]
    if not drawable:               # a genealogy without the particles' states: no value to draw
        return None
    state = drawable[0]
    tree = trial_genealogy(rows, [state])
    values = tree.states[:, :, 0]
    on_line = ancestral_lines(tree.ancestors)
    counts = on_line.sum(axis=1)
    segments, dark = parent_edges(tree.steps, tree.ancestors, values)
    last_step = int(tree.steps[-1])

    figure, axes = plt.subplots(figsize=(8.5, 5.2), layout="constrained")
    axes.add_collection(LineCollection(segments[~dark], colors="0.6", linewidths=0.5, alpha=0.6, zorder=1,
                                       rasterized=True, label="parent → child, every particle"))
    # The particles under the dark lines: a cloud of many particles would hide them otherwise.
    present = ~np.isnan(tree.weights)
    step_grid = np.broadcast_to(tree.steps[:, None], values.shape)
    reference_area = MARKER_AREA_FOR_ONE_PARTICLE / np.sqrt(tree.particle_counts.max())
    areas = reference_area * tree.weights * tree.particle_counts[:, None]     # area ∝ weight; 1/N_k: the reference
    # Thousands of particles a step overlap into a dark band: the more, the fainter each.
    opacity = min(0.7, 7.0 / np.sqrt(tree.particle_counts.max()))
    axes.scatter(step_grid[present], values[present], color="0.3", alpha=opacity, linewidths=0, zorder=2,
                 s=np.clip(areas[present], 0.5, LARGEST_AREA_SHARE * reference_area), rasterized=True)
    particles_handle = Line2D([], [], linestyle="none", marker="o", markersize=4, color="0.3",
                              label="particles before resampling (area ∝ weight)")
    axes.add_collection(LineCollection(segments[dark], colors="C3", linewidths=1.4, zorder=3,
                                       label=f"ancestral lines of the particles at step {last_step}"))
    injected = present & (tree.ancestors == NO_PARENT)
    injected[0] = False            # step 1's particles have no parent by nature
    if injected.any():
        axes.scatter(step_grid[injected], values[injected], marker="x", s=30, color="C1", zorder=4,
                     label="drawn afresh from the prior (no parent)")
    _draw_truth(result, axes, cell, trial, state)
    axes.autoscale_view()
    unit = result.units.get(f"state_{state}", result.units.get("position", ""))
    axes.set_xlabel("step")
    axes.set_ylabel(with_unit(state_text(state), unit))
    axes.grid(alpha=0.3)
    label = cell_labels(rows.iloc[:1], legend_columns_of(result, rows))[0]
    survivors = int(counts[0])
    axes.set_title(f"{result.manifest.get('name', '')}: genealogy of trial {trial} ({label}), "
                   f"{_count_text(tree.particle_counts)}, T = {last_step}\n"
                   f"the particles of step {last_step} descend from {survivors} distinct "
                   f"particle{'s' if survivors != 1 else ''} of step 1", fontsize=11)
    legend_outside(figure, extra_handles=[particles_handle])
    return figure


def _draw_truth(result: ResultFolder, axes, cell: str, trial, state: str) -> None:
    """The true path of the trial, when steps.csv traced it and holds the truth."""
    steps = result.steps
    column = f"truth_{state}"
    if steps.empty or column not in steps:
        return
    rows = steps[(steps["cell"] == cell) & (steps["trial"] == trial)]
    if rows.empty or rows[column].isna().all():
        return
    axes.plot(rows["step"], rows[column], color="C0", linestyle="--", linewidth=1.4, zorder=5, label="truth")


# -- how many lines survive: distinct ancestors over time ---------------------------------------

@FIGURES.register("distinct_ancestors")
def distinct_ancestors(result: ResultFolder):
    """Distinct ancestors of the last step's particles at each step, per cell (log scale), with N.

    From steps.csv's `distinct_ancestors`: the mean over the traced trials, each trial faint; N at the last step, falling back in time (path degeneracy). Needs the genealogy recorded.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    steps = result.steps
    if steps.empty or "distinct_ancestors" not in steps or steps["distinct_ancestors"].isna().all():
        return None
    frame = steps.dropna(subset=["distinct_ancestors"])
    layout = small_multiples(result, frame, single_size=(8, 4.8), log_y=True)
    references = {}                # cell -> N, the reference line of its panel
    for cell, group in frame.groupby("cell", sort=False):
        line = layout.lines[cell]
        axes = layout.axes_for(cell)
        for _, trial in group.groupby("trial"):
            axes.plot(trial["step"], trial["distinct_ancestors"], color=line.colour, alpha=0.3, linewidth=0.8)
        mean = group.groupby("step")["distinct_ancestors"].mean()
        axes.plot(mean.index, mean.values, color=line.colour, linewidth=1.8, label=line.label)
        particles = group["n_particles"].iloc[0] if "n_particles" in group else np.nan
        # A filter whose count varies has no one N: the last step's count (the largest) stands in.
        references[cell] = float(particles) if np.isfinite(particles) else float(group["distinct_ancestors"].max())
    for axes, count in dict.fromkeys((layout.axes_for(cell), count) for cell, count in references.items()):
        reference = axes.axhline(count, color="black", linestyle=":", linewidth=1.2)
    reference.set_label("N: every particle of the last step is its own ancestor")
    trials_handle = Line2D([], [], color="0.5", alpha=0.5, linewidth=0.8, label="each traced trial")
    layout.panels[0].set_ylim(0.8, 1.6 * max(references.values()))
    # Counts read as plain numbers at 1, 2, 5, 10, ...: a log axis's default labels only the
    # decades, which leaves a small N (one decade) with two labels.
    layout.panels[0].yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    layout.panels[0].yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    layout.panels[0].yaxis.set_minor_formatter(NullFormatter())
    traced = frame.groupby("cell")["trial"].nunique()
    count = f"{traced.min()}" if traced.min() == traced.max() else f"{traced.min()}-{traced.max()}"
    layout.finish(f"{result.manifest.get('name', '')}: distinct ancestors of the last step's particles\n"
                  f"lines: mean over the {count} traced trial{'s' if traced.max() > 1 else ''} per cell; "
                  "at 1, every particle's path shares that step's particle",
                  "step", "distinct ancestors (log scale)", extra_handles=[trials_handle, reference])
    return layout.figure
