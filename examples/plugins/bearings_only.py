r"""A pfx plugin: bearings-only tracking (Gordon, Salmond & Smith 1993, section 5; docs/plugins.md).

A target moves in the plane with constant velocity, disturbed by random accelerations; an
observer at the origin measures only its bearing. State :math:`(x, v_x, y, v_y)`:

.. math::

    x_k = \Phi x_{k-1} + \Gamma w_k, \quad
    \Phi = \begin{pmatrix} 1 & 1 & 0 & 0 \\ 0 & 1 & 0 & 0 \\ 0 & 0 & 1 & 1 \\ 0 & 0 & 0 & 1 \end{pmatrix}, \quad
    \Gamma = \begin{pmatrix} 1/2 & 0 \\ 1 & 0 \\ 0 & 1/2 \\ 0 & 1 \end{pmatrix}, \quad
    w_k \sim N(0, q^2 I_2),

    z_k = \operatorname{atan2}(y_k, x_k) + v_k, \quad v_k \sim N(0, r^2).

The paper's set-up, the presets here: :math:`q = 0.001`, :math:`r = 0.005`, 24 steps, the
target starting at :math:`(-0.05, 0.001, 0.7, -0.055)`, and the filters' prior
:math:`N((0, 0, 0.4, -0.05), \operatorname{diag}(0.5^2, 0.005^2, 0.3^2, 0.01^2))`.

A bearing is an angle: the model declares it (``measurement_angular_components = (0,)``, in
radians), so that the likelihood, the EKF, the UKF and the guided proposals all wrap the
innovation :math:`z - h(x)` into :math:`(-\pi, \pi]`: a bearing just below :math:`\pi` and one
just above :math:`-\pi` are close (docs/plugins.md, "Angles in the measurement"). The likelihood
is the default one, the gaussian log-density of that wrapped innovation. The state has no
angular component (``angular_components`` stays empty). No Jacobians are given: the EKF uses
central finite differences (of the wrapped bearing).

``propagate`` and ``measurement_mean`` take NumPy or JAX arrays (``xp = namespace(state)``,
:mod:`pfx.numerics.arrays`): the model runs on both of pfx's backends.

Run it: ``pfx run examples/plugins/bearings-only.yaml``.
"""

from typing import Literal

import numpy as np

import pfx
from pfx import namespace

TRANSITION = np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]])
NOISE_GAIN = np.array([[0.5, 0.0], [1.0, 0.0], [0.0, 0.5], [0.0, 1.0]])


@pfx.register_model
class BearingsOnly(pfx.Model):
    """Bearings-only tracking: constant velocity, bearing from the origin (Gordon, Salmond & Smith 1993)."""

    kind: Literal["bearings_only"] = "bearings_only"

    def presets(self):
        return {"steps": 24, "dt": 1.0,
                "process_noise": pfx.Noise(variance=0.001**2),
                "measurement_noise": pfx.Noise(variance=0.005**2),
                "initial": pfx.PointLaw(state=[-0.05, 0.001, 0.7, -0.055])}

    def default_prior(self):
        return pfx.GaussianLaw(mean=[0.0, 0.0, 0.4, -0.05], covariance=[0.5**2, 0.005**2, 0.3**2, 0.01**2])

    time_unit = "step"

    @property
    def state_names(self):
        return ("x", "vx", "y", "vy")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def process_noise_dimension(self):
        return 2                        # accelerations along x and y

    @property
    def position_components(self):
        return (0, 2)

    @property
    def measurement_angular_components(self):
        return (0,)                     # the bearing, in radians

    def propagate(self, state, control, noise):
        xp = namespace(state, noise)
        # the matrices in the state's dtype: a float64 constant would make a float32 state float64
        transition, gain = (xp.asarray(matrix, dtype=state.dtype) for matrix in (TRANSITION, NOISE_GAIN))
        return state @ transition.T + noise @ gain.T

    def measurement_mean(self, state):
        return namespace(state).arctan2(state[..., 2:3], state[..., 0:1])
