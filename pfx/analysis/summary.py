"""summary.csv: per cell, the statistics of every metric over its trials.

Only finite values count (``n`` says how many): a never-converged trial has no convergence
step. The interval is the t-interval mean +- t_{0.975, n-1} * sem; empty when n < 2.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:          # pandas is imported where a table is read
    import pandas as pd

# trials.csv columns that are identifiers or settings, not metrics to summarise
NON_METRIC_COLUMNS = {"cell", "trial", "seed", "truth_seed", "filter_seed", "steps"}


def summarize(trials: pd.DataFrame, label_columns: list[str]) -> pd.DataFrame:
    """One row per cell: n, mean, std, sem, 95% t-interval and median of every metric.

    Only finite values count (``n`` says how many): a never-converged trial has no
    convergence step. The interval is mean +- t_{0.975, n-1} * sem; empty when n < 2.
    """
    import pandas as pd

    keys = ["cell"] + [c for c in label_columns if c != "cell"]
    metrics = [c for c in trials.columns if c not in NON_METRIC_COLUMNS and c not in keys
               and (pd.api.types.is_numeric_dtype(trials[c]) or pd.api.types.is_bool_dtype(trials[c]))]
    rows = []
    for _, group in trials.groupby("cell", sort=False):
        row = {key: group[key].iloc[0] for key in keys}
        row["trials"] = len(group)
        for metric in metrics:
            values = group[metric].to_numpy(dtype=float)
            values = values[np.isfinite(values)]
            row.update({f"{metric}_{name}": value for name, value in describe(values).items()})
        rows.append(row)
    return pd.DataFrame(rows)


def describe(values: np.ndarray) -> dict[str, float]:
    """n, mean, std, sem, 95% t-interval (mean +- t_{0.975, n-1} sem) and median of the values."""
    n = values.size
    result = {"n": n, "mean": np.nan, "std": np.nan, "sem": np.nan,
              "ci95_low": np.nan, "ci95_high": np.nan, "median": np.nan}
    if n == 0:
        return result
    result["mean"] = float(values.mean())
    result["median"] = float(np.median(values))
    if n >= 2:
        from scipy import stats

        with np.errstate(over="ignore", invalid="ignore"):   # a diverged filter: std is inf
            std = float(values.std(ddof=1))
        sem = std / np.sqrt(n)
        half = float(stats.t.ppf(0.975, n - 1)) * sem
        result.update(std=std, sem=sem, ci95_low=result["mean"] - half, ci95_high=result["mean"] + half)
    return result
