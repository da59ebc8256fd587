r"""A pfx plugin: He, Ionides & King's (2010) measles in London (docs/benchmarks/measles-london.md).

He, Ionides & King (2010, *J. R. Soc. Interface* 7:271-283) explained the weekly measles reports
of English and Welsh towns, 1950-1963, with a stochastic SEIR model of whole individuals:
births enter the susceptibles with a school-entry cohort effect, transmission follows the
school terms, the force of infection carries gamma white noise (extra-demographic
stochasticity), and each compartment is left by Euler-multinomial draws. pomp's measles
lessons and pypomp (``pypomp.models.measles``, its model "001") carry the model; this plugin is
that model, written on pfx's documented interfaces only: ``pfx.Model``, covariates, an
accumulator, substeps and the count draws (``pfx.euler_multinomial``,
``pfx.gamma_white_noise``), in the array namespace so that it runs on both backends.

**The state** (whole people, as floats): susceptible :math:`S`, exposed (latent) :math:`E`,
infectious :math:`I`, recovered :math:`R = P - S - E - I`, the standardised noise integral
:math:`W` and :math:`C`, the recoveries (the week's true incidence) since the last report.
:math:`W` and :math:`C` are accumulators: they restart from 0 at every observation.

**The covariates** (``data.covariates``, interpolated linearly in time): the population
:math:`P(t)` and the birth rate :math:`B(t)` (births per year, read with He et al.'s delay of
4 years: the cohort reaching school age), both smoothing splines through the annual figures.

**One substep** of :math:`h` = ``substep_duration`` (a day, 1/365.25 year: 7 substeps a week)
from time :math:`t`, with the covariates read at :math:`t`:

.. math::

    b &= \begin{cases} c B / h + (1 - c) B & |t - \lfloor t \rfloor - 251/365| < h/2
                        \text{ (the school year's first day)}\\
                        (1 - c) B & \text{otherwise} \end{cases}
        \quad\text{births per year, a share } c \text{ (cohort) entering at once},\\
    s(t) &= 1 + a\, 0.2411 / 0.7589 \text{ in term (days 7-100, 115-199, 252-300, 308-356 of
           the year, inclusive)}, \quad 1 - a \text{ in holidays},\\
    \beta &= R_0\, s(t)\, (1 - e^{-(\gamma + \mu) h}) / h, \qquad
    \lambda = \beta\, (I + \iota)^{\alpha} / P,\\
    dW &\sim \Gamma(\text{shape } h / \sigma_{SE}^2, \text{ scale } \sigma_{SE}^2)
        \quad (\texttt{pfx.gamma\_white\_noise}: \text{mean } h, \text{ variance } \sigma_{SE}^2 h),\\
    \text{births} &\sim \text{Poisson}(b h),\\
    (n_{SE}, n_{S\dagger}) &\sim \text{EulerMultinomial}(S; \lambda\, dW / h, \mu; h), \quad
    (n_{EI}, n_{E\dagger}) \sim \text{EulerMultinomial}(E; \sigma, \mu; h), \quad
    (n_{IR}, n_{I\dagger}) \sim \text{EulerMultinomial}(I; \gamma, \mu; h),\\
    S &\leftarrow S + \text{births} - n_{SE} - n_{S\dagger}, \quad
    E \leftarrow E + n_{SE} - n_{EI} - n_{E\dagger}, \quad
    I \leftarrow I + n_{EI} - n_{IR} - n_{I\dagger}, \quad R \leftarrow P - S - E - I,\\
    W &\leftarrow W + (dW - h) / \sigma_{SE}, \qquad C \leftarrow C + n_{IR}.

**The measurement** of the week's reported cases :math:`y` given :math:`C`: a normal of mean
:math:`m = \rho C` and variance :math:`v = m (1 - \rho + \psi^2 m)` (binomial reporting with
overdispersion :math:`\psi`), discretised to whole numbers, with pomp's floor
:math:`\text{tol} = 10^{-18}` on the standard deviation and on the probability:

.. math::

    p(y \mid C) = \Phi\Big(\frac{y + \frac12 - m}{\sqrt v + \text{tol}}\Big)
                - \Phi\Big(\frac{y - \frac12 - m}{\sqrt v + \text{tol}}\Big) + \text{tol}
    \quad (y > 0), \qquad
    \Phi\Big(\frac{\frac12 - m}{\sqrt v + \text{tol}}\Big) + \text{tol} \quad (y = 0),

computed in the log domain (:func:`log_normal_interval`), so that a week far in a tail still gets
its exact probability down to the floor. A missing week (a blank row) is predict-only.

**The initial state** at :math:`t_0` = ``initial_time`` (one week before the first report): the
fractions :math:`S_0, E_0, I_0, R_0` (normalised to sum 1) of :math:`P(t_0)`, each rounded to a
whole number (pomp's ``nearbyint``), :math:`W = C = 0`.

**The parameters** default to He et al.'s maximum-likelihood estimate for London (their Table 2;
pypomp's ``AK_mles.csv``), under pomp's names; at them He et al. report log L = -3804.9.
The ten that He et al. estimate besides the initial fractions (all but ``mu``, which they fix)
are ``vectorised_parameters``: PMMH's chains and IF2's particles may carry their own values,
(R, 1, 1) or (R, N, 1) arrays, which every method reads through :meth:`He10Measles.parameter` as
(R, 1) or (R, N), beside the state's components (R, N).

**Where it differs from pomp's and pypomp's code.** The term rule is evaluated on the substep's
start time. In 1950, 1954, 1958 and 1962 the daily substeps start on whole days of the year, and
32 of them start exactly on a term's first or last day: on floating-point times the comparisons
``day >= 7`` and ``day <= 100`` are then decided by the time's last bits (pomp's double-precision
times, pypomp's 32-bit ones and pfx's each decide them their own way, a few in term, a few not).
The plugin rounds the day to 10^-6 first, so that every one of them is in term, as the rule says.
Which way they fall moves the log-likelihood by about one unit
(docs/benchmarks/measles-london.md). pypomp computes in 32-bit floats; the measurement's
probability is computed here in the log domain, so a week far in the normal's tail keeps its
exact value down to the floor, where the difference of two CDFs near 1 would round to 0.

``propagate`` is the substep's mean (:math:`dW = h`, every draw at its expectation): what pfx's
look-ahead and Gaussian filters would use; the particle filter draws with ``sample_substep``.

Run it: ``pfx run configs/benchmarks/measles-london/measles.yaml``.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, StrictInt

import pfx

TOLERANCE = 1.0e-18                       # pomp's tol: on the standard deviation and the probability
LOG_TOLERANCE = math.log(TOLERANCE)
DAYS_PER_YEAR = 365.25
SCHOOL_ENTRY = 251.0 / 365.0              # the cohort enters school on day 251 (pomp's test)
TERMS = ((7.0, 100.0), (115.0, 199.0), (252.0, 300.0), (308.0, 356.0))   # days of the year in term
TERM_SHARE = 0.7589                       # the share of the year in term: mean seasonality 1
DAY_RESOLUTION = 1.0e-6                   # days: the term test's resolution (seasonal_rates)
STATES = ("S", "E", "I", "R", "W", "C")
SUSCEPTIBLE, EXPOSED, INFECTIOUS, RECOVERED, NOISE, CASES = range(6)
POP, BIRTHRATE = 0, 1
FIRST_REPORT = 1950.0 + 5.0 / DAYS_PER_YEAR    # 1950-01-06, pomp's time of the first week


def log_normal_interval(low, high):
    r""":math:`\log(\Phi(\text{high}) - \Phi(\text{low}))` for low < high, accurate in both tails:
    an interval above 0 is taken as :math:`\Phi(-\text{low}) - \Phi(-\text{high})`, and the
    difference as :math:`\log\Phi(b) + \log(1 - e^{\log\Phi(a) - \log\Phi(b)})`."""
    xp = pfx.namespace(low, high)
    special = pfx.special_functions(xp)
    upper = (low + high) > 0.0
    a, b = xp.where(upper, -high, low), xp.where(upper, -low, high)
    log_a, log_b = special.log_ndtr(a), special.log_ndtr(b)
    gap = xp.where(xp.isfinite(log_b), log_a - log_b, -xp.inf)
    return log_b + xp.log1p(-xp.exp(xp.minimum(gap, 0.0)))


@pfx.register_model
class He10Measles(pfx.Model):
    """He et al.'s (2010) measles SEIR: Euler-multinomial counts, gamma white noise, school terms."""

    kind: Literal["he10_measles"] = "he10_measles"
    R0: float = Field(56.8, gt=0.0, description="basic reproduction number")
    sigma: float = Field(28.9, gt=0.0, description="rate of leaving the latent stage (per year)")
    gamma: float = Field(30.4, gt=0.0, description="recovery rate (per year)")
    iota: float = Field(2.9, ge=0.0, description="imported infections (people)")
    rho: float = Field(0.488, gt=0.0, le=1.0, description="reporting probability")
    sigmaSE: float = Field(0.0878, gt=0.0, description="extra-demographic noise intensity (gamma white noise)")
    psi: float = Field(0.116, ge=0.0, description="reporting overdispersion")
    cohort: float = Field(0.557, ge=0.0, le=1.0, description="share of the births entering at school start")
    amplitude: float = Field(0.554, ge=0.0, le=1.0, description="term-time seasonality amplitude")
    mu: float = Field(0.02, ge=0.0, description="natural death rate (per year; He et al. fix it)")
    alpha: float = Field(0.976, gt=0.0, description="mixing exponent on I + iota")
    S_0: float = Field(0.0297, ge=0.0, description="initial fraction susceptible")
    E_0: float = Field(5.17e-05, ge=0.0, description="initial fraction exposed")
    I_0: float = Field(5.14e-05, ge=0.0, description="initial fraction infectious")
    R_0: float = Field(0.97, ge=0.0, description="initial fraction recovered")
    substeps: StrictInt = Field(7, ge=1, le=100_000, description="substeps between weekly reports "
                                                              "(7: pomp's delta.t of one day, 1/365.25 year)")
    initial_time: float = Field(FIRST_REPORT - 7.0 / DAYS_PER_YEAR,
                                description="t0, the initial state's time (pomp's: a week before the first report)")

    integrates_substeps: ClassVar[bool] = True
    time_unit = "year"
    # He et al.'s estimated parameters, other than the initial fractions (read once, at t0)
    vectorised_parameters: ClassVar[tuple[str, ...]] = ("R0", "sigma", "gamma", "iota", "rho", "sigmaSE", "psi",
                                                        "cohort", "amplitude", "alpha")

    def presets(self):
        presets = {"steps": 730, "dt": 7.0 / DAYS_PER_YEAR,
                   "process_noise": pfx.Noise(variance=0.0),        # the counts' own randomness is drawn below
                   "measurement_noise": pfx.Noise(variance=1.0)}    # unused: log_likelihood is the discretised normal
        if self.initial is None:
            presets["initial"] = pfx.PointLaw(state=self.initial_state().tolist())
        return presets

    def check(self):
        if self.S_0 + self.E_0 + self.I_0 + self.R_0 <= 0.0:
            raise ValueError("@S_0: the initial fractions S_0..R_0 must not all be 0")

    @property
    def state_names(self):
        return STATES

    @property
    def state_units(self):
        return ("people",) * 4 + ("", "people")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def measurement_names(self):
        return ("cases",)

    @property
    def covariate_names(self):
        return ("pop", "birthrate")

    @property
    def accumulating_components(self):
        return (NOISE, CASES)

    def initial_state(self) -> np.ndarray:
        """x_0: the fractions S_0..R_0 (normalised) of P(t0), rounded to whole people; W = C = 0."""
        fractions = np.array([self.S_0, self.E_0, self.I_0, self.R_0])
        population = self.covariates_at(self.initial_time)[POP]
        return np.concatenate([np.rint(population * fractions / fractions.sum()), [0.0, 0.0]])

    def parameter(self, name: str):
        """A parameter as the methods below read it: a number, or, when the estimation gives one
        value per chain or per particle ((R, 1, 1) or (R, N, 1), ``vectorised_parameters``), an
        (R, 1) or (R, N) array that broadcasts with a state component (R, N)."""
        value = getattr(self, name)
        return value[..., 0] if getattr(value, "ndim", 0) == 3 else value

    # -- the substep ------------------------------------------------------------------------

    def seasonal_rates(self, time):
        """(b, beta, P) at the substep starting at ``time``: the births per year with the cohort
        effect, the term-time transmission rate and the population (module docstring)."""
        step = self.substep_duration
        cohort, amplitude, r0, gamma = (self.parameter(name) for name in ("cohort", "amplitude", "R0", "gamma"))
        covariates = self.covariates_at(time)             # NumPy, or JAX when the time is traced
        tx = pfx.namespace(covariates, time, cohort, gamma)
        population, births = covariates[POP], covariates[BIRTHRATE]
        year_fraction = time - tx.floor(time)
        entering = tx.abs(year_fraction - SCHOOL_ENTRY) < 0.5 * step
        birth_rate = (1.0 - cohort) * births + tx.where(entering, cohort * births / step, 0.0)
        # In 1950, 1954, 1958 and 1962 the daily substeps start on whole days of the year, so 32 of
        # them start exactly on a term's first or last day, where the time's last bits (1e-11 of
        # a day) would decide the comparison: the day is rounded to DAY_RESOLUTION first, so that
        # such a substep counts as in term, as the rule (days 7-100, ... inclusive) says.
        day = tx.round(year_fraction * DAYS_PER_YEAR / DAY_RESOLUTION) * DAY_RESOLUTION
        in_term = False
        for first, last in TERMS:
            in_term = in_term | ((day >= first) & (day <= last))
        seasonality = tx.where(in_term, 1.0 + amplitude * (1.0 - TERM_SHARE) / TERM_SHARE, 1.0 - amplitude)
        exponent = -(gamma + self.mu) * step
        leaving = -(math.expm1(exponent) if isinstance(exponent, float) else tx.expm1(exponent))
        beta = r0 * seasonality * leaving / step
        return birth_rate, beta, population

    def sample_substep(self, state, control, time, random):
        """One day: births, then whole individuals leave S, E and I by Euler-multinomial draws."""
        xp = pfx.namespace(state)
        step = self.substep_duration
        iota, alpha, noise_sd, sigma, gamma = (self.parameter(name) for name in ("iota", "alpha", "sigmaSE",
                                                                                 "sigma", "gamma"))
        birth_rate, beta, population = self.seasonal_rates(time)
        susceptible, exposed, infectious = state[..., SUSCEPTIBLE], state[..., EXPOSED], state[..., INFECTIOUS]
        force = beta * (infectious + iota) ** alpha / population
        noise = pfx.gamma_white_noise(random, noise_sd, step, shape=susceptible.shape[1:])   # dW, (R, N)
        births = random.poisson(xp.full_like(susceptible, birth_rate * step))
        deaths = xp.full_like(susceptible, self.mu)
        leaving_s = pfx.euler_multinomial(random, susceptible, xp.stack([force * noise / step, deaths], axis=-1), step)
        leaving_e = pfx.euler_multinomial(random, exposed, xp.stack([xp.full_like(deaths, sigma), deaths],
                                                                    axis=-1), step)
        leaving_i = pfx.euler_multinomial(random, infectious, xp.stack([xp.full_like(deaths, gamma), deaths],
                                                                       axis=-1), step)
        infections, onsets, recoveries = leaving_s[..., 0], leaving_e[..., 0], leaving_i[..., 0]
        new_susceptible = susceptible + births - leaving_s.sum(axis=-1)
        new_exposed = exposed + infections - leaving_e.sum(axis=-1)
        new_infectious = infectious + onsets - leaving_i.sum(axis=-1)
        return xp.stack([new_susceptible, new_exposed, new_infectious,
                         population - new_susceptible - new_exposed - new_infectious,
                         state[..., NOISE] + (noise - step) / noise_sd,
                         state[..., CASES] + recoveries], axis=-1)

    def propagate(self, state, control, noise, time):
        """The substep's mean (dW = h, each draw at its expectation): for the look-ahead and the
        Gaussian filters; the particle filter draws with :meth:`sample_substep`."""
        xp = pfx.namespace(state)
        step = self.substep_duration
        iota, alpha, sigma, gamma = (self.parameter(name) for name in ("iota", "alpha", "sigma", "gamma"))
        birth_rate, beta, population = self.seasonal_rates(time)
        susceptible, exposed, infectious = state[..., SUSCEPTIBLE], state[..., EXPOSED], state[..., INFECTIOUS]
        force = beta * (infectious + iota) ** alpha / population

        def exits(count, rate):          # expected leavers by the first exit (rate) and by death
            total = rate + self.mu
            leaving = count * -xp.expm1(-total * step)
            return leaving * rate / total, leaving * self.mu / total

        infections, deaths_s = exits(susceptible, force)
        onsets, deaths_e = exits(exposed, sigma)
        recoveries, deaths_i = exits(infectious, gamma)
        new_susceptible = susceptible + birth_rate * step - infections - deaths_s
        new_exposed = exposed + infections - onsets - deaths_e
        new_infectious = infectious + onsets - recoveries - deaths_i
        return xp.stack([new_susceptible, new_exposed, new_infectious,
                         population - new_susceptible - new_exposed - new_infectious,
                         state[..., NOISE], state[..., CASES] + recoveries], axis=-1)

    # -- the report -------------------------------------------------------------------------

    def reporting_moments(self, state):
        """(m, sd) of the week's reports given C: rho C and sqrt(m (1 - rho + psi^2 m)) + tol."""
        xp = pfx.namespace(state)
        rho, psi = self.parameter("rho"), self.parameter("psi")
        mean = rho * state[..., CASES]
        variance = mean * (1.0 - rho + psi**2 * mean)
        return mean, xp.sqrt(xp.maximum(variance, 0.0)) + TOLERANCE

    def measurement_mean(self, state):
        return (self.parameter("rho") * state[..., CASES])[..., None]

    def log_likelihood(self, measurement, state):
        """log p(y | C): the discretised normal plus pomp's floor (module docstring)."""
        xp = pfx.namespace(measurement, state)
        special = pfx.special_functions(xp)
        reports = measurement[..., 0]
        mean, scale = self.reporting_moments(state)
        high = (reports + 0.5 - mean) / scale
        low = (reports - 0.5 - mean) / scale
        probability = xp.where(reports > TOLERANCE, log_normal_interval(low, high), special.log_ndtr(high))
        value = xp.logaddexp(probability, LOG_TOLERANCE)
        return xp.where(state[..., CASES] < 0.0, -xp.inf, value)

    def simulate_measurement(self, state, random):
        xp = pfx.namespace(state)
        mean, scale = self.reporting_moments(state)
        draws = mean + scale * random.standard_normal(state.shape[1:-1])
        return xp.where(draws > 0.0, xp.round(draws), 0.0)[..., None]
