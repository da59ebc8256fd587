"""The range of each trials.csv column's values: where a metric cannot go (an RMSE below 0, a
share above 1), so that the intervals of summary.csv and steps_summary.csv stay inside it
(:func:`pfx.analysis.summary.cut_to_range`). A new metric adds its columns to
:data:`METRIC_RANGES`; a column that matches none may take any real value (log_likelihood).
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ValueRange:
    """The values a metric's column can take: [low, high], and whether it is a share (a yes/no
    per trial, written True/False, whose mean is a proportion). :mod:`pfx.analysis.summary`
    keeps its intervals inside the range."""

    low: float = -math.inf
    high: float = math.inf
    share: bool = False


ANY_VALUE = ValueRange()
NONNEGATIVE = ValueRange(low=0.0)
UNIT_INTERVAL = ValueRange(low=0.0, high=1.0)
SHARE = ValueRange(low=0.0, high=1.0, share=True)

# trials.csv column (an fnmatch pattern; the first that matches counts) -> its range. A column
# that matches none may take any real value (log_likelihood). A new metric adds its columns here.
METRIC_RANGES: dict[str, ValueRange] = {
    "rmse_*": NONNEGATIVE,
    "rms_error_*": NONNEGATIVE,
    "error_distance_*": NONNEGATIVE,
    "convergence_step": ValueRange(low=1.0),
    "converged": SHARE,
    "error_at_convergence": NONNEGATIVE,
    "ess_mean": NONNEGATIVE,
    "resample_count": NONNEGATIVE,
    "ancestral_tree_size": NONNEGATIVE,
    "degenerate_steps": NONNEGATIVE,
    "lost_particles": NONNEGATIVE,
    "particles_mean": NONNEGATIVE,
    "injected_mean": NONNEGATIVE,
    "grid_lost_mass": UNIT_INTERVAL,
    "nees_*": NONNEGATIVE,
    "nis_*": NONNEGATIVE,
    "move_acceptance": UNIT_INTERVAL,
    "run_time_s": NONNEGATIVE,
    "compile_time_s": NONNEGATIVE,
}


def metric_range(column: str) -> ValueRange:
    """The range of a trials.csv column's values (:data:`METRIC_RANGES`; any real value if unlisted)."""
    for pattern, value_range in METRIC_RANGES.items():
        if fnmatch.fnmatchcase(column, pattern):
            return value_range
    return ANY_VALUE
