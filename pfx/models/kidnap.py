"""Truth events: the kidnapped robot.

``kidnap: {step: k, to: [x, y, heading]}`` carries the true robot to ``to`` at step k: the truth
simulation applies the transition of step k as usual (the same random draws as without the
event), then sets :math:`x_k` = ``to``, and the measurement :math:`z_k` is taken there. The filter
is not told: its model may carry the setting (it is merged from the truth's), but only
:func:`pfx.models.simulation.simulate_truth` calls :meth:`pfx.models.base.Model.truth_event`.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt

from pfx.numerics.arrays import namespace


class Kidnap(BaseModel):
    """At step ``step`` the true robot is carried to the pose ``to`` (the filter is not told)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    step: StrictInt = Field(ge=1, description="the step k at which the robot is carried away (x_k = to)")
    to: tuple[StrictFloat, StrictFloat, StrictFloat] = Field(description="the pose [x, y, heading] it is carried to")

    def check(self, steps: int) -> None:
        if self.step > steps:
            raise ValueError(f"@kidnap.step: {self.step} is past the last step ({steps})")

    def apply(self, state, step: int):
        """x_k = to at the kidnapping step, unchanged otherwise (a copy; NumPy or JAX arrays)."""
        if step != self.step:
            return state
        xp = namespace(state)
        return xp.broadcast_to(xp.asarray(self.to, dtype=state.dtype), state.shape).copy()
