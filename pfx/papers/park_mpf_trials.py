r"""The trials of park-mpf's falling-body experiments, as the parts of its report read them
(:mod:`pfx.papers.park_mpf`).

Every filter experiment (``one-run``, ``ten-runs``, ``extended``) runs its arms on the same
trials: the particle filter with Gaussian weights (the *PF*, the baseline of every comparison),
the two readings of the paper's eq. (6) (the weightings ``mahalanobis-paper`` and
``mahalanobis-innovation``: *MPF-paper* and *MPF-innovation*) and, in the extended comparison, the
EKF and the UKF. :func:`arm_roles` tells them apart by trials.csv's labels; :func:`rmse_per_trial`
lays one state's RMSE out a trial per row, an arm per column.

**Divergence.** A trial's RMSE counts as diverged when it is infinite or above
:data:`DIVERGENCE_FACTOR` (1000) times the PF's median RMSE of that state
(:func:`pfx.analysis.paired_statistics.diverged`, :func:`diverged_trials`); diverged trials are
counted, left out of means and paired comparisons (which say so), and decide a claim about mean
RMSE on their own: a filter that diverges has no finite mean error.
"""

from __future__ import annotations

import pandas as pd

from pfx.analysis.paired_statistics import diverged
from pfx.papers.base import PaperResults

STATES = ("altitude", "velocity", "ballistic_coefficient")
DIVERGENCE_FACTOR = 1000.0        # RMSE above this many times the PF's median: diverged


def state_text(state: str) -> str:
    """A state's name in words (``ballistic coefficient``)."""
    return state.replace("_", " ")


def arm_roles(trials: pd.DataFrame) -> dict[str, str]:
    """Arm -> role: 'PF' (particle, gaussian weighting), 'paper' / 'innovation' (the MPF forms), or the filter kind."""
    roles = {}
    for arm, row in trials.drop_duplicates("arm").set_index("arm").iterrows():
        weighting = row.get("weighting")
        if row["filter"] == "particle" and weighting == "gaussian":
            roles[arm] = "PF"
        elif isinstance(weighting, str) and weighting.startswith("mahalanobis-"):
            roles[arm] = weighting.removeprefix("mahalanobis-")
        else:
            roles[arm] = str(row["filter"]).upper()
    return roles


def baseline_arm(roles: dict[str, str]) -> str:
    """The PF's arm: the baseline of every comparison."""
    return next(arm for arm, role in roles.items() if role == "PF")


def mpf_forms(roles: dict[str, str]) -> dict[str, str]:
    """MPF form -> arm, in the table's order."""
    return {role: arm for arm, role in roles.items() if role in ("paper", "innovation")}


def rmse_per_trial(trials: pd.DataFrame, state: str) -> pd.DataFrame:
    """RMSE of ``state``: one row per trial, one column per arm."""
    return trials.pivot(index="trial", columns="arm", values=f"rmse_{state}")


def diverged_trials(table: pd.DataFrame, baseline: str) -> pd.DataFrame:
    """True where a trial's RMSE (a table of :func:`rmse_per_trial`) diverged (module docstring)."""
    reference = table[baseline].to_numpy(dtype=float)
    return table.apply(lambda column: pd.Series(diverged(column.to_numpy(dtype=float), reference,
                                                         DIVERGENCE_FACTOR), index=column.index))


def state_units(results: PaperResults, experiment: str) -> dict[str, str]:
    """State -> the unit of its RMSE in the experiment's folder (ft, ft/s, 1/ft)."""
    units = results.folder(experiment).units
    return {state: units.get(f"state_{state}", "") for state in STATES}
