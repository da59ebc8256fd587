r"""The odometry motion model's figures: Probabilistic Robotics Figs. 5.8 (density) and 5.9 (samples).

The counterparts of Figs. 5.3 and 5.4 for the odometry model. The control is a pair of
odometry readings (``odometry_before``, ``odometry_after``), decomposed into a first rotation,
a translation and a second rotation; each setting gives :math:`\alpha_1..\alpha_4`
(:class:`pfx.motion.OdometryAlphas`):

.. math::

    \hat\delta_{rot1} = \delta_{rot1} - \mathrm{sample}(\alpha_1 \delta_{rot1}^2 + \alpha_2 \delta_{trans}^2), \quad
    \hat\delta_{trans} = \delta_{trans} - \mathrm{sample}(\alpha_3 \delta_{trans}^2
        + \alpha_4 (\delta_{rot1}^2 + \delta_{rot2}^2)), \quad
    \hat\delta_{rot2} = \delta_{rot2} - \mathrm{sample}(\alpha_1 \delta_{rot2}^2 + \alpha_2 \delta_{trans}^2)

(Table 5.6, :func:`pfx.motion.sample_motion_model_odometry`). Here :math:`\alpha_1, \alpha_2`
are the **rotational** error and :math:`\alpha_3, \alpha_4` the **translational** one (the
reverse of the velocity model's numbering). The book's Fig. 5.8 shows (a) a typical setting,
(b) unusually large translational error, (c) unusually large rotational error.

``odometry_motion_density`` and ``odometry_motion_samples`` write the same tables as the velocity
studies (:mod:`pfx.studies.robot_motion`), with the density of Table 5.5
(:func:`pfx.motion.pose_density_odometry` with and without the Jacobian
:math:`|\hat\delta_{trans}|`). The robot starts at ``start``, which need not equal the first
reading: only the readings' relative motion is used. Given the position, the heading is spread
only by :math:`\hat\delta_{rot2}`, of standard deviation
:math:`\sqrt{\alpha_1 \delta_{rot2}^2 + \alpha_2 \delta_{trans}^2}`.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from pfx.motion.distributions import MotionNoise
from pfx.motion.odometry import (
    OdometryAlphas,
    log_densities_odometry,
    move_by_odometry,
    relative_motion,
    sample_motion_model_odometry,
)
from pfx.studies.base import STUDIES
from pfx.studies.robot_motion import MotionDensity, MotionSamples, NamedSetting, Pose, RobotMotion


class OdometrySetting(NamedSetting):
    """A named setting of the odometry model's error parameters."""

    alphas: OdometryAlphas = Field(description="[alpha1, ..., alpha4] (Table 5.6)")


class OdometryMotion(RobotMotion):
    """One odometry reading pair applied at ``start`` under several named error settings."""

    odometry_before: Pose = Field((0.0, 0.0, 0.0), description="odometry reading before the motion [x, y, theta]")
    odometry_after: Pose = Field((1.0, 0.4, 0.8), description="odometry reading after the motion [x, y, theta]")
    settings: list[OdometrySetting] = Field(min_length=1, max_length=12,
                                            description="named alpha settings, one panel each: {name, label, alphas: [a1, ..., a4]}")

    def motion(self) -> tuple[float, float, float]:
        """(rot1, trans, rot2) of the readings."""
        return tuple(float(part) for part in relative_motion(self.odometry_before, self.odometry_after))

    def sample_poses(self, setting, noise: MotionNoise, count: int, random: np.random.Generator) -> np.ndarray:
        return sample_motion_model_odometry(self.odometry_before, self.odometry_after,
                                            np.broadcast_to(self.start, (count, 3)), setting.alphas, noise, random)

    def log_densities(self, poses, setting, noise: MotionNoise) -> tuple[np.ndarray, np.ndarray]:
        return log_densities_odometry(poses, self.odometry_before, self.odometry_after, self.start, setting.alphas,
                                      noise)

    def commanded_path(self, points: int) -> np.ndarray:
        """Turn by rot1 on the spot, drive straight, turn by rot2 at the end (last pose)."""
        rotation1, translation, rotation2 = self.motion()
        fractions = np.linspace(0.0, 1.0, points)
        path = move_by_odometry(np.broadcast_to(self.start, (points, 3)), rotation1, fractions * translation,
                                np.where(fractions < 1.0, 0.0, rotation2))
        path[0, 2] = self.start[2]
        return path

    def heading_spread(self, setting) -> float:
        rotation1, translation, rotation2 = self.motion()
        return math.sqrt(float(setting.alphas.variances(rotation1, translation, rotation2)[2]))


@STUDIES.register_kind
class OdometryMotionDensity(MotionDensity, OdometryMotion):
    """Fig. 5.8: the odometry model's pose density in x-y for named alpha settings, checked against the sampler."""

    kind: Literal["odometry_motion_density"] = "odometry_motion_density"


@STUDIES.register_kind
class OdometryMotionSamples(MotionSamples, OdometryMotion):
    """Fig. 5.9: poses drawn by sample_motion_model_odometry (normal and triangular) and their spread."""

    kind: Literal["odometry_motion_samples"] = "odometry_motion_samples"
