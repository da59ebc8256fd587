r"""A pfx plugin: King et al.'s cholera in Dhaka, pomp's ``dacca`` model (docs/benchmarks/dacca-cholera.md).

King, Ionides, Pascual & Bouma (2008, *Nature* 454:877-880) explained fifty years of monthly
cholera deaths in the Dacca district of Bengal (1891-1940) with a stochastic SIRS model whose
force of infection has a seasonal environmental reservoir and whose transmission rate carries
environmental noise. R's ``pomp`` package ships it as its ``dacca`` example (R/dacca.R) with the
maximum-likelihood parameters; this plugin is that model, written against pfx's substep API.

**The state** (people, a continuous approximation): susceptibles :math:`S`, severe (clinical,
infectious) infections :math:`I`, inapparent infections :math:`Y`, three stages of immunity
:math:`R_1, R_2, R_3`, the cholera deaths :math:`C` since the last observation, the integral
:math:`W` of the noise, and ``count``, a flag that is not zero when a positivity constraint was
violated since the last observation. :math:`C` and ``count`` are accumulating components: they
restart from 0 at every observation (pomp's ``accumvars``).

**The covariates** (the table ``data: {covariates: ...}``, linearly interpolated in time): the
population :math:`P(t)` and its derivative :math:`\dot P(t)` (a smoothing spline through the
censuses), the centred time ``trend`` :math:`\tau(t)`, and six periodic cubic B-splines
:math:`s_1(t) .. s_6(t)` of period one year.

**The transition**: one Euler-Maruyama step of :math:`h` = ``substep_duration`` (1/240 year,
20 substeps between monthly observations) from time :math:`t`, with
:math:`\Delta W \sim N(0, h)` (``process_noise``: a standard normal :math:`w`, scaled here,
:math:`\Delta W = \sqrt h\, w`), :math:`k = 3` immunity stages and

.. math::

    \beta(t) &= \exp\Big(\sum_i b_i s_i(t) + \beta_{trend}\, \tau(t)\Big), \qquad
    \omega(t) = \exp\Big(\sum_i \log\omega_i\, s_i(t)\Big),\\
    \lambda &= \Big(\omega(t) + \big(\beta(t) + \sigma\, \Delta W / h\big)\, (I / P)^{\alpha}\Big)\, S
        \quad\text{(infections per year)},\\
    S &\leftarrow S + \big(\dot P + \delta P - \lambda - \delta S + k\varepsilon R_3 + \rho Y\big)\, h,\\
    I &\leftarrow I + \big(c \lambda - m I - \delta I - \gamma I\big)\, h,\\
    Y &\leftarrow Y + \big((1 - c) \lambda - \delta Y - \rho Y\big)\, h,\\
    R_1 &\leftarrow R_1 + \big(\gamma I - k\varepsilon R_1 - \delta R_1\big)\, h, \quad
    R_j \leftarrow R_j + \big(k\varepsilon R_{j-1} - k\varepsilon R_j - \delta R_j\big)\, h \ (j = 2, 3),\\
    C &\leftarrow C + m I h, \qquad W \leftarrow W + \Delta W,

all right-hand sides evaluated at the substep's start (the covariates at time :math:`t`). Births
:math:`\dot P + \delta P` keep the total near the census. The model is a pure SDE: its only
randomness is the Gaussian :math:`\Delta W` (no binomial, Poisson or gamma draws).

As in pomp, a substep that leaves a compartment negative sets it (and the one it drains) to 0
and marks ``count`` (S: +1, I: +1e3, Y: +1e6, C: +1e9, an R stage: +1e12); a marked particle is
frozen until the next observation, where its likelihood is the floor ``tol`` below.

**The measurement**: the month's recorded deaths :math:`y` given :math:`C`, a normal with a
standard deviation proportional to :math:`C`, floored by :math:`\text{tol} = 10^{-18}`:

.. math::

    p(y \mid C) = N\big(y;\ C,\ (\tau C + \text{tol})^2\big) + \text{tol}
    \qquad (\text{tol alone when count} \ne 0).

**The initial state** at :math:`t_0` = ``initial_time`` (1891.0, one month before the first
observation): the fractions :math:`S_0, I_0, Y_0, R_{1,0}, R_{2,0}, R_{3,0}` (normalised to sum
1) of :math:`P(t_0)`, each rounded to a whole number of people (pomp's ``nearbyint``),
:math:`C = W = \text{count} = 0`.

**The parameters** default to pomp's ``dacca()`` arguments, King et al.'s maximum-likelihood
estimate, under pomp's names: ``gamma`` (recovery rate, per year), ``eps`` (waning of immunity),
``rho`` (waning after inapparent infection), ``delta`` (natural death rate), ``deltaI`` (:math:`m`,
cholera mortality), ``clin`` (:math:`c`, fraction of infections that are severe), ``alpha``,
``beta_trend``, ``logbeta`` (:math:`b_i`), ``logomega`` (:math:`\log\omega_i`), ``sd_beta``
(:math:`\sigma`), ``tau``, and the initial fractions. At them pomp's particle filter gives a
log-likelihood of -3748.6 for the 600 months.

Differences from pypomp's port (``pypomp.models.dacca``), which agrees with R pomp at the MLE
within Monte Carlo error: pypomp does not round the initial state, never resets ``count`` (a
violation costs every later month the floor, not only its own) and clips each compartment on
its own; this plugin follows R pomp, the source of the published number. Violations are rare
at the MLE (a large negative noise emptying a small I: a handful of the 4.8 million
particle-months of the J = 1000 check in tests/test_dacca_plugin.py), and a marked particle's
weight is the floor, so it is not resampled: both rules give the same likelihood there.

**Both backends.** ``propagate``, ``log_likelihood`` and ``simulate_measurement`` take NumPy or
JAX arrays (``xp = namespace(state)``, :mod:`pfx.numerics.arrays`), and ``propagate``'s time may
be a JAX tracer (the covariates are then interpolated in the compiled step): the state is built
as a stack of its components rather than written in place, and the positivity rule is a select.

Run it: ``pfx run configs/benchmarks/dacca-cholera/dacca.yaml``.
"""

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, StrictInt

import pfx
from pfx import namespace

IMMUNITY_STAGES = 3
SEASONAL_BASIS = 6
TOLERANCE = 1.0e-18                  # pomp's tol: the likelihood's floor and the scale's
LOG_TOLERANCE = float(np.log(TOLERANCE))
HALF_LOG_TWO_PI = float(0.5 * np.log(2.0 * np.pi))
COVARIATES = ("trend", "dpopdt", "pop") + tuple(f"seas_{i + 1}" for i in range(SEASONAL_BASIS))
STATES = ("S", "I", "Y") + tuple(f"R{j + 1}" for j in range(IMMUNITY_STAGES)) + ("deaths", "W", "count")
SUSCEPTIBLE, SEVERE, INAPPARENT, FIRST_IMMUNE, DEATHS, NOISE_INTEGRAL, COUNT = 0, 1, 2, 3, 6, 7, 8
TREND, DPOPDT, POP, SEASONS = 0, 1, 2, slice(3, 3 + SEASONAL_BASIS)
# What pomp adds to ``count`` when a compartment goes negative: which one, read off its digits.
VIOLATION_MARKS = {"S": 1.0, "I": 1.0e3, "Y": 1.0e6, "deaths": 1.0e9, "R": 1.0e12}


@pfx.register_model
class DaccaCholera(pfx.Model):
    """pomp's dacca: an SIRS model with an environmental reservoir, Euler-Maruyama substeps."""

    kind: Literal["dacca_cholera"] = "dacca_cholera"
    gamma: float = Field(20.8, ge=0.0, description="recovery rate (per year)")
    eps: float = Field(19.1, ge=0.0, description="rate of waning of immunity after severe infection (per year)")
    rho: float = Field(0.0, ge=0.0, description="rate of waning of immunity after inapparent infection (per year)")
    delta: float = Field(0.02, ge=0.0, description="baseline (natural) death rate (per year)")
    deltaI: float = Field(0.06, ge=0.0, description="cholera mortality rate m of severe infections (per year)")
    clin: float = Field(1.0, ge=0.0, le=1.0, description="fraction c of infections that are severe")
    alpha: float = Field(1.0, gt=0.0, description="exponent of I/P in the transmission term")
    beta_trend: float = Field(-0.00498, description="slope of the secular trend in log transmission (per year)")
    logbeta: tuple[float, ...] = Field((0.747, 6.38, -3.44, 4.23, 3.33, 4.55),
                                       description="seasonal log transmission rates b_1..b_6 (B-spline coefficients)")
    logomega: tuple[float, ...] = Field(tuple(float(v) for v in np.log([0.184, 0.0786, 0.0584, 0.00917,
                                                                          0.000208, 0.0124])),
                                        description="seasonal log environmental reservoir log(omega_1..omega_6)")
    sd_beta: float = Field(3.13, ge=0.0, description="environmental noise intensity sigma")
    tau: float = Field(0.23, ge=0.0, description="measurement error: the deaths' sd is tau * C")
    S_0: float = Field(0.621, ge=0.0, description="initial fraction susceptible")
    I_0: float = Field(0.378, ge=0.0, description="initial fraction with severe infection")
    Y_0: float = Field(0.0, ge=0.0, description="initial fraction with inapparent infection")
    R1_0: float = Field(0.000843, ge=0.0, description="initial fraction in immunity stage 1")
    R2_0: float = Field(0.000972, ge=0.0, description="initial fraction in immunity stage 2")
    R3_0: float = Field(1.16e-07, ge=0.0, description="initial fraction in immunity stage 3")
    substeps: StrictInt = Field(20, ge=1, le=100_000, description="Euler-Maruyama substeps between two observations "
                                                           "(20: pomp's delta.t = 1/240 year for monthly data)")
    initial_time: float = Field(1891.0, description="t0, the time of the initial state (pomp's: one month "
                                                    "before the first observation)")

    integrates_substeps: ClassVar[bool] = True
    time_unit = "year"

    def presets(self):
        # Monthly observations (substeps = 20: Euler steps of 1/240 year); w is standard normal
        # (scaled in propagate). The data's times fix dt and steps when the config reads the deaths.
        presets = {"steps": 600, "dt": 1.0 / 12.0,
                   "process_noise": pfx.Noise(variance=1.0),
                   "measurement_noise": pfx.Noise(variance=1.0)}
        if self.initial is None:
            presets["initial"] = pfx.PointLaw(state=self.initial_state().tolist())
        return presets

    def check(self):
        for name in ("logbeta", "logomega"):
            if len(getattr(self, name)) != SEASONAL_BASIS:
                raise ValueError(f"@{name}: {SEASONAL_BASIS} coefficients, one per seasonal B-spline")
        if sum(self.initial_fractions()) <= 0.0:
            raise ValueError("@S_0: the initial fractions S_0..R3_0 must not all be 0")

    @property
    def state_names(self):
        return STATES

    @property
    def state_units(self):
        return ("people",) * (DEATHS + 1) + ("year^1/2", "")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def measurement_names(self):
        return ("cholera_deaths",)

    @property
    def covariate_names(self):
        return COVARIATES

    @property
    def accumulating_components(self):
        return (DEATHS, COUNT)

    @property
    def process_noise_dimension(self):
        return 1

    def initial_fractions(self) -> tuple[float, ...]:
        return (self.S_0, self.I_0, self.Y_0, self.R1_0, self.R2_0, self.R3_0)

    def initial_state(self) -> np.ndarray:
        """x_0: the fractions S_0..R3_0 (normalised) of P(t0), rounded to whole people; C = W = count = 0."""
        fractions = np.asarray(self.initial_fractions())
        population = self.covariates_at(self.initial_time)[POP]
        compartments = np.rint(population * fractions / fractions.sum())     # round half to even, as C's nearbyint
        return np.concatenate([compartments, [0.0, 0.0, 0.0]])

    def propagate(self, state, control, noise, time):
        xp = namespace(state, noise)
        step = self.substep_duration
        covariates = self.covariates_at(time)          # NumPy, or JAX when the time is traced
        population, population_growth, seasons = covariates[POP], covariates[DPOPDT], covariates[SEASONS]
        cx = namespace(covariates)
        logbeta, logomega = (cx.asarray(values, dtype=covariates.dtype) for values in (self.logbeta, self.logomega))
        beta = cx.exp(cx.dot(seasons, logbeta) + self.beta_trend * covariates[TREND])
        omega = cx.exp(cx.dot(seasons, logomega))
        susceptible, severe, inapparent = state[..., SUSCEPTIBLE], state[..., SEVERE], state[..., INAPPARENT]
        immune = [state[..., FIRST_IMMUNE + j] for j in range(IMMUNITY_STAGES)]
        noise_increment = float(np.sqrt(step)) * noise[..., 0]               # dW ~ N(0, h)

        passage_rate = self.eps * IMMUNITY_STAGES
        passages = [self.gamma * severe] + [passage_rate * stage for stage in immune]
        infections = (omega + (beta + self.sd_beta * noise_increment / step)
                      * (severe / population) ** self.alpha) * susceptible
        disease_deaths = self.deltaI * severe
        wanings = self.rho * inapparent

        new = [None] * len(STATES)                 # the new state's components, in STATES order
        new[SUSCEPTIBLE] = susceptible + (population_growth + self.delta * population - infections
                                          - self.delta * susceptible + passages[-1] + wanings) * step
        new[SEVERE] = severe + (self.clin * infections - disease_deaths - self.delta * severe - passages[0]) * step
        new[INAPPARENT] = inapparent + ((1.0 - self.clin) * infections - self.delta * inapparent - wanings) * step
        for j in range(IMMUNITY_STAGES):
            new[FIRST_IMMUNE + j] = immune[j] + (passages[j] - passages[j + 1] - self.delta * immune[j]) * step
        new[DEATHS] = state[..., DEATHS] + disease_deaths * step
        new[NOISE_INTEGRAL] = state[..., NOISE_INTEGRAL] + noise_increment
        new[COUNT] = state[..., COUNT]
        shape = xp.broadcast_shapes(*(component.shape for component in new))
        new = mark_violations([xp.broadcast_to(component, shape) for component in new])
        frozen = state[..., COUNT:COUNT + 1] != 0.0   # pomp: a marked particle stays as it is until the next observation
        return xp.where(frozen, state, xp.stack(new, axis=-1))

    def measurement_mean(self, state):
        return state[..., DEATHS:DEATHS + 1].copy()

    def log_likelihood(self, measurement, state):
        xp = namespace(measurement, state)
        deaths = state[..., DEATHS]
        scale = self.tau * deaths + TOLERANCE
        residual = (measurement[..., 0] - deaths) / scale
        normal = -0.5 * residual**2 - xp.log(scale) - HALF_LOG_TWO_PI
        floored = xp.logaddexp(normal, LOG_TOLERANCE)                        # log(N(y; C, scale^2) + tol)
        violated = (state[..., COUNT] > 0.0) | ~xp.isfinite(self.tau * deaths)
        return xp.where(violated, LOG_TOLERANCE, floored)

    def simulate_measurement(self, state, random):
        # pomp draws NA for a marked particle; pfx's measurements are numbers, so every month gets a draw.
        deaths = state[..., DEATHS:DEATHS + 1]
        return deaths + (self.tau * deaths + TOLERANCE) * random.standard_normal(state.shape[1:-1] + (1,))


def mark_violations(components: list) -> list:
    """pomp's positivity rule on the state's components (a list in STATES order, NumPy or JAX
    arrays of one shape), in pomp's order: a negative compartment is set to 0 with the one it
    drains (S with I and Y; I or Y with S; R_j with R_(j+1); R_k with S), and ``count`` records
    which (VIOLATION_MARKS). Returns the new list; ``components`` is not changed.

    A rule sees what the rules before it left (S's rule may clear I before I's is checked). On
    NumPy a rule that finds no negative value is skipped (one comparison each when none occurs,
    the usual case); in a compiled JAX step every rule is a select."""
    components = list(components)
    xp = namespace(*components)
    last = FIRST_IMMUNE + IMMUNITY_STAGES - 1
    rules = [(SUSCEPTIBLE, (SUSCEPTIBLE, SEVERE, INAPPARENT), "S"), (SEVERE, (SEVERE, SUSCEPTIBLE), "I"),
             (INAPPARENT, (INAPPARENT, SUSCEPTIBLE), "Y"), (DEATHS, (DEATHS,), "deaths")]
    rules += [(FIRST_IMMUNE + j, (FIRST_IMMUNE + j, FIRST_IMMUNE + j + 1), "R") for j in range(IMMUNITY_STAGES - 1)]
    rules += [(last, (last, SUSCEPTIBLE), "R")]
    for component, cleared, mark in rules:
        negative = components[component] < 0.0
        if xp is not np or negative.any():      # on JAX a select, whatever the values
            for other in cleared:
                components[other] = xp.where(negative, 0.0, components[other])
            components[COUNT] = components[COUNT] + xp.where(negative, VIOLATION_MARKS[mark], 0.0)
    return components
