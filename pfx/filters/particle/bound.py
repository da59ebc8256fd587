r"""A particle filter bound once: every setting resolved, checked and factorised before any run.

:func:`bind_particle_filter` turns a cell's ``filter:`` settings, its model and its prior into a
:class:`BoundParticleFilter`, an immutable object that knows everything the engine needs:

===============  ===========================================================================
field            what it is (the ``filter:`` key it comes from)
===============  ===========================================================================
``resampling``   the resampler and the ESS rule (``resampler``, ``ess_threshold``; 0 for ``sis``):
                 :class:`~pfx.filters.particle.resampling.Resampling`
``weighting``    the weight update (``weighting``); ``weighting.is_likelihood`` says whether it
                 is the model's likelihood
``proposal``     a guided proposal bound to the model, its constants (Q, its Cholesky factor)
                 computed here, once (``proposal``); None: the transition (the bootstrap filter)
``auxiliary``    the auxiliary filter's first stage (``auxiliary``), or None
``move``         the move after resampling, bound to the model (``move``), or None
``diffusion``    the post-resampling noise (``diffusion``)
``adaptive``     the adaptive particle count (``adaptive``), or None: N fixed
``injection``    particle injection (``injection``), or None
===============  ===========================================================================

Config names and code names are the same. Every refusal (a guided proposal without a
transition density, a move on ``sis``, ...) is raised here, at plan time, as
``ValueError("@key: reason")`` (the key under ``filter``); nothing is checked again per batch or
per step. Calling the bound filter runs the engine on a batch of trials
(:class:`~pfx.filters.particle.engine.ParticleFilter`); a :class:`Recording` says which
diagnostics to record (they cost nothing unless asked for).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Optional

import numpy as np

from pfx.filters.particle.auxiliary import AuxiliaryFirstStage
from pfx.filters.particle.engine import ParticleFilter
from pfx.filters.particle.forecasting import forecast_samples, forecast_table
from pfx.filters.particle.jax_support import check_jax_settings
from pfx.filters.particle.recorders import Recording
from pfx.filters.particle.resampling import RESAMPLERS, Resampling
from pfx.filters.particle.smoothing import FilterHistory
from pfx.filters.smoothers import check_smoothers
from pfx.filters.trace import FilterTrace


@dataclass(frozen=True)
class BoundParticleFilter:
    """The particle filter of one cell, bound once (module docstring)."""

    kind: str                           # "particle" or "sis"
    model: Any                          # the model the filter assumes
    prior: Any                          # the bound initial law particles start from
    particles: int                      # N (with ``adaptive``: the maximum)
    resampling: Resampling
    weighting: Any
    diffusion: Any
    proposal: Any = None                # a bound guided proposal; None: the transition
    auxiliary: Optional[AuxiliaryFirstStage] = None
    move: Any = None                    # a bound move after resampling; None: no move
    adaptive: Any = None                # KLD-sampling settings; None: N fixed
    injection: Any = None               # augmented MCL settings; None: no injection
    smoothers: tuple = ()               # run after the filter on its recorded clouds (pfx.filters.smoothers)
    backend: str = "numpy"              # where it runs: numpy (engine.py) or jax (jax_engine.py)
    precision: str = "float64"          # the jax backend's floating point
    count_draws: str = "exact"          # binomial, Poisson, gamma: exact samplers or inverse CDFs (seeding.COUNT_DRAWS)
    compiled: Any = field(default=None, compare=False, repr=False)    # the jax backend's program

    @property
    def uses_compiled_step(self) -> bool:
        """Whether the model's compiled step (transition and likelihood in one pass) computes
        exactly this filter's proposal and weights: the bootstrap filter with the likelihood, on a
        model whose transition is one ``propagate`` call (no substeps between measurements, no
        accumulating components to reset), which is what a compiled step fuses."""
        model = self.model
        one_call = model.propagations_per_step == 1 and not tuple(model.accumulating_components)
        return self.proposal is None and self.auxiliary is None and self.weighting.is_likelihood and one_call

    def run(self, measurements: np.ndarray, random, recording: Recording = Recording()) -> FilterTrace:
        """Filter measurements (trials, T, m), one random stream per trial
        (:class:`~pfx.numerics.seeding.TrialStreams`); see :mod:`pfx.filters.particle.engine`."""
        if self.count_draws != getattr(random, "count_draws", "exact"):     # every draw of the filter's run, its smoothers' too
            random = random.with_count_draws(self.count_draws)
        if self.smoothers:          # what they run on is recorded too
            recording = replace(recording, history=recording.history or any(s.needs_history for s in self.smoothers),
                                genealogy=recording.genealogy or any(s.needs_genealogy for s in self.smoothers))
        if self.compiled is not None:
            trace = self.compiled.run(measurements, random, recording)
        else:
            trace = ParticleFilter(self, measurements, random, recording).run()
        if self.smoothers:
            history = FilterHistory(trace.particles, trace.log_weights, trace.ancestors)
            for smoother in self.smoothers:     # after the filter's draws, from the same streams
                trace.smoothed[smoother.label] = smoother.smooth(history, self.model, random)
        if recording.forecast is not None:      # from the kept clouds, on the forecast streams
            trace.forecast_samples = forecast_samples(self.model, recording.forecast, trace.forecast_clouds,
                                                      measurements, random)
            trace.forecasts = forecast_table(self.model, recording.forecast, trace.forecast_samples)
        return trace


def bind_particle_filter(kind: str, model, settings, prior) -> BoundParticleFilter:
    """Resolve and check a particle kind's settings for ``model`` (ValueError('@key: reason'))."""
    weighting, move, proposal = settings.weighting, settings.move, settings.proposal
    adaptive, injection = getattr(settings, "adaptive", None), getattr(settings, "injection", None)
    never_resamples = kind == "sis"
    bound_move = None
    if move.kind != "none":
        if never_resamples:
            raise ValueError(f"@move: sis never resamples, so there are no resampled particles to move "
                             f"({move.kind}); use kind: particle")
        if settings.diffusion.kind != "none":
            raise ValueError(f"@move: a move ({move.kind}) and a diffusion ({settings.diffusion.kind}) would both "
                             "rejuvenate the resampled particles; set diffusion: none (or move: none)")
        bound_move = move.bind(model, settings)
    if adaptive is not None:
        adaptive.check(model.state_dimension, settings.particles)
    bound_proposal = None
    if proposal.guided:
        if not weighting.is_likelihood:
            raise ValueError(f"@proposal: a guided proposal's importance weight needs the model's likelihood "
                             f"p(z | x); weighting {weighting.label()} is not one (use weighting: gaussian)")
        bound_proposal = proposal.bind(model)
    if settings.auxiliary:
        _check_auxiliary(kind, settings)
    check_smoothers(kind, model, settings)
    backend = getattr(settings, "backend", "numpy")
    if backend == "jax":
        check_jax_settings(settings)
    bound = BoundParticleFilter(
        kind=kind, model=model, prior=prior, particles=settings.particles,
        resampling=Resampling(RESAMPLERS[settings.resampler], 0.0 if never_resamples else settings.ess_threshold),
        weighting=weighting, diffusion=settings.diffusion, proposal=bound_proposal,
        auxiliary=AuxiliaryFirstStage() if settings.auxiliary else None, move=bound_move,
        adaptive=adaptive, injection=injection, smoothers=tuple(getattr(settings, "smoothers", ()) or ()),
        backend=backend, precision=getattr(settings, "precision", "float64"),
        count_draws=getattr(settings, "count_draws", "exact"))
    if backend == "jax":
        from pfx.filters.particle.jax_engine import JaxParticleFilter

        bound = replace(bound, compiled=JaxParticleFilter(bound))
        bound.compiled.check_model()
    return bound


def _check_auxiliary(kind: str, settings) -> None:
    if kind == "sis":
        raise ValueError("@auxiliary: the auxiliary particle filter resamples in its first stage and sis never "
                         "resamples; use kind: particle")
    if not settings.weighting.is_likelihood:
        raise ValueError(f"@auxiliary: the auxiliary particle filter weighs by the model's likelihood "
                         f"p(z | x); weighting {settings.weighting.label()} is not one (use weighting: gaussian)")
    # Its resampling is its first stage, before the proposal: a move, an adaptive count or an
    # injection (stages of the end-of-step resampling) would act on x_{k-1} with step k's
    # measurement, which none of them is defined for.
    for key in ("move", "adaptive", "injection"):
        value = getattr(settings, key, None)
        if value is not None and getattr(value, "kind", "none") != "none":
            raise ValueError(f"@auxiliary: the auxiliary particle filter does not combine with filter.{key} "
                             f"({value.kind}): its resampling is its first stage; use one or the other")
