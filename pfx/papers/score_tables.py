r"""The real-data benchmarks' predictive check: the filters' proper scores, side by side.

On recorded data there is no truth to compute an error against; a filter is judged by its
one-step-ahead predictions (docs/scores.md). Each real-data benchmark (estimation-nile,
sv-gbp-usd, dacca-cholera) runs a ``scores`` experiment with ``metrics.scores: true``, and its
report gains, from :func:`score_part`:

* a table of every cell's mean CRPS and log score over its runs (each run's mean over the
  record's steps), with 95% t-intervals, and each cell's difference from a baseline cell, paired
  run by run (:func:`pfx.analysis.compare.paired_comparison`), with its interval;
* the PIT's calibration on the record: the Kolmogorov-Smirnov p-value of the first run's PITs
  against U(0, 1) (steps.csv). For the exact predictive law of a right model the PITs are iid
  uniform; a small p-value says the model's predictions of this record are miscalibrated, a
  finding about the model, not the filter;
* a verdict: every cell's scores agree with the baseline's. All the cells approximate the same
  predictive law (the same model, parameters and data), so they may differ only by Monte Carlo
  error and by the excess score a particle approximation pays, which is O(1/N): for the log
  score about c / (2N) nats with c = N sum w^2 of order 1 to 4 (docs/scores.md). A cell agrees
  when its paired difference's 95% interval reaches into :math:`\pm 2|\bar s_0| / N` around 0
  (:math:`\bar s_0` the baseline's mean score, N the smaller particle count of the two cells;
  for the Kalman filter, whose scores are exact, the particle cell's N).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from pfx.analysis.compare import paired_comparison
from pfx.analysis.summary import describe
from pfx.papers.base import (
    Figure,
    PaperResults,
    Part,
    Table,
    Verdict,
    format_number,
    interval,
    markdown_table,
    verdict_from_checks,
)

FIGURE_CAPTIONS = {
    "pit_histogram.png": "The PIT of each step's measurement under the filter's one-step-ahead predictive law (the "
                         "first run), with the uniform density and its 95% band per bar: a U shape is an "
                         "over-confident forecast, a hump an under-confident one.",
    "score_over_time.png": "The CRPS and the log score of each step's measurement, per cell (the mean over the traced "
                           "runs): where the model predicts the record worst.",
    "forecast_fan.png": "Forecasts from a few origins, 1 to 10 steps ahead: the quantile bands of the predicted "
                        "measurement (90% lightest, 50% darker, the median a line) over the record (points).",
}
EXCESS_FACTOR = 2.0          # the O(1/N) excess allowed: EXCESS_FACTOR |mean score| / N


def score_columns(trials: pd.DataFrame) -> list[str]:
    """trials.csv's score columns in table order: each component's CRPS, then the log score."""
    crps = [column for column in trials.columns if column.startswith("crps_")]
    return crps + (["log_score"] if "log_score" in trials else [])


def pit_p_value(steps: pd.DataFrame, cell: str) -> float:
    """The KS p-value against U(0, 1) of the first traced run's PITs (every component, every step
    with a value) of a cell; NaN without PITs."""
    rows = steps[steps["cell"] == cell]
    if rows.empty:
        return float("nan")
    first = rows[rows["trial"] == rows["trial"].min()]
    values = first[[column for column in first.columns if column.startswith("pit_")]].to_numpy(dtype=float).ravel()
    values = values[np.isfinite(values)]
    return float(stats.kstest(values, "uniform").pvalue) if values.size else float("nan")


def _particles(row: pd.Series) -> float:
    value = row.get("n_particles")
    return float(value) if value is not None and pd.notna(value) else float("nan")


def score_part(results: PaperResults, experiment: str, *, by: str, baseline: str, claim: str,
               cell_name=None) -> Part:
    """The score table, the PIT's calibration and the agreement verdict of one ``scores``
    experiment (module docstring); cells are told apart by the label ``by`` (and the particle
    count, when it varies), and compared with the cell whose ``by`` is ``baseline``."""
    if not results.has(experiment):
        return Part()
    folder = results.folder(experiment)
    trials, steps = folder.trials, folder.steps
    columns = score_columns(trials)
    if not columns:
        return Part()
    label_columns = folder.label_columns
    groups = [column for column in ("arm", "n_particles") if column in label_columns and trials[column].nunique() > 1]
    cell_name = cell_name or (lambda row: ", ".join(f"{row[c]:g}" if isinstance(row[c], float) else str(row[c])
                                                    for c in groups))
    comparisons = {column: paired_comparison(trials, column, by=by, baseline=baseline, label_columns=label_columns)
                   for column in columns}
    rows, checks, evidence = [], [], []
    for cell, group in trials.groupby("cell", sort=False):
        first = group.iloc[0]
        row = {"cell": cell_name(first), "runs": len(group)}
        for column in columns:
            numbers = describe(group[column].to_numpy(dtype=float))
            row[f"{column} mean [95% CI]"] = (f"{format_number(numbers['mean'], 5)} "
                                              f"{interval(numbers['ci95_low'], numbers['ci95_high'], number=lambda v: format_number(v, 5))}")
            difference = _difference(comparisons[column], first, by, groups)
            if difference is None:
                row[f"{column} − baseline"] = "(baseline)"
                continue
            base = comparisons[column]
            baseline_row = trials[trials["cell"] == _baseline_cell(trials, first, by, baseline, groups)]
            particles = np.nanmin([_particles(first), _particles(baseline_row.iloc[0]) if len(baseline_row) else np.nan])
            tolerance = EXCESS_FACTOR * abs(float(difference["baseline_mean"])) / particles
            agrees = difference["ci95_low"] <= tolerance and difference["ci95_high"] >= -tolerance
            checks.append(bool(agrees))
            row[f"{column} − baseline"] = (f"{format_number(difference['mean_difference'], 3)} "
                                           f"{interval(difference['ci95_low'], difference['ci95_high'])}")
            evidence.append(f"{cell_name(first)} {column}: {format_number(difference['mean_difference'], 3)} "
                            f"{interval(difference['ci95_low'], difference['ci95_high'])} (allowed ±"
                            f"{format_number(tolerance, 2)})")
            del base
        row["PIT: KS p (first run)"] = format_number(pit_p_value(steps, cell), 3)
        rows.append(row)
    table = Table(f"Predictive scores on the record ({experiment}: each run's mean over the steps; smaller is better)",
                  markdown_table(pd.DataFrame(rows)),
                  "CRPS in the measurement's unit, the log score −log p(z_k | z_1:k−1) in nats per step; 95% "
                  "t-intervals over the runs; the difference from the baseline paired run by run (pfx compare). "
                  "PIT: the Kolmogorov-Smirnov p-value of the first run's PITs against U(0, 1): a small one says "
                  "the model's predictions of this record are miscalibrated (docs/scores.md).")
    items = [table] + [Figure(experiment, name, caption) for name, caption in FIGURE_CAPTIONS.items()
                       if name in results.figures(experiment)]
    verdict = Verdict(claim, verdict_from_checks(checks),
                      "paired differences from the baseline (95% intervals) against the O(1/N) excess allowed, "
                      f"2|mean|/N: {'; '.join(evidence)}.")
    return Part(items, [verdict])


def _difference(comparison: pd.DataFrame, first: pd.Series, by: str, groups: list[str]):
    """The comparison row of the cell ``first`` (None for a baseline cell)."""
    matches = comparison[comparison[by].astype(str) == str(first[by])]
    for column in groups:
        if column != by and column in matches:
            matches = matches[matches[column].astype(str) == str(first[column])]
    return None if matches.empty else matches.iloc[0]


def _baseline_cell(trials: pd.DataFrame, first: pd.Series, by: str, baseline: str, groups: list[str]) -> str:
    """The key of the baseline cell that ``first``'s cell is paired with (same other labels)."""
    matches = trials[trials[by].astype(str) == str(baseline)]
    for column in groups:
        if column != by:
            same = matches[matches[column].astype(str) == str(first[column])]
            matches = same if not same.empty else matches
    return matches["cell"].iloc[0] if not matches.empty else ""
