r"""The cost of PMMH's draws against the particle count, from chains.csv: how to choose N.

Each PMMH iteration runs one particle filter, whose cost grows with the particle count N; the
chain's draws are worth less the noisier the filter's likelihood estimate is, i.e. the smaller
N. The work per effective draw is therefore proportional to

.. math::

    \tau(N) \times N,

with :math:`\tau` the chain's integrated autocorrelation time (:mod:`pfx.analysis.autocorrelation`).
Doucet, Pitt, Deligiannidis & Kohn (2015) and Pitt, Silva, Giordani & Kohn (2012) show that
it is smallest where the sd of the log-likelihood estimate is about 1.2 (0.92 to 1.68,
depending on how well the exact-likelihood chain mixes), provided the random walk is the same
at every N.

``inefficiency_vs_particles`` draws it for a PMMH run whose cells sweep ``filter.particles``:
per estimated parameter, :math:`\tau \times N` against N on log axes, by ArviZ's effective
sample size (solid) and by batch means (dashed, each chain one batch), each with a bar of
:math:`\pm 2` standard errors from resampling whole chains, and the smallest value of the
parameters' mean marked. The draws are those after the warm-up; cells that differ in
something other than N get a panel each.
"""

from __future__ import annotations

import numpy as np

from pfx.analysis.autocorrelation import ESTIMATORS, inefficiency_table, mean_over_parameters
from pfx.figures.estimation_chains import read_chains
from pfx.figures.registry import FIGURES, draws_from
from pfx.result_folder import ResultFolder

BOOTSTRAP_SEED = 2015       # the resampling of chains for the error bars: fixed, so the figure never changes
BOOTSTRAP_REPLICATES = 100
LINE_STYLES = dict(zip(ESTIMATORS, ("-", "--")))


def particle_count_table(result: ResultFolder):
    """The folder's inefficiency table and its bootstrap replicates
    (:func:`pfx.analysis.autocorrelation.inefficiency_table`), each with a ``panel`` column naming
    the labels other than N; None without chains or without two particle counts."""
    chains = read_chains(result)
    if chains is None or "n_particles" not in chains.table or chains.table["n_particles"].nunique() < 2:
        return None
    draws = chains.after_warm_up
    others = [c for c in result.label_columns if c in draws and c != "n_particles" and draws[c].nunique() > 1]
    table, resampled = inefficiency_table(draws, chains.parameters, [*others, "n_particles"],
                                          np.random.default_rng(BOOTSTRAP_SEED), BOOTSTRAP_REPLICATES)

    def panels(frame):
        return frame.assign(panel=[", ".join(f"{name}={row[name]}" for name in others) for _, row in frame.iterrows()]
                            if others else "")

    return panels(table), panels(resampled)


@FIGURES.register("inefficiency_vs_particles")
@draws_from("chains")
def inefficiency_vs_particles(result: ResultFolder):
    """PMMH: integrated autocorrelation time x N against the particle count N (the work per effective draw).

    For a PMMH run sweeping `filter.particles`: the mean over the parameters by ArviZ's estimate (solid) and by batch means (dashed) with bars of ±2 standard errors from resampling chains, each parameter thin beside them; the smallest mean marked. Draws after the warm-up."""
    import matplotlib.pyplot as plt

    tables = particle_count_table(result)
    if tables is None or tables[0].empty:
        return None
    table, resampled = tables
    mean = mean_over_parameters(table, resampled, ["panel", "n_particles"])
    panels = list(dict.fromkeys(table["panel"]))
    figure, grid = plt.subplots(1, len(panels), figsize=(8.0 + 4.0 * (len(panels) - 1), 6.2), squeeze=False,
                                sharey=True, layout="constrained")
    colours = {parameter: f"C{index + 1}" for index, parameter in enumerate(dict.fromkeys(table["parameter"]))}
    for axes, panel in zip(grid.flat, panels):
        rows = table[table["panel"] == panel]
        for (parameter, estimator), line in rows.groupby(["parameter", "estimator"], sort=False):
            axes.plot(line["n_particles"], line["cost"], color=colours[parameter], linestyle=LINE_STYLES[estimator],
                      linewidth=0.9, alpha=0.6, label=f"{parameter} ({estimator})")
        for offset, (estimator, line) in zip((0.985, 1.015), mean[mean["panel"] == panel].groupby("estimator", sort=False)):
            axes.errorbar(line["n_particles"] * offset, line["cost"], yerr=2 * line["cost_se"], color="C0",
                          linestyle=LINE_STYLES[estimator], marker="o", markersize=4, capsize=3, linewidth=2.0,
                          label=f"mean over the parameters ({estimator}), ±2 se")
            best = line.loc[line["cost"].idxmin()]
            axes.plot([best["n_particles"] * offset], [best["cost"]], marker="*", markersize=14, color="black",
                      linestyle="none", markerfacecolor="black" if LINE_STYLES[estimator] == "-" else "none",
                      label=f"smallest mean ({estimator})")
        axes.set_xscale("log")
        axes.set_yscale("log")
        axes.set_xlabel("particles N")
        axes.grid(alpha=0.3, which="both")
        if panel:
            axes.set_title(panel, fontsize=10)
    grid.flat[0].set_ylabel("integrated autocorrelation time × N")
    chains = int(table["chains"].min())
    figure.suptitle(f"{result.manifest.get('name', '')}: work per effective draw against N "
                    f"({chains} chains per N, draws after the warm-up)", fontsize=11)
    handles, labels = grid.flat[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=3, fontsize=8)
    return figure
