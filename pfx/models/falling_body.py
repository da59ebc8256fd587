r"""Falling body (ballistic re-entry): altitude, velocity and ballistic coefficient from radar range.

State :math:`x = [x_1, x_2, x_3]` = [altitude, velocity, ballistic coefficient]; a radar at
horizontal distance :math:`M` and altitude :math:`H` measures the range

.. math:: z = \sqrt{M^2 + (x_1 - H)^2} + v, \qquad v \sim \text{noise}(R).

Two published parameterisations (sources and reference values: docs/reference-facts.md#falling-body):

``variant: jud`` (Athans, Wishner & Bertolini 1968; Julier, Uhlmann & Durrant-Whyte 2000):
:math:`\dot x_1 = -x_2,\ \dot x_2 = -e^{-\gamma x_1} x_2^2 x_3,\ \dot x_3 = 0` with
:math:`x_2` the downward speed, :math:`\gamma = 5\cdot10^{-5}` 1/ft, no gravity; measurements every
1 s for 60 s, truth integrated by RK4 at 64 sub-steps per second; truth starts at
[3e5 ft, 2e4 ft/s, 1e-3 1/ft] and the filter's prior is N([3e5, 2e4, 3e-5], diag(1e6, 4e6, 1e-4))
(a badly wrong x_3).

``variant: simon`` (D. Simon, *Optimal State Estimation*, 2006, Example 14.2):
:math:`\dot x_1 = x_2,\ \dot x_2 = \tfrac{\rho_0}{2} e^{-x_1/k} x_2^2 x_3 - g,\ \dot x_3 = 0` with
:math:`\rho_0 = 2,\ g = 32.2` ft/s², k = 2e4 ft, T = 0.5 s for 30 s, prior centred on the truth
with covariance diag(1e6, 4e6, 10). ``units: si`` gives the numerically equivalent SI form
(rho_0 = 1.225 kg/m³, g = 9.81 m/s², k = 6096 m, M = H = 30480 m, R = 929.03 m²).

Both are one equation in pfx: with :math:`s = -1` (jud, downward speed) or :math:`+1` (simon),
:math:`\dot x_1 = s x_2` and :math:`\dot x_2 = s\,(\tfrac{\rho_0}{2} e^{-x_1/k} x_2^2 x_3 - g)`;
jud is :math:`\rho_0 = 2`, :math:`k = 1/\gamma`, :math:`g = 0`.
Process noise (default zero, as in both sources) is added after each integration interval.
The model's ``substeps`` field is its own (older than the substeps of every model,
:mod:`pfx.models.base`): the RK4 or Euler steps inside one ``propagate`` call that spans the
whole interval (``substeps_inside_propagate``), so the transition calls ``propagate`` once per
step and draws one noise per interval, as the sources do.

EKF Jacobians: the measurement's is analytic, :math:`\partial r / \partial x = [(x_1 - H)/r, 0, 0]`
(:math:`r \ge M > 0`, so it is defined everywhere); the transition's is central finite differences
(the transition is an RK4 or Euler integration, not a closed form); the process noise is added
after the integration, so its Jacobian is the identity.

Simon's own reference truth (x_1 = 101026, 38791, 31123 ft at 10, 20, 30 s) was integrated by
Euler's method at 1 ms: ``integrator: euler, substeps: 500`` reproduces it; the default RK4
agrees with the exact solution to better than 0.01 ft and differs from the printed values by
at most 4 ft at the printed times (Euler's O(h) error reaches 7.4 ft elsewhere on the path).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal, Optional

import numpy as np
from pydantic import Field, StrictFloat, StrictInt

from pfx.laws.initial import GaussianLaw, PointLaw
from pfx.laws.noise import Noise
from pfx.models.base import MODELS, Model
from pfx.numerics.arrays import namespace, repeat
from pfx.numerics.compiled import compiled

FOOT = 0.3048
# rho0 x3 / 2 must be the same physical number in both unit systems: 1e-3 1/ft = 3.2808e-3 1/m.
SI_BALLISTIC_COEFFICIENT = 5.3564e-3

_PRESETS = {
    ("jud", "ft"): dict(
        radar_distance=1e5, radar_altitude=1e5, air_density=2.0, scale_height=2e4, gravity=0.0,
        dt=1.0, steps=60, substeps=64, measurement_variance=1e4,
        initial=[3e5, 2e4, 1e-3], prior_mean=[3e5, 2e4, 3e-5], prior_variance=[1e6, 4e6, 1e-4]),
    ("simon", "ft"): dict(
        radar_distance=1e5, radar_altitude=1e5, air_density=2.0, scale_height=2e4, gravity=32.2,
        dt=0.5, steps=60, substeps=13, measurement_variance=1e4,
        initial=[3e5, -2e4, 1e-3], prior_mean=[3e5, -2e4, 1e-3], prior_variance=[1e6, 4e6, 10.0]),
    ("simon", "si"): dict(
        radar_distance=30480.0, radar_altitude=30480.0, air_density=1.225, scale_height=6096.0,
        gravity=9.81, dt=0.5, steps=60, substeps=13, measurement_variance=929.03,
        initial=[91440.0, -6096.0, SI_BALLISTIC_COEFFICIENT],
        prior_mean=[91440.0, -6096.0, SI_BALLISTIC_COEFFICIENT],
        prior_variance=[1e6 * FOOT**2, 4e6 * FOOT**2, 10.0 * (SI_BALLISTIC_COEFFICIENT / 1e-3) ** 2]),
}


@MODELS.register_kind
class FallingBody(Model):
    """Falling body re-entry benchmark (variants jud and simon, feet or SI)."""

    kind: Literal["falling_body"] = "falling_body"
    variant: Literal["jud", "simon"] = Field("simon", description="parameterisation: jud (Athans/Julier) or simon")
    units: Literal["ft", "si"] = Field("ft", description="feet, or SI (variant simon only)")
    radar_distance: Optional[StrictFloat] = Field(None, gt=0, description="horizontal distance M of the radar")
    radar_altitude: Optional[StrictFloat] = Field(None, ge=0, description="altitude H of the radar")
    air_density: Optional[StrictFloat] = Field(None, gt=0, description="rho_0 (2 in the feet forms, so rho_0/2 = 1)")
    scale_height: Optional[StrictFloat] = Field(None, gt=0, description="k in exp(-x1/k) (1/gamma for jud)")
    gravity: Optional[StrictFloat] = Field(None, ge=0, description="g (0 for jud)")
    integrator: Literal["rk4", "euler"] = Field("rk4", description="integration scheme between measurements")
    substeps: Optional[StrictInt] = Field(None, ge=1, le=100_000, description="integration sub-steps per measurement interval")
    # propagate integrates the whole interval in `substeps` RK4 or Euler steps and adds the
    # process noise once, after it (the published setups): one propagate call per step.
    substeps_inside_propagate: ClassVar[bool] = True

    def presets(self):
        if (self.variant, self.units) not in _PRESETS:
            raise ValueError("@units: the SI form exists for variant simon only")
        preset = _PRESETS[(self.variant, self.units)]
        values = {key: preset[key] for key in
                  ("radar_distance", "radar_altitude", "air_density", "scale_height", "gravity",
                   "dt", "steps", "substeps")}
        values["process_noise"] = Noise(family="gaussian", variance=0.0)
        values["measurement_noise"] = Noise(family="gaussian", variance=preset["measurement_variance"])
        values["initial"] = PointLaw(state=preset["initial"])
        return values

    def default_prior(self):
        preset = _PRESETS[(self.variant, self.units)]
        return GaussianLaw(mean=preset["prior_mean"], covariance=preset["prior_variance"])

    @property
    def state_names(self):
        return ("altitude", "velocity", "ballistic_coefficient")

    @property
    def state_units(self):
        if self.units == "si":
            return ("m", "m/s", "m^2/kg")
        return ("ft", "ft/s", "1/ft")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def position_components(self):
        return (0,)

    def _derivative(self, altitude, velocity, coefficient):
        """(x1', x2') = s (x2, rho0/2 exp(-x1/k) x2^2 x3 - g), s = +1 (simon) or -1 (jud)."""
        xp = namespace(altitude)
        acceleration = (xp.exp(altitude * (-1.0 / self.scale_height)) * velocity * velocity * coefficient
                        * (0.5 * self.air_density) - self.gravity)
        if self.variant == "jud":                 # s = -1: x2 is the downward speed
            return -velocity, -acceleration
        return velocity, acceleration

    def propagate(self, state, control, noise):
        """x_k = f(x_{k-1}) + w_k: the interval integrated by ``substeps`` RK4 (or Euler) steps,
        then the process noise added; NumPy or JAX arrays."""
        altitude, velocity, coefficient = state[..., 0], state[..., 1], state[..., 2]
        h = self.dt / self.substeps
        derivative = self._derivative

        def substep(position):
            altitude, velocity = position
            if self.integrator == "euler":
                da, dv = derivative(altitude, velocity, coefficient)
                return altitude + h * da, velocity + h * dv
            a1, v1 = derivative(altitude, velocity, coefficient)
            a2, v2 = derivative(altitude + 0.5 * h * a1, velocity + 0.5 * h * v1, coefficient)
            a3, v3 = derivative(altitude + 0.5 * h * a2, velocity + 0.5 * h * v2, coefficient)
            a4, v4 = derivative(altitude + h * a3, velocity + h * v3, coefficient)
            return (altitude + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4),
                    velocity + h / 6.0 * (v1 + 2.0 * v2 + 2.0 * v3 + v4))

        # one compiled loop body on the jax backend, not `substeps` unrolled copies (pfx.numerics.arrays.repeat)
        altitude, velocity = repeat(self.substeps, substep, (altitude, velocity))
        # x_k = f(x_{k-1}) + w_k, component by component.
        xp = namespace(state, noise)
        if xp is not np:
            return xp.stack([value + noise[..., component]
                             for component, value in enumerate((altitude, velocity, coefficient))], axis=-1)
        # NumPy: written into one new array laid out like the noise (its layout decides which
        # kernels the filters' later matrix products take, hence their last bits: kept as ever).
        shape = np.broadcast_shapes(state.shape, noise.shape)
        moved = np.empty_like(noise) if noise.shape == shape else np.empty(shape)
        for component, value in enumerate((altitude, velocity, coefficient)):
            np.add(value, noise[..., component], out=moved[..., component])
        return moved

    def measurement_mean(self, state):
        offset = state[..., 0:1] - self.radar_altitude
        return namespace(state).sqrt(self.radar_distance ** 2 + offset * offset)

    def process_noise_jacobian(self, state, control):
        xp = namespace(state)
        return xp.broadcast_to(xp.eye(3, dtype=state.dtype), state.shape[:-1] + (3, 3))

    def measurement_jacobian(self, state):
        xp = namespace(state)
        offset = state[..., 0] - self.radar_altitude
        slope = offset / xp.sqrt(self.radar_distance ** 2 + offset * offset)
        zero = xp.zeros_like(slope)
        return xp.stack([slope, zero, zero], axis=-1)[..., None, :]

    def compiled_step(self):
        """The drag equations, the noise and the range likelihood in one compiled pass
        (:func:`falling_body_step`); None unless the range noise is Gaussian."""
        measurement = self.measurement_noise.independent_gaussian()
        if measurement is None:
            return None
        scale, log_determinant = measurement
        constants = np.array([
            -1.0 if self.variant == "jud" else 1.0, self.dt / self.substeps, float(self.substeps),
            1.0 if self.integrator == "rk4" else 0.0, 0.5 * self.air_density, -1.0 / self.scale_height,
            self.gravity, self.radar_distance ** 2, self.radar_altitude, float(scale[0]),
            0.5 * math.log(2.0 * math.pi), log_determinant])

        def step(state, control, noise, measurement):
            new_state = np.empty_like(noise) if noise.shape == state.shape else np.empty(state.shape)
            log_likelihood = np.empty(state.shape[:2])
            falling_body_step(state, noise, np.ascontiguousarray(measurement[..., 0]), constants, new_state,
                              log_likelihood)
            return new_state, log_likelihood

        return step


@compiled
def falling_body_step(state, noise, measurement, constants, new_state, log_likelihood):
    """x_k = f(x_{k-1}) + w_k and log p(z_k | x_k) for every particle, in one pass.

    The arithmetic is :meth:`FallingBody.propagate`'s and the Gaussian log-density's, operation
    for operation (only ``exp`` is the compiled one). ``constants``: s, h, substeps, RK4 (1) or
    Euler (0), rho0 / 2, -1 / k, g, M^2, H, range noise std, log(2 pi) / 2, log of the std.
    """
    sign, h, substeps, rk4 = constants[0], constants[1], int(constants[2]), constants[3] > 0.5
    half_density, decay, gravity = constants[4], constants[5], constants[6]
    radar_distance_squared, radar_altitude, noise_std = constants[7], constants[8], constants[9]
    half_log_two_pi, log_std = constants[10], constants[11]
    for r in range(state.shape[0]):
        z = measurement[r]
        for i in range(state.shape[1]):
            altitude, velocity, coefficient = state[r, i, 0], state[r, i, 1], state[r, i, 2]
            for _ in range(substeps):
                if rk4:
                    a1 = sign * velocity
                    v1 = sign * (np.exp(altitude * decay) * velocity * velocity * coefficient * half_density - gravity)
                    altitude2, velocity2 = altitude + 0.5 * h * a1, velocity + 0.5 * h * v1
                    a2 = sign * velocity2
                    v2 = sign * (np.exp(altitude2 * decay) * velocity2 * velocity2 * coefficient * half_density - gravity)
                    altitude3, velocity3 = altitude + 0.5 * h * a2, velocity + 0.5 * h * v2
                    a3 = sign * velocity3
                    v3 = sign * (np.exp(altitude3 * decay) * velocity3 * velocity3 * coefficient * half_density - gravity)
                    altitude4, velocity4 = altitude + h * a3, velocity + h * v3
                    a4 = sign * velocity4
                    v4 = sign * (np.exp(altitude4 * decay) * velocity4 * velocity4 * coefficient * half_density - gravity)
                    altitude = altitude + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
                    velocity = velocity + h / 6.0 * (v1 + 2.0 * v2 + 2.0 * v3 + v4)
                else:
                    acceleration = np.exp(altitude * decay) * velocity * velocity * coefficient * half_density - gravity
                    altitude, velocity = altitude + h * (sign * velocity), velocity + h * (sign * acceleration)
            altitude += noise[r, i, 0]
            velocity += noise[r, i, 1]
            coefficient += noise[r, i, 2]
            new_state[r, i, 0], new_state[r, i, 1], new_state[r, i, 2] = altitude, velocity, coefficient
            offset = altitude - radar_altitude
            standard = (z - np.sqrt(radar_distance_squared + offset * offset)) / noise_std
            log_likelihood[r, i] = (-0.5 * standard * standard - half_log_two_pi) - log_std
