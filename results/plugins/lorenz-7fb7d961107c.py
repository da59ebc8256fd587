r"""A pfx plugin: the Lorenz-63 and Lorenz-96 systems, DAPPER's data-assimilation benchmarks.

Both are ordinary differential equations :math:`\dot x = g(x)`, integrated between two
measurements by ``substeps`` steps of the classical fourth-order Runge-Kutta scheme (RK4) of
length :math:`h` = ``substep_duration`` = ``dt / substeps`` (docs/plugins.md, "Observation
intervals"). One call of ``propagate`` is one substep, with the process noise added after it:

.. math::

    k_1 = h\,g(x), \quad k_2 = h\,g(x + k_1/2), \quad k_3 = h\,g(x + k_2/2), \quad
    k_4 = h\,g(x + k_3), \qquad
    x \leftarrow x + \tfrac16 (k_1 + 2 k_2 + 2 k_3 + k_4) + w,

with :math:`w` one draw of ``process_noise`` per substep (its variance is per substep, not per
unit time). The presets give no process noise at all (variance 0: pfx then draws nothing), as
DAPPER's benchmark files do: the filters must find the truth from the measurements alone.

**Lorenz-63** (``kind: lorenz63``; Lorenz 1963), three components :math:`(x, y, z)`:

.. math::

    \dot x = \sigma (y - x), \qquad \dot y = \rho x - y - x z, \qquad \dot z = x y - \beta z,

with :math:`\sigma = 10, \rho = 28, \beta = 8/3`. Every component is measured with Gaussian
noise, :math:`z_k = x_k + v_k`, :math:`v_k \sim N(0, 2 I)`; the initial law is
:math:`N(\mu_0, 2 I)` with :math:`\mu_0 = (1.509, -1.531, 25.46)`. With ``dt: 0.25`` and
``substeps: 25`` (an RK4 step of 0.01) this is Sakov, Oliver & Bertino (2012)'s setup as DAPPER's
``mods/Lorenz63/sakov2012.py`` writes it.

**Lorenz-96** (``kind: lorenz96``; Lorenz 1996), ``dimension`` components on a ring
(indices modulo :math:`n`):

.. math::

    \dot x_i = (x_{i+1} - x_{i-2})\, x_{i-1} - x_i + F, \qquad i = 0, \dots, n - 1,

with forcing :math:`F = 8` and :math:`n = 10`. The components listed in ``observed`` (every
other one by default: 0, 2, 4, 6, 8) are measured with Gaussian noise of variance
:math:`1.5^2` (Bocquet, Pires & Wu 2010's standard deviation 1.5; DAPPER's PyPI release 1.7.1
has the variance 1.5 in its file, its GitHub master :math:`1.5^2`); the initial law is
:math:`N(0, 0.001 I)`. With ``dt: 0.05`` and ``substeps: 1`` this is DAPPER's
``mods/Lorenz96/bocquet2010.py``.

For the extended Kalman filter each model gives the exact Jacobian of its RK4 substep (the
tangent-linear RK4: each stage's Jacobian by the chain rule,
:math:`K_1 = h\,J(x)`, :math:`K_2 = h\,J(x + k_1/2)(I + K_1/2)`,
:math:`K_3 = h\,J(x + k_2/2)(I + K_2/2)`, :math:`K_4 = h\,J(x + k_3)(I + K_3)`,
:math:`F = I + \tfrac16 (K_1 + 2 K_2 + 2 K_3 + K_4)`, with :math:`J = \partial g / \partial x`),
and the process noise enters additively (:math:`L = I`).

Every function is vectorised over leading axes ``(..., d)`` (trials, particles) in float64.
Run it: ``pfx run configs/benchmarks/dapper-lorenz/lorenz63.yaml``.
"""

from typing import Callable, ClassVar, Literal, Optional

import numpy as np
from pydantic import Field

import pfx

Tendency = Callable[[np.ndarray], np.ndarray]
TendencyJacobian = Callable[[np.ndarray], np.ndarray]


def rk4_step(tendency: Tendency, state: np.ndarray, duration: float) -> np.ndarray:
    r"""One classical Runge-Kutta step of ``duration`` h for :math:`\dot x = g(x)`:
    :math:`x + (k_1 + 2 k_2 + 2 k_3 + k_4) / 6` with the stages of the module docstring."""
    k1 = duration * tendency(state)
    k2 = duration * tendency(state + k1 / 2.0)
    k3 = duration * tendency(state + k2 / 2.0)
    k4 = duration * tendency(state + k3)
    return state + (k1 + 2.0 * (k2 + k3) + k4) / 6.0


def rk4_step_jacobian(tendency: Tendency, jacobian: TendencyJacobian, state: np.ndarray,
                      duration: float) -> np.ndarray:
    r"""The Jacobian :math:`F = \partial x_{new} / \partial x` of :func:`rk4_step`, exact:
    :math:`F = I + (K_1 + 2 K_2 + 2 K_3 + K_4) / 6` with :math:`K_1 = h J(x)`,
    :math:`K_2 = h J(x + k_1/2)(I + K_1/2)`, :math:`K_3 = h J(x + k_2/2)(I + K_2/2)`,
    :math:`K_4 = h J(x + k_3)(I + K_3)`; shape (..., d, d)."""
    identity = np.eye(state.shape[-1])
    k1 = duration * tendency(state)
    K1 = duration * jacobian(state)
    k2 = duration * tendency(state + k1 / 2.0)
    K2 = duration * jacobian(state + k1 / 2.0) @ (identity + K1 / 2.0)
    k3 = duration * tendency(state + k2 / 2.0)
    K3 = duration * jacobian(state + k2 / 2.0) @ (identity + K2 / 2.0)
    K4 = duration * jacobian(state + k3) @ (identity + K3)
    return identity + (K1 + 2.0 * (K2 + K3) + K4) / 6.0


class _LorenzSystem(pfx.Model):
    """What the two systems share: RK4 substeps plus additive noise, Gaussian measurements of
    some components, the exact RK4 Jacobian for the EKF."""

    integrates_substeps: ClassVar[bool] = True       # propagate advances one substep_duration
    time_unit: ClassVar[str] = "model time units"

    def tendency(self, state: np.ndarray) -> np.ndarray:
        """g(x) = dx/dt, shape (..., d)."""
        raise NotImplementedError

    def tendency_jacobian(self, state: np.ndarray) -> np.ndarray:
        """J(x) = dg/dx, shape (..., d, d)."""
        raise NotImplementedError

    @property
    def observed_components(self) -> tuple[int, ...]:
        return tuple(range(self.state_dimension))

    @property
    def measurement_dimension(self):
        return len(self.observed_components)

    def propagate(self, state, control, noise):
        return rk4_step(self.tendency, state, self.substep_duration) + noise

    def measurement_mean(self, state):
        return state[..., list(self.observed_components)]

    def transition_jacobian(self, state, control):
        return rk4_step_jacobian(self.tendency, self.tendency_jacobian, state, self.substep_duration)

    def process_noise_jacobian(self, state, control):
        return np.broadcast_to(np.eye(self.state_dimension), state.shape + (self.state_dimension,))

    def measurement_jacobian(self, state):
        selection = np.eye(self.state_dimension)[list(self.observed_components)]
        return np.broadcast_to(selection, state.shape[:-1] + selection.shape)


@pfx.register_model
class Lorenz63(_LorenzSystem):
    """Lorenz-63: x' = sigma (y - x), y' = rho x - y - x z, z' = x y - beta z; RK4 substeps."""

    kind: Literal["lorenz63"] = "lorenz63"
    sigma: float = Field(10.0, description="Prandtl number sigma")
    rho: float = Field(28.0, description="Rayleigh number rho")
    beta: float = Field(8.0 / 3.0, description="geometric factor beta")

    def presets(self):
        # Sakov et al. (2012) as DAPPER's sakov2012.py: R = 2 I, X0 = N(x0, 2 I), no model noise,
        # a measurement every 0.25 (the config sets substeps: 25 for DAPPER's RK4 step of 0.01).
        return {"steps": 1001, "dt": 0.25,
                "process_noise": pfx.Noise(variance=0.0),
                "measurement_noise": pfx.Noise(variance=2.0),
                "initial": pfx.GaussianLaw(mean=[1.509, -1.531, 25.46], covariance=2.0)}

    @property
    def state_names(self):
        return ("x", "y", "z")

    def tendency(self, state):
        x, y, z = state[..., 0], state[..., 1], state[..., 2]
        return np.stack([self.sigma * (y - x), self.rho * x - y - x * z, x * y - self.beta * z], axis=-1)

    def tendency_jacobian(self, state):
        x, y, z = state[..., 0], state[..., 1], state[..., 2]
        zero, one = np.zeros_like(x), np.ones_like(x)
        rows = [[-self.sigma * one, self.sigma * one, zero],
                [self.rho - z, -one, -x],
                [y, x, -self.beta * one]]
        return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


@pfx.register_model
class Lorenz96(_LorenzSystem):
    """Lorenz-96: x_i' = (x_{i+1} - x_{i-2}) x_{i-1} - x_i + F on a ring; RK4 substeps."""

    kind: Literal["lorenz96"] = "lorenz96"
    dimension: int = Field(10, ge=4, le=10_000, description="number of components n on the ring")
    forcing: float = Field(8.0, description="forcing F")
    observed: Optional[list[int]] = Field(
        None, description="indices of the measured components (default every other one: 0, 2, 4, ...)")

    def presets(self):
        # Bocquet et al. (2010) as DAPPER's bocquet2010.py: X0 = N(0, 0.001 I), no model noise,
        # a measurement every 0.05 for T = 64; R = 1.5^2 I (GitHub master; PyPI 1.7.1: 1.5 I).
        return {"steps": 1280, "dt": 0.05,
                "observed": list(range(0, self.dimension, 2)),
                "process_noise": pfx.Noise(variance=0.0),
                "measurement_noise": pfx.Noise(variance=1.5**2),
                "initial": pfx.GaussianLaw(mean=[0.0] * self.dimension, covariance=0.001)}

    def check(self):
        if not self.observed:
            raise ValueError("@observed: give at least one measured component")
        if any(not 0 <= index < self.dimension for index in self.observed):
            raise ValueError(f"@observed: indices must lie in 0..{self.dimension - 1} (dimension {self.dimension})")
        if len(set(self.observed)) != len(self.observed):
            raise ValueError("@observed: each component at most once")

    @property
    def state_names(self):
        return tuple(f"x{index}" for index in range(self.dimension))

    @property
    def observed_components(self):
        return tuple(self.observed)

    def tendency(self, state):
        # np.roll(x, -1)[i] = x_{i+1}, np.roll(x, 2)[i] = x_{i-2}, np.roll(x, 1)[i] = x_{i-1}
        following, second_before, before = (np.roll(state, shift, axis=-1) for shift in (-1, 2, 1))
        return (following - second_before) * before - state + self.forcing

    def tendency_jacobian(self, state):
        # dg_i/dx_{i+1} = x_{i-1}, dg_i/dx_{i-2} = -x_{i-1}, dg_i/dx_{i-1} = x_{i+1} - x_{i-2}, dg_i/dx_i = -1
        n = self.dimension
        rows = np.arange(n)
        jacobian = np.zeros(state.shape + (n,))
        before = np.roll(state, 1, axis=-1)
        jacobian[..., rows, (rows + 1) % n] += before
        jacobian[..., rows, (rows - 2) % n] -= before
        jacobian[..., rows, (rows - 1) % n] += np.roll(state, -1, axis=-1) - np.roll(state, 2, axis=-1)
        jacobian[..., rows, rows] -= 1.0
        return jacobian
