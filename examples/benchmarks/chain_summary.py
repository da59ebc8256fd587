r"""Posterior means, sds and ArviZ's Monte Carlo standard errors of chains written by
``pmmh_particles_reference.py --chain-out``: the numbers the estimation-sv benchmark compares
pfx's PMMH with (docs/benchmarks/estimation-sv.md).

pfx never imports this script. It runs with pfx's own environment (it needs numpy, pandas and
arviz-stats, which pfx's posterior.csv uses for the same diagnostics), from the repository root:

    .venv/bin/python examples/benchmarks/chain_summary.py CHAIN.csv [CHAIN.csv ...]

Each file is one chain after its burn-in, one column per parameter (and an ``iteration``
column); several files are several independent chains, cut to the shortest. For each parameter
it prints, as JSON, the pooled mean and sd and ArviZ's diagnostics on the (chain, draw) array:
the Monte Carlo standard error of the mean (``mcse_mean``), the bulk effective sample size and,
with two chains or more, the rank-normalised split R-hat (Vehtari et al. 2021).
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pandas as pd
from arviz_stats.base import array_stats


def summarise(frames: list[pd.DataFrame]) -> dict:
    """Per parameter: n, mean, sd, mcse_mean, ess_bulk (and r_hat with two chains or more)."""
    length = min(len(frame) for frame in frames)
    names = [name for name in frames[0].columns if name != "iteration"]
    options = {"chain_axis": 0, "draw_axis": 1}
    summary = {}
    for name in names:
        draws = np.stack([frame[name].to_numpy(dtype=float)[:length] for frame in frames])
        row = {"n": int(draws.size), "mean": round(float(draws.mean()), 5), "sd": round(float(draws.std(ddof=1)), 5),
               "mcse_mean": round(float(array_stats.mcse(draws, method="mean", **options)), 5),
               "ess_bulk": round(float(array_stats.ess(draws, method="bulk", **options)), 1)}
        if len(frames) > 1:
            row["r_hat"] = round(float(array_stats.rhat(draws, **options)), 4)
        summary[name] = row
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("chains", nargs="+", help="one CSV file per chain (pmmh_particles_reference.py --chain-out)")
    options = parser.parse_args()
    frames = [pd.read_csv(path) for path in options.chains]
    print(json.dumps({"chains": len(frames), "draws_per_chain": min(len(f) for f in frames),
                      "files": [path.rsplit("/", 1)[-1] for path in options.chains],
                      "parameters": summarise(frames)}, indent=1))


if __name__ == "__main__":
    main()
