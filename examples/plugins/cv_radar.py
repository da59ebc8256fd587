r"""A pfx plugin: a constant-velocity target seen by a range-bearing radar (docs/estimation.md).

The target moves in the plane with constant velocity, disturbed by white accelerations; a radar
at the origin measures its range and bearing. State :math:`(x, v_x, y, v_y)` in metres and
metres per second, one step of ``dt`` seconds:

.. math::

    x_k = \Phi x_{k-1} + \Gamma w_k, \quad w_k \sim N(0, a^2 I_2), \qquad
    z_k = \begin{pmatrix} \sqrt{x_k^2 + y_k^2} \\ \operatorname{atan2}(y_k, x_k) \end{pmatrix} + v_k,
    \quad v_k \sim N\!\left(0, \operatorname{diag}(\sigma_r^2, \sigma_b^2)\right),

with :math:`\Phi` the constant-velocity transition and :math:`\Gamma` the acceleration gain of
``dt``. The model's own parameters are the three standard deviations ``acceleration_sd``
(:math:`a`, m/s²), ``range_sd`` (:math:`\sigma_r`, m) and ``bearing_sd`` (:math:`\sigma_b`,
rad); the noises are derived from them in :meth:`presets`, so an estimated ``range_sd`` moves
the measurement noise with it (each chain's model is derived again at its parameters).

The bearing is declared an angle, so the likelihood wraps its innovation into
:math:`(-\pi, \pi]`. ``propagate`` and ``measurement_mean`` take NumPy or JAX arrays
(``xp = namespace(state)``, :mod:`pfx.numerics.arrays`): the model runs on both of pfx's backends. Run it: ``pfx run examples/plugins/radar-range-noise.yaml``, PMMH on the
range noise with ``particles: auto``.
"""

from typing import Literal

import numpy as np
from pydantic import Field

import pfx
from pfx import namespace


@pfx.register_model
class ConstantVelocityRadar(pfx.Model):
    """A constant-velocity target, range and bearing from a radar at the origin."""

    kind: Literal["cv_radar"] = "cv_radar"
    acceleration_sd: float = Field(0.5, gt=0, description="sd of the white acceleration, m/s^2")
    range_sd: float = Field(5.0, gt=0, description="sd of the range measurement, m")
    bearing_sd: float = Field(0.01, gt=0, description="sd of the bearing measurement, rad")

    time_unit = "s"

    def presets(self):
        return {"steps": 60, "dt": 1.0,
                "process_noise": pfx.Noise(variance=self.acceleration_sd**2),
                "measurement_noise": pfx.Noise(variance=[self.range_sd**2, self.bearing_sd**2]),
                "initial": pfx.PointLaw(state=[-400.0, 12.0, 900.0, -6.0])}

    def default_prior(self):
        return pfx.GaussianLaw(mean=[-400.0, 12.0, 900.0, -6.0], covariance=[30.0**2, 2.0**2, 30.0**2, 2.0**2])

    @property
    def state_names(self):
        return ("x", "vx", "y", "vy")

    @property
    def measurement_dimension(self):
        return 2

    @property
    def process_noise_dimension(self):
        return 2                        # accelerations along x and y

    @property
    def position_components(self):
        return (0, 2)

    @property
    def measurement_angular_components(self):
        return (1,)                     # the bearing, in radians

    def propagate(self, state, control, noise):
        xp, dt = namespace(state, noise), self.dt
        # built on the host (dt is a number), then in the state's dtype (float64 or float32)
        transition = xp.asarray(np.array([[1.0, dt, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, dt],
                                          [0.0, 0.0, 0.0, 1.0]]), dtype=state.dtype)
        gain = xp.asarray(np.array([[dt**2 / 2, 0.0], [dt, 0.0], [0.0, dt**2 / 2], [0.0, dt]]), dtype=state.dtype)
        return state @ transition.T + noise @ gain.T

    def measurement_mean(self, state):
        xp = namespace(state)
        x, y = state[..., 0:1], state[..., 2:3]
        return xp.concatenate([xp.hypot(x, y), xp.arctan2(y, x)], axis=-1)
