"""What ``pfx run`` prints when a run ends: a short table of its main metrics per cell, and the
command a user would want next.

Read from the finished folder's summary.csv (the same numbers a notebook would load): per
cell, the columns that tell cells apart, the trial count, and for each main metric the mean
with its 95% confidence interval. On a terminal the table is drawn by rich; elsewhere (CI, a
pipe, a log file) it is plain aligned text.
"""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import pandas as pd

# (summary.csv metric, heading, scale, unit suffix): the metrics a reader looks at first
MAIN_METRICS = (("rmse_position", "position RMSE", 1.0, ""),
                ("error_distance_final", "final error", 1.0, ""),
                ("converged", "converged", 100.0, "%"),
                ("log_likelihood", "log-likelihood", 1.0, ""))


def _number(value: float) -> str:
    if value is None or not math.isfinite(value):
        return "inf" if value is not None and value == math.inf else "-"
    return f"{value:.4g}"


def _cell_value(row: pd.Series, metric: str, scale: float, suffix: str) -> str:
    mean = row.get(f"{metric}_mean")
    if mean is None or pd.isna(mean):
        return "-"
    low, high = row.get(f"{metric}_ci95_low"), row.get(f"{metric}_ci95_high")
    text = f"{_number(scale * mean)}{suffix}"
    if suffix == "%":                  # a share: its t-interval says little; the share itself does
        return text
    if low is not None and not pd.isna(low):
        text += f" [{_number(scale * low)}, {_number(scale * high)}]"
    return text


def summary_rows(folder: Path, manifest: dict) -> tuple[list[str], list[list[str]]]:
    """The table: a header and one row of text per cell."""
    summary = pd.read_csv(folder / "summary.csv")
    label_columns = [c for c in manifest.get("legend_columns", []) if c in summary] or ["arm"]
    unit = manifest.get("units", {}).get("position", "")
    metrics = [(metric, heading + (f" [{unit}]" if unit and suffix == "" and metric != "log_likelihood" else ""),
                scale, suffix) for metric, heading, scale, suffix in MAIN_METRICS
               if f"{metric}_mean" in summary and summary[f"{metric}_mean"].notna().any()]
    header = [*label_columns, "trials", *(heading for _, heading, _, _ in metrics)]
    rows = [[str(row[c]) for c in label_columns] + [str(int(row["trials"]))]
            + [_cell_value(row, metric, scale, suffix) for metric, _, scale, suffix in metrics]
            for _, row in summary.iterrows()]
    return header, rows


def next_command(folder: Path, manifest: dict) -> str | None:
    """``pfx compare`` by the column that varies most naturally (the arm, else the first swept
    column), or None when the run has a single cell."""
    columns = manifest.get("legend_columns", [])
    if len(manifest.get("cells", [])) < 2 or not columns:
        return None
    metric = "rmse_position"
    return f"pfx compare {shlex.quote(str(folder))} --metric {metric} --by {columns[0]}"


def print_run_summary(folder: Path, manifest: dict, echo, rich_console: bool) -> None:
    """Print the table and the next command (``echo`` for plain text, rich on a terminal)."""
    header, rows = summary_rows(folder, manifest)
    title = f"{manifest.get('name', '')}: mean [95% CI] over trials, per cell"
    if rich_console:
        from rich.console import Console
        from rich.table import Table

        table = Table(title=title, title_justify="left")
        labels = header.index("trials")              # the label columns come first
        for index, heading in enumerate(header):
            table.add_column(heading, justify="left" if index < labels else "right")
        for row in rows:
            table.add_row(*row)
        Console().print(table)
    else:
        widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
        echo(title)
        for line in [header, *rows]:
            echo("  " + "  ".join(text.ljust(width) for text, width in zip(line, widths)).rstrip())
    command = next_command(folder, manifest)
    if command:
        columns = manifest.get("legend_columns", [])
        echo(f"next: {command}   (paired differences, trial by trial, with 95% intervals"
             + (f"; --by any of: {', '.join(columns)})" if len(columns) > 1 else ")"))
