"""Which array module a value belongs to: ``numpy``, or ``jax.numpy`` for a JAX array (or tracer).

The rule of :mod:`pfx.numerics.arrays` (whose docstring teaches the array namespace), in a module
that imports nothing of pfx's, so that the lowest layers (the random streams' samplers,
:mod:`pfx.numerics.count_quantiles`) can use it without an import cycle. JAX is imported only
when a JAX array is met: pfx runs without it.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np


def namespace(*values: Any) -> ModuleType:
    """The array module for ``values``: ``jax.numpy`` if any of them is a JAX array (or a JAX
    tracer), else ``numpy``. Python numbers, None and NumPy arrays and scalars count as NumPy."""
    for value in values:
        if type(value) is np.ndarray:     # the NumPy backend's every call: the cheap test first
            continue
        if is_jax_array(value):
            return value.__array_namespace__()
    return np


def is_jax_array(value: Any) -> bool:
    """Whether ``value`` is a JAX array or tracer (without importing JAX for anything else)."""
    return type(value).__module__.startswith("jax") and hasattr(value, "__array_namespace__")


def special_functions(xp: ModuleType) -> ModuleType:
    """``scipy.special`` for NumPy, ``jax.scipy.special`` for JAX (gammaln, log_ndtr, ndtr, ...)."""
    if xp is np:
        import scipy.special

        return scipy.special
    import jax.scipy.special

    return jax.scipy.special
