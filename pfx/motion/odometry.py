r"""The odometry motion model: Probabilistic Robotics Tables 5.5 and 5.6 (corrected variance terms).

The control is a pair of odometry readings :math:`u_t = (\bar x_{t-1}, \bar x_t)`, poses in the
robot's internal (drifting) frame. Only their relative motion is used, decomposed into a
rotation, a translation and a second rotation:

.. math::

    \delta_{rot1} = \mathrm{atan2}(\bar y' - \bar y, \bar x' - \bar x) - \bar\theta, \quad
    \delta_{trans} = \sqrt{(\bar x' - \bar x)^2 + (\bar y' - \bar y)^2}, \quad
    \delta_{rot2} = \bar\theta' - \bar\theta - \delta_{rot1}.

**Sampling** (Table 5.6) perturbs each part, with variances from the readings:

.. math::

    \hat\delta_{rot1} = \delta_{rot1} - \mathrm{sample}(\alpha_1 \delta_{rot1}^2 + \alpha_2 \delta_{trans}^2), \quad
    \hat\delta_{trans} = \delta_{trans} - \mathrm{sample}(\alpha_3 \delta_{trans}^2 + \alpha_4 \delta_{rot1}^2
        + \alpha_4 \delta_{rot2}^2), \quad
    \hat\delta_{rot2} = \delta_{rot2} - \mathrm{sample}(\alpha_1 \delta_{rot2}^2 + \alpha_2 \delta_{trans}^2),

    x' = x + \hat\delta_{trans}\cos(\theta + \hat\delta_{rot1}), \quad
    y' = y + \hat\delta_{trans}\sin(\theta + \hat\delta_{rot1}), \quad
    \theta' = \theta + \hat\delta_{rot1} + \hat\delta_{rot2}.

These are the later printings' squared terms (the first printing had
:math:`\alpha_1|\delta_{rot1}| + \alpha_2 \delta_{trans}` and so on).

**The density** (Table 5.5) recovers :math:`\hat\delta` from the hypothesised poses
:math:`x_{t-1}, x_t` by the same decomposition and returns

.. math::

    \mathrm{prob}(\delta_{rot1} - \hat\delta_{rot1}, \alpha_1 \delta_{rot1}^2 + \alpha_2 \delta_{trans}^2)\,
    \mathrm{prob}(\delta_{trans} - \hat\delta_{trans},
                 \alpha_3 \delta_{trans}^2 + \alpha_4 \delta_{rot1}^2 + \alpha_4 \delta_{rot2}^2)\,
    \mathrm{prob}(\delta_{rot2} - \hat\delta_{rot2}, \alpha_1 \delta_{rot2}^2 + \alpha_2 \delta_{trans}^2).

The printed Table 5.5 writes the variance terms with the hypothesis' :math:`\hat\delta`; pfx uses
the readings' :math:`\delta`, the same terms as the sampler, so that the density is the density of
the sampler's noise (the two differ by second-order terms when the noise is small).

Choices, each where the book is silent:

* Angles are wrapped to :math:`(-\pi, \pi]`: :math:`\delta_{rot1}`, :math:`\delta_{rot2}` and the
  differences :math:`\delta - \hat\delta` of the rotations, and the new heading.
* **No translation** (:math:`\delta_{trans} = 0` exactly, a turn on the spot): the direction
  :math:`\mathrm{atan2}(0, 0)` means nothing, so :math:`\delta_{rot1} = 0` and the whole turn is
  :math:`\delta_{rot2}` (as ROS amcl does below a small translation); likewise for
  :math:`\hat\delta` in the density.
* **Two preimages.** The poses are reached with :math:`\hat\delta_{trans} \ge 0` or, turning the
  other way round, with :math:`(\hat\delta_{rot1} + \pi, -\hat\delta_{trans}, \hat\delta_{rot2} - \pi)`
  (a sample whose translation noise exceeds the translation itself). The density adds the product
  at both; the second is negligible unless the translation noise is comparable to the translation.

As for the velocity model, the value is the density of the noise at the preimage (the book's
definition), not divided by the Jacobian of the map to poses. The density of the pose itself
(:func:`pose_density_odometry`, what the sampler's poses follow) divides each preimage's term by

.. math:: |J| = \Big|\det\frac{\partial(x', y', \theta')}
                {\partial(\hat\delta_{rot1}, \hat\delta_{trans}, \hat\delta_{rot2})}\Big|
          = |\hat\delta_{trans}|

(polar coordinates: the area element is :math:`|\hat\delta_{trans}|\, d\hat\delta_{trans}\,
d\hat\delta_{rot1}`, and :math:`\hat\delta_{rot2}` moves the heading alone). Poses are ``(..., 3)`` arrays
(x, y, theta in radians); leading dimensions broadcast. NumPy or JAX arrays
(:mod:`pfx.numerics.arrays`): every function computes in its arguments' namespace, the same
operations on both.
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, model_validator

from pfx.motion.distributions import MotionNoise, Random, as_float_array, log_prob, log_product, sample
from pfx.numerics.angles import wrap_to_pi
from pfx.numerics.arrays import namespace
from pfx.registry import list_form


class OdometryAlphas(BaseModel):
    r"""The odometry model's error parameters :math:`\alpha_1 .. \alpha_4` (Table 5.6).

    In a config: a list ``[a1, a2, a3, a4]`` or a mapping ``{alpha1: ..., ...}``.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    alpha1: StrictFloat = Field(ge=0, description="variance of a rotation per its own square (rotation from rotation)")
    alpha2: StrictFloat = Field(ge=0, description="variance of a rotation per translation^2 (rad^2/m^2)")
    alpha3: StrictFloat = Field(
        ge=0, description="variance of the translation per its own square (translation from translation)")
    alpha4: StrictFloat = Field(ge=0, description="variance of the translation per rotation^2 (m^2/rad^2)")

    __get_pydantic_json_schema__ = list_form(4, 4)

    @model_validator(mode="before")
    @classmethod
    def _from_list(cls, data):
        if isinstance(data, (list, tuple)):
            if len(data) != 4:
                raise ValueError(f"expected 4 values [alpha1, ..., alpha4], got {len(data)}")
            return {f"alpha{i + 1}": value for i, value in enumerate(data)}
        return data

    @classmethod
    def of(cls, alphas: Union["OdometryAlphas", Sequence[float]]) -> "OdometryAlphas":
        """The alphas themselves, or a sequence a1..a4 made into them."""
        return alphas if isinstance(alphas, cls) else cls.model_validate(list(alphas))

    def variances(self, rotation1, translation, rotation2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Variances of the first rotation, the translation and the second rotation (Table 5.6)."""
        xp = namespace(rotation1, translation, rotation2)
        r1, t, r2 = xp.square(rotation1), xp.square(translation), xp.square(rotation2)
        return (self.alpha1 * r1 + self.alpha2 * t, self.alpha3 * t + self.alpha4 * (r1 + r2),
                self.alpha1 * r2 + self.alpha2 * t)


def relative_motion(pose_before, pose_after) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""(rot1, trans, rot2) taking ``pose_before`` to ``pose_after`` (Table 5.5, lines 2 to 4 and 5 to 7).

    .. math:: \delta_{rot1} = \mathrm{wrap}(\mathrm{atan2}(\Delta y, \Delta x) - \theta), \quad
              \delta_{trans} = \sqrt{\Delta x^2 + \Delta y^2}, \quad
              \delta_{rot2} = \mathrm{wrap}(\theta' - \theta - \delta_{rot1}),

    with :math:`\delta_{rot1} = 0` when there is no translation at all.
    """
    xp = namespace(pose_before, pose_after)
    pose_before = as_float_array(pose_before)
    pose_after = as_float_array(pose_after)
    dx = pose_after[..., 0] - pose_before[..., 0]
    dy = pose_after[..., 1] - pose_before[..., 1]
    translation = xp.hypot(dx, dy)
    rotation1 = xp.where(translation > 0, wrap_to_pi(xp.arctan2(dy, dx) - pose_before[..., 2]), 0.0)
    rotation2 = wrap_to_pi(pose_after[..., 2] - pose_before[..., 2] - rotation1)
    return rotation1, translation, rotation2


def move_by_odometry(pose, rotation1, translation, rotation2) -> np.ndarray:
    r"""Table 5.6, lines 5 to 7: turn by rot1, go straight by trans, turn by rot2.

    .. math:: x' = x + \delta_{trans}\cos(\theta + \delta_{rot1}), \quad
              y' = y + \delta_{trans}\sin(\theta + \delta_{rot1}), \quad
              \theta' = \mathrm{wrap}(\theta + \delta_{rot1} + \delta_{rot2}).
    """
    xp = namespace(pose, rotation1, translation, rotation2)
    pose = as_float_array(pose)
    heading = pose[..., 2] + rotation1
    return xp.stack(xp.broadcast_arrays(pose[..., 0] + translation * xp.cos(heading),
                                        pose[..., 1] + translation * xp.sin(heading),
                                        wrap_to_pi(heading + rotation2)), axis=-1)


def sample_motion_model_odometry(odometry_before, odometry_after, pose, alphas, noise: MotionNoise,
                                 random: Random) -> np.ndarray:
    r"""Table 5.6: a pose :math:`x_t \sim p(x_t \mid u_t, x_{t-1})` for readings :math:`u_t = (\bar x_{t-1}, \bar x_t)`.

    .. math::

        \hat\delta_{rot1} = \delta_{rot1} - \mathrm{sample}(\alpha_1 \delta_{rot1}^2 + \alpha_2 \delta_{trans}^2), \quad
        \hat\delta_{trans} = \delta_{trans}
            - \mathrm{sample}(\alpha_3 \delta_{trans}^2 + \alpha_4 (\delta_{rot1}^2 + \delta_{rot2}^2)),

        \hat\delta_{rot2} = \delta_{rot2} - \mathrm{sample}(\alpha_1 \delta_{rot2}^2 + \alpha_2 \delta_{trans}^2),

    then :func:`move_by_odometry`. Readings and poses are (..., 3) and broadcast; ``noise`` is
    ``normal`` or ``triangular``; ``random`` a Generator or TrialStreams (trial axis first).
    Three draws per pose, in the order rot1, trans, rot2.
    """
    xp = namespace(odometry_before, odometry_after, pose)
    rotation1, translation, rotation2 = relative_motion(odometry_before, odometry_after)
    pose = as_float_array(pose)
    shape = np.broadcast_shapes(rotation1.shape, pose.shape[:-1])
    rotation1, translation, rotation2 = (xp.broadcast_to(part, shape) for part in (rotation1, translation, rotation2))
    variance1, variance_trans, variance2 = OdometryAlphas.of(alphas).variances(rotation1, translation, rotation2)
    rotation1_hat = rotation1 - sample(variance1, random, noise)
    translation_hat = translation - sample(variance_trans, random, noise)
    rotation2_hat = rotation2 - sample(variance2, random, noise)
    return move_by_odometry(xp.broadcast_to(pose, shape + (3,)), rotation1_hat, translation_hat, rotation2_hat)


def log_motion_model_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas,
                              noise: MotionNoise) -> np.ndarray:
    """log of :func:`motion_model_odometry` (computed in the log domain; -inf where it is 0)."""
    xp = namespace(pose_now, odometry_before, odometry_after, pose_before)
    rotation1, translation, rotation2 = relative_motion(odometry_before, odometry_after)
    variance1, variance_trans, variance2 = OdometryAlphas.of(alphas).variances(rotation1, translation, rotation2)
    rotation1_hat, translation_hat, rotation2_hat = relative_motion(pose_before, pose_now)
    terms = []
    for sign in (1.0, -1.0):     # the two preimages (see the module docstring)
        turn = 0.0 if sign > 0 else np.pi
        terms.append(log_product(
            log_prob(wrap_to_pi(rotation1 - rotation1_hat - turn), variance1, noise),
            log_prob(translation - sign * translation_hat, variance_trans, noise),
            log_prob(wrap_to_pi(rotation2 - rotation2_hat + turn), variance2, noise)))
    return xp.logaddexp(*terms)


def log_densities_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas,
                           noise: MotionNoise = "normal") -> tuple[np.ndarray, np.ndarray]:
    """(log :func:`motion_model_odometry`, log :func:`pose_density_odometry`).

    Both preimages share :math:`|J| = |\\hat\\delta_{trans}|`, so it divides their sum.
    """
    log_book = log_motion_model_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas, noise)
    _, translation_hat, _ = relative_motion(pose_before, pose_now)
    with np.errstate(divide="ignore"):
        return log_book, log_product(log_book, -namespace(translation_hat).log(translation_hat))


def log_pose_density_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas,
                              noise: MotionNoise = "normal") -> np.ndarray:
    """log of :func:`pose_density_odometry`."""
    return log_densities_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas, noise)[1]


def pose_density_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas,
                          noise: MotionNoise = "normal") -> np.ndarray:
    r"""The density of the sampled pose (per m^2 rad): Table 5.5's value divided by :math:`|\hat\delta_{trans}|`.

    The density that :func:`sample_motion_model_odometry`'s poses follow (change of variables,
    see the module docstring); infinite at zero displacement (a set of measure zero).
    """
    log_density = log_pose_density_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas, noise)
    return namespace(log_density).exp(log_density)


def motion_model_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas,
                          noise: MotionNoise = "normal") -> np.ndarray:
    r"""Table 5.5: :math:`p(x_t \mid u_t, x_{t-1})` for readings :math:`u_t = (\bar x_{t-1}, \bar x_t)`, poses (..., 3).

    .. math::

        \sum_{\text{both preimages}}
        \mathrm{prob}(\delta_{rot1} - \hat\delta_{rot1}, \alpha_1 \delta_{rot1}^2 + \alpha_2 \delta_{trans}^2)\,
        \mathrm{prob}(\delta_{trans} - \hat\delta_{trans},
                     \alpha_3 \delta_{trans}^2 + \alpha_4 (\delta_{rot1}^2 + \delta_{rot2}^2))\,
        \mathrm{prob}(\delta_{rot2} - \hat\delta_{rot2}, \alpha_1 \delta_{rot2}^2 + \alpha_2 \delta_{trans}^2)

    with :math:`\delta` from the readings and :math:`\hat\delta` from the poses
    (:func:`relative_motion`); see the module docstring for the choices made.
    """
    log_density = log_motion_model_odometry(pose_now, odometry_before, odometry_after, pose_before, alphas, noise)
    return namespace(log_density).exp(log_density)
