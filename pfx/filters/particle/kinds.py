"""The particle filter kinds: ``particle`` (SIR with the ESS rule) and ``sis`` (never resample).

Both bind their settings once, at plan time (:func:`pfx.filters.particle.bound.bind_particle_filter`;
``sis`` with the ESS threshold 0), and run the engine on each batch with the diagnostics the
batch asks for.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from pfx.filters.base import FILTERS, FilterKind
from pfx.filters.particle.bound import BoundParticleFilter, Recording, bind_particle_filter


@FILTERS.register_kind
class SampleImportanceResampling(FilterKind):
    """Particle filter: resample when ESS < ess_threshold * N."""

    kind = "particle"
    reads = frozenset({"particles", "resampler", "ess_threshold", "weighting", "diffusion", "move", "adaptive",
                       "injection", "proposal", "auxiliary", "smoothers", "backend", "precision"})
    carries_particles = True
    takes_trace_rows = True
    computes_scores = True

    def __init__(self, bound: BoundParticleFilter):
        self.bound = bound

    @classmethod
    def plan(cls, model, settings, prior):
        cls.check_model_needs(model)
        return cls(bind_particle_filter(cls.kind, model, settings, prior))

    @classmethod
    def ess_threshold(cls, settings) -> float:
        """Resample when ESS < threshold * N."""
        return settings.ess_threshold

    def run(self, model, measurements, random, *, settings=None, prior=None, spread_criterion=None,
            consistency=False, snapshot=None, trace_rows: Optional[np.ndarray] = None, genealogy: bool = False,
            history: bool = False, scores: bool = False, forecast=None):
        """Run the bound filter (its model, settings and prior are the plan's; ``model``,
        ``settings`` and ``prior``, the generic interface's, are the same objects)."""
        return self.bound.run(measurements, random, Recording(
            spread_criterion=spread_criterion, consistency=consistency, snapshot=snapshot, trace_rows=trace_rows,
            genealogy=genealogy, history=history, scores=scores, forecast=forecast))


@FILTERS.register_kind
class SequentialImportanceSampling(SampleImportanceResampling):
    """Sequential importance sampling: a particle filter that never resamples."""

    kind = "sis"
    reads = frozenset({"particles", "weighting", "proposal", "auxiliary", "smoothers", "backend", "precision"})

    @classmethod
    def ess_threshold(cls, settings) -> float:
        return 0.0
