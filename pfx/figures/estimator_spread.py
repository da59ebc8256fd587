"""The spread of the log-likelihood estimate for fixed data against the particle count.

For configs whose trials share datasets (``datasets``; :mod:`pfx.analysis.estimator_spread`),
or filter recorded data (``data:``, one dataset for every trial):
the pooled within-dataset standard deviation of ``log_likelihood`` per arm against N, on
log-log axes, with its 95% interval (from the variance's chi-square interval) as error bars.
A particle filter's log-likelihood variance falls as 1/N for large N, so its sd falls along
the dotted slope -1/2 drawn through the first arm's largest N.
"""

from __future__ import annotations

import numpy as np

from pfx.analysis.estimator_spread import within_dataset_spread
from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder


@FIGURES.register("log_likelihood_spread_vs_particles")
def log_likelihood_spread_vs_particles(result: ResultFolder):
    """SD of the log-likelihood estimate over repeated runs on the same data, per arm, against N (log-log)."""
    import matplotlib.pyplot as plt

    trials = result.trials
    if trials.empty or "log_likelihood" not in trials or trials["n_particles"].isna().all():
        return None
    spread = within_dataset_spread(trials, result.label_columns, one_dataset=result.recorded_data)
    spread = spread.dropna(subset=["n_particles", "variance"])
    spread = spread[spread["variance"] > 0]
    if spread.empty:
        return None
    figure, axes = plt.subplots(figsize=(7.5, 4.6), layout="constrained")
    if "arm" not in spread:
        spread = spread.assign(arm="all")
    for name, group in spread.groupby("arm", sort=False):
        group = group.sort_values("n_particles")
        sd = group["sd"].to_numpy()
        below = sd - np.sqrt(group["variance_ci95_low"].to_numpy())
        above = np.sqrt(group["variance_ci95_high"].to_numpy()) - sd
        axes.errorbar(group["n_particles"], sd, yerr=[below, above], marker="o", capsize=3, label=str(name))
    first = spread[spread["arm"] == spread["arm"].iloc[0]]
    anchor = first.sort_values("n_particles").iloc[-1]
    counts = np.array(sorted(spread["n_particles"].unique()), dtype=float)
    axes.plot(counts, anchor["sd"] * np.sqrt(anchor["n_particles"] / counts), ":", color="grey",
              label="slope -1/2 (variance ∝ 1/N)")
    axes.set_xscale("log")
    axes.set_yscale("log")
    axes.set_xticks(counts, [f"{n:g}" for n in counts])
    axes.minorticks_off()
    axes.set_xlabel("number of particles N")
    axes.set_ylabel("sd of the log-likelihood estimate")
    runs = int(spread["runs"].max())
    datasets = int(spread["datasets"].max())
    axes.set_title(f"{result.manifest.get('name', '')}: spread of the log-likelihood estimate\n"
                   f"({runs} runs on {datasets} dataset{'s' if datasets > 1 else ''} per point; "
                   "bars: 95% interval)", fontsize=11)
    axes.grid(alpha=0.3, which="both")
    axes.legend(fontsize=8)
    return figure
