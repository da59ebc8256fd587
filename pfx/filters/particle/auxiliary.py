r"""The auxiliary particle filter's first stage (Pitt & Shephard 1999), ``filter.auxiliary: true``.

At step k, before the proposal, each particle gets a first-stage log-weight from its point
prediction :math:`\mu_i = f(x_{k-1,i}, u_k, 0)`:

.. math::

    \log \lambda_i = \log w_{k-1,i} + g_i, \qquad g_i = \log p(z_k \mid \mu_i),

normalised by log-sum-exp, with normaliser :math:`L^{(1)}_k = \log \sum_i w_{k-1,i} p(z_k \mid \mu_i)`
(the :math:`w_{k-1}` are normalised). The ancestors :math:`a_i` are resampled by :math:`\lambda`
with ``filter.resampler`` (then moved by ``filter.diffusion``, as after any resampling), the
proposal draws :math:`x_{k,i}` from :math:`x_{k-1,a_i}`, and the second stage weighs

.. math::

    \log \tilde w_{k,i} = \log p(z_k \mid x_{k,i}) - g_{a_i}
        \ (+ \log p(x_{k,i} \mid x_{k-1,a_i}) - \log q(x_{k,i} \mid x_{k-1,a_i}, z_k)),

from uniform weights, so its normaliser is :math:`L^{(2)}_k = \log \frac1N \sum_i \tilde w_{k,i}`.
The log-likelihood increment is :math:`L_k = L^{(1)}_k + L^{(2)}_k`, and
:math:`\prod_k e^{L_k}` is an unbiased estimate of :math:`p(z_{1:T})` (leaving out
:math:`L^{(1)}_k` is the classic bug).

**The ESS rule** applies to the first stage: the trials whose first-stage
:math:`\mathrm{ESS} = 1 / \sum_i \lambda_i^2` is below ``ess_threshold`` N are resampled
(threshold 1, the default: every step); the others carry :math:`\lambda` as their weights into
the second stage, which divides :math:`e^{g_i}` out again, so for them the step is exactly the
ordinary filter's (:math:`L_k = \log \sum_i w_{k-1,i} p(z_k \mid x_{k,i})` q-corrected). There is
no resampling at the end of the step: the next step's first stage is where the APF resamples.

Edge cases: a trial whose every first-stage weight underflows, or whose measurement is missing,
takes :math:`g = 0` (first stage = :math:`w_{k-1}`: still a valid APF, the second stage divides
by the same :math:`e^{g}`); a point prediction that is NaN (outside the model's domain) gets
:math:`g = -\infty` and is never chosen as an ancestor.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

from pfx.filters.backends import BOTH, Backends
from pfx.numerics.arrays import namespace
from pfx.numerics.log_weights import normalise_weights


class AuxiliaryFirstStage:
    """The first stage: the look-ahead weights of the particles of step k-1 (module docstring).

    It computes and returns; the kernel applies (:meth:`pfx.filters.particle.kernel.ParticleKernel.look_ahead`:
    adds the increment to the log-likelihood, takes the weights, resamples the trials the ESS
    rule picks with its resampling stage, and gathers the ancestors' look-ahead :math:`g_{a_i}`
    for the second stage), with the look-ahead each backend's driver evaluates.
    """

    backends = Backends(BOTH)

    def first_stage(self, log_weights: Any, look_ahead: Any, observed: Optional[Any]):
        """(log lambda, lambda, L1, g) from the normalised ``log_weights`` (R, N), the model's
        look-ahead (R, N) as it evaluated (NaN where a point prediction left the model's domain)
        and ``observed`` (R,) (None: every trial): the edge cases of the module docstring, as
        selects, on NumPy or JAX arrays."""
        xp = namespace(log_weights, look_ahead)
        look_ahead = xp.where(xp.isnan(look_ahead), -xp.inf, look_ahead)
        if observed is not None:
            look_ahead = xp.where(observed[:, None], look_ahead, 0.0)
        log_first, first, normaliser = normalise_weights(log_weights + look_ahead)
        underflow = ~xp.isfinite(normaliser)
        if xp is not np or underflow.any():       # NumPy skips the fallback where no trial needs it
            look_ahead = xp.where(underflow[:, None], 0.0, look_ahead)
            log_prior, prior, prior_normaliser = normalise_weights(log_weights)
            log_first = xp.where(underflow[:, None], log_prior, log_first)
            first = xp.where(underflow[:, None], prior, first)
            normaliser = xp.where(underflow, prior_normaliser, normaliser)
        if observed is not None:
            normaliser = xp.where(observed, normaliser, 0.0)
        return log_first, first, normaliser, look_ahead
