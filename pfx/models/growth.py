r"""The univariate nonstationary growth model: the classic particle-filter benchmark.

.. math::

    x_k = a\,x_{k-1} + \frac{b\,x_{k-1}}{1 + x_{k-1}^2} + c\cos(\omega k) + v_k,
    \qquad v_k \sim N(0, Q), \\[4pt]
    z_k = s\,x_k^2 + w_k, \qquad w_k \sim N(0, R),

with :math:`a = 1/2`, :math:`b = 25`, :math:`c = 8`, :math:`\omega = 1.2`, :math:`s = 1/20`,
:math:`Q = 10`, :math:`R = 1` (Gordon, Salmond & Smith 1993, the bootstrap filter's first
example; Arulampalam, Maskell, Gordon & Clapp 2002, section VI, eq. 79 to 81). Every preset
can be changed in the config (``a``, ``b``, ``c``, ``omega``, ``measurement_scale``,
``process_noise``, ``measurement_noise``, ``initial``, ``steps``).

Why it is hard: :math:`z` measures :math:`x^2`, so the sign of :math:`x` is observed only
through the dynamics, and the likelihood is bimodal (at :math:`\pm\sqrt{z/s}`) whenever the
predicted density straddles zero. The posterior is then bimodal too: its mean can sit between
the modes where the truth never is, and a Gaussian filter (EKF, UKF) locks onto one mode or
neither. The posterior of this scalar model can be computed almost exactly on a grid
(:mod:`pfx.filters.histogram`), which makes it the standard place to check a particle filter
against the true posterior rather than against the truth.

**Forcing term as a control input.** The term :math:`c\cos(\omega k)` depends on time alone; pfx
gives it to :meth:`GrowthModel.propagate` as the model's control input,
:math:`u_k = [c\cos(\omega (k - k_0))]` (:meth:`GrowthModel.control`, ``k = 1..T``), so that
``propagate(x, u, v) = a x + b x / (1 + x^2) + u + v`` is a function of the state, the control
and the noise only, like every other model's.

**Conventions differ between sources**, and pfx makes each one a setting:

* *Index of the cosine.* Arulampalam et al. (2002) write :math:`8\cos(1.2k)` in the equation
  for :math:`x_k`; implementations that follow Gordon et al. (1993), e.g. RcppSMC's
  ``pfNonlinBS``/``simNonlin`` and D. Simon's ``ParticleEx1.m``, use :math:`8\cos(1.2(k-1))`.
  ``forcing_offset`` is :math:`k_0`: 0 (the default, Arulampalam) or 1 (Gordon).
* *Initial state.* pfx's default is :math:`x_0 \sim N(0, 10)`, the prior variance equal to the
  process noise variance (RcppSMC's ``simNonlin`` draws its first state from :math:`N(0, 10)`;
  its filter starts from :math:`N(0, 4)`). Simon's ``ParticleEx1.m`` starts the truth at
  :math:`x_0 = 0.1` with a filter prior of variance 2 (and :math:`Q = 1`), the version often
  quoted as "x_0 = 0.1"; the TSSS R package (Kitagawa) uses :math:`x_0 \sim N(0, 5)` with
  :math:`Q = 1`, :math:`R = 10` and :math:`s = 1/10`. Set ``initial`` (truth),
  ``filter.initial`` (prior) and the noises for those.

Every method is plain arithmetic on NumPy or JAX arrays (:mod:`pfx.numerics.arrays`): the same
code runs on both backends; the control is computed on the host (NumPy) and given to either.

The model is scalar: state ``x`` (``position_components = (0,)``), one measurement; steps are
counted in time steps (``dt = 1``).

EKF Jacobians: analytic, :math:`F = a + b (1 - x^2) / (1 + x^2)^2`, :math:`L = 1`,
:math:`H = 2 s x` (zero at :math:`x = 0`, where the measurement carries no first-order
information: the EKF's well-known failure on this model).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, StrictFloat

from pfx.laws.initial import GaussianLaw
from pfx.laws.noise import Noise
from pfx.models.base import MODELS, Model
from pfx.numerics.arrays import namespace


@MODELS.register_kind
class GrowthModel(Model):
    """Univariate nonstationary growth model (Gordon, Salmond & Smith 1993)."""

    kind: Literal["growth"] = "growth"
    a: StrictFloat = Field(0.5, description="coefficient of x_{k-1} (1/2)")
    b: StrictFloat = Field(25.0, description="coefficient of x_{k-1} / (1 + x_{k-1}^2) (25)")
    c: StrictFloat = Field(8.0, description="amplitude of the forcing term c cos(omega k) (8)")
    omega: StrictFloat = Field(1.2, description="angular frequency of the forcing term, per step (1.2)")
    forcing_offset: Literal[0, 1] = Field(
        0, description="k0 in c cos(omega (k - k0)): 0 as Arulampalam et al. 2002, 1 as Gordon et al. 1993")
    measurement_scale: StrictFloat = Field(
        0.05, description="s in z = s x^2 + w (1/20)")

    time_unit: ClassVar[str] = "step"

    def presets(self):
        return {
            "steps": 50, "dt": 1.0,
            "process_noise": Noise(family="gaussian", variance=10.0),
            "measurement_noise": Noise(family="gaussian", variance=1.0),
            "initial": GaussianLaw(mean=[0.0], covariance=10.0),
        }

    @property
    def state_names(self):
        return ("x",)

    @property
    def measurement_dimension(self):
        return 1

    def control(self, step):
        """The forcing term u_k = [c cos(omega (k - k0))] applied between steps k-1 and k."""
        return np.array([self.c * np.cos(self.omega * (step - self.forcing_offset))])

    def propagate(self, state, control, noise):
        moved = self.a * state + self.b * state / (1.0 + state * state)
        if control is not None:
            moved = moved + control
        return moved + noise

    def measurement_mean(self, state):
        return self.measurement_scale * state * state

    def transition_jacobian(self, state, control):
        square = state * state
        return (self.a + self.b * (1.0 - square) / (1.0 + square) ** 2)[..., None]

    def process_noise_jacobian(self, state, control):
        return namespace(state).ones(state.shape[:-1] + (1, 1), dtype=state.dtype)

    def measurement_jacobian(self, state):
        return (2.0 * self.measurement_scale * state)[..., None]
