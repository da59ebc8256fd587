r"""An SIR epidemic with births and deaths, counted in whole individuals: a plugin on pfx's
documented interfaces, for both backends (docs/plugins.md, "Count-valued transitions").

State: susceptible S, infected I, recovered R, and C, the new infections since the last report
(an accumulator: reset to 0 at the start of every step). Each substep of h = dt / substeps:

* births ~ Poisson(mu P h) join S (P the population size, a constant of the model);
* S leaves by two exits, infection at rate beta I / P and death at rate mu:
  pfx.euler_multinomial (pomp's ``reulermultinom``);
* I leaves by recovery at rate gamma and death at rate mu; R by death at rate mu.

The report at each step counts each of the C new infections with probability rho:
y ~ Binomial(C, rho), whose log-probability is the likelihood.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

import pfx


@pfx.register_model
class SIR(pfx.Model):
    kind: Literal["sir"] = "sir"
    population: float = Field(10_000.0, gt=0, description="population size P (births balance deaths)")
    contact_rate: float = Field(2.0, ge=0, description="beta, per unit time")
    recovery_rate: float = Field(1.0, ge=0, description="gamma, per unit time")
    death_rate: float = Field(0.02, ge=0, description="mu, per unit time (also the birth rate)")
    reporting: float = Field(0.6, gt=0, lt=1, description="rho, the probability that an infection is reported")
    initially_infected: float = Field(20.0, ge=0, description="I at time 0")

    integrates_substeps = True          # propagate and sample_substep advance one substep

    def presets(self):
        infected = self.initially_infected
        return {"steps": 30, "dt": 1.0,
                "process_noise": pfx.Noise(variance=0.0),        # the counts' own randomness is drawn below
                "measurement_noise": pfx.Noise(variance=1.0),    # unused: log_likelihood is the binomial's
                "initial": pfx.PointLaw(state=[self.population - infected, infected, 0.0, 0.0])}

    @property
    def state_names(self):
        return ("S", "I", "R", "C")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def accumulating_components(self):
        return (3,)

    def rates(self, state):
        """The exits' rates per unit time: S by infection and death, I by recovery and death."""
        xp = pfx.namespace(state)
        infection = self.contact_rate * state[..., 1] / self.population
        susceptible_exits = xp.stack([infection, xp.full_like(infection, self.death_rate)], axis=-1)
        infected_exits = xp.stack([xp.full_like(infection, self.recovery_rate),
                                   xp.full_like(infection, self.death_rate)], axis=-1)
        return susceptible_exits, infected_exits

    def sample_substep(self, state, control, time, random):
        """One substep of h = dt / substeps: whole individuals move (Euler-multinomial draws)."""
        xp = pfx.namespace(state)
        step = self.substep_duration
        susceptible, infected, recovered, new = (state[..., j] for j in range(4))
        susceptible_exits, infected_exits = self.rates(state)
        births = random.poisson(xp.full_like(susceptible, self.death_rate * self.population * step))
        leaving_s = pfx.euler_multinomial(random, susceptible, susceptible_exits, step)   # (..., 2)
        leaving_i = pfx.euler_multinomial(random, infected, infected_exits, step)
        deaths_r = random.binomial(recovered, float(-np.expm1(-self.death_rate * step)))
        infections, recoveries = leaving_s[..., 0], leaving_i[..., 0]
        return xp.stack([susceptible + births - leaving_s.sum(axis=-1),
                         infected + infections - leaving_i.sum(axis=-1),
                         recovered + recoveries - deaths_r,
                         new + infections], axis=-1)

    def propagate(self, state, control, noise):
        """The mean of one substep (the rates' Euler step): what pfx's look-ahead and Gaussian
        filters use; the filter draws with sample_substep."""
        xp = pfx.namespace(state)
        step = self.substep_duration
        susceptible_exits, infected_exits = self.rates(state)
        leave_s = -xp.expm1(-susceptible_exits.sum(axis=-1) * step)
        leave_i = -xp.expm1(-infected_exits.sum(axis=-1) * step)
        share_s = susceptible_exits[..., 0] / xp.maximum(susceptible_exits.sum(axis=-1), 1e-300)
        share_i = infected_exits[..., 0] / infected_exits.sum(axis=-1)
        infections = state[..., 0] * leave_s * share_s
        recoveries = state[..., 1] * leave_i * share_i
        return xp.stack([state[..., 0] + self.death_rate * self.population * step - state[..., 0] * leave_s,
                         state[..., 1] + infections - state[..., 1] * leave_i,
                         state[..., 2] + recoveries - state[..., 2] * -xp.expm1(-self.death_rate * step),
                         state[..., 3] + infections], axis=-1)

    def measurement_mean(self, state):
        return self.reporting * state[..., 3:4]

    def simulate_measurement(self, state, random):
        return random.binomial(state[..., 3], self.reporting)[..., None]

    def log_likelihood(self, measurement, state):
        """log P(y | C) of y ~ Binomial(C, rho); -inf where y > C."""
        xp = pfx.namespace(state, measurement)
        log_gamma = pfx.special_functions(xp).gammaln
        reports, infections = measurement[..., 0], state[..., 3]
        possible = reports <= infections
        others = xp.where(possible, infections - reports, 0.0)
        value = (log_gamma(infections + 1.0) - log_gamma(reports + 1.0) - log_gamma(others + 1.0)
                 + reports * float(np.log(self.reporting)) + others * float(np.log1p(-self.reporting)))
        return xp.where(possible, value, -xp.inf)
