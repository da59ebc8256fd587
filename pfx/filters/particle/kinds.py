"""The particle filter kinds: ``particle`` (SIR with the ESS rule) and ``sis`` (never resample).

Both run :func:`pfx.filters.particle.engine.run_particle_filter`; ``sis`` forces the ESS threshold to 0.
"""

from __future__ import annotations

from pfx.filters.particle.engine import run_particle_filter
from pfx.filters.particle.resampling import RESAMPLERS
from pfx.filters.registry import FILTERS


def _run(model, measurements, random, *, settings, prior, spread_criterion, consistency=False, snapshot=None):
    return run_particle_filter(
        model, measurements, random, prior=prior, particles=settings.particles,
        resampler=RESAMPLERS[settings.resampler], ess_threshold=settings.effective_threshold(),
        weighting=settings.weighting, diffusion=settings.diffusion, spread_criterion=spread_criterion,
        consistency=consistency, snapshot=snapshot)


@FILTERS.register("particle")
def particle(model, measurements, random, *, settings, prior, spread_criterion, consistency=False,
             snapshot=None):
    """Particle filter: resample when ESS < ess_threshold * N."""
    return _run(model, measurements, random, settings=settings, prior=prior,
                spread_criterion=spread_criterion, consistency=consistency, snapshot=snapshot)


@FILTERS.register("sis")
def sequential_importance_sampling(model, measurements, random, *, settings, prior, spread_criterion,
                                   consistency=False, snapshot=None):
    """Sequential importance sampling: a particle filter that never resamples."""
    return _run(model, measurements, random, settings=settings, prior=prior,
                spread_criterion=spread_criterion, consistency=consistency, snapshot=snapshot)
