r"""NumPy's normal generator, compiled: ``Generator.standard_normal`` of many trials in one call.

Every trial owns a NumPy generator (:mod:`pfx.numerics.seeding`). Filling trial after trial with
``generator.standard_normal`` costs, on the machines pfx is benchmarked on, about 10 ns a
draw, four times the cost of the 64-bit word underneath it (about 2.2 ns for PCG64), and a
Python call per trial; the falling-body filter needs three draws per particle and step.
Here one compiled loop steps every trial's own PCG64 generator in place
(:mod:`pfx.numerics.pcg64`) and turns its words into normal draws as it goes: about 2 ns a
draw on top of the word, and no Python per trial.

The loop is NumPy's own algorithm (``random_standard_normal`` in NumPy's
``distributions.c``): the ziggurat method of Marsaglia & Tsang (2000) with 256 strips, on
NumPy's tables (:mod:`pfx.numerics.ziggurat_tables`). A 64-bit word gives the strip (bits 0-7),
the sign (bit 8) and a 52-bit uniform; the point is accepted at once when it lies in the
strip's rectangle (99 % of the draws), else the tail beyond :math:`r = 3.6541528853610088` is sampled by Marsaglia's
method or the wedge is tested against :math:`e^{-x^2/2}`, with further words as uniforms
:math:`(w \gg 11) \cdot 2^{-53}`, which is how PCG64 makes a double.

So the draws are exactly NumPy's, word for word, and each generator is left where
``standard_normal`` would have left it. Generators other than PCG64 (or a NumPy whose PCG64
is laid out otherwise, :func:`pfx.numerics.pcg64.layout_matches`) are served by
``generator.standard_normal`` itself.

This module imports numba; :mod:`pfx.numerics.seeding` imports it on the first draw only.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from pfx.numerics.compiled import compiled_now
from pfx.numerics.pcg64 import state_of, step
from pfx.numerics.ziggurat_tables import DENSITIES as _FI
from pfx.numerics.ziggurat_tables import STRIP_BOUNDS as _KI
from pfx.numerics.ziggurat_tables import STRIP_WIDTHS as _WI
from pfx.numerics.ziggurat_tables import TAIL_START as _R
from pfx.numerics.ziggurat_tables import TAIL_START_INVERSE as _INVERSE_R

_STRIP = np.uint64(0xFF)
_EIGHT = np.uint64(8)
_ONE = np.uint64(1)
_MANTISSA = np.uint64(0x000FFFFFFFFFFFFF)
_DOUBLE_SHIFT = np.uint64(11)
_DOUBLE_SCALE = 1.0 / 9007199254740992.0          # 2^-53: PCG64's next_double


@compiled_now
def normals(addresses, out):
    """out[row, :] = NumPy's standard normal draws from the PCG64 generator at ``addresses[row]``.

    (The tables are module constants, frozen into the compiled code.)
    """
    ki, wi, fi, r, inverse_r = _KI, _WI, _FI, _R, _INVERSE_R
    for row in range(out.shape[0]):
        state = state_of(addresses[row])
        low, high, increment_low, increment_high = state[0], state[1], state[2], state[3]
        for j in range(out.shape[1]):
            value = 0.0
            while True:
                low, high, bits = step(low, high, increment_low, increment_high)
                strip = np.intp(bits & _STRIP)
                bits = bits >> _EIGHT
                negative = (bits & _ONE) != 0
                magnitude = (bits >> _ONE) & _MANTISSA
                x = np.float64(np.int64(magnitude)) * wi[strip]     # < 2^52: the signed conversion is exact
                if negative:
                    x = -x
                if magnitude < ki[strip]:
                    value = x
                    break
                if strip == 0:                   # the tail beyond r
                    while True:
                        low, high, word = step(low, high, increment_low, increment_high)
                        u1 = np.float64(np.int64(word >> _DOUBLE_SHIFT)) * _DOUBLE_SCALE
                        low, high, word = step(low, high, increment_low, increment_high)
                        u2 = np.float64(np.int64(word >> _DOUBLE_SHIFT)) * _DOUBLE_SCALE
                        xx = -inverse_r * np.log1p(-u1)
                        yy = -np.log1p(-u2)
                        if yy + yy > xx * xx:
                            value = -(r + xx) if ((magnitude >> _EIGHT) & _ONE) != 0 else r + xx
                            break
                    break
                low, high, word = step(low, high, increment_low, increment_high)
                u = np.float64(np.int64(word >> _DOUBLE_SHIFT)) * _DOUBLE_SCALE
                if (fi[strip - 1] - fi[strip]) * u + fi[strip] < np.exp(-0.5 * x * x):   # the wedge
                    value = x
                    break
            out[row, j] = value
        state[0], state[1] = low, high


def standard_normal_rows(generators: Sequence[np.random.Generator], addresses: Optional[np.ndarray],
                         count: int) -> np.ndarray:
    """``generator.standard_normal(count)`` for every generator: shape (len(generators), count).

    ``addresses``: the generators' PCG64 states (:func:`pfx.numerics.pcg64.state_addresses`),
    or None (NumPy's own loop, trial by trial).
    """
    out = np.empty((len(generators), count))
    if len(generators) == 0 or count == 0:
        return out
    if addresses is None:
        for row, generator in zip(out, generators):
            generator.standard_normal(out=row)
        return out
    normals(addresses, out)
    return out
