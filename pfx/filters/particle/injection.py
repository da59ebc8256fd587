r"""Particle injection: augmented MCL (Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 8.3).

Two exponential averages of the measurement likelihood, a slow and a fast one,

.. math:: w_\text{slow} \leftarrow w_\text{slow} + \alpha_\text{slow}(w_\text{avg} - w_\text{slow}),
          \qquad
          w_\text{fast} \leftarrow w_\text{fast} + \alpha_\text{fast}(w_\text{avg} - w_\text{fast}),

(both start at 0, :math:`0 \le \alpha_\text{slow} < \alpha_\text{fast}`), and at resampling each
particle is replaced, with probability :math:`p = \max(0,\ 1 - w_\text{fast}/w_\text{slow})`, by
a draw from the filter's prior (its initial law: for ``sonar_mcl``, uniform over free space).
A sudden drop of the likelihood (the robot was kidnapped, the filter converged on the wrong
place) pulls :math:`w_\text{fast}` below :math:`w_\text{slow}` and injects particles.

:math:`w_\text{avg}`: the book takes the mean over particles of :math:`p(z_k \mid x_{k,i})` with
the particles just resampled (equal weights). pfx takes the weighted mean with the previous
weights, :math:`w_\text{avg} = \sum_i w_{k-1,i}\, p(z_k \mid x_{k,i}) = e^{L_k}`, the step's
log-normaliser (:mod:`pfx.filters.particle.engine`): the same number when the filter resampled
at the previous step, and the estimate of the predictive likelihood
:math:`p(z_k \mid z_{1:k-1})` when it did not (an unweighted mean would count the particles
that the previous measurements already ruled out). The averages are kept as logarithms
(log-sum-exp of the two terms), so a likelihood of :math:`e^{-800}` neither underflows nor
stops the averages. A step without a measurement leaves them unchanged.

The averages' update and the probability are functions of arrays (:func:`observed_averages`,
:func:`injection_probability`), NumPy or JAX; the kernel (:meth:`pfx.filters.particle.kernel.ParticleKernel.inject`)
carries the averages in its cloud and draws only in the resampled trials with :math:`p > 0`
(on JAX, a mask: every trial draws, only those replace).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, model_validator

from pfx.filters.backends import BOTH, Backends
from pfx.numerics.arrays import namespace


class AugmentedMCL(BaseModel):
    """Augmented MCL: inject prior draws at rate max(0, 1 - w_fast / w_slow)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    backends: ClassVar[Backends] = Backends(BOTH)
    kind: Literal["augmented"] = "augmented"
    alpha_slow: StrictFloat = Field(0.001, ge=0, lt=1, description="decay rate of the slow average (book: 0.001)")
    alpha_fast: StrictFloat = Field(0.1, gt=0, le=1, description="decay rate of the fast average (book: 0.1)")

    @model_validator(mode="after")
    def _rates(self) -> "AugmentedMCL":
        if not self.alpha_slow < self.alpha_fast:
            raise ValueError(f"@alpha_slow: must be less than alpha_fast ({self.alpha_slow:g} >= "
                             f"{self.alpha_fast:g}): the slow average must be the slower one")
        return self


# -- the mathematics, for both backends (NumPy or JAX arrays: pfx.numerics.arrays.namespace) ----------

def observed_averages(settings: AugmentedMCL, log_slow, log_fast, log_average, observed=None):
    """(log w_slow, log w_fast) after a step whose log-normaliser is ``log_average`` (R,):
    w <- (1 - alpha) w + alpha w_avg for both, in logs; the trials where ``observed`` (bool per
    trial, or None: all) is False keep theirs."""
    xp = namespace(log_slow, log_average)
    with np.errstate(divide="ignore"):
        slow = _blend(log_slow, log_average, settings.alpha_slow)
        fast = _blend(log_fast, log_average, settings.alpha_fast)
    if observed is None:
        return slow, fast
    return xp.where(observed, slow, log_slow), xp.where(observed, fast, log_fast)


def injection_probability(log_slow, log_fast):
    """p = max(0, 1 - w_fast / w_slow) per trial (0 while w_slow = 0)."""
    xp = namespace(log_slow, log_fast)
    with np.errstate(invalid="ignore", over="ignore"):
        ratio = xp.exp(log_fast - log_slow)
    return xp.where(xp.isneginf(log_slow), 0.0, xp.maximum(0.0, 1.0 - ratio))


def _blend(log_average: np.ndarray, log_value: np.ndarray, alpha: float) -> np.ndarray:
    """log((1 - alpha) e^a + alpha e^v), exactly -inf where both terms vanish."""
    xp = namespace(log_average, log_value)
    keep = np.log1p(-alpha) + log_average if alpha < 1.0 else xp.full_like(log_average, -np.inf)
    add = np.log(alpha) + log_value if alpha > 0.0 else xp.full_like(log_value, -np.inf)
    return xp.logaddexp(keep, add)
