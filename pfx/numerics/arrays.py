"""Array namespaces: one model code for NumPy arrays and JAX arrays.

A model's ``propagate``, ``measurement_mean`` and ``log_likelihood`` are written once and run on
both of pfx's backends (:mod:`pfx.filters.particle.engine` and
:mod:`pfx.filters.particle.jax_engine`): on the ``numpy`` backend they are given NumPy arrays,
on the ``jax`` backend JAX arrays (traced inside a compiled scan). Both
libraries implement the Python array API standard, whose entry point is the array's own
``__array_namespace__()``: the module of functions that works on it. A generic function asks
its arguments for that module and calls its functions::

    xp = namespace(state)
    return xp.stack([state[..., 0] + dt * state[..., 1], state[..., 1]], axis=-1)

On NumPy arrays ``namespace`` returns ``numpy`` itself, so the NumPy backend computes exactly
what it computed before a model was made generic (no wrapper, no copy). Python numbers and
NumPy scalars count as NumPy, so a model may mix its constants into either.

JAX arrays cannot be written in place, so a generic model updates functionally:
:func:`with_values` is ``out = state.copy(); out[index] = values`` on NumPy and
``state.at[index].set(values)`` on JAX, the same numbers either way.

JAX is imported only when a JAX array is met: pfx runs without it.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any, Callable

import numpy as np


def namespace(*values: Any) -> ModuleType:
    """The array module for ``values``: ``jax.numpy`` if any of them is a JAX array (or a JAX
    tracer), else ``numpy``. Python numbers, None and NumPy arrays and scalars count as NumPy."""
    for value in values:
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


def with_values(array: Any, index: Any, values: Any) -> Any:
    """A copy of ``array`` with ``array[index] = values``: a NumPy copy written in place, or
    JAX's functional ``array.at[index].set(values)``; ``array`` itself is never changed."""
    if is_jax_array(array):
        return array.at[index].set(values)
    out = np.array(array, dtype=float)       # the NumPy backend computes in float64
    out[index] = values
    return out


def constant_like(constant: Any, array: Any) -> Any:
    """A law's NumPy constant (a scale, a factor, a mean) to combine with ``array``: the constant
    itself for a NumPy array (the same numbers as ever), a JAX array of ``array``'s dtype for a
    JAX one (a float64 NumPy constant would otherwise make a float32 computation float64)."""
    if not is_jax_array(array):
        return constant
    return namespace(array).asarray(constant, dtype=array.dtype)


def repeat(times: int, body: Callable[[Any], Any], carry: Any) -> Any:
    """``body`` applied ``times`` times to ``carry`` (a value or a tuple of values): a Python loop
    on NumPy, ``jax.lax.fori_loop`` on JAX. Traced, a Python loop would unroll into ``times``
    copies of ``body`` (64 RK4 substeps: a program XLA takes minutes to compile); the JAX loop
    compiles ``body`` once. The backend is the carry's (:func:`namespace`); on NumPy the numbers
    are those of the plain loop, operation for operation."""
    values = carry if isinstance(carry, tuple) else (carry,)
    if namespace(*values) is np:
        for _ in range(times):
            carry = body(carry)
        return carry
    import jax

    return jax.lax.fori_loop(0, times, lambda _, current: body(current), carry)
