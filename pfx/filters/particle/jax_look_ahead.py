r"""The auxiliary particle filter's first stage on the JAX backend (``filter.auxiliary: true``).

The mathematics is :mod:`pfx.filters.particle.auxiliary`'s, and so is its code: the first-stage
weights :math:`\lambda`, the increment :math:`L^{(1)}_k` and the look-ahead :math:`g` with its
edge cases (a missing measurement or first-stage weights that all underflow: :math:`g = 0`; a
point prediction outside the model's domain: :math:`g = -\infty`) come from
:meth:`~pfx.filters.particle.auxiliary.AuxiliaryFirstStage.first_stage`, written once for both
backends. What this module adds is what the NumPy engine's ``look_ahead`` does around it, as
masks in the compiled step (:mod:`pfx.filters.particle.jax_engine`):

* the look-ahead of each particle of step k-1, :math:`g_i = \log p(z_k \mid \bar f_k(x_{k-1,i}))`
  from the noise-free prediction made with the compiled step's control and substep times (the
  NumPy model's ``look_ahead_log_weight`` reads them on the host by the step number); a model
  that overrides ``look_ahead_log_weight`` is called with the step as a traced integer;
* the ESS rule on :math:`\lambda`: every trial draws its ancestors by :math:`\lambda` with the
  configured resampler, and a select keeps the trials the rule did not pick, with :math:`\lambda`
  as their weights; the picked trials go through the post-resampling stage
  (:mod:`pfx.filters.particle.jax_after_resampling`: the diffusion, since the auxiliary filter
  combines with no move and no injection) and restart from uniform weights;
* the second stage's adjustment :math:`-g_{a_i}`, gathered by the ancestors where a trial
  resampled, and the genealogy's ancestors and ``resampled`` flags of step k, as the NumPy
  engine records them (identity and False for a trial the rule did not pick).

The engine's step then predicts (or proposes) from the first stage's cloud, weighs with the
adjustment, adds :math:`L^{(1)}_k` to the step's increment and does not resample at the end of
the step: the next first stage does.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp


class FirstStage(NamedTuple):
    """What the first stage of step k hands the rest of the step."""

    increment: Any            # (R,) L1_k, float64; 0 where the measurement is missing
    adjustment: Any           # (R, N) -g_{a_i}, the second stage's weight adjustment
    resampled: Any            # (R,) bool: the trials the ESS rule picked
    ancestors: Any            # (R, N) the resampled trials' ancestors; i -> i for the others


class JaxLookAhead:
    """The first stage of an engine (a :class:`~pfx.filters.particle.jax_engine.JaxParticleFilter`
    whose bound filter has ``auxiliary``); ``own_look_ahead``: whether the model overrides
    ``look_ahead_log_weight``."""

    def __init__(self, engine, own_look_ahead: bool):
        self.engine, self.model, self.dtype = engine, engine.model, engine.dtype
        self.auxiliary = engine.bound.auxiliary
        self.own_look_ahead = own_look_ahead

    def check_model(self) -> None:
        """Trace the model's own ``look_ahead_log_weight`` once on a tiny batch (nothing
        computed), with a traced step: one written for the host is refused at plan time."""
        if not self.own_look_ahead:
            return          # the default is log_likelihood at the prediction: the engine's probe traces both
        model = self.model
        with jax.enable_x64(True):
            state = jax.ShapeDtypeStruct((2, 3, model.state_dimension), self.dtype)
            step = jax.ShapeDtypeStruct((), jnp.int32)
            measurement = jax.ShapeDtypeStruct((2, 1, model.measurement_dimension), self.dtype)
            try:
                jax.eval_shape(model.look_ahead_log_weight, state, step, measurement)
            except Exception as error:      # any failure to trace: the method is NumPy-only
                reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
                raise ValueError(
                    f"@auxiliary: model {model.kind}'s look_ahead_log_weight does not run on the jax backend "
                    f"({reason[:160]}); write it against the array namespace with the step as an array, "
                    "or set backend: numpy") from None

    def look_ahead(self, previous, inputs):
        """g (R, N) of the particles ``previous`` of step k-1, as the model evaluates it (NaN
        where a prediction left its domain); a missing measurement's stand-in is 0."""
        measurement = inputs.measurement.astype(self.dtype)[:, None, :]
        if self.own_look_ahead:
            return jnp.asarray(self.model.look_ahead_log_weight(previous, inputs.step, measurement))
        predicted = self.engine.after_resampling.parent_means(previous, inputs)
        return jnp.asarray(self.model.log_likelihood(measurement, predicted))

    def apply(self, cloud, inputs, random):
        """Step k's first stage on the ``cloud`` of step k-1: (the cloud to predict from, its
        ``after`` updated, and the :class:`FirstStage`)."""
        engine, previous = self.engine, cloud.particles
        trials, count = cloud.log_weights.shape
        log_first, first, increment, look_ahead = self.auxiliary.first_stage(
            cloud.log_weights, self.look_ahead(previous, inputs), inputs.observed)
        log_first = log_first.astype(cloud.log_weights.dtype)
        identity = jnp.broadcast_to(jnp.arange(count, dtype=jnp.int32), (trials, count))
        resampled = engine.picks(1.0 / jnp.sum(first * first, axis=-1))
        if resampled is None:            # a threshold of 0: no trial ever resamples
            return cloud._replace(log_weights=log_first), FirstStage(
                increment=increment.astype(jnp.float64), adjustment=-look_ahead.astype(self.dtype),
                resampled=jnp.zeros(trials, bool), ancestors=identity)
        # the engine's resampling stage on the first-stage weights (no move, count or injection
        # combines with the auxiliary filter, so the ancestors are the draws, i -> i where not picked)
        state, log_weights, _, ancestors, _, after, _ = engine.resample(
            previous, log_first, first, None, random, None, cloud.after, inputs, resampled=resampled)
        look_ahead = jnp.take_along_axis(look_ahead, ancestors, axis=1)
        return cloud._replace(particles=state, log_weights=log_weights, after=after), FirstStage(
            increment=increment.astype(jnp.float64), adjustment=-look_ahead.astype(self.dtype),
            resampled=resampled, ancestors=ancestors)
