"""The study interface and its registry (see :mod:`pfx.studies`)."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict

from pfx.registry import Registry


class Study(BaseModel):
    """Base class of every study: its fields are its parameters."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: str
    #: units of the columns of its tables, for figure labels (column -> unit)
    units: ClassVar[dict[str, str]] = {}

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        """Compute the study; every random draw comes from ``random``. Returns name -> table."""
        raise NotImplementedError


STUDIES: Registry[type[Study]] = Registry("study")
