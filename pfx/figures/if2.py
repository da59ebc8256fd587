r"""The convergence of iterated filtering (IF2) to the maximum-likelihood estimate, from if2.csv
and maximum_likelihood.csv.

IF2 (Ionides, Nguyen, Atchade, Stoev & King 2015) maximises the likelihood
:math:`p(y_{1:T} \mid \theta)` with particle filters alone: every particle carries its own
parameter value, which takes a random-walk step at each time step, and the filter's resampling
keeps the values that explain the data. Each of M iterations filters the data once with that
swarm, starting from the swarm the previous one ended with, and the random walk's standard
deviation shrinks geometrically (the cooling schedule): the swarm contracts onto the maximum.
Several replicates from scattered starting points run side by side; those that end at the same
value and likelihood have found the maximum, one apart from them a local one.

``if2_convergence`` draws, per parameter, the swarm's mean after each iteration, a line per
replicate (a colour per cell), and, per parameter and for the log-likelihood, the final
estimate of the best replicate (the highest log-likelihood in maximum_likelihood.csv) as a
dashed line. The log-likelihood panel draws each iteration's filter estimate: it is that of
the perturbed swarm, so it climbs to a little below the best replicate's final log-likelihood
(which maximum_likelihood.csv evaluates at the fixed estimate, with its standard error).
A parameter whose values span a factor of :data:`LOG_AXIS_SPAN` or more (a variance started
at scattered orders of magnitude) is drawn on a log axis.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import numpy as np

from pfx.figures.estimation_chains import axis_name, count_text, finite_or_nan, parameter_columns, parameter_panels
from pfx.figures.layout import legend_outside, one_colour_per_cell
from pfx.figures.registry import FIGURES, draws_from
from pfx.result_folder import ResultFolder

if TYPE_CHECKING:
    import pandas as pd

LOG_AXIS_SPAN = 100.0


def best_replicate(maximum_likelihood: pd.DataFrame, cell: str) -> Optional[pd.Series]:
    """The row of maximum_likelihood.csv of the cell's replicate with the highest log-likelihood
    (None if the folder has none, or no replicate a finite log-likelihood)."""
    if maximum_likelihood.empty or not {"cell", "log_likelihood"} <= set(maximum_likelihood.columns):
        return None
    rows = maximum_likelihood[maximum_likelihood["cell"] == cell]
    values = rows["log_likelihood"].to_numpy(dtype=float)
    if not np.isfinite(values).any():
        return None
    return rows.iloc[int(np.argmax(np.where(np.isfinite(values), values, -np.inf)))]


def best_text(best: pd.Series) -> str:
    """"best -632.54 (se 0.05)": the best replicate's log-likelihood and its standard error."""
    text = f"best {float(best['log_likelihood']):.2f}"
    se = float(best.get("log_likelihood_se", np.nan))
    return text + (f" (se {se:.2g})" if np.isfinite(se) else "")


@FIGURES.register("if2_convergence")
@draws_from("if2")
def if2_convergence(result: ResultFolder):
    """IF2 convergence: each parameter's swarm mean and the log-likelihood estimate against the iteration, a line per replicate; the best replicate's estimate dashed.

    From if2.csv (a colour per cell) and maximum_likelihood.csv (the replicate with the highest log-likelihood, whose value and standard error the log-likelihood panel's title gives); replicates from scattered starts that meet have found the maximum.
    """
    if2 = result.optional_table("if2")
    if if2.empty or not {"cell", "replicate", "iteration"} <= set(if2.columns):
        return None
    parameters = parameter_columns(if2, "iteration")
    if not parameters:
        return None
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    maximum_likelihood = result.optional_table("maximum_likelihood")
    lines = one_colour_per_cell(result, if2)
    panels_of = [*parameters, "log_likelihood"]
    figure, panels, _ = parameter_panels(len(panels_of), panel_size=(3.6, 2.6))
    bests = {cell: best_replicate(maximum_likelihood, cell) for cell in lines}
    replicates, iterations = [], []
    for cell, rows in if2.groupby("cell", sort=False):
        line = lines[cell]
        paths = [path.sort_values("iteration") for _, path in rows.groupby("replicate", sort=True)]
        replicates.append(len(paths))
        iterations.append(int(rows["iteration"].max()))
        for axes, name in zip(panels, panels_of):
            for index, path in enumerate(paths):
                axes.plot(path["iteration"].to_numpy(dtype=float), finite_or_nan(path[name]), color=line.colour,
                          linewidth=0.9, alpha=0.6, label=line.label if index == 0 else None)
            best = bests[cell]
            if best is not None and name in best and np.isfinite(float(best[name])):
                axes.axhline(float(best[name]), color=line.colour, linestyle="--", linewidth=1.4)
    for axes, name in zip(panels, panels_of):
        values = np.concatenate([if2[name].to_numpy(dtype=float),
                                 [float(best[name]) for best in bests.values() if best is not None and name in best]])
        values = values[np.isfinite(values)]
        if name != "log_likelihood" and values.size and values.min() > 0 and values.max() >= LOG_AXIS_SPAN * values.min():
            axes.set_yscale("log")
        axes.set_ylabel("log-likelihood estimate" if name == "log_likelihood" else axis_name(name))
        axes.set_xlabel("IF2 iteration")
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))
        axes.grid(alpha=0.3)
    found = {cell: best for cell, best in bests.items() if best is not None}
    if found:
        panels[-1].set_title("\n".join(best_text(best) + (f" ({lines[cell].label})" if len(lines) > 1 else "")
                                       for cell, best in found.items()), fontsize=8)
    figure.suptitle(f"{result.manifest.get('name', '')}: IF2 convergence\n{count_text(replicates)} replicates x "
                    f"{count_text(iterations)} iterations per cell: the swarm's mean after each iteration",
                    fontsize=11)
    extra = [Line2D([], [], color="0.3", linestyle="--", linewidth=1.4,
                    label="best replicate's estimate (highest log-likelihood)")] if found else []
    legend_outside(figure, extra)
    return figure
