r"""How far a filter's estimates are from a reference filter's: the particle filter against the grid.

On a low-dimensional model the histogram (grid) filter (:mod:`pfx.filters.histogram`) computes
the posterior mean :math:`E[x_k \mid z_{1:k}]` to near machine precision, so the *gap*
:math:`\lVert \hat x^{N}_k - E[x_k \mid z_{1:k}] \rVert` between a particle filter's estimate
and the grid's measures the particle filter's own approximation error, free of the
irreducible error against the truth that every filter shares. Arms of one experiment see the
same truth and measurements trial by trial, so the gap is computed pair by pair from
``steps.csv`` (both cells' ``estimate_<state>`` columns, matched on trial and step).

**Theory.** For fixed data, the particle estimate of a posterior mean obeys a central limit
theorem, :math:`\sqrt N(\hat x^N_k - E[x_k \mid z_{1:k}]) \to N(0, V_k)` (Del Moral 2004;
Chopin 2004), so the root-mean-square gap of a trial over its steps,

.. math:: G_N = \Big(\frac1T \sum_{k=1}^T \lVert \hat x^N_k - E[x_k \mid z_{1:k}] \rVert^2\Big)^{1/2},

falls like :math:`N^{-1/2}`: :math:`\log G_N = c - \tfrac12 \log N` plus noise whose law does
not depend on N. The slope of :math:`\log G_N` against :math:`\log N`, fitted per trial by
least squares over the particle counts, is then an unbiased estimate of -1/2 in the
asymptotic regime; trials are independent, so the mean slope gets a t-interval
(:func:`pfx.analysis.summary.describe`). Trials whose posterior has a mode the particles miss at small
N (a rare measurement far in the prediction's tail) reach that regime later: their gaps make
the mean square heavy-tailed, which is why the per-trial log-log slope, not the slope of the
pooled root-mean-square, carries the interval.

The reference is the one cell whose filter kind is ``histogram``; every other cell is
compared with it. A *series* is a set of cells that differ only in their particle count
(and arm name): the label columns other than ``cell``, ``arm`` and ``n_particles`` agree.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pfx.analysis.summary import describe

REFERENCE_FILTER = "histogram"
UNSERIES_COLUMNS = {"cell", "arm", "n_particles"}


def series_columns(label_columns: list[str]) -> list[str]:
    """The label columns that define a series (all but cell, arm and particle count)."""
    return [c for c in label_columns if c not in UNSERIES_COLUMNS]


def step_gaps(steps: pd.DataFrame, label_columns: list[str]) -> pd.DataFrame:
    """One row per (compared cell, trial, step): its labels and ``gap`` to the reference's estimate."""
    estimates = [c for c in steps.columns if c.startswith("estimate_")]
    is_reference = steps["filter"] == REFERENCE_FILTER
    reference_cells = steps.loc[is_reference, "cell"].unique()
    if len(reference_cells) != 1:
        raise ValueError(f"steps.csv must hold exactly one {REFERENCE_FILTER!r} cell as the reference; "
                         f"found {len(reference_cells)}")
    reference = steps.loc[is_reference, ["trial", "step", *estimates]]
    joined = steps[~is_reference].merge(reference, on=["trial", "step"], suffixes=("", "_reference"))
    difference = joined[estimates].to_numpy(dtype=float) - joined[[f"{c}_reference" for c in estimates]].to_numpy(
        dtype=float)
    labels = ["cell"] + [c for c in label_columns if c != "cell" and c in joined]
    return joined[labels + ["trial", "step"]].assign(gap=np.sqrt(np.sum(difference ** 2, axis=1)))


def trial_gaps(steps: pd.DataFrame, label_columns: list[str]) -> pd.DataFrame:
    """One row per (compared cell, trial): ``rms_gap`` G_N over the trial's traced steps."""
    gaps = step_gaps(steps, label_columns)
    keys = [c for c in gaps.columns if c not in ("step", "gap")]
    squares = gaps.assign(square=gaps["gap"] ** 2)
    grouped = squares.groupby(keys, sort=False, dropna=False)["square"]
    out = grouped.mean().rename("mean_square_gap").reset_index()
    out["rms_gap"] = np.sqrt(out["mean_square_gap"])
    out["steps"] = grouped.size().to_numpy()
    return out


def gap_table(per_trial: pd.DataFrame) -> pd.DataFrame:
    """Per compared cell: trials, pooled RMS gap sqrt(mean of G_N^2), median and geometric mean of G_N."""
    rows = []
    for cell, group in per_trial.groupby("cell", sort=False):
        gaps = group["rms_gap"].to_numpy(dtype=float)
        positive = gaps[gaps > 0]
        rows.append({**{c: group[c].iloc[0] for c in group.columns
                        if c not in ("trial", "mean_square_gap", "rms_gap", "steps")},
                     "trials": len(gaps), "rms_gap": float(np.sqrt(np.mean(gaps ** 2))),
                     "median_rms_gap": float(np.median(gaps)),
                     "geometric_mean_rms_gap": float(np.exp(np.mean(np.log(positive)))) if positive.size else np.nan})
    return pd.DataFrame(rows)


def trial_slopes(per_trial: pd.DataFrame, label_columns: list[str]) -> pd.DataFrame:
    """Per (series, trial): the least-squares slope of log G_N against log N."""
    series = [c for c in series_columns(label_columns) if c in per_trial]
    rows = []
    for key, group in per_trial.groupby(series + ["trial"], sort=False, dropna=False):
        usable = group[(group["rms_gap"] > 0) & group["n_particles"].notna()]
        if usable["n_particles"].nunique() < 2:
            continue
        x = np.log(usable["n_particles"].to_numpy(dtype=float))
        y = np.log(usable["rms_gap"].to_numpy(dtype=float))
        slope = float(np.sum((x - x.mean()) * (y - y.mean())) / np.sum((x - x.mean()) ** 2))
        rows.append({**dict(zip(series + ["trial"], key)), "slope": slope})
    return pd.DataFrame(rows, columns=series + ["trial", "slope"])


def slope_summary(slopes: pd.DataFrame, label_columns: list[str]) -> pd.DataFrame:
    """Per series: the mean per-trial slope with its 95% t-interval (and n, sd, median)."""
    series = [c for c in series_columns(label_columns) if c in slopes]
    rows = []
    for key, group in (slopes.groupby(series, sort=False, dropna=False) if series else [((), slopes)]):
        key = key if isinstance(key, tuple) else (key,)
        rows.append({**dict(zip(series, key)), **describe(group["slope"].to_numpy(dtype=float))})
    return pd.DataFrame(rows)
