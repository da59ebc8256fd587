r"""Recorded data: filtering measurements that were read from files, not simulated.

A config names its files under ``data:``, each path relative to the config's folder::

    data:
      measurements: ../../examples/data/nile.csv   # required
      truth: truth.csv                             # optional: the true states, for the error metrics
      controls: controls.csv                       # optional: the control input of every step
      covariates: covariates.csv                   # optional: covariates over time (alone: simulate)

**The format** (each file is read and checked on its own by :mod:`pfx.config.data_files`). A
CSV file with a header row. The first column is ``step`` (the integers 1..T, in order: the step
of each row) or ``time`` (increasing numbers: the time of each step); then one column per
component, in any order:

* measurements: the model's measurement components, named ``z1..zm`` (always accepted) or by
  the model's own names (:attr:`pfx.models.base.Model.measurement_names`). A blank row (every
  measurement cell blank) is a missing measurement: that step is predict-only in every filter
  kind (no weight update, log-likelihood increment 0, no NIS). A row with some cells blank and
  others not is refused: the model interface has no likelihood of part of a measurement.
* truth: the model's state components by name (``pfx list models`` shows them); no blanks.
* controls: one column per control component (any names); no blanks. Its rows become the
  model's ``controls`` (one vector per step): only models with a ``controls`` setting take
  them (``linear_gaussian``, with its ``control_matrix``), and the config must not give both.

* covariates: a ``time`` column (any increasing grid, not tied to the steps), then one column
  per covariate the model reads (``Model.covariate_names``); no blanks. It fills the model's
  ``covariates`` (so the table is part of the cell key), read by ``Model.covariates_at(time)``
  with linear interpolation; :func:`pfx.config.covariate_files.check_covariate_spans` checks that it covers the times the
  transition reads. It is the one file allowed without measurements (then they are simulated).

Every other file must have the same first column as the measurements (``step`` or ``time``) with the
same values row by row.

**Steps and times.** T is the number of rows; a ``steps`` given in the model must equal it. A
``time`` column gives the times of steps 1..T (steps.csv's ``time``). Equally spaced times set
the model's ``dt`` to their spacing (a ``dt`` given in the model must agree); irregular times
are refused unless the model declares ``variable_dt`` (it then reads
:meth:`~pfx.models.base.Model.step_duration`): no built-in model does, since none has a
dt-dependent form that recorded data would need (``linear_gaussian``'s matrices are per step).

**Trials.** With data every trial filters the same measurements: trials are replicates of the
filter's own randomness (its stream, seeded per trial as always), and ``outputs.trace_trials``
defaults to every trial (10,000, the most it may be). Metrics that need the truth are empty
without a truth file.

**Bad data** is a :class:`~pfx.errors.ConfigError`: one line naming the data file, its line
(the header is line 1) and the column, before anything runs. A path that names no regular file
(a folder, a pipe, ``/dev/zero``) or a file over :data:`pfx.config.data_files.MAX_FILE_BYTES` is
refused, naming the config's key, without being read (:func:`pfx.user_files.read_user_file`). The
cell keys include a digest of the data, so a result folder is never reused for other data; the
resolved config holds the files' absolute paths, and a result folder's ``config.yaml`` names them
relative to the folder (:func:`pfx.run.folder_record.write_record_config`), so that it reruns from
the folder and a clone of a repository holding both keeps the same record.

:func:`prepare_recorded_data` reads and checks the files (:func:`pfx.config.data_files.read_table`)
and fills the model's ``steps``, ``dt`` and ``controls`` before the config is validated;
:func:`attach_recorded_data` checks the columns against each cell's models and gives each cell
its arrays (:class:`CellData`).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from pfx.config.covariate_files import fill_covariates
from pfx.config.data_files import (
    DataTable,
    check_alignment,
    dates_to_model_time,
    display_path,
    read_table,
    time_spacing,
)
from pfx.config.validation import validate
from pfx.errors import ConfigError
from pfx.models import MODELS
from pfx.models.time_axis import RELATIVE_TIME_TOLERANCE
from pfx.numerics.hashing import canonical_hash

TRACE_ALL_TRIALS = 10_000      # outputs.trace_trials' maximum: every trial of a data run


class DataConfig(BaseModel):
    """Recorded data to filter instead of simulated measurements (see docs/recorded-data.md)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    measurements: Optional[str] = Field(
        None, description="CSV file (relative to the config's folder): a `step` (1..T) or `time` column, then one "
                          "column per measurement component (z1..zm or the model's names); a blank row is a "
                          "missing measurement. Without it (covariates only) the measurements are simulated")
    truth: Optional[str] = Field(
        None, description="CSV file of the true states: `step`/`time`, then the state components by name "
                          "(without it the metrics that need the truth are empty)")
    controls: Optional[str] = Field(
        None, description="CSV file of the control inputs: `step`/`time`, then one column per control "
                          "component (fills the model's `controls`)")
    covariates: Optional[str] = Field(
        None, description="CSV file of covariates over time, for a model that reads them (its covariate_names): a "
                          "`time` column (increasing; any grid, interpolated linearly), then one column per "
                          "covariate (fills the model's `covariates`); allowed without measurements")

    @model_validator(mode="after")
    def _needs_measurements(self) -> "DataConfig":
        if self.measurements is None:
            for key in ("truth", "controls"):
                if getattr(self, key) is not None:
                    raise ValueError(f"@{key}: a {key} file goes with recorded measurements: give "
                                     "data.measurements too")
            if self.covariates is None:
                raise ValueError("@measurements: required (or data.covariates alone, to simulate with covariates)")
        return self


@dataclass
class CellData:
    """What a cell's batches filter: the arrays in the model's component order."""

    measurements: np.ndarray             # (T, m), NaN rows where the measurement is missing
    truth: Optional[np.ndarray]          # (T, d) or None
    observed: Optional[np.ndarray]       # (T,) False where missing; None when every step is measured


@dataclass
class RecordedData:
    """The files a config's ``data:`` names, read and checked (before the models exist)."""

    measurements: DataTable
    truth: Optional[DataTable]
    controls: Optional[DataTable]

    @property
    def steps(self) -> int:
        return len(self.measurements.index)

    @property
    def times(self) -> Optional[np.ndarray]:
        return self.measurements.index if self.measurements.index_name == "time" else None

    @property
    def digest(self) -> str:
        """A hash of the data's content (not of its paths): part of every cell key."""
        hasher = hashlib.sha256()
        for table in (self.measurements, self.truth, self.controls):
            if table is None:
                hasher.update(b"-")
                continue
            hasher.update(repr((table.index_name, table.columns, table.values.shape)).encode())
            hasher.update(np.ascontiguousarray(table.index, dtype=float).tobytes())
            hasher.update(np.ascontiguousarray(table.values, dtype=float).tobytes())
        return hasher.hexdigest()


# -- before validation: the files, and what they fix in the model ---------------------------------

def prepare_recorded_data(raw: dict, file: Optional[str]) -> Optional[RecordedData]:
    """Read and check the files ``raw["data"]`` names, and fill in what they fix before the
    config is validated: the model's ``steps`` (and ``dt``, ``controls``), the default
    ``outputs.trace_trials`` (every trial), and the files' absolute paths (for the resolved
    config). ``raw`` is changed in place; None when the config has no ``data``."""
    if not isinstance(raw, dict) or raw.get("data") is None:
        return None
    config = validate(DataConfig, raw["data"], file=file, prefix="data")
    model = raw.get("model")
    if config.covariates is not None:
        covariates = read_table(config.covariates, config_file=file, key="data.covariates", blanks=False)
        if isinstance(model, dict):
            fill_covariates(model, covariates, file)
    raw["data"] = {key: os.path.abspath(display_path(value, file)[1])
                   for key, value in config.model_dump().items() if value is not None}
    if config.measurements is None:
        return None                  # covariates only: the measurements are simulated as usual
    measurements = read_table(config.measurements, config_file=file, key="data.measurements", blanks=True)
    truth = controls = None
    if config.truth is not None:
        truth = read_table(config.truth, config_file=file, key="data.truth", blanks=False)
        check_alignment(truth, measurements)
    if config.controls is not None:
        controls = read_table(config.controls, config_file=file, key="data.controls", blanks=False)
        check_alignment(controls, measurements)
    data = RecordedData(measurements, truth, controls)
    kind = model.get("kind") if isinstance(model, dict) else None
    dates_to_model_time(measurements, [truth, controls], raw, MODELS[kind] if kind in MODELS else None)

    if isinstance(model, dict):
        _fix_steps_and_dt(model, data, file)
        if controls is not None:
            _fill_controls(model, controls, file)
    outputs = raw.get("outputs")
    if outputs is None:
        raw["outputs"] = outputs = {}
    if isinstance(outputs, dict) and "trace_trials" not in outputs:
        outputs["trace_trials"] = TRACE_ALL_TRIALS
    return data


def _fix_steps_and_dt(model: dict, data: RecordedData, file: Optional[str]) -> None:
    steps = model.get("steps")
    if steps is None:
        model["steps"] = data.steps
    elif steps != data.steps:
        raise ConfigError(f"{steps} disagrees with the {data.steps} rows of {data.measurements.file}: drop it "
                          f"(the data sets T) or make it {data.steps}", file=file, key="model.steps")
    if data.times is None:
        return
    spacing, _ = time_spacing(data.times)
    if spacing is None:
        return                        # irregular (checked against the model once it exists) or one step
    dt = model.get("dt")
    if dt is None:
        model["dt"] = spacing
    elif not isinstance(dt, (int, float)) or abs(dt - spacing) > RELATIVE_TIME_TOLERANCE * abs(spacing):
        raise ConfigError(f"{dt} disagrees with the spacing {spacing:g} of the times in {data.measurements.file}: "
                          "drop it (the data sets dt) or make them agree", file=file, key="model.dt")


def _fill_controls(model: dict, controls: DataTable, file: Optional[str]) -> None:
    kind = model.get("kind")
    if kind not in MODELS:
        return                       # the config's validation names the unknown kind
    if "controls" not in MODELS[kind].model_fields:
        raise ConfigError(f"model {kind} takes no control inputs (no `controls` setting)", file=file,
                          key="data.controls")
    if model.get("controls") is not None:
        raise ConfigError("controls are given twice: in model.controls and in data.controls; keep one",
                          file=file, key="data.controls")
    model["controls"] = controls.values.tolist()
    try:                             # the model's own check of the vectors' length, located in the file
        validate(MODELS[kind], model, file=file, prefix="model")
    except ConfigError as error:
        if error.key and error.key.startswith("model.controls"):
            raise controls.column_error(f"{len(controls.columns)} control column(s) for model {kind}: "
                                        f"{error.reason}") from None


# -- after the cells exist: columns against the models, and each cell's arrays ---------------------

def attach_recorded_data(cells: list, data: Optional[RecordedData], file: Optional[str]) -> None:
    """Check the files' columns against every cell's models, give each cell its arrays
    (``cell.data``, a :class:`CellData`) and the data's times, and make the data part of the
    cell's key (its filter stream key is kept: seeds as without data)."""
    if data is None:
        return
    digest = data.digest
    for cell in cells:
        for where, model in (("model", cell.truth_model), ("filter.model", cell.filter_model)):
            if model.steps != data.steps:
                raise ConfigError(f"{model.steps} disagrees with the {data.steps} rows of {data.measurements.file}",
                                  file=file, key=f"{where}.steps")
        _check_times(cell, data, file)
        cell.data = _cell_arrays(cell.truth_model, data)
        cell.key = canonical_hash({"cell": cell.key, "data": digest}, 12)


def _check_times(cell, data: RecordedData, file: Optional[str]) -> None:
    if data.times is None:
        return
    spacing, odd_row = time_spacing(data.times)
    for where, model in (("model", cell.truth_model), ("filter.model", cell.filter_model)):
        if odd_row is not None and not type(model).variable_dt:
            table = data.measurements
            gap = data.times[odd_row - 1] - data.times[odd_row - 2]
            raise ConfigError(f"irregular times ({gap:g} since the previous row, {data.times[1] - data.times[0]:g} "
                              f"between the first two): model {model.kind} takes a fixed dt (only a model that "
                              "declares variable_dt takes irregular times); use a `step` column or regular times",
                              file=table.file, line=table.lines[odd_row - 1], key="column time")
        if spacing is not None and abs(model.dt - spacing) > RELATIVE_TIME_TOLERANCE * abs(spacing):
            raise ConfigError(f"{model.dt} disagrees with the spacing {spacing:g} of the times in "
                              f"{data.measurements.file}", file=file, key=f"{where}.dt")
        model.use_recorded_times(data.times)


def _ordered(table: DataTable, accepted: list[tuple[str, ...]], what: str) -> np.ndarray:
    """The table's values with its columns in the order of the first accepted list of names they match."""
    for names in accepted:
        if sorted(table.columns) == sorted(names):
            return table.values[:, [table.columns.index(name) for name in names]]
    # Name both sides: the columns found, the columns expected, and how they differ (measured
    # against the accepted list the header comes closest to).
    alternatives = " or ".join(", ".join(names) for names in accepted)
    closest = max(accepted, key=lambda names: len(set(names) & set(table.columns)))
    unknown = [name for name in table.columns if all(name not in names for names in accepted)]
    missing = [name for name in closest if name not in table.columns]
    differences = []
    if unknown:
        differences.append(f"{', '.join(unknown)} {'is' if len(unknown) == 1 else 'are'} not among them")
    if missing:
        differences.append(f"{', '.join(missing)} {'is' if len(missing) == 1 else 'are'} missing")
    raise table.column_error(f"found {', '.join(table.columns)} after `{table.index_name}`, expected the "
                             f"{len(accepted[0])} {what}: {alternatives} ({'; '.join(differences)})",
                             unknown[0] if unknown else None)


def _cell_arrays(model, data: RecordedData) -> CellData:
    numbered = tuple(f"z{i + 1}" for i in range(model.measurement_dimension))
    names = tuple(model.measurement_names)
    accepted = [numbered] if names == numbered else [names, numbered]
    measurements = _ordered(data.measurements, accepted, f"measurement component(s) of model {model.kind}")
    truth = None
    if data.truth is not None:
        truth = _ordered(data.truth, [tuple(model.state_names)], f"state component(s) of model {model.kind}")
    missing = np.isnan(measurements).any(axis=1)
    return CellData(measurements=measurements, truth=truth, observed=~missing if missing.any() else None)
