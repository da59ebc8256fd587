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

import numbers
from typing import Any, Callable

import numpy as np

from pfx.numerics.array_namespace import is_jax_array, namespace, special_functions  # noqa: F401 (re-exported)
from pfx.numerics.key_streams import loop_pass
from pfx.numerics.parameter_checks import active_checks, collecting


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
    are those of the plain loop, operation for operation.

    ``times`` is a non-negative integer (a JAX integer with no axes may be traced: it is then
    not checked) and ``body`` a function of the carry: anything else is a ValueError naming it.
    Inside a compiled step, the laws' checks in ``body`` are carried out of the loop
    (:mod:`pfx.numerics.parameter_checks`), and a draw in ``body`` takes new keys at every pass
    (:func:`pfx.numerics.key_streams.loop_pass`), as it takes new numbers on NumPy."""
    _check_times(times)
    if not callable(body):
        raise ValueError(f"repeat: body must be a function of the carry, got {type(body).__name__}")
    values = carry if isinstance(carry, tuple) else (carry,)
    if namespace(*values) is np:
        for _ in range(times):
            carry = body(carry)
        return carry
    import jax

    def one_pass(index, current):           # traced once: the pass's draws fold in its index
        with loop_pass(index):
            return body(current)

    outer = active_checks()
    if outer is None:
        return jax.lax.fori_loop(0, times, one_pass, carry)

    def checked(index, state):              # a loop's body is traced apart: a block of its own
        current, codes = state
        with collecting(outer.trials) as checks:
            current = one_pass(index, current)
        return current, jax.numpy.where(codes != 0, codes, checks.codes)

    carry, codes = jax.lax.fori_loop(0, times, checked, (carry, jax.numpy.zeros(outer.trials, jax.numpy.int32)))
    outer.merge(codes)
    return carry


def _check_times(times: Any) -> None:
    """``repeat``'s count: a Python or NumPy integer >= 0, or a JAX integer with no axes (its sign
    checked when it has a value)."""
    if is_jax_array(times) and times.ndim == 0 and np.issubdtype(times.dtype, np.integer):
        import jax

        if isinstance(times, jax.core.Tracer) or int(times) >= 0:
            return
    elif isinstance(times, numbers.Integral) and not isinstance(times, bool) and times >= 0:
        return
    raise ValueError(f"repeat: times must be a non-negative integer, got {times!r}")
