r"""Figures of the chains of particle marginal Metropolis-Hastings (PMMH), from chains.csv,
posterior.csv and priors.csv.

PMMH (Andrieu, Doucet & Holenstein 2010) samples the posterior of a model's parameters
:math:`p(\theta \mid y_{1:T}) \propto p(y_{1:T} \mid \theta)\, p(\theta)`: at each iteration
a random walk proposes :math:`\theta'`, a particle filter estimates its likelihood
:math:`\hat p(y_{1:T} \mid \theta')`, and the chain moves there with probability

.. math::

    \min\Big(1, \frac{\hat p(y_{1:T} \mid \theta')\, p(\theta')}
                     {\hat p(y_{1:T} \mid \theta)\, p(\theta)}\Big)

(a symmetric proposal), keeping the estimate of the point it stands on. The estimate is
unbiased, so the chain's draws follow the exact posterior, but its noise makes the chain
sticky: a point whose likelihood was overestimated by luck is left only rarely, and the chain
lies flat for long stretches (as it does when its proposals reach too far). The figures show
what a reader checks before trusting the posterior summary (posterior.csv):

* ``chain_traces``: every chain's path, one row of panels per parameter and one for the
  log-likelihood estimate, a column per cell, the warm-up shaded. Chains that mix overlap like
  noise around one level from early on; a flat stretch is a sticky chain, a chain apart from the
  others one that has not yet found the posterior's mass.
* ``posterior_marginals``: per parameter, a histogram (density) of the draws after warm-up,
  pooled over the chains, per cell, with the prior density (priors.csv) dashed and the posterior
  mean marked: how far the data moved the parameter from its prior. The axes keep the
  histograms' scale: a prior that lies wholly above them (an improper flat prior's density 1,
  in whatever units the parameter has) is noted in the panel. Each panel's title gives
  the split R-hat (about 1 when the chains agree; above 1.01 they do not yet) and the bulk
  effective sample size from posterior.csv. Where pfx simulated the data (the config has no
  ``data:`` section), the true value of each parameter, the config's model's
  (:func:`true_parameter_values`), is a dash-dotted line: how far the posterior sits from the
  value that made the data. Recorded data have no known truth, and no line.
* ``posterior_pairs`` (:mod:`pfx.figures.estimation_pairs`, drawn from the chains as read
  here): the draws after warm-up of every pair of parameters, with each parameter's histogram on
  the diagonal and the correlation of the draws above it: a ridge (two variances that trade off
  against each other) is what slows a random walk down and what an adapted proposal follows.

This module reads the chains (:func:`read_chains`), the true values where pfx simulated the
data (:func:`true_parameter_values`), and draws the first two. Each cell has one colour in
every figure (:func:`pfx.figures.layout.one_colour_per_cell`); in the traces, where a column
holds one cell, the colours tell the chains apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import numpy as np

from pfx.figures.layout import CellLine, grid_columns, legend_outside, one_colour_per_cell
from pfx.figures.registry import FIGURES, draws_from
from pfx.result_folder import ResultFolder

if TYPE_CHECKING:
    import pandas as pd

FEWEST_BINS, MOST_BINS = 10, 50  # of a histogram of n draws: sqrt(n) bins within these
WARM_UP_SHADE = "0.88"
LONGEST_AXIS_NAME = 16          # characters of a parameter's name on a vertical axis, unbroken
TRUE_VALUE = "true value"       # the legend's name of the value that simulated the data
TRUE_LINE = {"color": "black", "linestyle": "-.", "linewidth": 1.6}


# -- reading the tables ---------------------------------------------------------------------------

def parameter_columns(table: pd.DataFrame, after: str) -> list[str]:
    """The estimated parameters of a table: its columns between ``after`` and ``log_likelihood``
    (chains.csv: after ``warm_up``; if2.csv: after ``iteration``), in order. A parameter's name
    is its dotted path into the model (``measurement_noise.variance``)."""
    columns = list(table.columns)
    if after not in columns or "log_likelihood" not in columns:
        return []
    return columns[columns.index(after) + 1:columns.index("log_likelihood")]


def as_flags(column: pd.Series) -> np.ndarray:
    """A column of True/False as booleans (pandas reads it as text where a field is empty)."""
    if column.dtype == bool:
        return column.to_numpy()
    return column.astype(str).str.strip().str.lower().isin(["true", "1", "1.0"]).to_numpy()


@dataclass(frozen=True)
class Chains:
    """chains.csv as the figures use it."""

    table: pd.DataFrame           # warm_up and accepted as booleans
    parameters: list[str]         # in posterior.csv's order (else chains.csv's)
    lines: dict[str, CellLine]    # cell key -> its label and colour

    @property
    def after_warm_up(self) -> pd.DataFrame:
        """The draws the posterior is summarised from: every chain's iterations after warm-up."""
        return self.table[~self.table["warm_up"]]

    def chain_counts(self) -> list[int]:
        return list(self.table.groupby("cell", sort=False)["chain"].nunique())


def read_chains(result: ResultFolder) -> Optional[Chains]:
    """The folder's chains (None if it has none). The parameters are posterior.csv's
    ``parameter`` values when it has them, else chains.csv's columns between ``warm_up`` and
    ``log_likelihood``."""
    table = result.optional_table("chains")
    if table.empty or not {"cell", "chain", "iteration", "warm_up", "log_likelihood"} <= set(table.columns):
        return None
    in_chains = parameter_columns(table, "warm_up")
    posterior = result.optional_table("posterior")
    if "parameter" in posterior:
        named = [name for name in dict.fromkeys(posterior["parameter"].astype(str)) if name in in_chains]
        in_chains = named or in_chains
    if not in_chains:
        return None
    table = table.assign(warm_up=as_flags(table["warm_up"]),
                         accepted=as_flags(table["accepted"]) if "accepted" in table else False)
    return Chains(table, in_chains, one_colour_per_cell(result, table))


def count_text(counts) -> str:
    """How many, over the cells: "16", or "8-16" when the cells differ."""
    counts = [int(count) for count in counts]
    low, high = min(counts), max(counts)
    return f"{low}" if low == high else f"{low}-{high}"


def axis_name(parameter: str) -> str:
    """A parameter's name for a vertical axis: a long dotted path broken after its last dot
    (``measurement_noise.`` over ``variance``), so the label fits beside its panel."""
    head, dot, tail = parameter.rpartition(".")
    return f"{head}.\n{tail}" if dot and len(parameter) > LONGEST_AXIS_NAME else parameter


def histogram_bins(values: np.ndarray) -> int:
    """Bins for a histogram of ``values``: sqrt(n), at least FEWEST_BINS and at most MOST_BINS."""
    return int(np.clip(round(math.sqrt(values.size)), FEWEST_BINS, MOST_BINS))


def histogram(axes, values: np.ndarray, line: CellLine) -> None:
    """A density histogram of one cell's draws: its colour faint inside, full on the outline,
    so that the cells' histograms stay apart where they overlap."""
    from matplotlib.colors import to_rgba

    axes.hist(values, bins=histogram_bins(values), density=True, histtype="stepfilled",
              facecolor=to_rgba(line.colour, 0.25), edgecolor=line.colour, linewidth=1.0, label=line.label)


def finite_or_nan(values) -> np.ndarray:
    """Values to plot: an infinite log-likelihood (a filter whose weights all vanished) as a gap."""
    values = np.asarray(values, dtype=float)
    return np.where(np.isfinite(values), values, np.nan)


# -- the true values, where pfx simulated the data -----------------------------------------------

def true_parameter_values(result: ResultFolder) -> dict[str, dict[str, float]]:
    """cell key -> estimated parameter (its column name) -> the value the data were simulated
    with; empty when the data were recorded (``data:``, the manifest's ``recorded_data``), when
    the folder has no config.yaml, or for a parameter without one number to show.

    An estimation cell without recorded data fits the dataset of trial 0 simulated from the
    true model: the config's ``model:`` section (config.yaml, every default written out), with
    the cell's sweep values set in. A parameter swept itself takes its cell's value (its label
    column, the path's dots as underscores); one inside a swept mapping, or holding a swept
    key, has no value read here, rather than a wrong one.
    """
    config = result.config
    model = config.get("model")
    parameters = (config.get("estimation") or {}).get("parameters") or {}
    if result.recorded_data or config.get("data") or not isinstance(model, dict) or not isinstance(parameters, dict):
        return {}
    sweep = config.get("sweep") or {}
    values: dict[str, dict[str, float]] = {}
    for entry in result.manifest.get("cells", []):
        cell_values = {}
        for path, settings in parameters.items():
            column = (settings or {}).get("name") or path.removeprefix("model.")
            value = _true_value(path, model, sweep, entry)
            if value is not None:
                cell_values[column] = value
        values[str(entry.get("cell"))] = cell_values
    return values


def _true_value(path: str, model: dict, sweep: dict, cell: dict) -> Optional[float]:
    """The number at the dotted ``path`` (``model.a.b``) in the cell's true model; None if
    there is no one finite number there (see :func:`true_parameter_values`)."""
    overlapping = [key for key in sweep if key == path or key.startswith(f"{path}.") or path.startswith(f"{key}.")]
    if overlapping == [path]:
        value = cell.get(path.replace(".", "_"))
    elif overlapping:
        return None
    else:
        value = model
        for part in path.split(".")[1:]:
            value = value.get(part) if isinstance(value, dict) else None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def true_values_of(truths: dict[str, dict[str, float]], cells, parameter: str) -> dict[str, float]:
    """cell -> the parameter's true value, for the ``cells`` that have one."""
    return {cell: truths[cell][parameter] for cell in cells if parameter in truths.get(cell, {})}


def draw_true_value(axes, values: dict[str, float], lines: dict[str, CellLine]) -> None:
    """A vertical line at the true value: one black line when every cell has the same value,
    else each cell's in its colour."""
    if len(set(values.values())) == 1:
        axes.axvline(next(iter(values.values())), **TRUE_LINE, zorder=4)
        return
    for cell, value in values.items():
        axes.axvline(value, **{**TRUE_LINE, "color": lines[cell].colour}, zorder=4)


# -- chain_traces -----------------------------------------------------------------------------------

def acceptance_text(rows: pd.DataFrame) -> str:
    """The share of the iterations after warm-up whose proposal was accepted."""
    after = rows[~rows["warm_up"]]
    if after.empty:
        return "no iteration after warm-up"
    return f"acceptance after warm-up {after['accepted'].mean():.0%}"


@FIGURES.register("chain_traces")
@draws_from("chains")
def chain_traces(result: ResultFolder):
    """PMMH chain traces: each parameter and the log-likelihood estimate against the iteration, a line per chain, warm-up shaded; a column per cell.

    From chains.csv: chains that mix overlap like noise around one level; a chain flat for long stretches rejects its proposals, stuck on a lucky overestimate of the likelihood (too noisy an estimate: more particles) or proposing too far; each column's title gives the acceptance rate after warm-up.
    """
    chains = read_chains(result)
    if chains is None:
        return None
    import matplotlib.pyplot as plt

    rows = [*chains.parameters, "log_likelihood"]
    cells = list(chains.lines)
    width = 7.5 if len(cells) == 1 else 1.0 + 3.4 * len(cells)
    figure, grid = plt.subplots(len(rows), len(cells), figsize=(width, 1.2 + 1.7 * len(rows)), sharex=True,
                                sharey="row", squeeze=False, layout="constrained")
    iterations, warm_ups = [], []
    for column, cell in enumerate(cells):
        cell_rows = chains.table[chains.table["cell"] == cell]
        paths = [path.sort_values("iteration") for _, path in cell_rows.groupby("chain", sort=True)]
        iterations.append(int(cell_rows["iteration"].max()))
        warm_up = cell_rows.loc[cell_rows["warm_up"], "iteration"]
        warm_ups.append(int(warm_up.max()) if not warm_up.empty else 0)
        for row, name in enumerate(rows):
            axes = grid[row, column]
            if warm_ups[-1] > 0:
                axes.axvspan(0, warm_ups[-1], color=WARM_UP_SHADE, linewidth=0, zorder=0)
            for index, path in enumerate(paths):
                axes.plot(path["iteration"].to_numpy(dtype=float), finite_or_nan(path[name]),
                          color=f"C{index % 10}", linewidth=0.6, alpha=0.75, rasterized=True)
            axes.grid(alpha=0.3)
        if len(cells) > 1:
            grid[0, column].set_title(f"{chains.lines[cell].label}\n{acceptance_text(cell_rows)}", fontsize=9)
        grid[-1, column].set_xlabel("iteration")
    for row, name in enumerate(rows):
        grid[row, 0].set_ylabel("log-likelihood\nestimate" if name == "log_likelihood" else axis_name(name))
    colours = "a colour each" if max(chains.chain_counts()) <= 10 else "ten colours in turn"
    title = (f"{result.manifest.get('name', '')}: PMMH chain traces\n"
             f"{count_text(chains.chain_counts())} chains ({colours}) x {count_text(iterations)} iterations "
             f"per cell, the first {count_text(warm_ups)} warm-up (shaded)")
    if len(cells) == 1:
        title += f"; {acceptance_text(chains.table)}"
    figure.suptitle(title, fontsize=11)
    return figure


# -- posterior_marginals ---------------------------------------------------------------------------------

def summary_row(posterior: pd.DataFrame, cell: str, parameter: str) -> Optional[pd.Series]:
    """posterior.csv's row of one cell and parameter (None if the folder has none)."""
    if posterior.empty or not {"cell", "parameter"} <= set(posterior.columns):
        return None
    rows = posterior[(posterior["cell"] == cell) & (posterior["parameter"].astype(str) == parameter)]
    return rows.iloc[0] if not rows.empty else None


def diagnostics_text(summary: Optional[pd.Series]) -> str:
    """"R-hat 1.003, bulk ESS 812" from a row of posterior.csv ("" without one)."""
    if summary is None:
        return ""
    parts = []
    for column, name, form in (("r_hat", "R-hat", ".3f"), ("ess_bulk", "bulk ESS", ".0f")):
        value = float(summary.get(column, np.nan))
        parts.append(f"{name} {value:{form}}" if np.isfinite(value) else f"{name} -")
    return ", ".join(parts)


def parameter_panels(count: int, panel_size=(3.6, 2.8)):
    """A figure of ``count`` panels in rows as full as possible (as the small multiples'), each
    panel with its own axes; returns the figure, the panels and the number of columns."""
    import matplotlib.pyplot as plt

    columns = grid_columns(count)
    rows = math.ceil(count / columns)
    figure, grid = plt.subplots(rows, columns, figsize=(1.0 + panel_size[0] * columns, 1.6 + panel_size[1] * rows),
                                squeeze=False, layout="constrained")
    panels = list(grid.flat)
    for unused in panels[count:]:
        figure.delaxes(unused)
    return figure, panels[:count], columns


@FIGURES.register("posterior_marginals")
@draws_from("chains")
def posterior_marginals(result: ResultFolder):
    """PMMH posterior of each parameter: histogram of the draws after warm-up (chains pooled) per cell, the prior dashed, the posterior mean marked.

    From chains.csv, with the prior density from priors.csv and, from posterior.csv, the mean and each panel's split R-hat and bulk effective sample size. Where pfx simulated the data (no `data:` section), the true value from config.yaml's model is a dash-dotted line.
    """
    chains = read_chains(result)
    if chains is None or chains.after_warm_up.empty:
        return None
    from matplotlib.lines import Line2D

    draws = chains.after_warm_up
    posterior = result.optional_table("posterior")
    priors = result.optional_table("priors")
    truths = true_parameter_values(result)
    figure, panels, columns = parameter_panels(len(chains.parameters))
    drew_prior = drew_truth = False
    for index, (axes, parameter) in enumerate(zip(panels, chains.parameters)):
        notes = []
        for cell, line in chains.lines.items():
            values = draws.loc[draws["cell"] == cell, parameter].to_numpy(dtype=float)
            values = values[np.isfinite(values)]
            if values.size == 0:
                continue
            histogram(axes, values, line)
            summary = summary_row(posterior, cell, parameter)
            mean = float(summary["mean"]) if summary is not None and "mean" in summary else np.nan
            if not np.isfinite(mean):
                mean = float(values.mean())       # the same draws' mean, posterior.csv's definition
            axes.axvline(mean, color=line.colour, linewidth=1.6)
            text = diagnostics_text(summary)
            if text:
                notes.append(f"{line.label}: {text}" if len(chains.lines) > 1 else text)
        true_values = true_values_of(truths, chains.lines, parameter)
        if true_values:
            draw_true_value(axes, true_values, chains.lines)
            drew_truth = True
        if "parameter" in priors:
            prior = priors[priors["parameter"].astype(str) == parameter].sort_values("value")
            if not prior.empty:
                # On the posterior's scale: a prior far flatter than the posterior, or an improper
                # flat one (density 1 in any units), would otherwise squash the histograms flat.
                axes.plot(prior["value"], prior["density"], "--", color="black", linewidth=1.2, scaley=False)
                drew_prior = True
                inside = prior.loc[prior["density"] > 0, "density"]        # 0 on the support's edge
                if not inside.empty and inside.min() > axes.get_ylim()[1]:
                    axes.text(0.98, 0.96, f"prior above the axes\n(density ≥ {inside.min():.3g})",
                              transform=axes.transAxes, ha="right", va="top", fontsize=8)
        if notes:
            axes.set_title("\n".join(notes), fontsize=8)
        axes.set_xlabel(parameter)
        if index % columns == 0:
            axes.set_ylabel("density")
        axes.grid(alpha=0.3)
    extra = [Line2D([], [], color="0.3", linewidth=1.6, label="posterior mean")]
    if drew_prior:
        extra.append(Line2D([], [], color="black", linestyle="--", linewidth=1.2, label="prior"))
    if drew_truth:
        extra.append(Line2D([], [], **TRUE_LINE, label=TRUE_VALUE))
    figure.suptitle(f"{result.manifest.get('name', '')}: PMMH posterior marginals\n"
                    f"draws after warm-up, pooled over {count_text(chains.chain_counts())} chains "
                    f"({count_text(draws.groupby('cell', sort=False).size())} per cell)"
                    + ("\ndash-dotted: the true value, which simulated the data" if drew_truth else ""),
                    fontsize=11)
    legend_outside(figure, extra)
    return figure
