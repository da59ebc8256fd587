r"""The velocity motion model's figures: Probabilistic Robotics Figs. 5.3 (density) and 5.4 (samples).

The robot at ``start`` is commanded :math:`u = (v, \omega)` for :math:`\Delta t` (``control``,
``dt``): without noise it drives along an arc of radius :math:`v/\omega`. Each named setting
gives the six error parameters :math:`\alpha_1..\alpha_6` (:class:`pfx.motion.VelocityAlphas`):

.. math::

    \hat v = v + \mathrm{sample}(\alpha_1 v^2 + \alpha_2 \omega^2), \quad
    \hat\omega = \omega + \mathrm{sample}(\alpha_3 v^2 + \alpha_4 \omega^2), \quad
    \hat\gamma = \mathrm{sample}(\alpha_5 v^2 + \alpha_6 \omega^2)

(Table 5.3, :func:`pfx.motion.sample_motion_model_velocity`). The book's three settings are
(a) a default, (b) larger translational error (:math:`\alpha_1, \alpha_2`) and smaller
rotational error, (c) larger rotational error (:math:`\alpha_3, \alpha_4`) and smaller
translational; it prints no values, so the config chooses them.

``velocity_motion_density`` writes the x-y density (Table 5.1's terms, with and without the
Jacobian, :func:`pfx.motion.pose_density_velocity`, summed over headings) and its chi-square
check against the sampler; ``velocity_motion_samples`` the 500 samples per setting, normal and
triangular, and their spread along and across the motion. Tables and columns:
:mod:`pfx.studies.robot_motion`. Given the position, the heading is spread only by
:math:`\hat\gamma\Delta t`, of standard deviation :math:`\sqrt{\alpha_5 v^2 + \alpha_6 \omega^2}\,\Delta t`.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, StrictFloat

from pfx.motion.distributions import MotionNoise
from pfx.motion.velocity import VelocityAlphas, log_densities_velocity, move_on_arc, sample_motion_model_velocity
from pfx.studies.base import STUDIES
from pfx.studies.robot_motion import MotionDensity, MotionSamples, NamedSetting, RobotMotion


class VelocitySetting(NamedSetting):
    """A named setting of the velocity model's error parameters."""

    alphas: VelocityAlphas = Field(description="[alpha1, ..., alpha6] (Table 5.3)")


class VelocityMotion(RobotMotion):
    """One velocity command from ``start`` under several named error settings."""

    control: tuple[StrictFloat, StrictFloat] = Field(
        (1.0, 0.75), description="the command [v, w]: translational (m/s) and rotational (rad/s, positive = left) velocity")
    dt: StrictFloat = Field(1.0, gt=0, le=1000, description="how long the command is held (s)")
    settings: list[VelocitySetting] = Field(min_length=1, max_length=12,
                                            description="named alpha settings, one panel each: {name, label, alphas: [a1, ..., a6]}")

    def sample_poses(self, setting, noise: MotionNoise, count: int, random: np.random.Generator) -> np.ndarray:
        return sample_motion_model_velocity(self.control, np.broadcast_to(self.start, (count, 3)), self.dt,
                                            setting.alphas, noise, random)

    def log_densities(self, poses, setting, noise: MotionNoise) -> tuple[np.ndarray, np.ndarray]:
        return log_densities_velocity(poses, self.control, self.start, self.dt, setting.alphas, noise)

    def commanded_path(self, points: int) -> np.ndarray:
        v, w = self.control
        times = np.linspace(0.0, self.dt, points)
        return move_on_arc(np.broadcast_to(self.start, (points, 3)), v, w, 0.0, times)

    def heading_spread(self, setting) -> float:
        v, w = self.control
        return math.sqrt(float(setting.alphas.variances(v, w)[2])) * self.dt


@STUDIES.register_kind
class VelocityMotionDensity(MotionDensity, VelocityMotion):
    """Fig. 5.3: the velocity model's pose density in x-y for named alpha settings, checked against the sampler."""

    kind: Literal["velocity_motion_density"] = "velocity_motion_density"


@STUDIES.register_kind
class VelocityMotionSamples(MotionSamples, VelocityMotion):
    """Fig. 5.4: poses drawn by sample_motion_model_velocity (normal and triangular) and their spread."""

    kind: Literal["velocity_motion_samples"] = "velocity_motion_samples"
