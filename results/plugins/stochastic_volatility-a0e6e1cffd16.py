r"""A pfx plugin: the stochastic-volatility model (docs/plugins.md), with its own guided proposal
and its own look-ahead for the auxiliary particle filter (Pitt & Shephard 1999).

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

    \ell(x) = \log p(y \mid x) = -\tfrac12 \left( \log 2\pi + x + \log s^2 + \frac{y^2}{s^2 e^{x}} \right),

with :math:`s^2` the measurement noise variance (1 by default). ``measurement_mean`` is
:math:`E[y \mid x] = 0`, which carries no information about :math:`x`: Kalman filters, which see
only the mean, cannot track this model, and neither can the EKF and UKF proposals; the particle
filters can. The process noise enters additively, :math:`x_k = f(x_{k-1}) + \sigma w_k`
(``process_noise_jacobian`` is the constant :math:`\sigma`), so pfx derives the transition
density :math:`N(x_k; f(x_{k-1}), \sigma^2)` that the histogram filter and guided proposals use.

**The model's own proposal and look-ahead: a Taylor expansion of the log-likelihood.** At step
k the prior of :math:`x_k` given a particle :math:`x_{k-1}` is :math:`N(m, \sigma^2)`,
:math:`m = \mu + \phi (x_{k-1} - \mu)`. Expanding :math:`\ell` about :math:`m`, with
:math:`r = y_k^2 / s^2`,

.. math::

    \ell(x) \approx \ell(m) + \ell'(m) (x - m) + \tfrac12 \ell''(m) (x - m)^2, \qquad
    \ell'(m) = \tfrac12 (r e^{-m} - 1), \quad \ell''(m) = -\tfrac12 r e^{-m} \le 0,

makes prior times approximate likelihood a Gaussian in :math:`x`:

* **second order** (``order: 2``, the default): :math:`q = N(m + v \ell'(m), v)` with
  :math:`1/v = 1/\sigma^2 + \tfrac12 r e^{-m}`; since :math:`\ell'' \le 0` the variance is
  always positive, and it shrinks where the return is large against the predicted volatility,
  as the true posterior does;
* **first order** (``order: 1``; Pitt & Shephard's expansion of :math:`e^{-x}`, and the
  ``proposal`` of the ``particles`` library's ``StochVol``): :math:`q = N(m + \sigma^2 \ell'(m),
  \sigma^2)`. Since :math:`e^{-x} \ge e^{-m}(1 - (x - m))`, this linear approximation bounds
  :math:`\ell` from above (which is what Pitt & Shephard's rejection sampler needs), but it keeps
  the prior's variance and, at a return large against :math:`e^{m/2}`, moves the mean by
  :math:`\tfrac12 \sigma^2 r e^{-m}`, far past the likelihood's peak.

The proposal (``filter.proposal: stochastic_volatility_taylor``) draws from :math:`q` and returns
the importance correction :math:`\log p(x_k \mid x_{k-1}) - \log q(x_k \mid x_{k-1}, y_k)`.

The auxiliary filter's first-stage weight (the model's ``look_ahead: first_order`` or
``second_order``) is the predictive density of :math:`y_k` under the same approximation,
:math:`g(x_{k-1}) = \log \int N(x; m, \sigma^2)\, e^{\hat\ell(x)}\, dx`:

.. math::

    g_2 = \ell(m) + \tfrac12 \log (v / \sigma^2) + \tfrac12 \ell'(m)^2 v, \qquad
    g_1 = \ell(m) + \tfrac12 \ell'(m)^2 \sigma^2 .

With the proposal of the same order, :math:`q(x) = N(x; m, \sigma^2) e^{\hat\ell(x) - g}`, so the
second-stage weight :math:`p(y \mid x) p(x \mid x_{k-1}) / (q(x) e^{g})` is
:math:`e^{\ell(x) - \hat\ell(x)}`: the auxiliary filter is fully adapted as far as the expansion
is exact (Pitt & Shephard's "adapted" filter). :math:`g_1` (the ``logeta`` of ``particles``' ``StochVol``,
up to a constant) grows without bound as :math:`m \to -\infty` at a fixed return,
:math:`g_1 \approx \tfrac18 \sigma^2 r^2 e^{-2m}`, while the true predictive density falls like
:math:`e^{-r e^{-m}/2}`: once :math:`r e^{-m} > 2/\sigma^2` it favours exactly the particles the
return rules out. :math:`g_2 \approx -\tfrac12 m - \tfrac14 r e^{-m}` falls as the truth does.
The default look-ahead (``point``) is pfx's own, :math:`\ell(m)`, the likelihood at the point
prediction.

The model is written once for both of pfx's backends (docs/plugins.md, "Writing a model for
both backends"): every method takes NumPy or JAX arrays and asks them for their array module,
``xp = namespace(state)`` (:mod:`pfx.numerics.arrays`).

Run it: ``pfx run examples/plugins/stochastic-volatility.yaml``; the GBP/USD benchmark
(docs/benchmarks/sv-gbp-usd.md) runs the three filters on recorded returns.
"""

from typing import Literal

import numpy as np
from pydantic import Field

import pfx
from pfx import namespace

LOG_TWO_PI = float(np.log(2.0 * np.pi))     # a Python float: it keeps a float32 computation float32


@pfx.register_model
class StochasticVolatility(pfx.Model):
    """Stochastic volatility: x_k = mu + phi (x_{k-1} - mu) + sigma w_k, y_k = exp(x_k / 2) v_k."""

    kind: Literal["stochastic_volatility"] = "stochastic_volatility"
    mu: float = Field(-1.0, description="mean log-variance")
    phi: float = Field(0.95, gt=-1.0, lt=1.0, description="persistence of the log-variance, |phi| < 1")
    sigma: float = Field(0.25, gt=0.0, description="standard deviation of the log-variance's innovations")
    look_ahead: Literal["point", "first_order", "second_order"] = Field(
        "point", description="the auxiliary filter's first-stage weight: the likelihood at the point prediction "
                             "(point), or the predictive density under the first- or second-order Taylor expansion "
                             "of the log-likelihood about the prior mean (Pitt & Shephard)")

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
    # propagate broadcasts mu, phi and sigma of shape (R, 1, 1) or (R, N, 1) against the state
    # (R, N, 1): parameter estimation runs many chains in one batch (docs/estimation.md)
    vectorised_parameters = ("mu", "phi", "sigma")

    @property
    def state_names(self):
        return ("log_variance",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return self.mu + self.phi * (state - self.mu) + self.sigma * noise

    def process_noise_jacobian(self, state, control):
        # x_k = f(x_{k-1}) + sigma w_k: the noise enters additively with the constant gain sigma.
        return np.full(state.shape[:-1] + (1, 1), self.sigma)

    def measurement_mean(self, state):
        return namespace(state).zeros_like(state[..., :1])

    def simulate_measurement(self, state, random):
        noise = self.measurement_noise.sample(random, state.shape[1:-1])     # (trials, ..., 1)
        return namespace(state).exp(state / 2.0) * noise

    def log_likelihood(self, measurement, state):
        xp = namespace(measurement, state)
        variance = self.return_variance()
        terms = LOG_TWO_PI + state + float(np.log(variance)) + measurement**2 / (variance * xp.exp(state))
        return -0.5 * terms[..., 0]

    def return_variance(self) -> float:
        """s^2, the variance of v_k."""
        return float(self.measurement_noise.covariance()[0, 0])

    def prior_mean(self, previous):
        """m = mu + phi (x_{k-1} - mu), the mean of x_k given x_{k-1}: (...) from (..., 1)."""
        return self.mu + self.phi * (previous[..., 0] - self.mu)

    def expansion(self, prior_mean, measurement, order: int):
        r"""The Taylor expansion of :math:`\ell` about the prior mean m (module docstring) and the
        Gaussian it makes with the prior: (l(m), l'(m), mean, variance) of
        :math:`q = N(m + v \ell'(m), v)`, each shaped like ``prior_mean``; ``measurement`` (R, 1, 1)
        or broadcastable. ``order`` 2: :math:`1/v = 1/\sigma^2 - \ell''(m)`; 1: :math:`v = \sigma^2`."""
        xp = namespace(prior_mean, measurement)
        ratio = measurement[..., 0] ** 2 / self.return_variance() * xp.exp(-prior_mean)     # r e^{-m}
        value = self.log_likelihood(measurement, prior_mean[..., None])
        slope = 0.5 * (ratio - 1.0)
        prior_variance = self.sigma**2
        if order == 2:
            variance = 1.0 / (1.0 / prior_variance + 0.5 * ratio)
        else:
            variance = xp.full_like(ratio, prior_variance)
        return value, slope, prior_mean + variance * slope, variance

    def look_ahead_log_weight(self, previous, step, measurement):
        r"""The first-stage weight g(x_{k-1}): the likelihood at the point prediction (``point``),
        or :math:`\log \int N(x; m, \sigma^2) e^{\hat\ell(x)} dx` under the first- or second-order
        expansion (module docstring): :math:`\ell(m) + \tfrac12 \log(v / \sigma^2) + \tfrac12 \ell'(m)^2 v`."""
        if self.look_ahead == "point":
            return super().look_ahead_log_weight(previous, step, measurement)
        order = 2 if self.look_ahead == "second_order" else 1
        value, slope, _, variance = self.expansion(self.prior_mean(previous), measurement, order)
        return value + 0.5 * namespace(variance).log(variance / self.sigma**2) + 0.5 * slope**2 * variance


@pfx.register_proposal
class StochasticVolatilityTaylor(pfx.Proposal):
    """The stochastic-volatility model's own proposal: the AR(1) prior times a Taylor expansion of
    log p(y | x) about the prior mean (Pitt & Shephard 1999)."""

    kind: Literal["stochastic_volatility_taylor"] = "stochastic_volatility_taylor"
    order: Literal[1, 2] = Field(2, description="order of the expansion of log p(y | x): 2 (the precision "
                                                "grows with the return) or 1 (Pitt & Shephard's, the prior's variance)")

    def check(self, model):
        if not isinstance(model, StochasticVolatility):
            raise ValueError(f"@proposal: stochastic_volatility_taylor is the stochastic-volatility model's own "
                             f"proposal; model {model.kind} is not that model")

    def propose(self, model, previous, step, measurement, observed, random):
        r"""Draw :math:`x_k \sim q = N(m + v \ell'(m), v)` for every particle (module docstring) and
        return it with :math:`\log p(x_k \mid x_{k-1}) - \log q(x_k \mid x_{k-1}, y_k)`, (R, N)."""
        xp = namespace(previous, measurement)
        prior_mean = model.prior_mean(previous)                             # (R, N)
        returns = measurement[:, None, :]                                   # (R, 1, 1)
        if observed is not None:                  # a missing return: any finite stand-in, then the prior
            returns = xp.where(observed[:, None, None], returns, 0.0)
        _, _, mean, variance = model.expansion(prior_mean, returns, self.order)
        if observed is not None:
            mean = xp.where(observed[:, None], mean, prior_mean)
            variance = xp.where(observed[:, None], variance, model.sigma**2)
        standard = random.standard_normal(prior_mean.shape[1:])            # (R, N)
        state = (mean + xp.sqrt(variance) * standard)[..., None]
        log_proposal = -0.5 * (xp.log(2.0 * np.pi * variance) + standard**2)
        adjustment = model.transition_log_density(state, previous, step) - log_proposal
        if observed is not None:
            adjustment = xp.where(observed[:, None], adjustment, 0.0)
        return state, adjustment
