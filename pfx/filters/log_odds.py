r"""The binary Bayes filter in log odds (Probabilistic Robotics, Table 4.2).

A static binary state :math:`x` (a door open or closed, a grid cell occupied or free) is
estimated from measurements through an *inverse* measurement model :math:`p(x \mid z_t)`. In
log odds, :math:`l = \log \frac{p}{1 - p}`, Bayes' rule becomes a sum:

.. math::

    l_t = l_{t-1} + \log\frac{p(x \mid z_t)}{1 - p(x \mid z_t)} - \log\frac{p(x)}{1 - p(x)},
    \qquad l_0 = \log\frac{p(x)}{1 - p(x)},

    \mathrm{bel}_t(x) = 1 - \frac{1}{1 + e^{l_t}}.

(Each measurement's log odds are added and the prior's, counted once in :math:`l_0`, is taken
back out: two measurements whose log odds lie symmetrically about the prior's cancel; with the
prior 1/2, inverse probabilities p and 1 - p, like 0.7 and 0.3.) Every function is vectorised
over any array of cells (an occupancy-grid-like use): a whole grid is updated by one array
operation.

**Probabilities 0 and 1** have infinite log odds, and a later contrary measurement would
produce :math:`\infty - \infty`. pfx clips every probability into
:math:`[\epsilon, 1 - \epsilon]` with ``epsilon = 1e-9`` by default (log odds within
:math:`\pm 20.7`), so a certain measurement still counts as very strong but not as final, and a
contrary certain one undoes it exactly.
Values outside :math:`[0, 1]` or NaN are refused (``ValueError``).

:func:`corridor_example` is a small worked example: a 1-D row of cells in front of a range
sensor, updated over repeated noisy scans (the data for a figure); :func:`corridor_runs` runs
many independent corridors at once (the ``binary_bayes`` study, :mod:`pfx.studies.binary_bayes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import expit

EPSILON = 1e-9


def log_odds(probability, epsilon: float = EPSILON) -> np.ndarray:
    r"""The log odds :math:`\log \frac{p}{1 - p}`, limited to :math:`\pm\log\frac{1 - \epsilon}{\epsilon}`.

    That is p clipped into [epsilon, 1 - epsilon]; the limit is applied to the log odds, so that
    p = 1 and p = 0 give exactly opposite values.
    """
    probability = np.asarray(probability, dtype=float)
    if np.any(np.isnan(probability)) or np.any((probability < 0) | (probability > 1)):
        raise ValueError("probabilities must lie in [0, 1]")
    bound = math.log1p(-epsilon) - math.log(epsilon)
    with np.errstate(divide="ignore"):
        return np.clip(np.log(probability) - np.log1p(-probability), -bound, bound)


def belief(log_odds_value) -> np.ndarray:
    r""":math:`\mathrm{bel} = 1 - 1/(1 + e^{l})` (Table 4.2's recovery of the probability), without overflow."""
    return expit(np.asarray(log_odds_value, dtype=float))


def binary_bayes_filter(previous_log_odds, inverse_measurement, prior, epsilon: float = EPSILON) -> np.ndarray:
    r"""Table 4.2, one step: :math:`l_t = l_{t-1} + \log\frac{p(x|z_t)}{1 - p(x|z_t)} - \log\frac{p(x)}{1 - p(x)}`.

    ``inverse_measurement`` is :math:`p(x \mid z_t)` per cell, ``prior`` :math:`p(x)`; all broadcast.
    """
    return np.asarray(previous_log_odds, dtype=float) + log_odds(inverse_measurement, epsilon) \
        - log_odds(prior, epsilon)


def run_binary_bayes_filter(inverse_measurements, prior, epsilon: float = EPSILON) -> np.ndarray:
    r"""Log odds :math:`l_1 .. l_T` from :math:`l_0 = \log\frac{p(x)}{1 - p(x)}`, shape (T, ...).

    ``inverse_measurements`` has shape (T, ...): :math:`p(x \mid z_t)` for t = 1..T and every cell.
    The recursion unrolls to :math:`l_t = l_0 + \sum_{s \le t} (\log\frac{p(x|z_s)}{1 - p(x|z_s)} - l_0)`.
    """
    prior_log_odds = log_odds(prior, epsilon)
    increments = log_odds(inverse_measurements, epsilon) - prior_log_odds
    return prior_log_odds + np.cumsum(increments, axis=0)


def inverse_range_sensor(cell_centres, measured_range, *, thickness: float, free: float, occupied: float,
                         prior: float) -> np.ndarray:
    """p(occupied | z) of cells along a range sensor's beam (a simplified inverse sensor model).

    A cell whose centre lies before the measured range was seen through: ``free``; one whose centre
    lies within ``thickness`` behind it is the surface that reflected the beam: ``occupied``; cells
    further behind were not seen: ``prior`` (no information). Returns shape
    ``measured_range.shape + cell_centres.shape``.
    """
    cell_centres = np.asarray(cell_centres, dtype=float)
    behind = cell_centres - np.asarray(measured_range, dtype=float)[..., None]
    return np.where(behind < 0, free, np.where(behind < thickness, occupied, prior))


@dataclass
class CorridorRuns:
    """Independent runs of the corridor example: arrays over (run, scan, cell)."""

    centres: np.ndarray               # (cells,) cell centres, distance from the sensor
    occupied: np.ndarray              # (cells,) the truth
    measured_ranges: np.ndarray       # (runs, scans)
    inverse_probabilities: np.ndarray  # (runs, scans, cells): p(occupied | z) per scan
    log_odds: np.ndarray              # (runs, scans, cells): l_t after each scan

    def table(self, run: int = 0) -> pd.DataFrame:
        """One run as one row per (scan, cell) (the columns of :func:`corridor_example`)."""
        scans, cells = self.log_odds.shape[1:]
        return pd.DataFrame({
            "scan": np.repeat(np.arange(1, scans + 1), cells),
            "cell": np.tile(np.arange(cells), scans),
            "position": np.tile(self.centres, scans),
            "occupied": np.tile(self.occupied, scans),
            "measured_range": np.repeat(self.measured_ranges[run], cells),
            "inverse_probability": self.inverse_probabilities[run].ravel(),
            "log_odds": self.log_odds[run].ravel(),
            "belief": belief(self.log_odds[run]).ravel(),
        })


def corridor_runs(random: np.random.Generator, *, runs: int = 1, cells: int = 40, cell_size: float = 0.25,
                  obstacle: tuple[int, int] = (24, 28), scans: int = 10, range_std: float = 0.1,
                  free: float = 0.3, occupied: float = 0.7, prior: float = 0.5) -> CorridorRuns:
    """``runs`` independent corridors (see :func:`corridor_example`), all updated by one array operation.

    Run r uses the r-th ``scans`` normal draws, so run 0 is :func:`corridor_example` with the same generator.
    """
    centres = (np.arange(cells) + 0.5) * cell_size
    truth = (np.arange(cells) >= obstacle[0]) & (np.arange(cells) < obstacle[1])
    ranges = obstacle[0] * cell_size + range_std * random.standard_normal((runs, scans))
    inverse = inverse_range_sensor(centres, ranges, thickness=cell_size, free=free, occupied=occupied,
                                   prior=prior)
    # the filter runs along its first axis: scans first, then back to (run, scan, cell)
    accumulated = run_binary_bayes_filter(np.moveaxis(inverse, 1, 0), prior)
    return CorridorRuns(centres, truth, ranges, inverse, np.moveaxis(accumulated, 0, 1))


def corridor_example(random: np.random.Generator, *, cells: int = 40, cell_size: float = 0.25,
                     obstacle: tuple[int, int] = (24, 28), scans: int = 10, range_std: float = 0.1,
                     free: float = 0.3, occupied: float = 0.7, prior: float = 0.5) -> pd.DataFrame:
    """Occupancy of a 1-D row of cells seen by a range sensor at 0, scan after scan.

    Cells ``obstacle[0] <= i < obstacle[1]`` are occupied; each scan measures the distance to the
    obstacle's near face plus N(0, range_std^2) noise; :func:`inverse_range_sensor` (thickness one
    cell: the surface cell) turns it into p(occupied | z) per cell and :func:`run_binary_bayes_filter` accumulates.
    Returns one row per (scan, cell): ``scan`` (1..scans), ``cell``, ``position`` (the cell's centre),
    ``occupied`` (the truth), ``measured_range``, ``inverse_probability``, ``log_odds``, ``belief``.
    """
    return corridor_runs(random, runs=1, cells=cells, cell_size=cell_size, obstacle=obstacle, scans=scans,
                         range_std=range_std, free=free, occupied=occupied, prior=prior).table(0)
