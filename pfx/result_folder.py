"""The result folder, in one place: writing its files atomically, reading its tables
(:class:`ResultFolder`, all that figures and reports see) and its manifest.

Files are written atomically: to a temporary file in the same folder, then renamed over the
target, so a reader (or an interrupted run) never sees half a file. Missing values (a trial
that never converged) are written as empty fields, never as ``nan``; a diverged value is
written as ``inf`` (pandas reads it back as infinity).

What a run may do with a folder that already holds results (resume, extend, refuse) is
:mod:`pfx.folder_state`'s to decide. A folder this process could not create or write into (under
a regular file, read-only) is refused before anything is written (:func:`check_writable`; every
command that writes runs it).

One run writes a folder at a time (:func:`pfx.folder_lock.folder_lock`); what a run read before it held the
lock is read again once it does, since another run may have been writing the folder meanwhile.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import tempfile
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Optional

from pfx.errors import ConfigError
from pfx.user_files import UnreadableFile, read_user_file

if TYPE_CHECKING:          # pandas and numpy are imported where a table is read, not before
    import numpy as np
    import pandas as pd

MANIFEST = "manifest.json"
CELLS = "cells"
# A finished folder's manifest carries this flag while its figures are being drawn: a run stopped
# then (Ctrl-C, SIGTERM) leaves a complete folder whose rerun draws them, never one that says
# "up to date" with figures missing.
FIGURES_PENDING = "figures_pending"
MAX_MANIFEST_BYTES = 100 * 1024 * 1024


# -- writing ------------------------------------------------------------------------------------

def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# mkstemp creates files readable by their owner only; results get the usual permissions.
FILE_MODE = 0o666 & ~_current_umask()


def write_text(text: str, path: str | Path) -> None:
    """Write a text file atomically."""
    write_bytes(text.encode("utf-8"), path)


def write_bytes(content: bytes, path: str | Path) -> None:
    """Write a file atomically: to a temporary file in the same folder, then renamed over it."""
    path = Path(path)
    descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=path.suffix)
    try:
        with os.fdopen(descriptor, "wb") as handle:
            handle.write(content)
        os.chmod(temporary, FILE_MODE)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def write_csv(frame: pd.DataFrame, path: str | Path) -> None:
    """Write a table atomically; NaN becomes an empty field."""
    write_text(frame.to_csv(index=False, na_rep="", lineterminator="\n"), path)


# -- reading -------------------------------------------------------------------------------------

def read_table(path: str | Path) -> pd.DataFrame:
    """A CSV table of the folder (an empty file: an empty table). The one reader: a cell key is
    12 hex digits and is read as text, or "910808017e06" would become the number 9.1e14 and
    "012345678901" lose its zero."""
    import pandas as pd

    try:
        return pd.read_csv(path, dtype={"cell": str})
    except pd.errors.EmptyDataError:
        return pd.DataFrame()


# The tables of an estimation folder, by method (besides config.yaml, manifest.json, estimation/, figures/).
ESTIMATION_TABLES = {"pmmh": ("chains", "posterior", "priors"), "if2": ("if2", "maximum_likelihood"),
                     "profile": ("if2", "maximum_likelihood", "profile", "profile_interval", "profile_smoothed")}


def estimation_kind(method: str) -> str:
    """"a PMMH estimation folder", "an IF2 estimation folder", "a profile-likelihood estimation folder"."""
    return f"{'an' if method == 'if2' else 'a'} {'profile-likelihood' if method == 'profile' else method.upper()} " \
           "estimation folder"


class MissingTable(FileNotFoundError):
    """A table the folder does not have (a figure of a filter run asked of an estimation folder)."""

    def __init__(self, name: str, path: Path):
        super().__init__(2, f"no {name}.csv", str(path))
        self.name = name


class ResultFolder:
    """A result folder as figures see it: its CSV tables and its manifest, nothing else."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def table(self, name: str) -> pd.DataFrame:
        """A table of the folder; :class:`MissingTable` if it has none of that name."""
        path = self.path / f"{name}.csv"
        if not path.is_file():
            raise MissingTable(name, path)
        return read_table(path)

    @property
    def tables(self) -> set[str]:
        """The names of the tables the folder holds (its CSV files, without ``.csv``)."""
        return {path.stem for path in self.path.glob("*.csv")}

    @property
    def is_estimation(self) -> bool:
        """Whether an estimation run made the folder (its manifest says so)."""
        return "estimation" in (read_manifest(self.path) or {})

    @property
    def kind(self) -> str:
        """What made the folder, in words: "a PMMH estimation folder", "a filter run's folder", ..."""
        manifest = read_manifest(self.path) or {}
        if "estimation" in manifest:
            return estimation_kind(str(manifest["estimation"].get("method", "")))
        if "study" in manifest:
            return f"a study's folder ({manifest['study']})"
        return "a filter run's folder"

    @cached_property
    def trials(self) -> pd.DataFrame:
        return self.table("trials")

    @cached_property
    def steps(self) -> pd.DataFrame:
        return self.table("steps")

    @cached_property
    def steps_summary(self) -> pd.DataFrame:
        """steps_summary.csv: one row per (cell, step) over every trial of the cell.

        A folder written before that table existed gets the same columns computed from the
        traced trials of steps.csv instead (:attr:`steps_summary_covers_every_trial` is then
        False, and a figure should say "traced trials"), so figures have one drawing path.
        """
        if (self.path / "steps_summary.csv").exists():
            return self.table("steps_summary")
        return self._steps_summary_from_traces()

    @property
    def steps_summary_covers_every_trial(self) -> bool:
        """True when :attr:`steps_summary` is the run's own table, False when derived from steps.csv."""
        return (self.path / "steps_summary.csv").exists()

    @property
    def state_names(self) -> list[str]:
        """The model's state components in order (from the manifest's units, else steps.csv)."""
        names = [key.removeprefix("state_") for key in self.units if key.startswith("state_")]
        return names or [c.removeprefix("truth_") for c in self.steps.columns if c.startswith("truth_")]

    def state_error(self, frame: pd.DataFrame, state: str) -> np.ndarray:
        """estimate - truth of one state component in rows of steps.csv; an angle's (the
        manifest's ``angular_states``) wrapped into half a turn either side, as
        :func:`pfx.analysis.metrics.state_error` does."""
        import numpy as np

        from pfx.numerics.angles import wrap_difference

        with np.errstate(over="ignore", invalid="ignore"):
            error = (frame[f"estimate_{state}"] - frame[f"truth_{state}"]).to_numpy(dtype=float)
        if state in self.manifest.get("angular_states", []):
            return wrap_difference(error, self.manifest["full_turn"])
        return error

    def _steps_summary_from_traces(self) -> pd.DataFrame:
        """steps_summary.csv's table computed from the traced trials in steps.csv (older folders).

        Each cell's traces become (trials, steps) arrays of the per-step values, summarised by
        the very function the run uses (:func:`pfx.analysis.step_summary.summarize_steps`).
        """
        import numpy as np
        import pandas as pd

        from pfx.analysis.step_summary import QUANTITIES, SIGNED_QUANTITIES, summarize_steps

        steps = self.steps
        if steps.empty:
            return pd.DataFrame()
        # steps.csv starts with the cell columns (cell, labels, swept keys), then "trial".
        cell_columns = list(steps.columns[:steps.columns.get_loc("trial")])
        states = [c.removeprefix("truth_") for c in steps.columns if c.startswith("truth_")]
        summaries = []
        for _, rows in steps.groupby("cell", sort=False):
            values = {quantity: self._by_trial(rows, rows.get(quantity, np.nan))
                      for quantity in (*QUANTITIES, *SIGNED_QUANTITIES)}
            for state in states:
                values[f"squared_error_{state}"] = self._by_trial(rows, self.state_error(rows, state) ** 2)
            first = rows.iloc[0]
            times = rows.groupby("step")["time"].first().to_numpy(dtype=float)
            summaries.append(summarize_steps(values, states, {c: first[c] for c in cell_columns}, times))
        return pd.concat(summaries, ignore_index=True)

    @staticmethod
    def _by_trial(rows: pd.DataFrame, values) -> np.ndarray:
        """Per-step values of one cell's rows of steps.csv as an array: one row per trial, one column per step."""
        table = rows.assign(_value=values).pivot(index="trial", columns="step", values="_value")
        return table.to_numpy(dtype=float)

    @cached_property
    def summary(self) -> pd.DataFrame:
        return self.table("summary")

    @cached_property
    def particles(self) -> pd.DataFrame:
        """particles.csv: the kept particle clouds (empty if the config kept none)."""
        return self.optional_table("particles")

    @cached_property
    def genealogy(self) -> pd.DataFrame:
        """genealogy.csv: one row per (cell, trial, step, particle) of the first few trials of
        each cell, with its parent's index among the step before's particles (empty if the
        config recorded none; :mod:`pfx.analysis.genealogy` turns a trial's rows into arrays)."""
        return self.optional_table("genealogy")

    @cached_property
    def forecasts(self) -> pd.DataFrame:
        """forecasts.csv: one row per (cell, trial, origin, horizon) of the forecasts asked for
        (``outputs.forecasts``; empty if none: :mod:`pfx.filters.particle.forecasting`)."""
        return self.optional_table("forecasts")

    @cached_property
    def scene(self) -> pd.DataFrame:
        """scene.csv: the model's fixed world (beacons, walls, path; empty if it has none)."""
        return self.optional_table("scene")

    def optional_table(self, name: str) -> pd.DataFrame:
        import pandas as pd

        return self.table(name) if (self.path / f"{name}.csv").exists() else pd.DataFrame()

    @property
    def position_states(self) -> list[str]:
        """The state columns that form the position (the first two are drawn on maps)."""
        return self.manifest.get("position_states", [])

    @cached_property
    def manifest(self) -> dict:
        return json.loads((self.path / "manifest.json").read_text())

    @cached_property
    def config(self) -> dict:
        """config.yaml: the config as it ran, every default written out
        (:mod:`pfx.run.folder_record`); an empty mapping for a folder without a readable one."""
        from pfx.safe_yaml import parse_yaml

        path = self.path / "config.yaml"
        if not path.is_file():
            return {}
        try:
            config = parse_yaml(path.read_text(), str(path))
        except (ConfigError, UnicodeDecodeError):
            return {}
        return config if isinstance(config, dict) else {}

    @property
    def units(self) -> dict:
        return self.manifest.get("units", {})

    @property
    def recorded_data(self) -> bool:
        """Whether the run filtered recorded measurements (``data:``): every trial then filters
        the same data, whatever its ``truth_seed``."""
        return bool(self.manifest.get("recorded_data", False))

    @property
    def label_columns(self) -> list[str]:
        return self.manifest.get("label_columns", ["arm"])

    @property
    def auxiliary_cells(self) -> set[str]:
        """The cells that ran the auxiliary particle filter (``filter.auxiliary``; the manifest's
        cell entries say so), whose ESS is that of the second-stage weights."""
        return {entry["cell"] for entry in self.manifest.get("cells", [])
                if str(entry.get("auxiliary", False)).lower() == "true"}

    def cell_names(self, frame: pd.DataFrame) -> pd.Series:
        """A legend label per row: the arm (if several) and the swept values, joined."""
        columns = [c for c in self.manifest.get("legend_columns", []) if c in frame]
        if not columns:
            columns = ["arm"]
        if columns == ["arm"]:
            return frame["arm"].astype(str)
        parts = [(c + "=") + frame[c].astype(str) if c != "arm" else frame[c].astype(str) for c in columns]
        label = parts[0]
        for part in parts[1:]:
            label = label + ", " + part
        return label


# -- the state of a folder a run writes to --------------------------------------------------------

def read_manifest(out: Path) -> Optional[dict]:
    """The folder's manifest, or None if it has none or it is unreadable."""
    try:        # a user names the folder: its manifest.json could be a pipe that never ends
        manifest = json.loads(read_user_file(Path(out) / MANIFEST, MAX_MANIFEST_BYTES))
    except (UnreadableFile, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def finished_manifest(out: Path, *, needs: tuple[str, ...] = ()) -> dict:
    """The manifest of a finished result folder (that also holds the files ``needs``); else
    a ConfigError naming the folder: the one check that commands reading a folder use."""
    manifest = read_manifest(out)
    missing = [name for name in needs if not (Path(out) / name).is_file()]
    if manifest is None or manifest.get("complete") is not True or missing:
        wanted = " and ".join(["a complete manifest.json", *missing])
        raise ConfigError(f"not a finished pfx result folder (it needs {wanted})", file=str(out))
    return manifest


def write_manifest(manifest: dict, out: Path) -> None:
    """Write the folder's manifest.json (atomically, as every file)."""
    write_text(json.dumps(manifest, indent=2), Path(out) / MANIFEST)


def record_figures(out: Path, names: list[str], config_hash: Callable[[Path], str]) -> None:
    """Add figures to a finished folder's record (manifest and config.yaml), so that ``pfx
    figures`` renders them again and a rerun of the config keeps or drops them knowingly. The
    manifest's ``config_hash`` is the rewritten config.yaml's, as ``config_hash(path)`` computes
    it (the plan's: with its plugins' code and its data files' contents), so that a rerun of the
    config finds the folder up to date."""
    import yaml

    manifest = read_manifest(out)
    new = [name for name in names if name not in manifest.get("figures", [])]
    if not new:
        return
    manifest["figures"] = [*manifest.get("figures", []), *new]
    config_path = Path(out) / "config.yaml"
    if config_path.is_file():
        config = yaml.safe_load(config_path.read_text())
        config.setdefault("outputs", {})["figures"] = manifest["figures"]
        write_text(yaml.safe_dump(config, sort_keys=False), config_path)
        manifest["config_hash"] = config_hash(config_path)
    write_text(json.dumps(manifest, indent=2), Path(out) / MANIFEST)


def _may(path: Path, mode: int) -> bool:
    """Whether this process may access ``path`` so (by its effective user, where the system tells)."""
    return os.access(path, mode, effective_ids=os.access in os.supports_effective_ids)


def check_writable(out: Path, what: str = "result folder") -> None:
    """Refuse, before anything is written, a folder this process could not create or write into.

    An existing ``out`` must be a folder it may write, enter and read (a run lists it); a missing one is created
    with its missing parents, so its nearest existing ancestor must be a folder it may write
    and enter. (Root passes the permission checks whatever the modes, except on a read-only
    file system; the run's first mkdir and lock file catch what slips through.)
    """
    out = Path(out)
    for folder in (out, *out.parents):
        try:
            mode = os.stat(folder).st_mode
        except (FileNotFoundError, NotADirectoryError, PermissionError):
            continue       # not there, or behind an ancestor the loop reaches next
        except OSError as error:      # a loop of symbolic links, a path too long
            raise ConfigError(f"cannot reach the {what}: {error.strerror or error}", file=str(out)) from None
        if folder == out:
            if not stat.S_ISDIR(mode):
                raise ConfigError(f"exists and is not a folder (the {what} must be one); choose another folder",
                                  file=str(out))
            for access, adjective in ((os.W_OK | os.X_OK, "writable"), (os.R_OK, "readable")):
                if not _may(out, access):
                    raise ConfigError(f"{what} is not {adjective} (permission denied); choose another folder",
                                      file=str(out))
        elif not stat.S_ISDIR(mode):
            raise ConfigError(f"cannot create the {what}: {folder} is a file, not a folder", file=str(out))
        elif not _may(folder, os.W_OK | os.X_OK):
            raise ConfigError(f"cannot create the {what}: {folder} is not writable (permission denied); "
                              "choose another folder", file=str(out))
        return


def clear_outputs(out: Path, names) -> None:
    """Remove pfx's own outputs from a folder (--fresh): the named files, cells/, figures/ and
    plugins/ (the copies of a plugin run's code)."""
    for name in names:
        (out / name).unlink(missing_ok=True)
    for folder in (CELLS, "figures", "plugins"):
        shutil.rmtree(out / folder, ignore_errors=True)
