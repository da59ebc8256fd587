"""The committed record of a reproduction: recompute, compare, and keep what agrees.

``results/`` is committed: it is the record a reader sees, and ``make reproduce-papers`` on a
fresh clone must leave it unchanged when pfx computes the same numbers. Two things in a result
folder never repeat exactly from one run to the next:

* **what the run measured of itself**: run times (``run_time_s`` in trials.csv and its summary
  columns), the manifest's start and end times, wall times, git revision, platform and library
  versions;
* **the last bits of floating-point results on another machine**: NumPy picks its SIMD kernels
  (exp, log, sin ...) by the processor's instruction sets, and OpenBLAS its matrix kernels, so
  two processors round differently in the last place. The same machine with the same library
  versions gives the same bits (every draw comes from the trial's own stream); another machine
  differs by about 1e-16 relative, amplified where a computation is ill-conditioned (up to
  about 1e-5 relative in park-mpf's extended runs, whose Mahalanobis weighting inverts nearly
  singular covariances).

So a reproduction runs into a staging folder beside the committed one and compares them
(:func:`compare_folders`): the same files, the same text, every number within
:data:`RELATIVE_TOLERANCE` of the committed one, the manifest equal but for what the run measured
of itself. Near zero a relative tolerance means nothing, so two numbers also agree when they are
closer than :data:`SCALE_TOLERANCE` times the largest value of their column, or than
:data:`ABSOLUTE_TOLERANCE` (the rounding noise of quantities of order one: a grid filter's lost
probability mass of 1e-16 is such noise, and its sign or size is not a result). Where they agree, the committed tables and manifest stay, byte for byte, and the
staging folder's figures and everything else replace the old ones (a change to a figure's code
shows); where they differ, the new folder replaces the old one and the report says which table
and column moved, and by how much. Any real change (another seed, another draw, another
algorithm) moves a Monte Carlo number by far more than the tolerance; a refactor that changes
no number leaves ``git status`` clean.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from pfx.result_folder import MANIFEST, read_table

RELATIVE_TOLERANCE = 1e-4
SCALE_TOLERANCE = 1e-12
ABSOLUTE_TOLERANCE = 1e-12
# What a run measures of itself: never the same twice, never a reason to rewrite the record.
TIMING_COLUMN_PREFIXES = ("run_time_s", "compile_time_s")
MANIFEST_VOLATILE_KEYS = frozenset({"started", "finished", "wall_time_s", "cell_wall_time_s", "git_revision",
                                    "platform", "python", "numpy", "pfx_version"})
STAGING_SUFFIX = ".reproducing"


@dataclass
class Difference:
    """Why two result folders do not hold the same numbers: the first file (and column) that differs."""

    file: str
    what: str

    def __str__(self) -> str:
        return f"{self.file}: {self.what}"


def compare_folders(committed: Path, fresh: Path) -> Optional[Difference]:
    """None when ``fresh`` holds the same results as ``committed`` (module docstring), else the
    first difference found."""
    tables = sorted(path.relative_to(committed) for path in committed.rglob("*.csv") if "figures" not in path.parts)
    fresh_tables = sorted(path.relative_to(fresh) for path in fresh.rglob("*.csv") if "figures" not in path.parts)
    if tables != fresh_tables:
        gone, new = sorted(set(tables) - set(fresh_tables)), sorted(set(fresh_tables) - set(tables))
        return Difference(str(gone[0] if gone else new[0]), "only in the " + ("committed" if gone else "new") + " folder")
    for name in tables:
        difference = compare_tables(read_table(committed / name), read_table(fresh / name))
        if difference:
            return Difference(str(name), difference)
    arrays = sorted(path.relative_to(committed) for path in committed.rglob("*.npy"))
    if arrays != sorted(path.relative_to(fresh) for path in fresh.rglob("*.npy")):
        return Difference("*.npy", "the saved arrays differ in number or name")
    for name in arrays:
        old, new = np.load(committed / name), np.load(fresh / name)
        if old.shape != new.shape:
            return Difference(str(name), f"shape {old.shape} -> {new.shape}")
        moved = _largest_relative_change(old.ravel().astype(float), new.ravel().astype(float))
        if moved is not None:
            return Difference(str(name), f"moved by {moved:.3g} relative (tolerance {RELATIVE_TOLERANCE:g})")
    for name in ("config.yaml",):
        if (committed / name).read_bytes() != (fresh / name).read_bytes():
            return Difference(name, "differs")
    if _stable(_manifest(committed)) != _stable(_manifest(fresh)):
        return Difference(MANIFEST, "differs beyond its times and the machine it ran on")
    return None


def compare_tables(committed: pd.DataFrame, fresh: pd.DataFrame) -> Optional[str]:
    """None when two tables agree (the same columns, rows and text; numbers within tolerance,
    run times aside); else what differs, in words."""
    if list(committed.columns) != list(fresh.columns):
        return f"columns differ ({', '.join(map(str, committed.columns))} -> {', '.join(map(str, fresh.columns))})"
    if len(committed) != len(fresh):
        return f"{len(committed)} rows -> {len(fresh)}"
    for column in committed.columns:
        if str(column).startswith(TIMING_COLUMN_PREFIXES):
            continue
        old, new = committed[column], fresh[column]
        if old.dtype.kind in "fiub" and new.dtype.kind in "fiub":
            moved = _largest_relative_change(old.to_numpy(dtype=float), new.to_numpy(dtype=float))
            if moved is not None:
                return f"column {column} moved by {moved:.3g} relative (tolerance {RELATIVE_TOLERANCE:g})"
        elif not old.astype(str).equals(new.astype(str)):
            return f"column {column}'s text differs"
    return None


def _largest_relative_change(old: np.ndarray, new: np.ndarray) -> Optional[float]:
    """The largest relative change between two columns of numbers when it exceeds the tolerance
    (or the missing and infinite values differ: then inf); None when they agree."""
    finite = np.isfinite(old) & np.isfinite(new)
    if not np.array_equal(np.isnan(old), np.isnan(new)) or not np.array_equal(old[~finite & ~np.isnan(old)],
                                                                               new[~finite & ~np.isnan(new)]):
        return math.inf
    if not finite.any():
        return None
    old, new = old[finite], new[finite]
    magnitude = np.maximum(np.abs(old), np.abs(new))
    allowed = RELATIVE_TOLERANCE * magnitude + max(SCALE_TOLERANCE * magnitude.max(), ABSOLUTE_TOLERANCE)
    change = np.abs(new - old)
    if np.all(change <= allowed):
        return None
    return float(np.max(change / np.where(magnitude > 0, magnitude, 1.0)))


def _manifest(folder: Path) -> dict:
    return json.loads((folder / MANIFEST).read_text())


def _stable(value):
    """A manifest without what the run measured of itself (at any depth: each cell's wall time)."""
    if isinstance(value, dict):
        return {key: _stable(item) for key, item in value.items() if key not in MANIFEST_VOLATILE_KEYS}
    if isinstance(value, list):
        return [_stable(item) for item in value]
    return value


def staging_folder(target: Path) -> Path:
    """Where a reproduction of ``target`` is computed before it is compared (beside it, so that
    moving it into place is a rename on the same file system)."""
    return target.with_name(target.name + STAGING_SUFFIX)


def settle(target: Path, staging: Path) -> Optional[Difference]:
    """Put the reproduction in ``staging`` in place of ``target``: where the numbers agree, keep
    the committed folder and take only the new figures (their code may have changed); else take
    the new folder whole. Returns the difference (None: the numbers agree, the record was kept)."""
    difference = compare_folders(target, staging)
    if difference is None:
        _replace(target / "figures", staging / "figures")
        shutil.rmtree(staging)
    else:
        _replace(target, staging)
    return difference


def _replace(old: Path, new: Path) -> None:
    """Put folder ``new`` where ``old`` is, by renames (``old`` may be missing; ``new`` too)."""
    retired = old.with_name(old.name + ".retired")
    shutil.rmtree(retired, ignore_errors=True)
    if old.exists():
        old.rename(retired)
    if new.exists():
        new.rename(old)
    shutil.rmtree(retired, ignore_errors=True)
