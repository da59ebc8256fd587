r"""The velocity motion model: Probabilistic Robotics Tables 5.1 and 5.3 (corrected printing).

A robot at pose :math:`x_{t-1} = (x, y, \theta)` is commanded a translational velocity
:math:`v` and a rotational velocity :math:`\omega` for a time :math:`\Delta t`; it moves on a
circle of radius :math:`v/\omega`. The executed velocities differ from the command, and a final
extra rotation :math:`\hat\gamma` keeps the pose distribution three-dimensional:

.. math::

    \hat v = v + \mathrm{sample}(\alpha_1 v^2 + \alpha_2 \omega^2), \quad
    \hat\omega = \omega + \mathrm{sample}(\alpha_3 v^2 + \alpha_4 \omega^2), \quad
    \hat\gamma = \mathrm{sample}(\alpha_5 v^2 + \alpha_6 \omega^2),

    x' = x - \tfrac{\hat v}{\hat\omega} \sin\theta + \tfrac{\hat v}{\hat\omega} \sin(\theta + \hat\omega\Delta t), \quad
    y' = y + \tfrac{\hat v}{\hat\omega} \cos\theta - \tfrac{\hat v}{\hat\omega} \cos(\theta + \hat\omega\Delta t), \quad
    \theta' = \theta + \hat\omega\Delta t + \hat\gamma\Delta t

(Table 5.3; ``sample(b)`` and ``prob(a, b)`` take a variance, :mod:`pfx.motion.distributions`).
pfx writes the arc in the equivalent form

.. math::

    x' = x + \hat v\Delta t\, \mathrm{sinc}(\tfrac{\hat\omega\Delta t}{2})
         \cos(\theta + \tfrac{\hat\omega\Delta t}{2}), \quad
    y' = y + \hat v\Delta t\, \mathrm{sinc}(\tfrac{\hat\omega\Delta t}{2}) \sin(\theta + \tfrac{\hat\omega\Delta t}{2}),
    \qquad \mathrm{sinc}(a) = \sin(a)/a,

(from :math:`\sin B - \sin A = 2\cos\frac{A+B}{2}\sin\frac{B-A}{2}`): the chord of the arc, of
length :math:`|\hat v\Delta t\,\mathrm{sinc}|`, in the direction halfway between the two headings.
It equals the book's expression wherever that one is defined and is exactly the straight line
:math:`x' = x + \hat v\Delta t\cos\theta` at :math:`\hat\omega = 0`, with no threshold and no
loss of precision as :math:`\hat\omega \to 0`. Headings are wrapped to :math:`(-\pi, \pi]`.

**The density** :math:`p(x_t \mid u_t, x_{t-1})` (Table 5.1) inverts the motion: it finds the
executed :math:`(\hat v, \hat\omega, \hat\gamma)` that lead from :math:`x_{t-1}` to
:math:`x_t` and returns

.. math::

    \mathrm{prob}(v - \hat v,\ \alpha_1 v^2 + \alpha_2 \omega^2)\;
    \mathrm{prob}(\omega - \hat\omega,\ \alpha_3 v^2 + \alpha_4 \omega^2)\;
    \mathrm{prob}(\hat\gamma,\ \alpha_5 v^2 + \alpha_6 \omega^2).

The book finds the circle's centre :math:`(x^*, y^*)` from :math:`\mu`, then
:math:`\Delta\theta`, :math:`\hat v = \Delta\theta\, r^* / \Delta t`,
:math:`\hat\omega = \Delta\theta / \Delta t`, :math:`\hat\gamma = (\theta' - \theta)/\Delta t - \hat\omega`.
pfx computes the same circle in the robot's frame, which needs no centre and has a straight-line
limit: with the displacement :math:`(f, l)` ahead of and to the left of the robot, chord
:math:`c = \sqrt{f^2 + l^2}` and chord angle :math:`\varphi = \mathrm{atan2}(l, f)`, the arc
tangent to the heading turns by twice the chord angle (tangent-chord theorem), so

.. math::

    \hat\omega\Delta t = 2\varphi, \qquad \hat v\Delta t = c / \mathrm{sinc}(\varphi), \qquad
    \hat\gamma\Delta t = \mathrm{wrap}(\theta' - \theta - \hat\omega\Delta t),

the exact inverse of the arc above (straight ahead: :math:`\varphi = 0`, :math:`\hat v\Delta t = c`).
Two differences from the printed table, both deliberate:

* **Direction of travel.** The printed :math:`\hat v = \Delta\theta\, r^*/\Delta t` takes the
  unsigned radius :math:`r^*`, so :math:`\hat v` gets the sign of :math:`\Delta\theta`: a robot
  driving forward while turning right (:math:`v > 0`, :math:`\omega < 0`) is assigned
  :math:`\hat v < 0` and a near-zero density. The same two points are reached forward
  (:math:`\hat v > 0`, the chord angle :math:`\varphi`) or backward (:math:`\hat v < 0`, the
  chord angle :math:`\varphi \pm \pi`, i.e. :math:`\mathrm{wrap}(\varphi + \pi)`, and
  :math:`\hat v\Delta t = -c/\mathrm{sinc}`); pfx evaluates the product above at both preimages
  and adds them. Whenever :math:`|v|` is large against its noise the wrong-direction term is
  negligible and the result is the book's; near :math:`v = 0` both directions count.
* **Turns up to a full circle.** :math:`\hat\omega\Delta t = 2\varphi` covers
  :math:`(-2\pi, 2\pi]`, where normalising :math:`\Delta\theta` to :math:`(-\pi, \pi]` would
  misread turns of more than half a circle per step.

A pose with no displacement at all (:math:`c = 0`) is read as :math:`\hat v = \hat\omega = 0`
forward and as a full turn on the spot backward: there the split between :math:`\hat\omega` and
:math:`\hat\gamma` is not determined by the poses, a degenerate case of the book's model. As in
the book, the value is the density of the executed noise at the pose's preimage; the density of
the pose itself also divides by the Jacobian of the map
:math:`(\hat v, \hat\omega, \hat\gamma) \mapsto x_t`, which the book's algorithm leaves out:

.. math::

    p_{pose}(x_t \mid u_t, x_{t-1}) = \sum_{\text{forward, backward}}
    \frac{\mathrm{prob}(\cdot)\,\mathrm{prob}(\cdot)\,\mathrm{prob}(\cdot)}{|J|}, \qquad
    |J| = \Big|\det \frac{\partial(x', y', \theta')}{\partial(\hat v, \hat\omega, \hat\gamma)}\Big|
        = \tfrac12 |\hat v|\, \Delta t^4\, \mathrm{sinc}^2(\tfrac{\hat\omega\Delta t}{2})

(:func:`arc_jacobian`, :func:`pose_density_velocity`). This is the density the sampler's poses
follow (it integrates to 1 over :math:`(x, y, \theta)`); Table 5.1's value is it times
:math:`|J|`, which varies with :math:`\hat v`, so the two differ in shape by a few per cent
when the translational noise is a few per cent of :math:`v`.

Arrays: poses are ``(..., 3)`` (x, y, theta in radians), controls ``(..., 2)`` (v, omega);
leading dimensions broadcast. NumPy or JAX arrays (:mod:`pfx.numerics.arrays`): every function
computes in its arguments' namespace, the same operations on both (a sampler draws from the
``random`` it is given: a NumPy Generator, TrialStreams or KeyStreams).
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, model_validator

from pfx.motion.distributions import MotionNoise, Random, as_float_array, log_prob, log_product, sample
from pfx.numerics.angles import wrap_to_pi
from pfx.numerics.arrays import namespace
from pfx.registry import list_form


class VelocityAlphas(BaseModel):
    r"""The velocity model's error parameters :math:`\alpha_1 .. \alpha_6` (Table 5.3).

    In a config: a list ``[a1, a2, a3, a4, a5, a6]`` or a mapping ``{alpha1: ..., ...}``.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    alpha1: StrictFloat = Field(ge=0, description="variance of v^ per v^2 (translational error from translation)")
    alpha2: StrictFloat = Field(
        ge=0, description="variance of v^ per w^2 (translational error from rotation; m^2/rad^2)")
    alpha3: StrictFloat = Field(
        ge=0, description="variance of w^ per v^2 (rotational error from translation; rad^2/m^2)")
    alpha4: StrictFloat = Field(ge=0, description="variance of w^ per w^2 (rotational error from rotation)")
    alpha5: StrictFloat = Field(ge=0, description="variance of the final rotation g^ per v^2 (rad^2/m^2)")
    alpha6: StrictFloat = Field(ge=0, description="variance of the final rotation g^ per w^2")

    __get_pydantic_json_schema__ = list_form(6, 6)

    @model_validator(mode="before")
    @classmethod
    def _from_list(cls, data):
        if isinstance(data, (list, tuple)):
            if len(data) != 6:
                raise ValueError(f"expected 6 values [alpha1, ..., alpha6], got {len(data)}")
            return {f"alpha{i + 1}": value for i, value in enumerate(data)}
        return data

    @classmethod
    def of(cls, alphas: Union["VelocityAlphas", Sequence[float]]) -> "VelocityAlphas":
        """The alphas themselves, or a sequence a1..a6 made into them."""
        return alphas if isinstance(alphas, cls) else cls.model_validate(list(alphas))

    def variances(self, v, w) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r"""Variances of :math:`\hat v`, :math:`\hat\omega`, :math:`\hat\gamma` for the command (v, w)."""
        xp = namespace(v, w)
        v2, w2 = xp.square(v), xp.square(w)
        return (self.alpha1 * v2 + self.alpha2 * w2, self.alpha3 * v2 + self.alpha4 * w2,
                self.alpha5 * v2 + self.alpha6 * w2)


def _sinc(angle):
    """sin(a) / a, equal to 1 at a = 0."""
    xp = namespace(angle)
    return xp.sinc(as_float_array(angle) / np.pi)


def move_on_arc(pose, v, w, gamma, dt: float) -> np.ndarray:
    r"""The pose after driving at (v, w) for dt, then turning by gamma dt (Table 5.3, lines 5 to 7).

    .. math:: (x, y) \mathrel{+}= v\Delta t\,\mathrm{sinc}(\omega\Delta t/2)\,
              (\cos, \sin)(\theta + \omega\Delta t/2), \quad
              \theta' = \mathrm{wrap}(\theta + \omega\Delta t + \gamma\Delta t).
    """
    xp = namespace(pose, v, w, gamma)
    pose = as_float_array(pose)
    theta = pose[..., 2]
    half_turn = 0.5 * w * dt
    chord = v * dt * _sinc(half_turn)
    heading = theta + half_turn
    return xp.stack(xp.broadcast_arrays(pose[..., 0] + chord * xp.cos(heading),
                                        pose[..., 1] + chord * xp.sin(heading),
                                        wrap_to_pi(theta + w * dt + gamma * dt)), axis=-1)


def executed_velocities(pose_before, pose_now, dt: float, direction: int = 1):
    r"""The executed :math:`(\hat v, \hat\omega, \hat\gamma)` leading from ``pose_before`` to ``pose_now``.

    Table 5.1, lines 2 to 8, in the robot's frame (see the module docstring):
    :math:`\hat\omega\Delta t = 2\varphi`, :math:`\hat v\Delta t = \pm c/\mathrm{sinc}(\varphi)`,
    :math:`\hat\gamma\Delta t = \mathrm{wrap}(\theta' - \theta - \hat\omega\Delta t)`, with
    ``direction`` +1 (forward, :math:`\hat v \ge 0`) or -1 (backward, chord angle turned by pi).
    Returns three arrays of the broadcast leading shape.
    """
    xp = namespace(pose_before, pose_now)
    pose_before = as_float_array(pose_before)
    pose_now = as_float_array(pose_now)
    dx = pose_now[..., 0] - pose_before[..., 0]
    dy = pose_now[..., 1] - pose_before[..., 1]
    theta = pose_before[..., 2]
    ahead = dx * xp.cos(theta) + dy * xp.sin(theta)
    left = -dx * xp.sin(theta) + dy * xp.cos(theta)
    chord = xp.hypot(ahead, left)
    chord_angle = xp.arctan2(left, ahead)
    if direction < 0:
        chord_angle = wrap_to_pi(chord_angle + np.pi)
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = xp.where(chord > 0, np.sign(direction) * chord / _sinc(chord_angle), 0.0)
    turn = 2.0 * chord_angle
    final_turn = wrap_to_pi(pose_now[..., 2] - theta - turn)
    return distance / dt, turn / dt, final_turn / dt


def sample_motion_model_velocity(control, pose, dt: float, alphas, noise: MotionNoise,
                                 random: Random) -> np.ndarray:
    r"""Table 5.3: a pose :math:`x_t \sim p(x_t \mid u_t, x_{t-1})` for control (v, w) and pose (x, y, theta).

    .. math::

        \hat v = v + \mathrm{sample}(\alpha_1 v^2 + \alpha_2 \omega^2), \quad
        \hat\omega = \omega + \mathrm{sample}(\alpha_3 v^2 + \alpha_4 \omega^2), \quad
        \hat\gamma = \mathrm{sample}(\alpha_5 v^2 + \alpha_6 \omega^2),

    then the arc of :func:`move_on_arc`. ``control`` (..., 2) and ``pose`` (..., 3) broadcast;
    ``noise`` is ``normal`` or ``triangular`` (Table 5.4); ``random`` a Generator or TrialStreams
    (then the leading axis is the trial axis). Three draws per pose, in the order v, w, gamma.
    """
    xp = namespace(control, pose)
    control, pose = as_float_array(control), as_float_array(pose)
    shape = np.broadcast_shapes(control.shape[:-1], pose.shape[:-1])
    v, w = (xp.broadcast_to(control[..., i], shape) for i in range(2))
    variance_v, variance_w, variance_gamma = VelocityAlphas.of(alphas).variances(v, w)
    v_hat = v + sample(variance_v, random, noise)
    w_hat = w + sample(variance_w, random, noise)
    gamma_hat = sample(variance_gamma, random, noise)
    return move_on_arc(xp.broadcast_to(pose, shape + (3,)), v_hat, w_hat, gamma_hat, dt)


def arc_jacobian(v_hat, w_hat, dt: float) -> np.ndarray:
    r""":math:`|\det \partial(x', y', \theta') / \partial(\hat v, \hat\omega, \hat\gamma)|
    = \tfrac12 |\hat v|\, \Delta t^4\, \mathrm{sinc}^2(\hat\omega\Delta t / 2)`.

    In the robot's frame the move is the chord :math:`c = \hat v\Delta t\,\mathrm{sinc}\,\varphi`
    at the angle :math:`\varphi = \hat\omega\Delta t / 2`. In polar coordinates
    :math:`(c, \varphi)` the area element is :math:`|c|\, dc\, d\varphi`, and
    :math:`\partial(c, \varphi)/\partial(\hat v, \hat\omega)` is triangular with diagonal
    :math:`(\Delta t\,\mathrm{sinc}\,\varphi, \Delta t / 2)`; :math:`\theta'` gains
    :math:`\Delta t` per unit of :math:`\hat\gamma`, on which x' and y' do not depend.
    """
    xp = namespace(v_hat, w_hat)
    return 0.5 * xp.abs(v_hat) * dt ** 4 * _sinc(0.5 * as_float_array(w_hat) * dt) ** 2


def log_densities_velocity(pose_now, control, pose_before, dt: float, alphas,
                           noise: MotionNoise = "normal") -> tuple[np.ndarray, np.ndarray]:
    """(log :func:`motion_model_velocity`, log :func:`pose_density_velocity`), sharing the preimages.

    Each preimage's term is the noise density (Table 5.1's product); the pose density divides
    each term by its :func:`arc_jacobian` before the two preimages are added.
    """
    xp = namespace(pose_now, control, pose_before)
    control = as_float_array(control)
    v, w = control[..., 0], control[..., 1]
    variance_v, variance_w, variance_gamma = VelocityAlphas.of(alphas).variances(v, w)
    noise_terms, pose_terms = [], []
    for direction in (1, -1):
        v_hat, w_hat, gamma_hat = executed_velocities(pose_before, pose_now, dt, direction)
        term = log_product(log_prob(v - v_hat, variance_v, noise),
                           log_prob(w - w_hat, variance_w, noise),
                           log_prob(gamma_hat, variance_gamma, noise))
        noise_terms.append(term)
        with np.errstate(divide="ignore"):
            pose_terms.append(log_product(term, -xp.log(arc_jacobian(v_hat, w_hat, dt))))
    return xp.logaddexp(*noise_terms), xp.logaddexp(*pose_terms)


def log_motion_model_velocity(pose_now, control, pose_before, dt: float, alphas,
                              noise: MotionNoise) -> np.ndarray:
    """log of :func:`motion_model_velocity` (computed in the log domain; -inf where it is 0)."""
    return log_densities_velocity(pose_now, control, pose_before, dt, alphas, noise)[0]


def log_pose_density_velocity(pose_now, control, pose_before, dt: float, alphas,
                              noise: MotionNoise = "normal") -> np.ndarray:
    """log of :func:`pose_density_velocity`."""
    return log_densities_velocity(pose_now, control, pose_before, dt, alphas, noise)[1]


def pose_density_velocity(pose_now, control, pose_before, dt: float, alphas,
                          noise: MotionNoise = "normal") -> np.ndarray:
    r"""The density of the sampled pose (per m^2 rad): Table 5.1's terms divided by :func:`arc_jacobian`.

    .. math::

        \sum_{\text{forward, backward}}
        \frac{\mathrm{prob}(v - \hat v, \alpha_1 v^2 + \alpha_2 \omega^2)\,
               \mathrm{prob}(\omega - \hat\omega, \alpha_3 v^2 + \alpha_4 \omega^2)\,
               \mathrm{prob}(\hat\gamma, \alpha_5 v^2 + \alpha_6 \omega^2)}
              {\tfrac12 |\hat v|\, \Delta t^4\, \mathrm{sinc}^2(\hat\omega\Delta t/2)}

    The density that :func:`sample_motion_model_velocity`'s poses follow (change of variables);
    infinite where the Jacobian vanishes (no displacement, a set of measure zero).
    """
    log_density = log_pose_density_velocity(pose_now, control, pose_before, dt, alphas, noise)
    return namespace(log_density).exp(log_density)


def motion_model_velocity(pose_now, control, pose_before, dt: float, alphas,
                          noise: MotionNoise = "normal") -> np.ndarray:
    r"""Table 5.1: :math:`p(x_t \mid u_t, x_{t-1})` for poses (..., 3) and controls (..., 2).

    .. math::

        \sum_{\text{forward, backward}}
        \mathrm{prob}(v - \hat v, \alpha_1 v^2 + \alpha_2 \omega^2)\,
        \mathrm{prob}(\omega - \hat\omega, \alpha_3 v^2 + \alpha_4 \omega^2)\,
        \mathrm{prob}(\hat\gamma, \alpha_5 v^2 + \alpha_6 \omega^2)

    with :math:`(\hat v, \hat\omega, \hat\gamma)` from :func:`executed_velocities` (see the module
    docstring for the two preimages and the straight-line limit).
    """
    log_density = log_motion_model_velocity(pose_now, control, pose_before, dt, alphas, noise)
    return namespace(log_density).exp(log_density)
