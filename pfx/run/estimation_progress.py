"""An estimation run's progress files: each cell's rows so far, kept as the run goes and read
back, checked, when a run resumes or extends the folder.

``estimation/<cell>.csv`` holds the rows of chains.csv (PMMH) or if2.csv (IF2) without the
cell's columns (:mod:`pfx.config.estimation_tables`), every iteration so far, in order: chain
(or replicate) 0, 1, ... of iteration 0 (the starts), then of iteration 1, and so on. IF2 also
keeps the particle swarm its last pass left, ``estimation/<cell>.swarm.npy``; a PMMH cell with
``particles: auto``, the particle counts its pilot measured, ``estimation/<cell>.particle_count.csv``.

pfx writes each file whole (to a temporary file, then renamed over it), so a file cut short,
with other columns, with a field that is not a number of the right kind, or with a row missing,
repeated or out of place, was changed by something else. Such a file is refused, naming it and
its line (:func:`damaged`), never read back as data: rows read from it would become chains.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import numpy as np
import pandas as pd

from pfx.config.estimation_tables import CHAINS, IF2, PARTICLE_COUNT
from pfx.errors import ConfigError
from pfx.estimation.likelihood_spread import Spread
from pfx.result_folder import write_bytes

if TYPE_CHECKING:
    from pfx.config.plan import Cell

PROGRESS = "estimation"
INTEGER_COLUMNS = ("chain", "replicate", "iteration")
FLAG_COLUMNS = ("warm_up", "accepted")
FLAGS = {"True": True, "False": False}


def progress_file(out: Path, cell: Cell) -> Path:
    return out / PROGRESS / f"{cell.key}.csv"


def swarm_file(out: Path, cell: Cell) -> Path:
    return out / PROGRESS / f"{cell.key}.swarm.npy"


def damaged(path: Path, what: str, line: Optional[int] = None) -> ConfigError:
    """The one line for a progress file pfx did not write as it is."""
    return ConfigError(f"{what}; pfx writes its progress files whole, so this was done by something else: "
                       "restore the file, or use --fresh to compute the folder again", file=str(path), line=line)


def read_rows(path: Path, method: str, parameters: list[str], count: int, warm_up: int = 0) -> pd.DataFrame:
    """A cell's progress file, checked (module docstring): its rows with the types the run wrote
    (whole numbers, True/False flags, floats), or a ConfigError naming the file and the line.

    ``method``: pmmh or if2; ``parameters``: the parameters' columns; ``count``: the chains (or
    replicates) of every iteration; ``warm_up`` (PMMH): the iterations flagged ``warm_up``. A
    PMMH chain's log-likelihood is finite (its start's is checked, and a proposal without one is
    never accepted); IF2's is empty at iteration 0 (the starts) and may be -inf after (a pass
    whose every particle lost its weight).
    """
    layout = CHAINS if method == "pmmh" else IF2
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise damaged(path, "is not a text file") from None
    lines = text.split("\n")
    if text == "":
        raise damaged(path, "is empty")
    if lines[-1] != "":
        raise damaged(path, "the last row is cut short (the file does not end with a line end)", len(lines))
    lines.pop()
    expected = layout.progress_columns(parameters)
    if lines[0].split(",") != expected:
        raise damaged(path, f"its columns are {lines[0]!r}, not {','.join(expected)!r}", 1)
    for number, line in enumerate(lines[1:], start=2):
        if line.count(",") != len(expected) - 1:
            raise damaged(path, f"{line.count(',') + 1} fields, not {len(expected)}", number)
    fields = pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False, na_filter=False)
    if fields.empty:
        raise damaged(path, "has no rows", 1)
    rows = pd.DataFrame({name: _column(path, name, fields[name]) for name in expected})
    _check_order(path, rows, layout.before[0], count)
    log_likelihood, start = rows["log_likelihood"], rows["iteration"] == 0
    if method == "pmmh":
        checks = ((~np.isfinite(log_likelihood), "log_likelihood is not a finite number"),
                  (rows["warm_up"] != (rows["iteration"] <= warm_up),
                   f"warm_up does not say whether the iteration is one of the first {warm_up}"))
    else:
        checks = ((log_likelihood.isna() != start, "log_likelihood is empty exactly at iteration 0 (the starts)"),)
    for wrong, what in checks:
        if wrong.any():
            raise damaged(path, what, _line(wrong))
    return rows


def _line(flags: pd.Series) -> int:
    """The file's line of the first flagged row (line 1 is the header)."""
    return int(np.argmax(flags.to_numpy())) + 2


def _column(path: Path, name: str, text: pd.Series) -> pd.Series:
    """A column's fields as the run wrote them, or a ConfigError at the first field that is not."""
    if name in FLAG_COLUMNS:
        bad = ~text.isin(list(FLAGS))
        if bad.any():
            raise damaged(path, f"{name} is {text[bad].iloc[0]!r}, not True or False", _line(bad))
        return text.map(FLAGS).astype(bool)
    values = pd.to_numeric(text, errors="coerce").astype(float)
    if name in INTEGER_COLUMNS:
        bad = ~np.isfinite(values) | (values != np.round(values)) | (values < 0)
        kind = "a whole number"
    elif name == "log_likelihood":
        bad = (values.isna() & (text != "")) | (values == np.inf)      # empty: IF2's starts; -inf: zero likelihood
        kind = "a log-likelihood"
    else:
        bad = ~np.isfinite(values)
        kind = "a finite number"
    if bad.any():
        raise damaged(path, f"{name} is {text[bad].iloc[0]!r}, not {kind}", _line(bad))
    return values.astype(np.int64) if name in INTEGER_COLUMNS else values


def _check_order(path: Path, rows: pd.DataFrame, member: str, count: int) -> None:
    """Every iteration from 0 on has each of the ``count`` chains (``member``: chain or replicate)
    once, in order (module docstring)."""
    index = np.arange(len(rows))
    expected_member, expected_iteration = index % count, index // count
    members, iterations = rows[member].to_numpy(), rows["iteration"].to_numpy()
    wrong = (members != expected_member) | (iterations != expected_iteration)
    if wrong.any():
        first = int(np.argmax(wrong))
        raise damaged(path, f"{member} {members[first]} of iteration {iterations[first]} where {member} "
                            f"{expected_member[first]} of iteration {expected_iteration[first]} belongs (a row is "
                            "missing, repeated or out of place)", first + 2)
    if len(rows) % count:
        raise damaged(path, f"the file ends within iteration {iterations[-1]}, with {len(rows) % count} of its "
                            f"{count} rows", len(rows) + 2)


def save_swarm(swarm: np.ndarray, path: Path) -> None:
    buffer = io.BytesIO()
    np.save(buffer, swarm)
    write_bytes(buffer.getvalue(), path)


def read_swarm(path: Path, shape: tuple[int, ...]) -> np.ndarray:
    """IF2's swarm (replicates, particles, parameters) as the last pass left it, checked: a NumPy
    array of finite float64 values of that shape, or a ConfigError naming the file."""
    try:
        swarm = np.load(io.BytesIO(path.read_bytes()), allow_pickle=False)
    except (ValueError, OSError, EOFError):
        raise damaged(path, "is not a NumPy array file (.npy)") from None
    if not isinstance(swarm, np.ndarray) or swarm.dtype != np.float64 or swarm.shape != shape:
        found = f"{swarm.dtype} array of shape {swarm.shape}" if isinstance(swarm, np.ndarray) else "no array"
        raise damaged(path, f"holds a {found}, not the float64 array of shape {shape} (replicates, particles, "
                            "parameters) of this cell's swarm")
    if not np.isfinite(swarm).all():
        raise damaged(path, "holds values that are not finite numbers")
    return swarm


# -- the pilot of `particles: auto` ---------------------------------------------------------------------

def pilot_file(out: Path, cell: Cell, stage: str = "before_chains") -> Path:
    """The particle counts the pilot measured for a cell (:mod:`pfx.estimation.particle_count`)
    before the chains, or after their warm-up (``stage``): particle_count.csv's rows of the cell
    and stage without their columns; read back, a resumed or extended run keeps the choice
    instead of measuring again."""
    suffix = "" if stage == "before_chains" else f"_{stage}"
    return out / PROGRESS / f"{cell.key}.particle_count{suffix}.csv"


def read_pilot(path: Path) -> tuple[list[Spread], int]:
    """A cell's pilot file, checked as the other progress files are (module docstring): the rows
    measured, in order, and the particle count marked chosen; or a ConfigError naming the file
    and the line. (Whether the rows are those the rule measures, and its choice, the caller checks
    by replaying the rule on them.)"""
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise damaged(path, "is not a text file") from None
    lines = text.split("\n")
    if lines[-1] != "":
        raise damaged(path, "the last row is cut short (the file does not end with a line end)", len(lines))
    expected = ",".join(PARTICLE_COUNT.own)
    if lines[0] != expected:
        raise damaged(path, f"its columns are {lines[0]!r}, not {expected!r}", 1)
    rows, chosen = [], []
    for number, line in enumerate(lines[1:-1], start=2):
        fields = dict(zip(PARTICLE_COUNT.own, line.split(",")))
        if line.count(",") != len(PARTICLE_COUNT.own) - 1:
            raise damaged(path, f"{line.count(',') + 1} fields, not {len(PARTICLE_COUNT.own)}", number)
        try:
            particles, runs, finite = (int(fields[name]) for name in ("particles", "runs", "finite"))
            mean, sd, _, seconds = (float(fields[name] or "nan") for name in ("mean", "sd", "sd_standard_error",
                                                                              "run_time_s"))
        except ValueError:
            raise damaged(path, "a field is not a number of its column's kind", number) from None
        if fields["chosen"] not in FLAGS:
            raise damaged(path, f"chosen is {fields['chosen']!r}, not True or False", number)
        plausible = (particles >= 1 and runs >= 2 and 0 <= finite <= runs and seconds >= 0
                     and (math.isfinite(mean) if finite else mean == -math.inf)
                     and (math.isfinite(sd) and sd >= 0 if finite > 1 else math.isnan(sd)))
        if not plausible:
            raise damaged(path, "a row that no measurement gives (counts, mean, sd or seconds out of range)", number)
        rows.append(Spread(particles, runs, finite, mean, sd, seconds))
        if FLAGS[fields["chosen"]]:
            chosen.append(particles)
    if len(chosen) != 1:
        raise damaged(path, f"{len(chosen)} rows are marked chosen, not one", len(lines) - 1)
    return rows, chosen[0]
