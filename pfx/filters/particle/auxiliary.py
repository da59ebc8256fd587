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

import numpy as np


def first_stage(run, step: int) -> np.ndarray:
    """Resample ``run``'s ancestors by the first-stage weights (module docstring); add
    :math:`L^{(1)}_k` to the log-likelihood; return :math:`g_{a_i}` per particle, (R, N)."""
    model, t = run.model, step - 1
    observed = None if run.missing is None else ~run.missing[:, t]
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        predicted = model.propagate(run.state, model.control(step),
                                    np.zeros(run.state.shape[:-1] + (model.process_noise_dimension,)))
        measurement = run.measurements[:, t, None, :]
        if observed is not None:
            measurement = np.where(observed[:, None, None], measurement, 0.0)
        look_ahead = model.log_likelihood(measurement, predicted)
    look_ahead = np.where(np.isnan(look_ahead), -np.inf, look_ahead)
    if observed is not None:
        look_ahead[~observed] = 0.0
    log_first, first, normaliser = run.normalise(run.log_weights + look_ahead)
    underflow = ~np.isfinite(normaliser)
    if underflow.any():
        look_ahead[underflow] = 0.0
        log_first[underflow], first[underflow], normaliser[underflow] = run.normalise(run.log_weights[underflow])
    if observed is not None:
        normaliser = np.where(observed, normaliser, 0.0)
    run.trace.log_likelihood += normaliser
    run.log_weights, run.weights = log_first, first
    rows = run.rows_to_resample(1.0 / np.einsum("rn,rn->r", first, first))
    if rows.size:
        indices, selected = run.resample(rows, step)
        look_ahead[selected] = np.take_along_axis(look_ahead[selected], indices, axis=-1)
    return look_ahead
