r"""Prior laws of estimated parameters, and the transformations a random walk moves them in.

Parameter estimation (:mod:`pfx.estimation`) gives each estimated parameter :math:`\theta_j` a
prior :math:`\pi_j` (independent priors: :math:`\log \pi(\theta) = \sum_j \log \pi_j(\theta_j)`)
and moves it on an unconstrained scale :math:`u_j = g_j(\theta_j)`:

==============  ==============================  =========================================  ==========================
transform       :math:`u = g(\theta)`            :math:`\theta = g^{-1}(u)`                   support of :math:`\theta`
==============  ==============================  =========================================  ==========================
``none``        :math:`\theta`                   :math:`u`                                    the real line
``log``         :math:`\log \theta`              :math:`e^u`                                  :math:`(0, \infty)`
``logit``       :math:`\log\frac{\theta - a}{b - \theta}`  :math:`a + (b - a) / (1 + e^{-u})`  :math:`(a, b)`
==============  ==============================  =========================================  ==========================

A random walk on :math:`u` is a Metropolis-Hastings proposal for :math:`\theta` whose density
carries the Jacobian :math:`|d\theta / du|`: the target on the :math:`u` scale is
:math:`\pi(\theta(u))\, |d\theta/du|`, and :meth:`Transform.log_jacobian` gives
:math:`\log |d\theta/du|` (:math:`u` for ``log``; :math:`\log(b - a) + \log s(u) + \log(1 - s(u))`
for ``logit``, with :math:`s` the logistic function). Without a transform named, a parameter
takes the one its prior's support asks for.

The laws are scipy.stats distributions (log-densities and quantiles); draws come from an
explicit :class:`numpy.random.Generator` (a chain's own stream), never a global one. scipy.stats
is imported when a law is first built, not with this module: every config is checked against
these models, and importing scipy.stats costs every ``pfx`` command about half a second.
:meth:`Transform.to_natural` also takes JAX arrays: IF2 on the jax backend maps every
particle's parameters to the natural scale inside its compiled pass (:mod:`pfx.estimation.compiled_if2`).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, StrictFloat, model_validator
from scipy.special import expit, logit

from pfx.numerics.arrays import is_jax_array, namespace, special_functions


class _Prior(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    _frozen: Any = PrivateAttr(None)

    def frozen(self) -> Any:
        """The frozen scipy.stats distribution, made once: building one costs a few tenths of a
        millisecond, and PMMH asks for the prior's density at every iteration."""
        if self._frozen is None:
            self._frozen = self.distribution()
        return self._frozen

    def distribution(self):
        """The frozen scipy.stats distribution (a new one)."""
        raise NotImplementedError

    @property
    def support(self) -> tuple[float, float]:
        lower, upper = self.frozen().support()
        return float(lower), float(upper)

    def log_density(self, value: np.ndarray) -> np.ndarray:
        """log pi(value); -inf outside the support."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(self.frozen().logpdf(value), dtype=float)

    def sample(self, generator: np.random.Generator, size=None) -> np.ndarray:
        return self.frozen().rvs(size=size, random_state=generator)

    def label(self) -> str:
        parameters = ", ".join(f"{key}={value:g}" for key, value in self.model_dump().items() if key != "law")
        return f"{self.law}({parameters})"


class UniformPrior(_Prior):
    """Uniform on [lower, upper]."""

    law: Literal["uniform"] = "uniform"
    lower: StrictFloat = Field(description="lower end")
    upper: StrictFloat = Field(description="upper end (> lower)")

    @model_validator(mode="after")
    def _check(self):
        if not self.upper > self.lower:
            raise ValueError("@upper: must exceed lower")
        return self

    def distribution(self):
        from scipy import stats

        return stats.uniform(loc=self.lower, scale=self.upper - self.lower)


class NormalPrior(_Prior):
    """Normal with mean and standard deviation sd."""

    law: Literal["normal"] = "normal"
    mean: StrictFloat = Field(0.0, description="mean")
    sd: StrictFloat = Field(gt=0, description="standard deviation")

    def distribution(self):
        from scipy import stats

        return stats.norm(loc=self.mean, scale=self.sd)


class LogNormalPrior(_Prior):
    """log theta ~ Normal(mean, sd)."""

    law: Literal["lognormal"] = "lognormal"
    mean: StrictFloat = Field(0.0, description="mean of log theta")
    sd: StrictFloat = Field(gt=0, description="standard deviation of log theta")

    def distribution(self):
        from scipy import stats

        return stats.lognorm(s=self.sd, scale=math.exp(self.mean))


class GammaPrior(_Prior):
    """Gamma with shape a and rate b: density proportional to theta^(a-1) exp(-b theta)."""

    law: Literal["gamma"] = "gamma"
    shape: StrictFloat = Field(gt=0, description="shape a")
    rate: StrictFloat = Field(1.0, gt=0, description="rate b (1 / scale)")

    def distribution(self):
        from scipy import stats

        return stats.gamma(a=self.shape, scale=1.0 / self.rate)


class InverseGammaPrior(_Prior):
    """Inverse gamma with shape a and scale b: density proportional to theta^(-a-1) exp(-b / theta)."""

    law: Literal["inverse_gamma"] = "inverse_gamma"
    shape: StrictFloat = Field(gt=0, description="shape a")
    scale: StrictFloat = Field(1.0, gt=0, description="scale b")

    def distribution(self):
        from scipy import stats

        return stats.invgamma(a=self.shape, scale=self.scale)


class BetaPrior(_Prior):
    """Beta(a, b) on [lower, upper] (default [0, 1])."""

    law: Literal["beta"] = "beta"
    a: StrictFloat = Field(gt=0, description="first shape")
    b: StrictFloat = Field(gt=0, description="second shape")
    lower: StrictFloat = Field(0.0, description="lower end")
    upper: StrictFloat = Field(1.0, description="upper end (> lower)")

    @model_validator(mode="after")
    def _check(self):
        if not self.upper > self.lower:
            raise ValueError("@upper: must exceed lower")
        return self

    def distribution(self):
        from scipy import stats

        return stats.beta(self.a, self.b, loc=self.lower, scale=self.upper - self.lower)


class FlatPrior(_Prior):
    """Improper flat prior on (lower, upper) (default: the real line): log pi = 0 inside.
    For maximum likelihood (IF2), or a posterior proportional to the likelihood."""

    law: Literal["flat"] = "flat"
    lower: StrictFloat = Field(-math.inf, description="lower end (default -inf)")
    upper: StrictFloat = Field(math.inf, description="upper end (default +inf)")
    model_config = ConfigDict(extra="forbid", allow_inf_nan=True)

    @property
    def support(self) -> tuple[float, float]:
        return self.lower, self.upper

    def log_density(self, value):
        value = np.asarray(value, dtype=float)
        return np.where((value > self.lower) & (value < self.upper), 0.0, -np.inf)

    def sample(self, generator, size=None):
        raise ValueError("a flat prior cannot be drawn from: give the parameter a start")


Prior = Annotated[Union[UniformPrior, NormalPrior, LogNormalPrior, GammaPrior, InverseGammaPrior, BetaPrior,
                        FlatPrior], Field(discriminator="law")]


# -- transformations ------------------------------------------------------------------------------

class Transform:
    """u = g(theta) and back, with log |d theta / d u| (module docstring)."""

    name = "none"

    def __init__(self, lower: float = -math.inf, upper: float = math.inf):
        self.lower, self.upper = lower, upper

    def to_unconstrained(self, value):
        return np.asarray(value, dtype=float)

    def to_natural(self, value):
        return value if is_jax_array(value) else np.asarray(value, dtype=float)

    def log_jacobian(self, value):
        """log |d theta / d u| at u = ``value``."""
        return np.zeros_like(np.asarray(value, dtype=float))


class LogTransform(Transform):
    name = "log"

    def to_unconstrained(self, value):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(np.asarray(value, dtype=float) - self.lower)

    def to_natural(self, value):
        return self.lower + namespace(value).exp(value)

    def log_jacobian(self, value):
        return np.asarray(value, dtype=float)


class LogitTransform(Transform):
    name = "logit"

    def to_unconstrained(self, value):
        with np.errstate(divide="ignore", invalid="ignore"):
            return logit((np.asarray(value, dtype=float) - self.lower) / (self.upper - self.lower))

    def to_natural(self, value):
        return self.lower + (self.upper - self.lower) * special_functions(namespace(value)).expit(value)

    def log_jacobian(self, value):
        share = expit(np.asarray(value, dtype=float))
        with np.errstate(divide="ignore"):
            return math.log(self.upper - self.lower) + np.log(share) + np.log1p(-share)


TransformName = Literal["none", "log", "logit"]


def make_transform(name: Optional[str], support: tuple[float, float]) -> Transform:
    """The transform ``name`` for a parameter whose prior has ``support``; None: the one the
    support asks for (none on the real line, log on a half-line, logit on an interval).
    ValueError('@transform: ...') when the transform does not fit the support."""
    lower, upper = support
    if name is None:
        name = "none" if math.isinf(lower) and math.isinf(upper) else "logit" if math.isfinite(upper) and \
            math.isfinite(lower) else "log"
    if name == "none":
        return Transform(lower, upper)
    if name == "log":
        if not math.isfinite(lower) or math.isfinite(upper):
            raise ValueError(f"@transform: log needs a prior supported on (lower, inf); this one's support is "
                             f"({lower:g}, {upper:g})")
        return LogTransform(lower, upper)
    if not (math.isfinite(lower) and math.isfinite(upper)):
        raise ValueError(f"@transform: logit needs a prior on a bounded interval; this one's support is "
                         f"({lower:g}, {upper:g})")
    return LogitTransform(lower, upper)
