"""Filter kinds: every way pfx estimates the state, on the same models, metrics and CSV.

A filter kind is a function registered under the name a config gives as ``filter.kind``::

    run(model, measurements, random, *, settings, prior, spread_criterion, consistency) -> FilterTrace

It may carry a plan-time check, ``run.check(model, settings, prior)``, raising
``ValueError("@key: reason")`` (key under ``filter``) or a ConfigError when the kind cannot run
on that model: configs are refused before anything runs.

``model`` is the model the filter assumes, ``measurements`` has shape (trials, T, m),
``random`` is a :class:`~pfx.numerics.seeding.TrialStreams` (one stream per trial), ``settings`` the
cell's :class:`~pfx.config.schema.FilterConfig`, ``prior`` the bound initial law.
To add a kind: write the function in a module of this package and register it below.
"""

from pfx.filters import (
    histogram,  # noqa: F401  (registers histogram)
    kalman,  # noqa: F401  (registers kf, ekf, ukf)
    particle,  # noqa: F401  (registers particle, sis)
)
from pfx.filters.registry import FILTERS

# kinds that carry particles (their cells have a particle count, resampler and weighting)
PARTICLE_KINDS = frozenset({"particle", "sis"})

__all__ = ["FILTERS", "PARTICLE_KINDS"]
