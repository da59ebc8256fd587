r"""A pfx plugin: the stochastic-volatility model (docs/plugins.md).

The log-variance :math:`x_k` of an asset's returns follows a stationary AR(1) process, and
each return :math:`y_k` is zero-mean noise scaled by the current volatility:

.. math::

    x_k = \mu + \phi (x_{k-1} - \mu) + \sigma w_k, \qquad y_k = e^{x_k / 2} v_k,
    \qquad w_k, v_k \sim N(0, 1),

with the stationary initial law :math:`x_0 \sim N(\mu, \sigma^2 / (1 - \phi^2))`.

The measurement is not "h(x) + noise" (the noise multiplies), so the model overrides both
halves of the measurement contract: ``simulate_measurement`` (how the truth's returns are
drawn, from the trials' random streams) and ``log_likelihood``:

.. math::

    \log p(y \mid x) = -\tfrac12 \left( \log 2\pi + x + \log s^2 + \frac{y^2}{s^2 e^{x}} \right),

with :math:`s^2` the measurement noise variance (1 by default). ``measurement_mean`` is
:math:`E[y \mid x] = 0`, which carries no information about :math:`x`: Kalman filters, which see
only the mean, cannot track this model; the particle filters can.

Run it: ``pfx run examples/plugins/stochastic-volatility.yaml``.
"""

from typing import Literal

import numpy as np
from pydantic import Field

import pfx


@pfx.register_model
class StochasticVolatility(pfx.Model):
    """Stochastic volatility: x_k = mu + phi (x_{k-1} - mu) + sigma w_k, y_k = exp(x_k / 2) v_k."""

    kind: Literal["stochastic_volatility"] = "stochastic_volatility"
    mu: float = Field(-1.0, description="mean log-variance")
    phi: float = Field(0.95, gt=-1.0, lt=1.0, description="persistence of the log-variance, |phi| < 1")
    sigma: float = Field(0.25, gt=0.0, description="standard deviation of the log-variance's innovations")

    def presets(self):
        # w_k and v_k are standard normal: sigma scales w_k in propagate, exp(x / 2) scales v_k.
        return {"steps": 100, "dt": 1.0,
                "process_noise": pfx.Noise(variance=1.0),
                "measurement_noise": pfx.Noise(variance=1.0),
                "initial": pfx.GaussianLaw(mean=[self.mu], covariance=self.sigma**2 / (1.0 - self.phi**2))}

    def check(self):
        if self.measurement_noise.family != "gaussian":
            raise ValueError("@measurement_noise.family: the stochastic-volatility likelihood is written "
                             "for gaussian v_k")

    time_unit = "step"

    @property
    def state_names(self):
        return ("log_variance",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return self.mu + self.phi * (state - self.mu) + self.sigma * noise

    def measurement_mean(self, state):
        return np.zeros(state.shape[:-1] + (1,))

    def simulate_measurement(self, state, random):
        noise = self.measurement_noise.sample(random, state.shape[1:-1])     # (trials, ..., 1)
        return np.exp(state / 2.0) * noise

    def log_likelihood(self, measurement, state):
        variance = float(self.measurement_noise.covariance()[0, 0])
        terms = np.log(2.0 * np.pi) + state + np.log(variance) + measurement**2 / (variance * np.exp(state))
        return -0.5 * terms[..., 0]
