"""Compile, or load from numba's cache, every compiled loop of the engine before timing it.

It lives with the benchmark, its one caller: the compiled loops themselves
(:mod:`pfx.numerics.compiled`) know nothing of the modules that use them.
"""

from __future__ import annotations

import time

import numpy as np

from pfx.filters.particle import cloud, resampling
from pfx.numerics import pcg64, ziggurat
from pfx.numerics.seeding import TrialStreams


def warm_up() -> dict:
    """Compile (or load from the cache) every compiled loop of the engine; report how.

    Returns ``{"seconds": time taken, "compiled": count, "loaded": count}``, for the benchmark
    to show what numba costs on first use.
    """
    started = time.perf_counter()
    streams = TrialStreams.from_seeds([0, 1])
    weights = np.full((2, 4), 0.25)
    indices = resampling.systematic(weights, streams)
    # Particle arrays come both row-major and component by component (Noise.sample's layout).
    for state in (np.zeros((2, 4, 3)), np.moveaxis(streams.standard_normal((3, 4)), 1, -1)):
        cloud.resample_rows(state, np.arange(2), indices)
    seconds = time.perf_counter() - started
    counts = {"compiled": 0, "loaded": 0}
    lazy = [function.dispatcher() for function in (resampling.inverse_cdf_walk, cloud.gather_particles)]
    for dispatcher in lazy + [ziggurat.normals, pcg64.uniforms]:
        stats = dispatcher.stats
        counts["loaded"] += sum(stats.cache_hits.values())
        counts["compiled"] += sum(stats.cache_misses.values())
    return {"seconds": seconds, **counts}
