r"""The binary Bayes filter's example (Probabilistic Robotics, Table 4.2): a corridor scanned repeatedly.

A row of ``cells`` cells of width ``cell_size`` lies in front of a range sensor at 0; cells
``obstacle[0] .. obstacle[1] - 1`` are occupied. Each scan measures the distance to the
obstacle's near face with N(0, ``range_std``^2) noise; the inverse sensor model
(:func:`pfx.filters.log_odds.inverse_range_sensor`) gives p(occupied | z) = ``free`` to cells before
the measured range, ``occupied`` to the cell just behind it, and the ``prior`` (no information) to
the cells further behind, which the beam never reached. Each cell's log odds accumulate
(Table 4.2):

.. math::

    l_t = l_{t-1} + \log\frac{p(x \mid z_t)}{1 - p(x \mid z_t)} - \log\frac{p(x)}{1 - p(x)}, \qquad
    \mathrm{bel}_t = 1 - \frac{1}{1 + e^{l_t}}.

The cells the sensor sees are those up to the face, ``cell <= obstacle[0]`` (**visible**); the
others are occluded and should keep the prior. The study runs ``runs`` independent corridors
(:func:`pfx.filters.log_odds.corridor_runs`); the first is the worked example. Tables:

* ``beliefs``: the example, one row per (scan, cell): ``scan``, ``cell``, ``position`` (m),
  ``occupied``, ``measured_range`` (m), ``inverse_probability``, ``log_odds``, ``belief``;
* ``convergence``: one row per scan, over the runs (``runs``, and the ``prior``):
  ``visible_error_mean`` / ``_se`` (the mean over
  visible cells of :math:`|\mathrm{bel} - \mathrm{truth}|`), ``visible_wrong_mean`` / ``_se`` (the
  share of visible cells not on the true side of 1/2; exactly 1/2 counts as wrong),
  ``hidden_belief_mean`` (mean belief of the occluded cells);
* ``final``: one row per cell after the last scan: ``occupied``, ``visible``,
  ``example_belief`` (the first run), ``belief_mean`` / ``belief_se`` over the runs and
  ``correct_share`` (runs on the true side of 1/2).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
import pandas as pd
from pydantic import Field, StrictFloat, StrictInt, model_validator

from pfx.filters.log_odds import belief, corridor_runs
from pfx.studies.base import STUDIES, Study


@STUDIES.register_kind
class BinaryBayesCorridor(Study):
    """Table 4.2: a corridor of cells scanned repeatedly by a range sensor, beliefs in log odds."""

    kind: Literal["binary_bayes"] = "binary_bayes"
    cells: StrictInt = Field(40, ge=2, le=10_000, description="cells in the row")
    cell_size: StrictFloat = Field(0.25, gt=0, description="cell width (m)")
    obstacle: tuple[StrictInt, StrictInt] = Field((24, 28), description="occupied cells [first, last + 1)")
    scans: StrictInt = Field(10, ge=1, le=10_000, description="scans per run")
    range_std: StrictFloat = Field(0.1, ge=0, description="standard deviation of the measured range (m)")
    free: StrictFloat = Field(0.3, gt=0, lt=1, description="p(occupied | z) of a cell before the measured range")
    occupied: StrictFloat = Field(0.7, gt=0, lt=1, description="p(occupied | z) of the cell just behind it")
    prior: StrictFloat = Field(0.5, gt=0, lt=1, description="p(occupied) before any scan")
    runs: StrictInt = Field(1000, ge=1, le=1_000_000,
                            description="independent runs (the first is the worked example)")

    units: ClassVar[dict[str, str]] = {"position": "m", "measured_range": "m"}

    @model_validator(mode="after")
    def _obstacle_inside(self):
        first, end = self.obstacle
        if not 0 <= first < end <= self.cells:
            raise ValueError(f"obstacle: needs 0 <= first < end <= cells = {self.cells}, got [{first}, {end}]")
        return self

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        corridor = corridor_runs(random, runs=self.runs, cells=self.cells, cell_size=self.cell_size,
                                 obstacle=self.obstacle, scans=self.scans, range_std=self.range_std,
                                 free=self.free, occupied=self.occupied, prior=self.prior)
        beliefs = belief(corridor.log_odds)                     # (runs, scans, cells)
        truth = corridor.occupied
        visible = np.arange(self.cells) <= self.obstacle[0]
        correct = np.where(truth, beliefs > 0.5, beliefs < 0.5)
        error = np.abs(beliefs - truth)
        convergence = pd.DataFrame({
            "scan": np.arange(1, self.scans + 1), "runs": self.runs, "prior": self.prior,
            "visible_error_mean": error[..., visible].mean(axis=(0, 2)),
            "visible_error_se": _standard_error(error[..., visible].mean(axis=2)),
            "visible_wrong_mean": (~correct[..., visible]).mean(axis=(0, 2)),
            "visible_wrong_se": _standard_error((~correct[..., visible]).mean(axis=2)),
            "hidden_belief_mean": beliefs[..., ~visible].mean(axis=(0, 2)) if (~visible).any() else np.nan,
        })
        last = beliefs[:, -1, :]
        final = pd.DataFrame({
            "cell": np.arange(self.cells), "position": corridor.centres, "occupied": truth, "visible": visible,
            "example_belief": last[0], "belief_mean": last.mean(axis=0), "belief_se": _standard_error(last),
            "correct_share": correct[:, -1, :].mean(axis=0),
        })
        return {"beliefs": corridor.table(0), "convergence": convergence, "final": final}


def _standard_error(values: np.ndarray) -> np.ndarray:
    """Standard error of the mean over the first axis (runs); 0 with a single run."""
    runs = values.shape[0]
    return values.std(axis=0, ddof=1) / math.sqrt(runs) if runs > 1 else np.zeros(values.shape[1:])
