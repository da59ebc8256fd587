"""Paired comparisons between arms (or the values of any label column), trial by trial.

``pfx compare RESULT_DIR --metric M --by FIELD [--baseline VALUE]`` reads ``trials.csv`` and
compares every value of the column ``FIELD`` (default ``arm``) with a baseline value. It
prints the table on stdout and writes it atomically (:func:`pfx.result_folder.write_csv`) to
``RESULT_DIR/compare_<M>_by_<FIELD>.csv``, named on stderr. Options: ``--baseline VALUE``,
``--higher-is-better``, ``--bootstrap B`` (B >= 100), ``--versus COLUMN`` (other metric columns of
the same trials compared with M within each cell, a smoother's error beside the filter's: the
rows are stacked by :func:`metrics_as_rows` under a label column ``estimate``, compared
``--by estimate`` with M as the baseline, and written to ``compare_<M>_versus_<COLUMNS>.csv``).

**Pairing.** Trial t of every cell sees the same true trajectory and measurements (the truth
stream depends only on the root seed and t), so the metric of trial t under value v and under
the baseline form a pair, and the difference removes the trial-to-trial variation of the truth
(common random numbers). Pairs are matched on ``trial`` and on the *grouping columns*: every
label column of the manifest except ``FIELD`` itself, ``cell``, columns with one value in the
whole table (nothing to match) and columns that are a function of ``FIELD`` (each value of
``FIELD`` has one value of them: ``n_particles`` when arm ``small`` sets 5 particles and arm
``big`` 50 is part of what the arms differ in, not something to match). So a sweep over
particle counts yields one comparison per particle count. A grouping column that is empty in
every row of one side (the particle count of a Kalman filter) is a setting that side does not
use: that side's trial t is paired with trial t of every group of the other side (a KF
baseline against the particle filter at each swept particle count); rows that no label tells
apart (the KF cells of such a sweep: same labels, same trial) count once, the first in the
table. Each value of ``FIELD`` other than the baseline (default: the first value of ``FIELD``
in the table's order, i.e. the first arm of the config) is compared with the baseline, in
each group holding both; rows come value by value, groups in the table's order.

**One row per (group, value)**, columns: the grouping columns, ``FIELD`` (the compared value),
``baseline`` (the baseline value), ``metric``, ``n_pairs``, ``excluded_pairs``,
``baseline_mean`` and ``mean`` (the metric's mean over the *used* pairs, so that
``mean - baseline_mean == mean_difference``), ``mean_difference`` (value - baseline, mean over
pairs), ``relative_change`` (``mean_difference / |baseline_mean|``, a fraction; empty when the
baseline mean is 0), ``ci95_low``, ``ci95_high``, ``ci_method``, ``p_value``, ``better``,
``wins``, ``losses``, ``ties``.

**The statistics** of each row's pairs (which pairs are excluded, the interval, the p-value,
the wins, the sign of the relative change) are :func:`pfx.analysis.paired_statistics.statistics_of_pairs`';
:mod:`pfx.analysis.paired_statistics` describes them. ``--higher-is-better`` changes only ``better``
and the wins and losses; ``--bootstrap B`` (B >= 100) a percentile-bootstrap interval instead of the
t-interval, from the fixed seed :data:`~pfx.analysis.paired_statistics.BOOTSTRAP_SEED`. Besides the
pairs with a missing or infinite value, ``excluded_pairs`` counts any trial present on one side only.

``paired_comparison`` is pure (a DataFrame in, a DataFrame out) and raises
:class:`~pfx.errors.ConfigError` for the user's mistakes (unknown metric or column, unknown
baseline, a column with one value, no pairs); ``format_table`` renders the result as plain
aligned text (readable in CI logs; an empty label shows as ``(empty)``, a missing number as ``-``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Iterable, Optional

import numpy as np

from pfx.analysis.compare_versus import VERSUS, metrics_as_rows
from pfx.analysis.paired_statistics import BOOTSTRAP_SEED, statistics_of_pairs
from pfx.analysis.summary import NON_METRIC_COLUMNS
from pfx.errors import ConfigError
from pfx.registry import closest_name

if TYPE_CHECKING:          # pandas is imported where a table is read
    import pandas as pd

MISSING_LABEL = "(empty)"           # an empty label field in the printed table (a Kalman filter's particle count)
RESULT_COLUMNS = ("baseline", "metric", "n_pairs", "excluded_pairs", "baseline_mean", "mean",
                  "mean_difference", "relative_change", "ci95_low", "ci95_high", "ci_method", "p_value",
                  "better", "wins", "losses", "ties")


def metric_columns(trials: pd.DataFrame, label_columns: Iterable[str]) -> list[str]:
    """The columns of trials.csv that ``--metric`` may name: numeric or boolean, not labels."""
    import pandas as pd

    labels = set(label_columns) | {"cell"}
    return [c for c in trials.columns if c not in NON_METRIC_COLUMNS and c not in labels
            and (pd.api.types.is_numeric_dtype(trials[c]) or pd.api.types.is_bool_dtype(trials[c]))]


def output_name(metric: str, by: str, versus: Iterable[str] = ()) -> str:
    """The file the command writes into the result folder."""
    versus = list(versus)
    if versus:
        return f"compare_{metric}_versus_{'_'.join(versus)}.csv"
    return f"compare_{metric}_by_{by}.csv"


def paired_comparison(trials: pd.DataFrame, metric: str, by: str = "arm", baseline: Optional[str] = None,
                      label_columns: Optional[list[str]] = None, *, higher_is_better: bool = False,
                      bootstrap: Optional[int] = None, bootstrap_seed: int = BOOTSTRAP_SEED,
                      versus: Iterable[str] = ()) -> pd.DataFrame:
    """Compare each value of ``by`` with ``baseline`` on ``metric``, pairing trials (module docstring).

    ``label_columns`` are the manifest's (default: ``[by]``); ``baseline`` may be given as
    text (``"50"`` names the ``n_particles`` value 50); ``bootstrap`` = B resamples for a
    percentile-bootstrap interval instead of the t-interval. ``versus`` names other columns of
    the same trials to compare ``metric`` with (a smoother's error beside the filter's): the
    comparison is then ``by="estimate"`` over :func:`metrics_as_rows`, ``metric`` the baseline.
    """
    import pandas as pd

    if trials.empty:
        raise ConfigError("trials.csv has no rows", key="--metric")
    versus = list(versus)
    if versus:
        if by != "arm":
            raise ConfigError("--by and --versus cannot be combined: --versus compares columns of the "
                              "same trials, within each cell", key="--by")
        _check_metric(trials, metric, list(label_columns or []))
        for column in versus:
            _check_metric(trials, column, list(label_columns or []), key="--versus")
        trials = metrics_as_rows(trials, metric, versus, label_columns or [])
        by, baseline = VERSUS, metric if baseline is None else baseline
        label_columns = [*(label_columns or []), VERSUS]
    label_columns = list(label_columns) if label_columns is not None else [by]
    if by not in label_columns:
        label_columns.append(by)
    _check_metric(trials, metric, label_columns)
    _check_by(trials, by, label_columns)
    values = _unique(trials[by])
    if len(values) < 2:
        raise ConfigError(_single_value_message(trials, by, values[0], label_columns), key="--by")
    base = values[0] if baseline is None else _find_value(values, baseline, by)
    groups = grouping_columns(trials, by, label_columns)
    if bootstrap is not None and bootstrap < 1:
        raise ConfigError("the number of bootstrap resamples must be at least 1", key="--bootstrap")

    keys = groups + [by, "trial"]
    frame = trials[keys].copy()
    frame["_value"] = trials[metric].to_numpy(dtype=float)
    frame["_order"] = np.arange(len(frame))
    frame = frame.drop_duplicates(keys, keep="first")     # cells told apart only by settings their filter ignores
    reference = frame[_matches(frame[by], base)]
    reference_unused = _unused(reference, groups)
    rows = []
    for value in values:
        if _same(value, base):
            continue
        other = frame[_matches(frame[by], value)]
        other_unused = _unused(other, groups)
        matched = [c for c in groups if c not in reference_unused and c not in other_unused] + ["trial"]
        merged = reference[[c for c in groups if c not in reference_unused] + ["trial", "_value", "_order"]].merge(
            other[[c for c in groups if c not in other_unused] + ["trial", "_value", "_order"]],
            on=matched, how="outer", suffixes=("_base", "_other"), indicator=True)
        for column in groups:
            if column not in merged:                  # empty on both sides
                merged[column] = np.nan
        merged = merged.assign(_first=merged[["_order_base", "_order_other"]].min(axis=1))
        merged = merged.sort_values("_first", kind="stable")      # groups in the table's order
        for group_key, group in (merged.groupby(groups, sort=False, dropna=False) if groups else [((), merged)]):
            if not (group["_merge"] == "both").any():
                continue                              # the baseline or the value is absent from this group
            group_key = group_key if isinstance(group_key, tuple) else (group_key,)
            row: dict[str, Any] = dict(zip(groups, group_key))
            row[by] = value
            row.update(statistics_of_pairs(group["_value_base"].to_numpy(dtype=float),
                                           group["_value_other"].to_numpy(dtype=float),
                                           higher_is_better, bootstrap, bootstrap_seed))
            row["baseline"] = base
            row["metric"] = metric
            rows.append(row)
    if not rows or sum(row["n_pairs"] for row in rows) == 0:
        reason = ("no trial has a finite value of the metric in both the baseline and another value"
                  if rows else f"no group of trials holds both the baseline {_text(base)!r} and another value "
                               f"of {by!r} (pairs are matched on trial"
                               + (f" and {', '.join(groups)})" if groups else ")"))
        raise ConfigError(f"no pairs to compare on {metric!r}: {reason}", key="--metric" if rows else "--by")
    return pd.DataFrame(rows, columns=groups + [by] + list(RESULT_COLUMNS))


def _single_value_message(trials: pd.DataFrame, by: str, value, label_columns: list[str]) -> str:
    """Why nothing can be compared by ``by``, and which label columns could be (one line).

    A run without arms has the single arm 'default', so the default ``--by arm`` compares
    nothing; the swept columns are what the user most likely wants instead.
    """
    varying = [c for c in label_columns if c not in (by, "cell", "trial") and c in trials
               and trials[c].nunique(dropna=False) > 1]
    message = f"column {by!r} has a single value ({_text(value)!r}) in trials.csv: nothing to compare"
    if varying:
        return message + f"; label columns that vary: {', '.join(varying)} (try --by {varying[0]})"
    return message + "; no label column varies (one cell only)"


def _unused(side: pd.DataFrame, groups: list[str]) -> list[str]:
    """Grouping columns empty in every row of one side: settings its filter does not use."""
    return [c for c in groups if side[c].isna().all()]


def grouping_columns(trials: pd.DataFrame, by: str, label_columns: Iterable[str]) -> list[str]:
    """The label columns pairs are matched on, besides ``trial`` (see the module docstring)."""
    columns = []
    for column in label_columns:
        if column in (by, "cell", "trial") or column not in trials:
            continue
        if trials[column].nunique(dropna=False) <= 1:
            continue                                  # one value everywhere: nothing to match
        per_value = trials.groupby(by, sort=False, dropna=False)[column].nunique(dropna=False)
        if (per_value <= 1).all():
            continue                                  # a function of `by`: part of what is compared
        columns.append(column)
    return columns


def _check_metric(trials: pd.DataFrame, metric: str, label_columns: list[str], key: str = "--metric") -> None:
    metrics = metric_columns(trials, label_columns)
    if metric in metrics:
        return
    if metric in trials.columns:
        raise ConfigError(f"column {metric!r} of trials.csv is not a metric (choose from {', '.join(metrics)})",
                          key=key)
    hint = closest_name(metric, metrics)
    raise ConfigError(f"no metric {metric!r} in trials.csv"
                      + (f" (did you mean {hint!r}?)" if hint else f"; choose from {', '.join(metrics)}"),
                      key=key)


def _check_by(trials: pd.DataFrame, by: str, label_columns: list[str]) -> None:
    if "trial" not in trials.columns:
        raise ConfigError("trials.csv has no 'trial' column", key="--by")
    candidates = [c for c in label_columns if c in trials.columns and c != "cell"]
    if by in candidates:
        return
    hint = closest_name(by, candidates)
    raise ConfigError(f"no label column {by!r} in trials.csv"
                      + (f" (did you mean {hint!r}?)" if hint else "")
                      + f"; choose from {', '.join(candidates)}", key="--by")


def _unique(column: pd.Series) -> list:
    """The column's values in order of first appearance (a missing value counts once)."""
    import pandas as pd

    return list(pd.unique(column))


def _is_missing(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def _same(a, b) -> bool:
    return (_is_missing(a) and _is_missing(b)) or (not _is_missing(a) and not _is_missing(b) and a == b)


def _matches(column: pd.Series, value) -> pd.Series:
    return column.isna() if _is_missing(value) else column == value


def _text(value) -> str:
    """A value as text, as it reads in trials.csv ('' for a missing one)."""
    if _is_missing(value):
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (np.integer, np.floating)):
        value = value.item()
    return str(value)


def _find_value(values: list, baseline: str, by: str):
    """The value of ``by`` that ``--baseline`` names: same text, or the same number."""
    for value in values:
        if _text(value) == str(baseline):
            return value
    try:
        number = float(baseline)
    except (TypeError, ValueError):
        number = None
    if number is not None:
        for value in values:
            if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)) \
                    and not _is_missing(value) and float(value) == number:
                return value
    names = [_text(v) for v in values]
    hint = closest_name(str(baseline), names)
    raise ConfigError(f"column {by!r} has no value {baseline!r}"
                      + (f" (did you mean {hint!r}?)" if hint else "")
                      + f"; values: {', '.join(names)}", key="--baseline")


# -- the printed table ------------------------------------------------------------------------

def _number(value, digits: int = 4) -> str:
    if _is_missing(value):
        return "-"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return f"{float(value):.{digits}g}"


def _percent(value) -> str:
    if _is_missing(value) or not np.isfinite(value):
        return "-"
    percent = 100 * float(value)
    return f"{percent:+.1f}%" if abs(percent) < 1e5 else f"{percent:+.3g}%"


def _label_texts(column: pd.Series) -> list[str]:
    """A label column as text; a float column of whole numbers (particle counts beside empty
    fields) without the '.0'; an empty field as (empty)."""
    values = column.tolist()
    present = [v for v in values if not _is_missing(v)]
    whole = bool(present) and all(isinstance(v, float) and v.is_integer() for v in present)
    return [MISSING_LABEL if _is_missing(v) else str(int(v)) if whole else _text(v) for v in values]


def format_table(result: pd.DataFrame, by: str) -> str:
    """The comparison as plain aligned text: a heading line, then one line per row."""
    groups = list(result.columns[:list(result.columns).index(by)])
    first = result.iloc[0]
    method = first["ci_method"]
    interval = ("95% t-interval" if method == "t"
                else f"95% percentile bootstrap ({method.split('-', 1)[1]} resamples, seed {BOOTSTRAP_SEED})")
    heading = (f"{first['metric']}: {by} vs baseline {_label_texts(result['baseline'])[0]!r}, paired by trial"
               + (f" within {', '.join(groups)}" if groups else "")
               + f"; difference = value - baseline; {interval}; paired t-test p; "
               + f"win = {first['better']} {first['metric']} than the baseline")
    header = groups + [by, "pairs", "excluded", "baseline_mean", "mean", "difference", "relative",
                       "ci95_low", "ci95_high", "p_value", "wins", "losses", "ties"]
    labels = {c: _label_texts(result[c]) for c in groups + [by]}
    lines = []
    for index, (_, row) in enumerate(result.iterrows()):
        lines.append([labels[c][index] for c in groups + [by]]
                     + [_number(row["n_pairs"]), _number(row["excluded_pairs"]), _number(row["baseline_mean"]),
                        _number(row["mean"]), _number(row["mean_difference"]), _percent(row["relative_change"]),
                        _number(row["ci95_low"]), _number(row["ci95_high"]), _number(row["p_value"], 3),
                        _number(row["wins"]), _number(row["losses"]), _number(row["ties"])])
    left = len(groups) + 1                            # labels left-aligned, numbers right-aligned
    widths = [max(len(header[i]), *(len(line[i]) for line in lines)) for i in range(len(header))]

    def render(cells: list[str]) -> str:
        return "  ".join(cell.ljust(widths[i]) if i < left else cell.rjust(widths[i])
                         for i, cell in enumerate(cells)).rstrip()

    return "\n".join([heading, render(header)] + [render(line) for line in lines])
