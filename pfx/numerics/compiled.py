"""Compiled loops: numba, imported on first use, compiled once and cached on disk.

A few steps of the engine are loops that NumPy cannot express without extra passes over the
particles or a Python loop per trial: the merged walk of the inverse CDF
(:func:`pfx.filters.particle.resampling.inverse_cdf`), the gather of resampled particles
(:func:`pfx.filters.particle.cloud.resample_rows`), each trial's PCG64 generator stepped in place
(:mod:`pfx.numerics.pcg64`) and the ziggurat that turns its 64-bit words into normal draws
(:mod:`pfx.numerics.ziggurat`). Each is an ordinary Python function decorated with
:func:`compiled` (or :func:`compiled_now`); it stays next to the mathematics it implements.

Why numba, and what it costs (measured by ``pfx bench``, see docs/performance.md):
at N = 1e5 those three steps took about half of a particle-step before (binary search
~20 ns, NumPy's fancy-index gather ~20 ns, NumPy's normal generator ~30 ns of ~140 ns);
compiled, they take ~6, ~2 and ~12 ns. Compiling them costs a few seconds once per machine;
numba then caches the machine code in ``__pycache__`` (or its user-wide cache directory
when the package folder is read-only; ``NUMBA_CACHE_DIR`` chooses another), and a later
process loads it in a fraction of a second.

``import numba`` alone takes about half a second, so it happens on the first call of a
compiled function, not when pfx is imported: ``pfx validate`` and ``pfx list`` never pay it.
A function compiled lazily may not call another one (numba sees only the lazy wrapper); each is
self-contained. Compiled functions that call one another (the ziggurat calls the PCG64 step)
live in modules that import numba themselves and are imported on first use
(:func:`compiled_now`).
"""

from __future__ import annotations

import functools
from typing import Callable


def compiled(function: Callable) -> Callable:
    """``numba.njit(cache=True)`` of ``function``, applied at its first call."""
    dispatcher = None

    @functools.wraps(function)
    def call(*args):
        nonlocal dispatcher
        if dispatcher is None:
            dispatcher = _jit(function)
        return dispatcher(*args)

    call.dispatcher = lambda: _jit(function) if dispatcher is None else dispatcher
    return call


def compiled_now(function: Callable) -> Callable:
    """``numba.njit(cache=True)`` of ``function`` at once: for a module that imports numba itself
    and is imported only when first needed (:mod:`pfx.numerics.pcg64`), whose compiled functions
    call one another (which the lazy wrappers of :func:`compiled` cannot)."""
    return _jit(function)


@functools.lru_cache(maxsize=None)
def _jit(function: Callable):
    import numba

    # nogil: a compiled loop releases the GIL, so threads (a Dask worker's, say) can overlap.
    return numba.njit(cache=True, nogil=True)(function)


# -- numba's cache for code that runs under a module name of pfx's (plugin files) -------------------

@functools.lru_cache(maxsize=None)
def keep_cache_apart(module_prefix: str) -> None:
    """Cache the compiled functions of modules named ``<module_prefix>...`` apart from those of
    the same source file under any other module name.

    numba finds a function's cache entry by its source file, name and line; the entry's code
    names the module the function was compiled in, and loading it imports that module by name.
    pfx runs a plugin file as the module ``pfx_plugin_<stem>_<hash>`` (pfx/config/plugins.py),
    and ``import stem`` makes the same file the module ``stem``: each process found the other's
    entry and failed to import its module (``ModuleNotFoundError: pfx_plugin_...``, or the
    plugin imported a second time under its own name). Here the entries of such modules carry
    the module's name in their file names (``walk.step-12-pfx_plugin_walk_0123456789ab.py311.nbi``),
    in numba's usual folders (``NUMBA_CACHE_DIR``, ``__pycache__`` beside the file, the user's
    cache): every version of a plugin file has its own entries, and a file imported by hand keeps
    numba's usual ones. Called before such a module runs (numba picks a function's cache folder
    when ``@njit(cache=True)`` decorates it); once per process.
    """
    from numba.core import caching

    def apart(locator):
        class ModuleApart(locator):
            """numba's ``locator``, for the functions of the prefixed modules only, their module's
            name added to the entries' names."""

            def __init__(self, py_func, py_file):
                super().__init__(py_func, py_file)
                self._module = py_func.__module__

            def get_disambiguator(self):
                return f"{super().get_disambiguator()}-{self._module}"

            @classmethod
            def from_function(cls, py_func, py_file):
                if not str(getattr(py_func, "__module__", "")).startswith(module_prefix):
                    return None
                return super().from_function(py_func, py_file)

        ModuleApart.__name__ = ModuleApart.__qualname__ = f"ModuleApart{locator.__name__}"
        return ModuleApart

    # numba tries its locators in order and keeps the first that applies; these come first and
    # apply only to the prefixed modules, each in the folder numba's own locator would choose.
    caching.CacheImpl._locator_classes[:0] = [apart(locator) for locator in (
        caching.UserProvidedCacheLocator, caching.InTreeCacheLocator, caching.UserWideCacheLocator)]
