"""One recorded-data file, read and checked on its own: the CSV format every ``data:`` file shares.

A data file is CSV text in UTF-8 with a header row. Its first column is ``step`` (the integers
1..T, in order, no gap and no repeat) or ``time`` (strictly increasing numbers, whose
differences are finite); then one column per component, each named once, in any order. Every
cell is a finite number. A file that takes missing values (the measurements) may leave a row
entirely blank after its first column; a row with some cells blank and others not is refused,
and a file that takes none (truth, controls, covariates) refuses any blank cell. Empty lines,
and blank ones before the header, are skipped.

:func:`read_table` reads one file into a :class:`DataTable`; :func:`check_alignment` checks that
a truth or controls file has the measurements' first column, row for row; :func:`time_spacing`
finds the common spacing of regular times. What each file's columns must be named, and what
its values fill in, depends on the config's models: that is :mod:`pfx.config.data`'s part
(and :mod:`pfx.config.covariate_files`'). This module knows no model.

**Bad data** is a :class:`~pfx.errors.ConfigError`: one line naming the data file, its line
(the header is line 1) and the column. A path that names no regular file (a folder, a pipe,
``/dev/zero``) or a file over :data:`MAX_FILE_BYTES` is refused, naming the config's key
(``data.measurements``, ...), without being read (:func:`pfx.user_files.read_user_file`).
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from pfx.errors import ConfigError
from pfx.models.time_axis import time_slack
from pfx.user_files import UnreadableFile, read_user_file

MAX_FILE_BYTES = 100 * 1024 * 1024
INDEX_COLUMNS = ("step", "time")


@dataclass
class DataTable:
    """One data file, read and checked on its own."""

    file: str                      # the path as shown in messages (relative to the working directory)
    index_name: str                # "step" or "time"
    index: np.ndarray              # (T,) the first column
    columns: list[str]             # the other columns' names
    values: np.ndarray             # (T, columns) NaN where a cell is blank
    lines: list[int]               # the file line of each row (the header is line 1)
    header_line: int

    def column_error(self, reason: str, column: Optional[str] = None, line: Optional[int] = None) -> ConfigError:
        return ConfigError(reason, file=self.file, line=line or self.header_line,
                           key=f"column {column}" if column else None)



def display_path(given: str, config_file: Optional[str]) -> tuple[str, Path]:
    """(the path as messages show it, the path to open): relative to the config's folder."""
    path = Path(given).expanduser()
    if not path.is_absolute() and config_file:
        path = Path(config_file).parent / path
    return os.path.normpath(str(path)), path


def _number(text: str, table_file: str, line: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"{text!r} is not a number (leave a missing value blank)", file=table_file,
                          line=line, key=f"column {column}") from None
    if not math.isfinite(value):
        raise ConfigError(f"{text!r} is not a finite number (leave a missing value blank)", file=table_file,
                          line=line, key=f"column {column}")
    return value


def read_table(given: str, *, config_file: Optional[str], key: str, blanks: bool) -> DataTable:
    """Read one data file (see the module docstring); ``blanks``: whether blank rows are allowed
    (missing measurements). ``key`` (``data.measurements``, ...) locates a file that cannot be read."""
    shown, path = display_path(given, config_file)
    try:
        text = read_user_file(path, MAX_FILE_BYTES).decode("utf-8-sig")
    except UnreadableFile as error:
        reason = f"no such file: {shown}" if error.missing else f"{shown} {error.reason}"
        raise ConfigError(reason, file=config_file, key=key) from None
    except UnicodeDecodeError:
        raise ConfigError("not a UTF-8 text file", file=shown) from None

    reader = csv.reader(io.StringIO(text, newline=""))
    header, header_line, rows, lines = None, 0, [], []
    try:
        for row in reader:
            if not row or all(not cell.strip() for cell in row) and header is None:
                continue                       # blank lines before the header, or empty lines
            if header is None:
                header, header_line = [cell.strip() for cell in row], reader.line_num
            else:
                rows.append(row)
                lines.append(reader.line_num)
    except csv.Error as error:
        raise ConfigError(f"not a valid CSV file: {error}", file=shown, line=reader.line_num) from None
    if header is None:
        raise ConfigError("the file is empty: it needs a header row (step or time, then one column per "
                          "component) and one row per step", file=shown)
    if header[0] not in INDEX_COLUMNS:
        raise ConfigError(f"the first column must be `step` or `time`, not {header[0]!r}", file=shown,
                          line=header_line, key="column 1")
    for position, name in enumerate(header):
        if not name:
            raise ConfigError("a column without a name", file=shown, line=header_line, key=f"column {position + 1}")
        if header.index(name) != position:
            raise ConfigError("appears twice in the header", file=shown, line=header_line, key=f"column {name}")
    if len(header) < 2:
        raise ConfigError(f"no column after `{header[0]}`: give one column per component", file=shown,
                          line=header_line)
    if not rows:
        raise ConfigError("the file has a header but no rows: give one row per step", file=shown, line=header_line)

    columns = header[1:]
    index = np.empty(len(rows))
    values = np.full((len(rows), len(columns)), np.nan)
    for r, (row, line) in enumerate(zip(rows, lines)):
        if len(row) != len(header):
            raise ConfigError(f"{len(row)} cells, the header has {len(header)} columns", file=shown, line=line)
        first = row[0].strip()
        if not first:
            raise ConfigError(f"the {header[0]} is blank", file=shown, line=line, key=f"column {header[0]}")
        index[r] = _number(first, shown, line, header[0])
        blank = [not cell.strip() for cell in row[1:]]
        if any(blank) and not blanks:
            name = columns[blank.index(True)]
            raise ConfigError(f"a blank cell: this file ({key}) takes no missing values", file=shown, line=line,
                              key=f"column {name}")
        if any(blank) and not all(blank):
            name = columns[blank.index(True)]
            raise ConfigError("a partly blank measurement: a row is either complete or entirely blank (a "
                              "missing measurement); partial rows are not supported", file=shown, line=line,
                              key=f"column {name}")
        for c, cell in enumerate(row[1:]):
            if not blank[c]:
                values[r, c] = _number(cell.strip(), shown, line, columns[c])
    table = DataTable(file=shown, index_name=header[0], index=index, columns=columns, values=values,
                      lines=lines, header_line=header_line)
    _check_index(table)
    return table


def _check_index(table: DataTable) -> None:
    """Steps 1..T in order (no gap, no repeat), or strictly increasing times."""
    index, lines, name = table.index, table.lines, table.index_name
    if name == "step":
        for r, value in enumerate(index):
            if value != int(value):
                raise ConfigError(f"step {value:g} is not a whole number", file=table.file, line=lines[r],
                                  key="column step")
            expected = r + 1
            if value == expected:
                continue
            if r and value == index[r - 1]:
                reason = f"step {int(value)} appears twice (lines {lines[r - 1]} and {lines[r]})"
            elif value > expected:
                reason = (f"step {expected} is missing (this row has step {int(value)}): give one row per step, "
                          "blank for a missing measurement")
            else:
                reason = f"steps must run 1, 2, ..., T in order; this row has step {int(value)}, expected {expected}"
            raise ConfigError(reason, file=table.file, line=lines[r], key="column step")
        return
    for r in range(1, len(index)):
        if index[r] == index[r - 1]:
            raise ConfigError(f"time {index[r]:g} appears twice (lines {lines[r - 1]} and {lines[r]})",
                              file=table.file, line=lines[r], key="column time")
        if index[r] < index[r - 1]:
            raise ConfigError(f"times must increase: {index[r]:g} comes after {index[r - 1]:g}",
                              file=table.file, line=lines[r], key="column time")
        # The spacing of the times is their differences: one that overflows (finite times near
        # the largest float, 1.7e308, of both signs) would become an infinite dt downstream.
        if not math.isfinite(float(index[r]) - float(index[r - 1])):
            raise ConfigError(f"the time since the previous row ({index[r]:g} - {index[r - 1]:g}) is too large "
                              "to be represented as a number: use smaller times (e.g. measured from the first)",
                              file=table.file, line=lines[r], key="column time")


def check_alignment(table: DataTable, measurements: DataTable) -> None:
    """A truth or controls file has the measurements' first column, row for row."""
    if table.index_name != measurements.index_name:
        raise ConfigError(f"the first column is `{table.index_name}`, the measurements' ({measurements.file}) "
                          f"`{measurements.index_name}`: use the same", file=table.file, line=table.header_line,
                          key="column 1")
    name = table.index_name
    for r in range(min(len(table.index), len(measurements.index))):
        if table.index[r] != measurements.index[r]:
            raise ConfigError(f"{name} {table.index[r]:g} differs from the measurements' {name} "
                              f"{measurements.index[r]:g} (line {measurements.lines[r]} of {measurements.file})",
                              file=table.file, line=table.lines[r], key=f"column {name}")
    if len(table.index) > len(measurements.index):
        r = len(measurements.index)
        raise ConfigError(f"{len(table.index)} rows, the measurements ({measurements.file}) {len(measurements.index)}: "
                          f"{name} {table.index[r]:g} has no measurement row", file=table.file, line=table.lines[r],
                          key=f"column {name}")
    if len(table.index) < len(measurements.index):
        r = len(table.index)
        raise ConfigError(f"{len(table.index)} rows, the measurements ({measurements.file}) {len(measurements.index)}: "
                          f"the file ends before {name} {measurements.index[r]:g}", file=table.file,
                          line=table.lines[-1], key=f"column {name}")


def time_spacing(times: np.ndarray) -> tuple[Optional[float], Optional[int]]:
    """(the common spacing of regular times, None) or (None, the first row whose spacing differs)."""
    if len(times) < 2:
        return None, None
    gaps = np.diff(times)
    irregular = np.abs(gaps - gaps[0]) > time_slack(times)
    if irregular.any():
        return None, int(np.argmax(irregular)) + 2        # the row at the end of the first odd gap
    return float(gaps[0]), None
