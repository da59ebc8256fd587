"""``pfx compare --versus``: other estimates of the same trials (a smoother's error beside the
filter's) stacked as rows, so that the paired comparison compares them trial by trial within
each cell (:func:`pfx.analysis.compare.paired_comparison`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Iterable

if TYPE_CHECKING:
    import pandas as pd

VERSUS = "estimate"            # the label column of metrics compared with --versus


def metrics_as_rows(trials: pd.DataFrame, metric: str, versus: list[str],
                    label_columns: Iterable[str] = ()) -> pd.DataFrame:
    """trials.csv with ``metric`` and each ``versus`` column (another estimate of the same trial:
    a smoother's ``rmse_ffbs_position`` beside the filter's ``rmse_position``) stacked into the
    one column ``metric``, and a label column ``estimate`` naming which: so that
    :func:`paired_comparison` ``by="estimate"`` compares them trial by trial, within each cell.

    A cell (a combination of ``label_columns``) whose ``versus`` column is empty on every trial
    has no such estimate (an arm without that smoother): its rows for that column are left out,
    so the comparison has no row for it rather than a row of 0 pairs."""
    import pandas as pd

    cells = [column for column in label_columns if column in trials]
    frames = []
    for column in dict.fromkeys([metric, *versus]):
        frame = trials.drop(columns=[c for c in (metric, *versus) if c in trials]).copy()
        frame[VERSUS] = column
        frame[metric] = trials[column].to_numpy()
        if column != metric:
            present = trials[column].notna()
            has_estimate = present.groupby([trials[c] for c in cells], dropna=False).transform("any") if cells \
                else pd.Series(present.any(), index=trials.index)
            frame = frame[has_estimate.to_numpy()]
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)
