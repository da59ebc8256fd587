"""Truth events: the kidnapped robot.

``kidnap: {step: k, to: [x, y, heading]}`` carries the true robot to ``to`` at step k: the truth
simulation applies the transition of step k as usual (the same random draws as without the
event), then sets :math:`x_k` = ``to``, and the measurement :math:`z_k` is taken there. The filter
is not told: its model may carry the setting (it is merged from the truth's), but only
:func:`pfx.models.simulation.simulate_truth` calls :meth:`pfx.models.base.Model.truth_event`.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt


class Kidnap(BaseModel):
    """At step ``step`` the true robot is carried to the pose ``to`` (the filter is not told)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    step: StrictInt = Field(ge=1, description="the step k at which the robot is carried away (x_k = to)")
    to: tuple[StrictFloat, StrictFloat, StrictFloat] = Field(description="the pose [x, y, heading] it is carried to")

    def check(self, steps: int) -> None:
        if self.step > steps:
            raise ValueError(f"@kidnap.step: {self.step} is past the last step ({steps})")

    def apply(self, state: np.ndarray, step: int) -> np.ndarray:
        """x_k = to at the kidnapping step, unchanged otherwise."""
        if step != self.step:
            return state
        carried = state.copy()
        carried[..., :] = np.asarray(self.to, dtype=float)
        return carried
