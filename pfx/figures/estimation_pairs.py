"""The pair plot of a PMMH posterior (figure ``posterior_pairs``), from chains.csv.

A random walk through the parameters of particle marginal Metropolis-Hastings (the chains
:mod:`pfx.figures.estimation_chains` reads and describes) is slowed most by parameters whose
posterior is a ridge: two that trade off against each other, so that only moves along the ridge
are accepted. The pair plot shows it: the draws after warm-up of every pair of parameters,
evenly thinned to at most :data:`MOST_POINTS_PER_CELL` per cell (the correlations use every
draw), with each parameter's histogram on the diagonal and the correlation of the draws above it.
An adapted proposal follows such a ridge. With simulated data (the config has no ``data:``
section) the true point, the config's model's
(:func:`~pfx.figures.estimation_chains.true_parameter_values`), is a star in each scatter and a
dash-dotted line on the diagonal. Each cell has one colour, as in the other estimation figures.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from pfx.analysis.estimation_flags import correlation  # the one the flag line names, computed once
from pfx.figures.estimation_chains import (
    TRUE_VALUE,
    Chains,
    axis_name,
    count_text,
    draw_true_value,
    histogram,
    read_chains,
    true_parameter_values,
    true_values_of,
)
from pfx.figures.layout import legend_outside
from pfx.figures.registry import FIGURES, draws_from
from pfx.result_folder import ResultFolder

MOST_POINTS_PER_CELL = 2000     # of a pair plot's scatter: more is one blot, and slow to draw


def evenly_thinned(count: int, most: int = MOST_POINTS_PER_CELL) -> np.ndarray:
    """Indices of at most ``most`` of ``count`` draws, evenly spaced from the first to the last
    (pooled draws run chain by chain, so every chain keeps its share; no random choice)."""
    if count <= most:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, most).round().astype(int))


@FIGURES.register("posterior_pairs")
@draws_from("chains")
def posterior_pairs(result: ResultFolder):
    """PMMH posterior pair plot: the draws after warm-up of every pair of parameters, a colour per cell; histograms on the diagonal, correlations above.

    From chains.csv, chains pooled, evenly thinned to at most 2000 points per cell (the correlations use every draw): ridges show the parameters the data cannot tell apart. Where pfx simulated the data, the true point is a star.
    """
    chains = read_chains(result)
    if chains is None or chains.after_warm_up.empty:
        return None
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    parameters = chains.parameters
    count = len(parameters)
    size = 1.2 + 2.3 * max(count, 2)
    figure, grid = plt.subplots(count, count, figsize=(size, size + 0.4), sharex="col", squeeze=False,
                                layout="constrained")
    draws = {cell: rows[parameters].to_numpy(dtype=float)
             for cell, rows in chains.after_warm_up.groupby("cell", sort=False)}
    truths = true_parameter_values(result)
    drew_truth = False
    for row in range(count):
        for column in range(count):
            axes = grid[row, column]
            if row < column:                # above the diagonal: the correlation of the pair
                axes.axis("off")
                for place, (cell, values) in enumerate(draws.items()):
                    rho = correlation(values[:, column], values[:, row])
                    axes.text(0.5, 0.5 + 0.14 * (len(draws) / 2 - place - 0.5), f"corr {rho:.2f}",
                              transform=axes.transAxes, ha="center", va="center", fontsize=9,
                              color=chains.lines[cell].colour)
                continue
            for cell, values in draws.items():
                line = chains.lines[cell]
                if row == column:
                    finite = values[np.isfinite(values[:, row]), row]
                    if finite.size:
                        histogram(axes, finite, line)
                else:
                    shown = values[evenly_thinned(len(values))]
                    axes.scatter(shown[:, column], shown[:, row], s=3, alpha=0.35, color=line.colour,
                                 linewidths=0, rasterized=True)
            drew_truth = _draw_true_point(axes, truths, chains, parameters[column],
                                          parameters[row] if row != column else None) or drew_truth
            axes.grid(alpha=0.3)
            if row == column:
                axes.set_title(parameters[row], fontsize=9)
                axes.tick_params(axis="y", left=False, labelleft=False)
            elif column == 0:
                axes.set_ylabel(axis_name(parameters[row]))
            if row == count - 1:
                axes.set_xlabel(parameters[column])
    for row in range(count):               # a row's scatters share the range of its parameter
        for column in range(row):
            grid[row, column].set_ylim(grid[row, row].get_xlim())
            if column > 0:
                grid[row, column].tick_params(axis="y", labelleft=False)
    per_cell = count_text(len(values) for values in draws.values())
    figure.suptitle(f"{result.manifest.get('name', '')}: PMMH posterior, parameters in pairs\n"
                    f"draws after warm-up pooled over {count_text(chains.chain_counts())} chains ({per_cell} per cell, "
                    f"at most {MOST_POINTS_PER_CELL} drawn); above the diagonal: correlation"
                    + ("\nstar: the true point, which simulated the data (a dash-dotted line on the diagonal)"
                       if drew_truth else ""), fontsize=11)
    legend_outside(figure, [Line2D([], [], linestyle="none", marker="*", markersize=11, color="black",
                                   label=TRUE_VALUE)] if drew_truth else [])
    return figure


def _draw_true_point(axes, truths: dict, chains: Chains, x_parameter: str, y_parameter: Optional[str]) -> bool:
    """The true value in one panel of the pair plot: a line on the diagonal (``y_parameter``
    None), a star at the true point in a scatter; each distinct value once, black when the cells
    share it. Whether anything was drawn."""
    x_values = true_values_of(truths, chains.lines, x_parameter)
    if y_parameter is None:
        if x_values:
            draw_true_value(axes, x_values, chains.lines)
        return bool(x_values)
    y_values = true_values_of(truths, chains.lines, y_parameter)
    points = {cell: (x_values[cell], y_values[cell]) for cell in x_values if cell in y_values}
    one_point = len(set(points.values())) == 1
    for cell, (x, y) in points.items():
        axes.scatter([x], [y], marker="*", s=140, color="black" if one_point else chains.lines[cell].colour,
                     edgecolors="white", linewidths=0.8, zorder=5)
        if one_point:
            break
    return bool(points)
