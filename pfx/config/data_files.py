"""One recorded-data file, read and checked on its own: the CSV format every ``data:`` file shares.

A data file is CSV text in UTF-8 with a header row. Its first column is ``step`` (the integers
1..T, in order, no gap and no repeat) or ``time`` (strictly increasing numbers, whose
differences are finite, or ISO dates, YYYY-MM-DD: :func:`dates_to_model_time`); then one column
per component, each named once, in any order. Every
cell is a finite number. A file that takes missing values (the measurements) may leave a row
entirely blank after its first column; a row with some cells blank and others not is refused,
and a file that takes none (truth, controls, covariates) refuses any blank cell. Empty lines,
and blank ones before the header, are skipped.

:func:`read_table` reads one file into a :class:`DataTable`; :func:`check_alignment` checks that
a truth or controls file has the measurements' first column, row for row; :func:`time_spacing`
finds the common spacing of regular times. What each file's columns must be named, and what
its values fill in, depends on the config's models: that is :mod:`pfx.config.data`'s part
(and :mod:`pfx.config.covariate_files`'). This module knows no model, but for the time unit
that dates are counted in (:func:`dates_to_model_time`, given the model's class).

**Bad data** is a :class:`~pfx.errors.ConfigError`: one line naming the data file, its line
(the header is line 1) and the column. A path that names no regular file (a folder, a pipe,
``/dev/zero``) or a file over :data:`MAX_FILE_BYTES` is refused, naming the config's key
(``data.measurements``, ...), without being read (:func:`pfx.user_files.read_user_file`).
"""

from __future__ import annotations

import csv
import datetime
import io
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from pfx.config.time_units import time_unit
from pfx.errors import ConfigError
from pfx.models.time_axis import TimeAxis, time_slack
from pfx.user_files import UnreadableFile, read_user_file

MAX_FILE_BYTES = 100 * 1024 * 1024
INDEX_COLUMNS = ("step", "time")
ISO_DATE = re.compile(r"\d{4}-\d{2}-\d{2}")
# The time units a date converts to exactly (a model's ``time_unit``, lower case, without a
# plural s) -> that unit's count in one day. Months and years have no fixed length in days.
DAY_IN = {"s": 86_400.0, "sec": 86_400.0, "second": 86_400.0, "min": 1_440.0, "minute": 1_440.0,
          "h": 24.0, "hr": 24.0, "hour": 24.0, "d": 1.0, "day": 1.0, "w": 1 / 7, "wk": 1 / 7, "week": 1 / 7}


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
    # A time column of dates: the first, as written (the index holds day numbers until
    # dates_to_model_time counts them in the run's unit), and the line that says what they became.
    first_date: Optional[str] = None
    note: Optional[str] = None

    def time_text(self, value: float) -> str:
        """A value of the first column as the file wrote it: a number, or a date (a day number)."""
        if self.first_date is not None and value == int(value) and 1 <= value <= datetime.date.max.toordinal():
            return datetime.date.fromordinal(int(value)).isoformat()
        return f"{value:g}"

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
    dates = None                       # the first row's date, if the time column holds dates (day numbers)
    values = np.full((len(rows), len(columns)), np.nan)
    for r, (row, line) in enumerate(zip(rows, lines)):
        if len(row) != len(header):
            raise ConfigError(f"{len(row)} cells, the header has {len(header)} columns", file=shown, line=line)
        first = row[0].strip()
        if not first:
            raise ConfigError(f"the {header[0]} is blank", file=shown, line=line, key=f"column {header[0]}")
        if r == 0 and header[0] == "time" and ISO_DATE.fullmatch(first):
            _refuse_dates_in(key, shown, line)
            dates = first
        index[r] = _date(first, shown, line) if dates else _number(first, shown, line, header[0])
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
                      lines=lines, header_line=header_line, first_date=dates)
    _check_index(table)
    return table


def _date(text: str, table_file: str, line: int) -> float:
    """An ISO date (YYYY-MM-DD) as a day number (days since 1 January of year 1)."""
    try:
        if not ISO_DATE.fullmatch(text):
            raise ValueError(text)
        return float(datetime.date.fromisoformat(text).toordinal())
    except ValueError:
        raise ConfigError(f"{text!r} is not a date (YYYY-MM-DD), as the first row's time is", file=table_file,
                          line=line, key="column time") from None


def _refuse_dates_in(key: str, table_file: str, line: int) -> None:
    """Dates are read in the measurements and the files aligned with them, counted from the
    measurements' first date; a covariates file is read before them, on its own time axis."""
    if key == "data.covariates":
        raise ConfigError("dates are not read in a covariates file: give its times as numbers in the model's "
                          "time unit, counted from the measurements' first date (time 0)", file=table_file,
                          line=line, key="column time")


def dates_to_model_time(measurements: DataTable, aligned: list[Optional[DataTable]], raw: dict,
                        model_class) -> None:
    """A time column of dates, counted from the measurements' first date (time 0) in the run's
    time unit (:func:`pfx.config.time_units.time_unit`: the config's ``time_unit``, else the
    unit ``model_class`` declares); where neither says one, in days, and ``raw`` (the config,
    changed in place) gets ``time_unit: day``, so that the figures and the record say so and
    the record reruns the same. Every table's index is set in that unit, and the measurements'
    :attr:`DataTable.note` says so in one line. ConfigError where the unit is not one a date
    converts to exactly (a month, a year, a step). ``aligned``: the truth and controls tables
    (None where absent), which hold the same dates row by row (:func:`check_alignment`).
    Tables of numbers are left alone."""
    first_date = measurements.first_date
    if first_date is None:
        return
    kind = getattr(model_class, "model_fields", {}).get("kind")
    kind = f"model {kind.default}" if kind is not None and kind.default else "the model"
    configured = isinstance(raw.get("time_unit"), str) and bool(raw["time_unit"])
    declared = next((cls for cls in getattr(model_class, "__mro__", ()) if "time_unit" in vars(cls)),
                    TimeAxis) is not TimeAxis
    unit = time_unit(raw, model_class) if configured or declared else "day"
    per_day = DAY_IN.get(unit.strip().lower().removesuffix("s") or unit.strip().lower())
    if per_day is None:
        source = "the config's time_unit is" if configured else f"{kind} counts time in"
        raise ConfigError(f"holds dates, and {source} {unit!r}, which a date does not convert to exactly: write the "
                          f"times as numbers in {unit} (for years, decimal years such as 1944.0192), or use a `step` "
                          "column", file=measurements.file, line=measurements.lines[0], key="column time")
    origin = measurements.index[0]
    for table in [measurements, *aligned]:
        if table is not None:
            table.index = (table.index - origin) * per_day
            table.first_date = None            # its index is the model's time now
    if configured:
        said = "the config's time_unit"
    elif declared:
        said = f"{kind}'s time unit"
    else:
        raw["time_unit"] = "day"
        said = f"{kind} declares no time unit, so they count days (time_unit: day)"
    measurements.note = (f"{measurements.file}: column time: the dates are read as {_plural(unit)} since "
                         f"{first_date} (time 0): {said}")


def _plural(unit: str) -> str:
    named = {"s": "seconds", "sec": "seconds", "min": "minutes", "h": "hours", "hr": "hours", "d": "days",
             "w": "weeks", "wk": "weeks"}
    word = unit.strip().lower()
    return named.get(word, word if word.endswith("s") else word + "s")


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
            raise ConfigError(f"time {table.time_text(index[r])} appears twice (lines {lines[r - 1]} and {lines[r]})",
                              file=table.file, line=lines[r], key="column time")
        if index[r] < index[r - 1]:
            raise ConfigError(f"times must increase: {table.time_text(index[r])} comes after "
                              f"{table.time_text(index[r - 1])}",
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
    if (table.first_date is None) != (measurements.first_date is None):
        held = {True: "numbers", False: "dates"}
        raise ConfigError(f"the times are {held[table.first_date is None]}, the measurements' ({measurements.file}) "
                          f"{held[measurements.first_date is None]}: use the same", file=table.file,
                          line=table.lines[0], key="column time")
    name = table.index_name
    for r in range(min(len(table.index), len(measurements.index))):
        if table.index[r] != measurements.index[r]:
            raise ConfigError(f"{name} {table.time_text(table.index[r])} differs from the measurements' {name} "
                              f"{measurements.time_text(measurements.index[r])} (line {measurements.lines[r]} of {measurements.file})",
                              file=table.file, line=table.lines[r], key=f"column {name}")
    if len(table.index) > len(measurements.index):
        r = len(measurements.index)
        raise ConfigError(f"{len(table.index)} rows, the measurements ({measurements.file}) {len(measurements.index)}: "
                          f"{name} {table.time_text(table.index[r])} has no measurement row", file=table.file, line=table.lines[r],
                          key=f"column {name}")
    if len(table.index) < len(measurements.index):
        r = len(table.index)
        raise ConfigError(f"{len(table.index)} rows, the measurements ({measurements.file}) {len(measurements.index)}: "
                          f"the file ends before {name} {measurements.time_text(measurements.index[r])}", file=table.file,
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
