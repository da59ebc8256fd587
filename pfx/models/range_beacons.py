r"""Planar position tracked from ranges to known beacons (tags, landmarks).

State :math:`x = [p_x, p_y]`. Each step measures the distance to every beacon :math:`b_j`:

.. math:: z_{k,j} = \lVert x_k - b_j \rVert + v_{k,j}.

Motion, chosen by ``motion``:

* ``odometry``: :math:`x_k = x_{k-1} + u_k + w_k`, where the control :math:`u_k = c_k - c_{k-1}`
  is the displacement along the designed ``path`` :math:`c` (encoder distance and gyro heading,
  as in han-lee's robot). With zero process noise and ``initial`` at the path's start the truth
  follows the path exactly.
* ``random_walk``: :math:`x_k = x_{k-1} + w_k` (no knowledge of the motion: bayes-blog's system
  model).

The path is a Lissajous curve ``c(t) = centre + amplitude * sin(frequency * t + phase)`` with
``t = 2 pi * turns * k / T``, or a polyline through ``waypoints`` sampled at equal arc length.
``region`` is the box the filter's default prior is uniform over.

EKF Jacobians: analytic. The transition's (state and noise) is the identity; the measurement's
row j is the unit vector :math:`(x - b_j)^\top / \lVert x - b_j \rVert` (zero at the beacon itself,
where the range is not differentiable).

``propagate`` and ``measurement_mean`` take NumPy or JAX arrays (:mod:`pfx.numerics.arrays`):
one model for both backends. The Jacobians are the EKF's (NumPy only).
"""

from __future__ import annotations

from typing import Annotated, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, StrictFloat

from pfx.laws.initial import PointLaw, UniformLaw
from pfx.laws.noise import Noise
from pfx.models.base import MODELS, Model
from pfx.numerics.arrays import namespace

Point = tuple[StrictFloat, StrictFloat]


class LissajousPath(BaseModel):
    """c(t) = centre + amplitude * sin(frequency * t + phase), t = 2 pi turns k / T."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["lissajous"] = "lissajous"
    center: Point = (0.0, 0.0)
    amplitude: Point = (1.0, 1.0)
    frequency: Point = (1.0, 2.0)
    phase: Point = (np.pi / 2, 0.0)
    turns: StrictFloat = Field(1.0, gt=0)

    def points(self, steps: int) -> np.ndarray:
        t = 2 * np.pi * self.turns * np.arange(steps + 1)[:, None] / steps
        return np.asarray(self.center) + np.asarray(self.amplitude) * np.sin(
            np.asarray(self.frequency) * t + np.asarray(self.phase))


class WaypointPath(BaseModel):
    """A polyline through the waypoints, sampled at T + 1 points of equal arc length."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["waypoints"] = "waypoints"
    points_: list[Point] = Field(alias="points", min_length=2)
    closed: bool = Field(False, description="return to the first waypoint at the end")

    def points(self, steps: int) -> np.ndarray:
        corners = np.asarray(self.points_, dtype=float)
        if self.closed:
            corners = np.vstack([corners, corners[:1]])
        lengths = np.r_[0.0, np.cumsum(np.hypot(*np.diff(corners, axis=0).T))]
        targets = np.linspace(0.0, lengths[-1], steps + 1)
        return np.column_stack([np.interp(targets, lengths, corners[:, 0]),
                                np.interp(targets, lengths, corners[:, 1])])


Path = Annotated[Union[LissajousPath, WaypointPath], Field(discriminator="kind")]


class Region(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    low: Point
    high: Point


@MODELS.register_kind
class RangeBeacons(Model):
    """Planar position from ranges to known beacons; odometry-driven or random-walk motion."""

    kind: Literal["range_beacons"] = "range_beacons"
    beacons: list[Point] = Field(min_length=1, description="beacon positions [[x, y], ...]")
    motion: Literal["odometry", "random_walk"] = Field("odometry", description="motion model")
    path: Path = Field(default_factory=LissajousPath, description="designed path (drives odometry)")
    region: Optional[Region] = Field(None, description="box of the default uniform prior")
    unit: str = Field("m", description="length unit, for labels")

    _path_points: np.ndarray = PrivateAttr(None)
    _beacon_array: np.ndarray = PrivateAttr(None)

    def presets(self):
        start = self.path.points(self.steps or 80)[0]
        return {
            "steps": 80, "dt": 1.0,
            "process_noise": Noise(family="gaussian", variance=0.01),
            "measurement_noise": Noise(family="gaussian", variance=0.25),
            "initial": PointLaw(state=[float(start[0]), float(start[1])]),
        }

    def check(self):
        if self.region is not None and any(high <= low for low, high in zip(self.region.low, self.region.high)):
            raise ValueError("@region.high: every high must exceed its low")

    def setup(self):
        self._path_points = self.path.points(self.steps)
        self._beacon_array = np.asarray(self.beacons, dtype=float)

    @property
    def state_names(self):
        return ("x", "y")

    @property
    def state_units(self):
        return (self.unit, self.unit)

    @property
    def measurement_dimension(self):
        return len(self.beacons)

    @property
    def path_points(self) -> np.ndarray:
        """The designed path c_0..c_T, shape (T + 1, 2)."""
        return self._path_points

    def default_prior(self):
        if self.region is None:
            points = self._path_points
            margin = 0.1 * (points.max(axis=0) - points.min(axis=0)) + 1.0
            low, high = points.min(axis=0) - margin, points.max(axis=0) + margin
            return UniformLaw(low=low.tolist(), high=high.tolist())
        return UniformLaw(low=list(self.region.low), high=list(self.region.high))

    def scene(self):
        elements = [{"element": "beacon", "x": x, "y": y, "label": f"tag {j + 1}"}
                    for j, (x, y) in enumerate(self.beacons)]
        if self.motion == "odometry":
            elements += [{"element": "path", "x": x, "y": y} for x, y in self._path_points]
        if self.region is not None:
            elements.append({"element": "region", "x": self.region.low[0], "y": self.region.low[1],
                             "x_end": self.region.high[0], "y_end": self.region.high[1]})
        return elements

    def control(self, step):
        if self.motion == "random_walk":
            return None
        return self._path_points[step] - self._path_points[step - 1]

    def propagate(self, state, control, noise):
        return state + noise if control is None else state + control + noise

    def measurement_mean(self, state):
        # sqrt(dx^2 + dy^2) per beacon: no (..., m, 2) intermediate and no reduction over a
        # trailing axis; several times faster than a norm over the last axis, and this is the
        # filter's hot spot (evaluated for every particle at every step).
        beacons = self._beacon_array
        dx = state[..., 0, None] - beacons[:, 0]
        dy = state[..., 1, None] - beacons[:, 1]
        xp = namespace(state)
        if xp is not np:        # JAX arrays cannot be written; XLA fuses the same operations
            return xp.sqrt(dx * dx + dy * dy)
        # NumPy: in place, into the fresh dx (no temporaries)
        dx *= dx
        dy *= dy
        dx += dy
        return np.sqrt(dx, out=dx)

    def transition_jacobian(self, state, control):
        return np.broadcast_to(np.eye(2), state.shape[:-1] + (2, 2))

    def process_noise_jacobian(self, state, control):
        return np.broadcast_to(np.eye(2), state.shape[:-1] + (2, 2))

    def measurement_jacobian(self, state):
        difference = state[..., None, :] - self._beacon_array          # (..., m, 2)
        distance = np.sqrt(np.sum(difference * difference, axis=-1, keepdims=True))
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(distance > 0, difference / distance, 0.0)
