r"""A pfx plugin: the boarding-school influenza outbreak of 1978, pomp's ``bsflu`` (docs/bsflu.md).

In January 1978 influenza went through a boys' boarding school in the north of England: 763
boys, 512 of them ill (BMJ 1978, 1(6112):587). pomp's tutorials fit the number confined to bed
each day with an SIRR model of whole boys; this plugin is that model, written on pfx's documented
interfaces (``pfx.Model``, substeps, ``pfx.euler_multinomial``) in the array namespace, so that it
runs on both backends.

**The state** (whole boys, as floats): susceptible :math:`S`, infected :math:`I`, confined to bed
:math:`R_1` and convalescent :math:`R_2`. At time 0 (the day before the first report)
:math:`S = N - 1`, :math:`I = 1`, :math:`R_1 = R_2 = 0`, with :math:`N = 763`.

**One substep** of :math:`h` = ``1 / substeps`` day (pomp's ``delta.t = 1/12``: 12 substeps a day),
each compartment left by an Euler-multinomial draw (pomp's ``reulermultinom`` with one exit,
a binomial of probability :math:`1 - e^{-\text{rate}\,h}`):

.. math::

    n_{SI} &\sim \text{Bin}(S, 1 - e^{-\beta I / N\, h}), \quad
    n_{I R_1} \sim \text{Bin}(I, 1 - e^{-\mu_{IR} h}), \quad
    n_{R_1 R_2} \sim \text{Bin}(R_1, 1 - e^{-\mu_{R_1} h}),\\
    S &\leftarrow S - n_{SI}, \quad I \leftarrow I + n_{SI} - n_{I R_1}, \quad
    R_1 \leftarrow R_1 + n_{I R_1} - n_{R_1 R_2}, \quad R_2 \leftarrow R_2 + n_{R_1 R_2}.

**The measurement**: the boys reported in bed, :math:`B \sim \text{Poisson}(\rho R_1)`, whose
log-probability :math:`B \log(\rho R_1) - \rho R_1 - \log B!` is the likelihood (``xlogy``, so
that :math:`R_1 = 0` gives probability 1 to :math:`B = 0` and 0 to any other count; pomp's
tutorial adds :math:`10^{-6}` to the mean instead).

**The parameters**, under pomp's names: ``Beta`` (:math:`\beta`, contacts per day), ``mu_IR``
(per day), ``rho`` (the share of the boys in bed that are reported) and ``mu_R1`` (per day;
pomp's tutorial fixes it at 512 / 1557, the ill boys over the bed-days reported: a mean of
about 3 days in bed). The first three are ``vectorised_parameters``: IF2's particles and
PMMH's chains may carry their own values, (R, 1, 1) or (R, N, 1) arrays, which every method
reads through :meth:`BoardingSchoolFlu.parameter` as (R, 1) or (R, N). The basic reproduction
number is :math:`R_0 = \beta / \mu_{IR}`.

``propagate`` is the substep's mean (every draw at its expectation): what pfx's look-ahead and
Gaussian filters would use; the particle filter draws with ``sample_substep``.

Run it: ``pfx run configs/examples/bsflu.yaml``.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, StrictInt

import pfx

BOYS = 763                          # at risk of infection (BMJ 1978)
SUSCEPTIBLE, INFECTED, IN_BED, CONVALESCENT = range(4)


@pfx.register_model
class BoardingSchoolFlu(pfx.Model):
    """pomp's bsflu SIRR model: Euler-multinomial counts of boys, Poisson reports of those in bed."""

    kind: Literal["bsflu"] = "bsflu"
    Beta: float = Field(3.7, gt=0.0, description="transmission rate beta (per day): S -> I at beta I / N")
    mu_IR: float = Field(2.0, gt=0.0, description="rate of going to bed, I -> R1 (per day)")
    rho: float = Field(0.95, gt=0.0, le=1.0, description="reporting probability of a boy in bed")
    mu_R1: float = Field(512.0 / 1557.0, gt=0.0, description="rate of leaving bed, R1 -> R2 (per day; pomp's "
                                                             "tutorial fixes it at 512/1557)")
    population: float = Field(float(BOYS), gt=1.0, description="N, the boys at risk")
    substeps: StrictInt = Field(12, ge=1, le=100_000, description="substeps a day (12: pomp's delta.t = 1/12)")

    integrates_substeps: ClassVar[bool] = True
    time_unit = "day"
    vectorised_parameters: ClassVar[tuple[str, ...]] = ("Beta", "mu_IR", "rho", "mu_R1")

    def presets(self):
        return {"steps": 14, "dt": 1.0,
                "process_noise": pfx.Noise(variance=0.0),        # the counts' own randomness is drawn below
                "measurement_noise": pfx.Noise(variance=1.0),    # unused: log_likelihood is the Poisson's
                "initial": pfx.PointLaw(state=[self.population - 1.0, 1.0, 0.0, 0.0])}

    @property
    def state_names(self):
        return ("S", "I", "R1", "R2")

    @property
    def state_units(self):
        return ("boys",) * 4

    @property
    def measurement_dimension(self):
        return 1

    @property
    def measurement_names(self):
        return ("reports",)

    def parameter(self, name: str):
        """A parameter as the methods read it: a number, or, when the estimation gives one value
        per chain or per particle ((R, 1, 1) or (R, N, 1)), an (R, 1) or (R, N) array that
        broadcasts with a state component (R, N)."""
        value = getattr(self, name)
        return value[..., 0] if getattr(value, "ndim", 0) == 3 else value

    def exit_rates(self, state):
        """Each compartment's rate of leaving per day, (..., 3): S by infection, I to bed, R1 out of bed."""
        xp = pfx.namespace(state)
        infection = self.parameter("Beta") * state[..., INFECTED] / self.population
        shape = infection.shape
        return xp.stack([infection,
                         xp.broadcast_to(xp.asarray(self.parameter("mu_IR"), dtype=state.dtype), shape),
                         xp.broadcast_to(xp.asarray(self.parameter("mu_R1"), dtype=state.dtype), shape)], axis=-1)

    def sample_substep(self, state, control, time, random):
        """One substep of h = 1 / substeps day: whole boys leave S, I and R1 (Euler-multinomial draws)."""
        xp = pfx.namespace(state)
        step = self.substep_duration
        rates = self.exit_rates(state)
        infections, to_bed, out_of_bed = (
            pfx.euler_multinomial(random, state[..., j], rates[..., j:j + 1], step)[..., 0] for j in range(3))
        return xp.stack([state[..., SUSCEPTIBLE] - infections,
                         state[..., INFECTED] + infections - to_bed,
                         state[..., IN_BED] + to_bed - out_of_bed,
                         state[..., CONVALESCENT] + out_of_bed], axis=-1)

    def propagate(self, state, control, noise):
        """The substep's mean: each compartment loses its share 1 - exp(-rate h)."""
        xp = pfx.namespace(state)
        leaving = state[..., :3] * -xp.expm1(-self.exit_rates(state) * self.substep_duration)
        infections, to_bed, out_of_bed = leaving[..., 0], leaving[..., 1], leaving[..., 2]
        return xp.stack([state[..., SUSCEPTIBLE] - infections,
                         state[..., INFECTED] + infections - to_bed,
                         state[..., IN_BED] + to_bed - out_of_bed,
                         state[..., CONVALESCENT] + out_of_bed], axis=-1)

    def measurement_mean(self, state):
        return (self.parameter("rho") * state[..., IN_BED])[..., None]

    def simulate_measurement(self, state, random):
        return random.poisson(self.measurement_mean(state)[..., 0])[..., None]

    def log_likelihood(self, measurement, state):
        """log P(B | R1) of B ~ Poisson(rho R1): B log(rho R1) - rho R1 - log B!."""
        xp = pfx.namespace(state, measurement)
        special = pfx.special_functions(xp)
        reports = measurement[..., 0]
        mean = self.parameter("rho") * state[..., IN_BED]
        return special.xlogy(reports, mean) - mean - special.gammaln(reports + 1.0)
