r"""A planar robot moved by Probabilistic Robotics' motion models, seen through landmark ranges.

State :math:`x = (x, y, \theta)`: position and heading (radians, wrapped to :math:`(-\pi, \pi]`).

**Motion** (``motion``): the transition :math:`p(x_k \mid u_k, x_{k-1})` is sampled by one of the
book's algorithms (:mod:`pfx.motion`), with its noise parameters :math:`\alpha` and the
``normal`` or ``triangular`` error of Table 5.4:

* ``velocity`` (Table 5.3): :math:`u_k = (v_k, \omega_k)`, the velocity command of step k;
* ``odometry`` (Table 5.6): :math:`u_k = (\bar x_{k-1}, \bar x_k)`, two odometry readings.

Both come from one list of commands, ``controls``: segments ``[v, w]`` or ``[v, w, steps]``
(held for ``steps`` steps of ``dt``). Integrated without noise from the initial law's mean, the
commands give the *nominal path* :math:`\bar x_0 .. \bar x_T`; the odometry model reads it as the
odometry (the path a robot that executed its commands exactly would report). So a truth moved by
the velocity model and a filter assuming the odometry model (or the reverse) describe the same
intended motion; with every :math:`\alpha = 0` the truth follows the nominal path exactly.

**Measurement**: the range to every landmark :math:`l_j`, and with ``bearings: true`` also the
bearing relative to the heading, :math:`z = (r_1..r_m, b_1..b_m) + v`:

.. math:: r_j = \lVert (x, y) - l_j \rVert, \qquad
          b_j = \mathrm{wrap}(\mathrm{atan2}(l_{j,y} - y, l_{j,x} - x) - \theta).

The bearings are declared angular measurement components (``measurement_angular_components``),
so the likelihood (the ``gaussian`` weighting), the Kalman filters and the guided proposals wrap
the bearing innovation :math:`z - h(x)` to :math:`(-\pi, \pi]`
(:mod:`pfx.filters.kalman.measurement_form`); the distance weightings take the plain
difference, so with bearings near :math:`\pm\pi` weigh by the likelihood.

**Process noise, for the Gaussian filters.** The motion noise is not additive in the state: it
perturbs the control with variances that depend on the control. pfx writes it as
:math:`x_k = f(x_{k-1}, u_k, w_k)` with a standardised :math:`w_k` (three independent
unit-variance components of the motion's family), e.g. for the velocity model
:math:`\hat v = v + \sqrt{\alpha_1 v^2 + \alpha_2\omega^2}\, w_1` (``propagate``). ``process_noise``
is therefore fixed (unit variance, the motion's family; leave it out of the config). The particle
filter and the truth never use it: they sample the book's algorithm directly (``transition``).
The EKF and UKF linearise ``propagate`` and add :math:`L Q L^\top` with :math:`Q = I`,
:math:`L = \partial f/\partial w` (central finite differences): for the velocity model this is
the book's EKF prediction (Table 7.2, :math:`V_t M_t V_t^\top`) with the extra rotation
:math:`\hat\gamma`. Analytic Jacobians: :math:`F = \partial f / \partial x` (the identity plus
:math:`\partial(x', y')/\partial\theta = (-\Delta y, \Delta x)`, for both motions) and the
measurement's. The histogram filter refuses this model (its noise is not additive).

``angular_components = (2,)``: theta is an angle (for circular means and wrapped errors).

**Both backends.** ``transition``, ``propagate``, ``measurement_mean``, ``measure`` and the
likelihood compute in the state's array namespace (:mod:`pfx.numerics.arrays`): NumPy arrays on
the ``numpy`` backend, JAX arrays on the ``jax`` backend, the same operations. The controls
(commands, nominal path) are NumPy arrays made once on the host; ``transition`` draws from the
``random`` it is given (TrialStreams or KeyStreams). The Jacobians are the EKF's (NumPy only).
"""

from __future__ import annotations

import math
from typing import Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, StrictFloat, StrictInt, model_validator

from pfx.laws.initial import PointLaw
from pfx.laws.noise import Noise
from pfx.models.base import MODELS, Model
from pfx.models.kidnap import Kidnap
from pfx.motion.distributions import MotionNoise
from pfx.motion.odometry import OdometryAlphas, move_by_odometry, relative_motion, sample_motion_model_odometry
from pfx.motion.velocity import VelocityAlphas, move_on_arc, sample_motion_model_velocity
from pfx.numerics.angles import wrap_to_pi
from pfx.numerics.arrays import namespace, with_values
from pfx.registry import kind_union, list_form

Point = tuple[StrictFloat, StrictFloat]

# Presets: errors of about 10% in each motion part at the default commands (v = 1 m/s,
# w up to pi/8 rad/s, dt = 1 s), and a loop with four straight sides and four quarter turns.
DEFAULT_VELOCITY_ALPHAS = (0.01, 0.01, 0.001, 0.01, 0.0005, 0.005)
DEFAULT_ODOMETRY_ALPHAS = (0.01, 0.0005, 0.01, 0.001)
DEFAULT_CONTROLS = [[1.0, 0.0, 8], [1.0, math.pi / 8, 4]] * 4
DEFAULT_LANDMARKS = [(-4.0, -3.0), (14.0, -3.0), (14.0, 16.0), (-4.0, 16.0)]
DEFAULT_RANGE_VARIANCE = 0.09            # (0.3 m)^2
DEFAULT_BEARING_VARIANCE = 0.0025        # (0.05 rad)^2, about 3 degrees

_NOISE_FAMILY = {"normal": "gaussian", "triangular": "triangular"}


class VelocityMotion(BaseModel):
    """Velocity motion model (Tables 5.1, 5.3): the control is the commanded (v, w)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["velocity"] = "velocity"
    alphas: VelocityAlphas = Field(default_factory=lambda: VelocityAlphas.of(DEFAULT_VELOCITY_ALPHAS),
                                   description="[alpha1, ..., alpha6] (Table 5.3)")
    noise: MotionNoise = Field("normal", description="error distribution: normal or triangular (Table 5.4)")


class OdometryMotion(BaseModel):
    """Odometry motion model (Tables 5.5, 5.6): the control is two odometry readings."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["odometry"] = "odometry"
    alphas: OdometryAlphas = Field(default_factory=lambda: OdometryAlphas.of(DEFAULT_ODOMETRY_ALPHAS),
                                   description="[alpha1, ..., alpha4] (Table 5.6)")
    noise: MotionNoise = Field("normal", description="error distribution: normal or triangular (Table 5.4)")


Motion = kind_union(VelocityMotion, OdometryMotion)


class ControlSegment(BaseModel):
    """A velocity command (v, w) held for ``steps`` steps: ``[v, w]``, ``[v, w, steps]`` or a mapping."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    v: StrictFloat = Field(description="translational velocity (length unit per second)")
    w: StrictFloat = Field(description="rotational velocity (rad per second, positive = left)")
    steps: StrictInt = Field(1, ge=1, le=1_000_000, description="steps the command is held")

    __get_pydantic_json_schema__ = list_form(2, 3)

    @model_validator(mode="before")
    @classmethod
    def _from_list(cls, data):
        if isinstance(data, (list, tuple)):
            if len(data) not in (2, 3):
                raise ValueError(f"expected [v, w] or [v, w, steps], got {len(data)} values")
            return dict(zip(("v", "w", "steps"), data))
        return data


@MODELS.register_kind
class PlanarRobot(Model):
    """Planar robot (x, y, theta) moved by the velocity or odometry motion model; landmark ranges."""

    kind: Literal["planar_robot"] = "planar_robot"
    process_noise: Optional[Noise] = Field(
        None, description="fixed by `motion` (unit-variance standardised motion noise, for the EKF/UKF); leave it out")
    motion: Motion = Field(default_factory=VelocityMotion,
                           description="motion model: {kind: velocity | odometry, alphas, noise}")
    controls: Optional[list[ControlSegment]] = Field(
        None, min_length=1,
        description="velocity commands [v, w] or [v, w, steps]; the odometry readings are their noise-free path")
    landmarks: Optional[list[Point]] = Field(None, min_length=1, description="landmark positions [[x, y], ...]")
    bearings: bool = Field(False, description="also measure the bearing to each landmark (after the ranges)")
    unit: str = Field("m", description="length unit, for labels")
    kidnap: Optional[Kidnap] = Field(
        None, description="{step: k, to: [x, y, theta]}: the true robot is carried to `to` at step k "
                          "(the filter is not told); default none")

    _commands: np.ndarray = PrivateAttr(None)
    _nominal_path: np.ndarray = PrivateAttr(None)
    _landmark_array: np.ndarray = PrivateAttr(None)

    def presets(self):
        controls = self.controls if self.controls is not None else \
            [ControlSegment.model_validate(segment) for segment in DEFAULT_CONTROLS]
        landmark_count = len(self.landmarks if self.landmarks is not None else DEFAULT_LANDMARKS)
        variance = [DEFAULT_RANGE_VARIANCE] * landmark_count
        if self.bearings:
            variance += [DEFAULT_BEARING_VARIANCE] * landmark_count
        return {
            "controls": controls,
            "landmarks": list(DEFAULT_LANDMARKS),
            "steps": sum(segment.steps for segment in controls),
            "dt": 1.0,
            "process_noise": self._standard_noise(),
            "measurement_noise": Noise(family="gaussian", variance=variance),
            "initial": PointLaw(state=[0.0, 0.0, 0.0]),
        }

    def _standard_noise(self) -> Noise:
        return Noise(family=_NOISE_FAMILY[self.motion.noise], variance=1.0)

    def check(self):
        if self.kidnap is not None:
            self.kidnap.check(self.steps)
        available = sum(segment.steps for segment in self.controls)
        if self.steps > available:
            raise ValueError(f"@steps: the controls cover {available} step(s), fewer than steps = {self.steps}")
        variance = np.asarray(self.process_noise.variance, dtype=float)
        unit = np.array_equal(variance, np.eye(3)) if variance.ndim == 2 else bool(np.all(variance == 1.0))
        if self.process_noise.family != _NOISE_FAMILY[self.motion.noise] or not unit or self.process_noise.df:
            raise ValueError("@process_noise: fixed by the motion model (unit variance, family of motion.noise); "
                             "set the motion noise with motion.alphas and motion.noise instead")

    def truth_event(self, state, step):
        return state if self.kidnap is None else self.kidnap.apply(state, step)

    def setup(self):
        self._commands = np.repeat([[s.v, s.w] for s in self.controls],
                                   [s.steps for s in self.controls], axis=0)[: self.steps]
        poses = [np.asarray(self.initial.mean_vector(), dtype=float)]
        for v, w in self._commands:
            poses.append(move_on_arc(poses[-1], v, w, 0.0, self.dt))
        self._nominal_path = np.stack(poses)
        self._landmark_array = np.asarray(self.landmarks, dtype=float)

    # -- description -----------------------------------------------------------------------------

    @property
    def state_names(self):
        return ("x", "y", "theta")

    @property
    def state_units(self):
        return (self.unit, self.unit, "rad")

    @property
    def position_components(self):
        return (0, 1)

    @property
    def angular_components(self) -> tuple[int, ...]:
        """Theta (index 2) is an angle in radians."""
        return (2,)

    @property
    def measurement_dimension(self):
        return len(self.landmarks) * (2 if self.bearings else 1)

    @property
    def measurement_angular_components(self) -> tuple[int, ...]:
        """The bearings (after the ranges), in radians."""
        return tuple(range(len(self.landmarks), 2 * len(self.landmarks))) if self.bearings else ()

    @property
    def commands(self) -> np.ndarray:
        """The velocity commands (v_k, w_k) of steps 1..T, shape (T, 2)."""
        return self._commands

    @property
    def nominal_path(self) -> np.ndarray:
        """The noise-free path of the commands (the odometry readings), poses 0..T, shape (T + 1, 3)."""
        return self._nominal_path

    # -- motion ----------------------------------------------------------------------------------

    def control(self, step):
        """(v_k, w_k) for the velocity model; the readings (x̄_{k-1}, x̄_k), shape (2, 3), for odometry."""
        if self.motion.kind == "velocity":
            return self._commands[step - 1]
        return self._nominal_path[step - 1: step + 1]

    def sample_transition(self, state, control, times, random):
        """Sample the book's algorithm (Table 5.3 or 5.6) for every pose; trial axis first."""
        if self.motion.kind == "velocity":
            return sample_motion_model_velocity(control, state, self.dt, self.motion.alphas, self.motion.noise,
                                                random)
        return sample_motion_model_odometry(control[0], control[1], state, self.motion.alphas,
                                            self.motion.noise, random)

    def propagate(self, state, control, noise):
        """f(x, u, w) with standardised noise w (for the Gaussian filters; see the module docstring)."""
        xp = namespace(state, control, noise)
        if self.motion.kind == "velocity":
            v, w = control[..., 0], control[..., 1]
            variance_v, variance_w, variance_gamma = self.motion.alphas.variances(v, w)
            return move_on_arc(state, v + xp.sqrt(variance_v) * noise[..., 0],
                               w + xp.sqrt(variance_w) * noise[..., 1],
                               xp.sqrt(variance_gamma) * noise[..., 2], self.dt)
        rotation1, translation, rotation2 = relative_motion(control[..., 0, :], control[..., 1, :])
        variance1, variance_trans, variance2 = self.motion.alphas.variances(rotation1, translation, rotation2)
        return move_by_odometry(state, rotation1 - xp.sqrt(variance1) * noise[..., 0],
                                translation - xp.sqrt(variance_trans) * noise[..., 1],
                                rotation2 - xp.sqrt(variance2) * noise[..., 2])

    def transition_jacobian(self, state, control):
        moved = self.propagate(state, control, np.zeros(state.shape[:-1] + (3,)))
        jacobian = np.zeros(state.shape[:-1] + (3, 3))
        jacobian[..., [0, 1, 2], [0, 1, 2]] = 1.0
        jacobian[..., 0, 2] = -(moved[..., 1] - state[..., 1])
        jacobian[..., 1, 2] = moved[..., 0] - state[..., 0]
        return jacobian

    # -- measurement -----------------------------------------------------------------------------

    def measurement_mean(self, state):
        xp = namespace(state)
        difference = self._landmark_array - state[..., None, :2]              # (..., m, 2): robot -> landmark
        ranges = xp.sqrt(xp.sum(difference * difference, axis=-1))
        if not self.bearings:
            return ranges
        bearings = wrap_to_pi(xp.arctan2(difference[..., 1], difference[..., 0]) - state[..., None, 2])
        return xp.concatenate([ranges, bearings], axis=-1)

    def _wrap_bearings(self, values):
        """The measurement with its bearings wrapped to (-pi, pi] (a copy)."""
        if self.bearings:
            count = len(self.landmarks)
            values = with_values(values, (..., slice(count, None)), wrap_to_pi(values[..., count:]))
        return values

    def measure(self, state, noise):
        return self._wrap_bearings(self.measurement_mean(state) + noise)

    def measurement_jacobian(self, state):
        difference = state[..., None, :2] - self._landmark_array              # (..., m, 2): landmark -> robot
        squared = np.sum(difference * difference, axis=-1, keepdims=True)
        distance = np.sqrt(squared)
        with np.errstate(invalid="ignore", divide="ignore"):
            range_rows = np.where(distance > 0, difference / distance, 0.0)
            bearing_rows = np.where(squared > 0, np.stack([-difference[..., 1], difference[..., 0]], axis=-1)
                                    / squared, 0.0)
        zeros = np.zeros(range_rows.shape[:-1] + (1,))
        rows = [np.concatenate([range_rows, zeros], axis=-1)]
        if self.bearings:
            rows.append(np.concatenate([bearing_rows, zeros - 1.0], axis=-1))
        return np.concatenate(rows, axis=-2)
