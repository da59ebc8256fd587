"""Covariates from a recorded data file: the model's ``covariates`` filled from the file's table
(its errors located at the file's row and column), and every cell's models checked to have
covariates for all the times their transitions read.
"""

from __future__ import annotations

import re
from typing import Optional

from pfx.config.validation import validate
from pfx.errors import ConfigError
from pfx.models import MODELS


def fill_covariates(model: dict, covariates, file: Optional[str]) -> None:
    """The model's ``covariates`` from the table ``covariates`` (a
    :class:`pfx.config.data_files.DataTable`): ``time`` and one list per column (the model
    checks the names against its ``covariate_names`` when it is validated)."""
    if covariates.index_name != "time":
        raise ConfigError("the first column of a covariates file must be `time` (covariates are read by time, "
                          "between the steps too)", file=covariates.file, line=covariates.header_line, key="column 1")
    if model.get("covariates") is not None:
        raise ConfigError("covariates are given twice: in model.covariates and in data.covariates; keep one",
                          file=file, key="data.covariates")
    table = {"time": covariates.index.tolist()}
    table.update({name: covariates.values[:, c].tolist() for c, name in enumerate(covariates.columns)})
    model["covariates"] = table
    kind = model.get("kind")
    if kind not in MODELS:
        return                       # the config's validation names the unknown kind
    try:                             # the model's own check of the columns, located in the file
        validate(MODELS[kind], model, file=file, prefix="model")
    except ConfigError as error:
        if error.key and error.key.startswith("model.covariates"):
            # A value's row and column (model.covariates.NAME[ROW]), else the header
            cell = re.fullmatch(r"model\.covariates\.([^.\[]+)\[(\d+)\]", error.key)
            if cell and cell.group(1) in covariates.columns and int(cell.group(2)) < len(covariates.lines):
                raise ConfigError(error.reason, file=covariates.file, line=covariates.lines[int(cell.group(2))],
                                  key=f"column {cell.group(1)}") from None
            raise ConfigError(error.reason, file=covariates.file, line=covariates.header_line) from None


def check_covariate_spans(cells: list, raw: dict, file: Optional[str]) -> None:
    """Every cell's models have covariates for all the times their transitions read (once the
    recorded times, if any, are known); ``raw`` is the config (where the table came from)."""
    from_data = isinstance(raw.get("data"), dict) and raw["data"].get("covariates") is not None
    for cell in cells:
        for where, model in (("model", cell.truth_model), ("filter.model", cell.filter_model)):
            try:
                model.check_covariate_span()
            except ValueError as error:
                reason = str(error).split(": ", 1)[-1]
                raise ConfigError(reason, file=file, key="data.covariates" if from_data
                                  else f"{where}.covariates") from None
