r"""Figures of a quantity over time, one line per cell, over every trial (steps_summary.csv).

* ``error_over_time``: the mean error distance :math:`\bar e_k` at each step over the cell's
  :math:`n` trials (named after the model's position: ``|error| of x`` for one state
  component, ``position error distance`` for several);
* ``ess_over_time``: the mean effective sample size before resampling as a share of the
  particles, :math:`\overline{N_{\mathrm{eff}}}_k / N`;
* ``nees_over_time``: the mean NEES (log scale) against its expected value :math:`d`, the
  state dimension, for a consistent filter. A (trial, step) whose covariance cannot be
  inverted reliably (a collapsed particle cloud) has no NEES: the mean is over the others
  (steps_summary.csv's ``nees_n``), and the title counts the values left out.

The ESS of the auxiliary particle filter is that of its second-stage weights, which its
first-stage resampling leaves flatter than other filters' weights: ``ess_over_time`` and
``ess_decay`` name its cells in their titles (:func:`pfx.figures.layout.auxiliary_note`).

Each line is the mean over every trial of the cell, and its band the 95% t-interval of that
mean (steps_summary.csv, :mod:`pfx.analysis.step_summary`): where two bands do not overlap, the cells
differ by more than their trials' spread explains. With fewer than 6 trials there is no band,
and the title says why. A folder written before steps_summary.csv
existed draws the same statistics over its traced trials (steps.csv; see
:attr:`pfx.result_folder.ResultFolder.steps_summary`), and its title says "traced trials".

Sweeps with many cells are drawn as small multiples, legends sit below the panels, and a cell
whose mean diverges (a filter that lost the target: errors of 1e20) stops at the edge of the
axes with a triangle and a note, so the other lines keep their scale (:mod:`pfx.figures.layout`);
on the NEES's log axis the edge is :data:`LOG_AXIS_CEILING`.
"""

from __future__ import annotations

import numpy as np

from pfx.analysis.summary import MINIMUM_VALUES
from pfx.figures.layout import (
    auxiliary_note,
    cell_labels,
    error_quantity,
    legend_columns_of,
    off_scale_limit,
    peak_text,
    plot_within,
    small_multiples,
    time_axis,
    time_text,
    trials_text,
)
from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

STATISTICS = ("mean", "ci95_low", "ci95_high")
# The top of a log axis: a mean NEES of 1e278 (a collapsed cloud's) made matplotlib place ticks
# past the largest double and fail; nothing near this is a value to read, so a line beyond it
# leaves the axes with a note, as a diverging line does on a linear axis.
LOG_AXIS_CEILING = 1e100


def _over_time(result: ResultFolder, quantity: str, what: str, y_label: str, unit: str = "",
               scale=None, log_y: bool = False, reference=None, notes=()):
    """Mean line and 95% CI band of ``quantity`` per cell, divided by ``scale(rows)`` if given.

    ``reference`` = (value, label) draws a dashed horizontal line in every panel (e.g. the
    expected NEES); ``notes`` are lines added to the title (what the figure left out, what a
    value means for some cell). Returns the :class:`~pfx.figures.layout.SmallMultiples` (for
    the figure to set its limits), or None when no cell has a value.
    """
    summary = result.steps_summary
    if summary.empty or summary[f"{quantity}_mean"].isna().all():
        return None
    x_column, x_label = time_axis(result)
    series = {}                    # cell -> (time, mean, low, high), the cells with a value
    for cell, rows in summary.groupby("cell", sort=False):
        divisor = scale(rows) if scale is not None else 1.0
        with np.errstate(over="ignore", invalid="ignore"):
            mean, low, high = (rows[f"{quantity}_{statistic}"].to_numpy(dtype=float) / divisor
                               for statistic in STATISTICS)
        if not np.isnan(mean).all():   # the ESS of a Kalman filter has none: no panel, no line
            series[cell] = (rows[x_column].to_numpy(dtype=float), mean, low, high)
    drawn = summary["cell"].isin(series)
    layout = small_multiples(result, summary[drawn], log_y=log_y)
    if log_y:
        # A log axis spans the decades: only a line beyond LOG_AXIS_CEILING needs clipping; a
        # band's lower edge at or below zero (a wide interval) is drawn at the bottom of the axes.
        positive = np.concatenate([np.concatenate([mean, low]) for _, mean, low, _ in series.values()])
        bottom = np.min(positive[np.isfinite(positive) & (positive > 0)], initial=1.0) / 2
        series = {cell: (time, mean, np.where(low > 0, low, bottom), high)
                  for cell, (time, mean, low, high) in series.items()}
        limit = LOG_AXIS_CEILING
        in_scale = [cell for cell, (_, mean, _, _) in series.items() if not np.nanmax(mean) > limit]
    else:
        peaks = {cell: float(np.nanmax(np.abs(np.concatenate([mean, np.where(np.isfinite(high), high, mean)]))))
                 for cell, (_, mean, _, high) in series.items()}
        limit, in_scale = off_scale_limit(peaks)
    for cell, (time, mean, low, high) in series.items():
        line = layout.lines[cell]
        first_outside = plot_within(layout.axes_for(cell), time, mean, limit, line.colour, line.label, low, high)
        if cell not in in_scale and first_outside is not None:
            layout.note(cell, f"{line.label}: off scale from {time_text(time[first_outside], result)} "
                              f"(mean up to {peak_text(np.nanmax(mean), unit)})")
    extra = []
    if reference is not None:
        value, label = reference
        for axes in layout.panels:
            axes.axhline(value, color="black", linestyle="--", linewidth=1)
        extra = [layout.panels[0].lines[-1]]
        extra[0].set_label(label)      # once, in the legend's last place
    axes = layout.panels[0]            # every panel shares its limits
    if log_y:
        axes.set_ylim(bottom=bottom, top=limit if len(in_scale) < len(series) else None)
    elif np.isfinite(limit):
        axes.set_ylim(min(0.0, axes.get_ylim()[0]), limit)
    trials = trials_text(summary[drawn], result.steps_summary_covers_every_trial)
    if any(np.isfinite(low).any() for _, _, low, _ in series.values()):
        band = ", band: 95% CI"
    elif summary[drawn]["trials"].max() < MINIMUM_VALUES:
        band = f", no band: a 95% CI needs {MINIMUM_VALUES} trials"
    else:
        band = ""
    title = f"{result.manifest.get('name', '')}: {what}\nmean over {trials} per cell{band}"
    title += "".join(f"\n{note}" for note in notes if note)
    left_out = summary[~drawn].drop_duplicates("cell")
    if not left_out.empty:             # say so, rather than leave the reader looking for them
        title += f"\nno values for: {', '.join(cell_labels(left_out, legend_columns_of(result, left_out)))}"
    layout.finish(title, x_label, y_label, extra_handles=extra)
    return layout


@FIGURES.register("error_over_time")
def error_over_time(result: ResultFolder):
    """Mean error distance over time per cell over every trial, with the 95% CI of the mean.

    From steps_summary.csv; the axis names the error (`|error| of altitude [ft]`, or `position error distance [m]` for several position states).
    """
    quantity = error_quantity(result)
    layout = _over_time(result, "error_distance", f"{quantity.title} over time", quantity.axis_label,
                        unit=result.units.get("position", ""))
    if layout is None:
        return None
    layout.panels[0].set_ylim(bottom=0)
    return layout.figure


@FIGURES.register("nees_over_time")
def nees_over_time(result: ResultFolder):
    """Mean NEES over time per cell (log scale) against its expected value d, the state dimension.

    From steps_summary.csv, every trial; a (trial, step) whose covariance cannot be inverted reliably has no NEES: the mean leaves it out and the title counts what it left out.
    """
    dimension = len(result.state_names)
    layout = _over_time(result, "nees", "normalised estimation error squared (NEES)",
                        f"NEES (consistent filter: d = {dimension})", log_y=True,
                        reference=(dimension, f"expected: d = {dimension}"), notes=[_left_out_nees(result)])
    return layout.figure if layout is not None else None


def _left_out_nees(result: ResultFolder) -> str:
    """What the NEES means leave out: the (trial, step) values whose covariance could not be
    inverted reliably (steps_summary.csv's ``trials - nees_n``), in the cells that have a NEES."""
    summary = result.steps_summary
    if "nees_n" not in summary:
        return ""
    counts = summary[summary.groupby("cell")["nees_n"].transform("sum") > 0]
    left_out = int((counts["trials"] - counts["nees_n"]).sum())
    if not left_out:
        return ""
    return (f"left out: {left_out} of {int(counts['trials'].sum())} (trial, step) values whose covariance "
            "could not be inverted reliably (a collapsed particle cloud)")


@FIGURES.register("ess_over_time")
def ess_over_time(result: ResultFolder):
    """Mean effective sample size (as a share of N) over time per cell, before resampling.

    From steps_summary.csv, with the 95% CI of the mean; the title names the cells of the auxiliary filter, whose ESS is that of its second-stage weights.
    """
    summary = result.steps_summary
    if summary.empty or "n_particles" not in summary or summary["n_particles"].isna().all():
        return None
    layout = _over_time(result, "ess", "effective sample size before resampling", "ESS / N",
                        scale=lambda rows: float(rows["n_particles"].iloc[0]), notes=[auxiliary_note(result, summary)])
    if layout is None:
        return None
    layout.panels[0].set_ylim(0, 1.05)
    return layout.figure
