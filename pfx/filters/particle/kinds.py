"""The particle filter kinds: ``particle`` (SIR with the ESS rule) and ``sis`` (never resample).

Both run :class:`pfx.filters.particle.engine.ParticleFilter`; ``sis`` forces the ESS threshold to 0.
"""

from __future__ import annotations

from pfx.filters.base import FILTERS, FilterKind
from pfx.filters.particle.engine import run_particle_filter
from pfx.filters.particle.moves import check_move
from pfx.filters.particle.proposals import check_particle_settings
from pfx.filters.particle.resampling import RESAMPLERS


@FILTERS.register_kind
class SampleImportanceResampling(FilterKind):
    """Particle filter: resample when ESS < ess_threshold * N."""

    kind = "particle"
    reads = frozenset({"particles", "resampler", "ess_threshold", "weighting", "diffusion", "move", "adaptive",
                       "injection", "proposal", "auxiliary"})
    carries_particles = True
    takes_trace_rows = True

    @classmethod
    def plan(cls, model, settings, prior):
        check_move(cls.kind, settings.move, model, settings)     # filter.move (pfx.filters.particle.moves)
        if settings.adaptive is not None:
            settings.adaptive.check(model.state_dimension, settings.particles)
        check_particle_settings(cls.kind, model, settings)       # proposal and auxiliary (proposals.py)
        return super().plan(model, settings, prior)

    @classmethod
    def ess_threshold(cls, settings) -> float:
        """Resample when ESS < threshold * N."""
        return settings.ess_threshold

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None, trace_rows=None):
        return run_particle_filter(
            model, measurements, random, prior=prior, particles=settings.particles,
            resampler=RESAMPLERS[settings.resampler], ess_threshold=self.ess_threshold(settings),
            weighting=settings.weighting, diffusion=settings.diffusion, spread_criterion=spread_criterion,
            consistency=consistency, snapshot=snapshot, trace_rows=trace_rows, move=settings.move,
            adaptive=getattr(settings, "adaptive", None), injection=getattr(settings, "injection", None),
            proposal=settings.proposal if settings.proposal.guided else None, auxiliary=settings.auxiliary)


@FILTERS.register_kind
class SequentialImportanceSampling(SampleImportanceResampling):
    """Sequential importance sampling: a particle filter that never resamples."""

    kind = "sis"
    reads = frozenset({"particles", "weighting", "proposal", "auxiliary"})

    @classmethod
    def ess_threshold(cls, settings) -> float:
        return 0.0
