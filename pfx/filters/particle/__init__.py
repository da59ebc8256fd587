"""The particle filter: its engine (many trials advanced at once), and the components a config
swaps in and out: resamplers, weightings (the weight update) and diffusions (moves after
resampling). :mod:`pfx.filters.particle.kinds` registers the filter kinds that run it,
``particle`` and ``sis``.

May import :mod:`pfx.filters.trace`, :mod:`pfx.laws`, :mod:`pfx.numerics`; nothing above.
"""

from pfx.filters.particle import kinds  # noqa: F401  (registers particle, sis)
