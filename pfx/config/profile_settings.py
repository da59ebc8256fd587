r"""The ``estimation.profile`` section: a likelihood profile over one model parameter
(``estimation.method: profile``; docs/estimation.md, "Profile likelihood").

The profile of a parameter :math:`\psi` is :math:`\ell_p(\psi) = \max_\theta \ell(\psi, \theta)`,
the log-likelihood maximised over the other parameters :math:`\theta` at each value of
:math:`\psi`. A profile run fixes :math:`\psi` at each value of a grid and maximises over
:math:`\theta` by IF2 from ``chains`` starts per grid value; the Monte Carlo adjusted profile
(:mod:`pfx.estimation.profile`) then smooths the estimates and gives the confidence interval.

The run *is* one IF2 run (:func:`profile_as_if2`): its replicates are every (grid value, start)
pair, grid-major (replicate ``g * chains + k`` is start k at grid value g), all rows of one
batch, and the profiled parameter is one more estimated parameter whose random walk has sd 0
(it never moves from its grid value) on the untransformed scale. So the profile resumes and
extends exactly as IF2 does, with the same progress files.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, model_validator

from pfx.laws.priors import FlatPrior

SMALLEST_GRID = 3       # a quadratic needs three parameter values


class ProfileSettings(BaseModel):
    """The profiled parameter and its grid: ``grid`` (the values), or ``lower``, ``upper`` and
    ``points`` (evenly spaced values)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    parameter: str = Field(pattern=r"^model\.[A-Za-z_].*$",
                           description="dotted path into the model of the profiled parameter (e.g. "
                                       "model.measurement_noise.variance); fixed at each grid value")
    grid: Optional[list[StrictFloat]] = Field(None, description="the profiled parameter's values (at least 3, "
                                                                "distinct); or lower, upper and points")
    lower: Optional[StrictFloat] = Field(None, description="the grid's first value (with upper and points)")
    upper: Optional[StrictFloat] = Field(None, description="the grid's last value (with lower and points)")
    points: Optional[StrictInt] = Field(None, ge=SMALLEST_GRID, le=10_000,
                                        description="evenly spaced grid values from lower to upper")
    name: Optional[str] = Field(None, pattern=r"^[A-Za-z_][A-Za-z0-9_.]*$",
                                description="column name in the tables (default: the path without `model.`)")
    level: StrictFloat = Field(0.95, gt=0, lt=1, description="the confidence interval's level")
    span: StrictFloat = Field(0.75, gt=0, le=1, description="the fraction of the estimates in each local quadratic "
                                                            "fit of the Monte Carlo adjusted profile (loess's span)")

    @model_validator(mode="after")
    def _check(self):
        spaced = [key for key in ("lower", "upper", "points") if getattr(self, key) is not None]
        if self.grid is not None and spaced:
            raise ValueError(f"@{spaced[0]}: give the grid's values (grid) or lower, upper and points, not both")
        if self.grid is None:
            missing = [key for key in ("lower", "upper", "points") if getattr(self, key) is None]
            if missing:
                raise ValueError(f"@{missing[0]}: give the profile's grid: grid (its values) or lower, upper and "
                                 "points")
            if not self.upper > self.lower:
                raise ValueError(f"@upper: {self.upper:g} must exceed lower ({self.lower:g})")
            return self
        if len(self.grid) < SMALLEST_GRID:
            raise ValueError(f"@grid: {len(self.grid)} value(s); a profile needs at least {SMALLEST_GRID} (the "
                             "smoothed profile is a local quadratic)")
        if len(set(self.grid)) != len(self.grid):
            raise ValueError("@grid: a value appears twice; give distinct values (more starts per value: chains)")
        return self

    @property
    def values(self) -> list[float]:
        """The grid, as the run takes it (the values given, or evenly spaced)."""
        if self.grid is not None:
            return list(self.grid)
        return [float(value) for value in np.linspace(self.lower, self.upper, self.points)]

    @property
    def column(self) -> str:
        return self.name or self.parameter[len("model."):]


def check_profile(estimation, reserved: set[str]) -> None:
    """ValueError ("@key: ...") where a config's ``profile`` and ``method`` disagree, or the
    profiled parameter is also estimated, or its column name is taken."""
    profile = estimation.profile
    if estimation.method != "profile":
        if profile is not None:
            raise ValueError(f"@profile: read only by method: profile, and the method is {estimation.method}; "
                             "drop it, or set method: profile")
        return
    if profile is None:
        raise ValueError("@profile: method: profile needs the profiled parameter and its grid, e.g. profile: "
                         "{parameter: model.mu, grid: [0, 0.5, 1]}")
    if profile.parameter in estimation.parameters:
        raise ValueError(f"@profile.parameter: {profile.parameter} is also among the estimated parameters; the "
                         "profile fixes it at each grid value and maximises over the others: drop it from parameters")
    key = "profile.name" if profile.name else "profile.parameter"
    if profile.column in [estimation.column(path) for path in estimation.parameters]:
        raise ValueError(f"@{key}: {profile.column!r} is also an estimated parameter's column name; give one a `name`")
    if profile.column in reserved:
        raise ValueError(f"@{key}: {profile.column!r} is a column of the estimation tables, which the profiled "
                         "parameter's column would overwrite; give it another `name`")


def profile_as_if2(estimation):
    """The IF2 run a profile is (module docstring); any other method's settings unchanged.

    The starts per grid value (``chains`` of them) repeat at every grid value: a list of starts
    is laid out grid-major, and ``start: prior`` draws each (grid value, start) row its own."""
    if estimation.method != "profile":
        return estimation
    profile, starts = estimation.profile, estimation.chains
    grid = profile.values
    rows = len(grid) * starts
    template = next(iter(estimation.parameters.values()))
    # The profiled parameter: never perturbed (sd 0, on the untransformed scale, so the swarm keeps
    # the grid value), under a flat prior (IF2 reads only a prior's support; the model refuses what it must).
    fixed = template.model_copy(update={"prior": FlatPrior(), "transform": "none", "random_walk_sd": 0.0,
                                        "start": [float(value) for value in grid for _ in range(starts)],
                                        "name": profile.column})
    others = {path: parameter.model_copy(update={"start": [float(value) for _ in grid for value in parameter.start]})
              if isinstance(parameter.start, list) else parameter
              for path, parameter in estimation.parameters.items()}
    return estimation.model_copy(update={"method": "if2", "chains": rows, "profile": None,
                                         "parameters": {profile.parameter: fixed, **others}})

