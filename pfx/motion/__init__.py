"""Probabilistic Robotics' motion models for a planar robot (Thrun, Burgard & Fox 2005, ch. 5).

A motion model is the transition law :math:`p(x_t \\mid u_t, x_{t-1})` of a robot pose
:math:`x = (x, y, \\theta)` under a control :math:`u_t`. Each comes as the book gives it, twice:
a sampler (what a particle filter's prediction step needs) and a density (what a histogram filter,
or a figure of the distribution, needs). Modules:

* :mod:`pfx.motion.distributions`: ``prob(a, b)`` and ``sample(b)`` of variance b, normal or
  triangular (Tables 5.2 and 5.4, corrected printing);
* :mod:`pfx.motion.velocity`: control :math:`(v, \\omega)`, Tables 5.1 and 5.3;
* :mod:`pfx.motion.odometry`: control = two odometry readings, Tables 5.5 and 5.6;
* :func:`pfx.numerics.angles.wrap_to_pi`: headings wrapped to (-pi, pi].

The book's densities are the density of the noise at the pose's preimage; ``pose_density_*``
also divide by the Jacobian of the map from noise to pose, giving the density the sampled poses
follow (the two differ in shape by a few per cent; see :mod:`pfx.motion.velocity`).

:class:`pfx.models.planar_robot.PlanarRobot` makes either one the transition of a pfx model.
"""

from pfx.motion.distributions import (
                                      log_prob,
                                      prob,
                                      prob_normal,
                                      prob_triangular,
                                      sample,
                                      sample_normal,
                                      sample_triangular,
)
from pfx.motion.odometry import (
                                      OdometryAlphas,
                                      motion_model_odometry,
                                      pose_density_odometry,
                                      relative_motion,
                                      sample_motion_model_odometry,
)
from pfx.motion.velocity import (
                                      VelocityAlphas,
                                      arc_jacobian,
                                      executed_velocities,
                                      motion_model_velocity,
                                      pose_density_velocity,
                                      sample_motion_model_velocity,
)
from pfx.numerics.angles import wrap_to_pi

__all__ = ["wrap_to_pi", "log_prob", "prob", "prob_normal", "prob_triangular", "sample", "sample_normal",
           "sample_triangular", "OdometryAlphas", "motion_model_odometry", "relative_motion",
           "sample_motion_model_odometry", "VelocityAlphas", "executed_velocities", "motion_model_velocity",
           "sample_motion_model_velocity", "arc_jacobian", "pose_density_velocity", "pose_density_odometry"]
