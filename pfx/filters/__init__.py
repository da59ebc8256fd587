"""Filter kinds: every way pfx estimates the state, on the same models, metrics and CSV.

A filter kind is a subclass of :class:`~pfx.filters.base.FilterKind` registered at its definition
(``@FILTERS.register_kind``) under the name a config gives as ``filter.kind``. It declares the
settings it reads, its own settings blocks and what it needs of a model; its ``plan`` runs once
per cell, before anything runs (checks, and what is fixed per cell, such as the histogram
filter's grid), and its ``run`` filters a batch of trials into a
:class:`~pfx.filters.trace.FilterTrace`. See :mod:`pfx.filters.base`.

Sub-packages by family: :mod:`~pfx.filters.particle` (the particle filter's engine and
components), :mod:`~pfx.filters.kalman` (kf, ekf, ukf), :mod:`~pfx.filters.histogram` (the grid
filter); :mod:`~pfx.filters.log_odds` is the binary Bayes filter of occupancy cells.
To add a kind: a module with its class, and one import line below.

May import :mod:`pfx.laws`, :mod:`pfx.numerics`, :mod:`pfx.safe_yaml`, :mod:`pfx.registry`,
:mod:`pfx.errors`; never models, config or anything above.
"""

from pfx.filters import (
    histogram,  # noqa: F401  (registers histogram)
    kalman,  # noqa: F401  (registers kf, ekf, ukf)
    particle,  # noqa: F401  (registers particle, sis)
)
from pfx.filters.base import FILTERS, FilterKind, run_filter

__all__ = ["FILTERS", "FilterKind", "run_filter"]
