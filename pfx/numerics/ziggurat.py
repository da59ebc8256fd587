r"""NumPy's normal generator, compiled: ``Generator.standard_normal`` of many trials in one call.

Every trial owns a NumPy generator (:mod:`pfx.numerics.seeding`). Filling trial after trial with
``generator.standard_normal`` costs, on the machines pfx is benchmarked on, about 10 ns a
draw, four times the cost of the 64-bit word underneath it (about 2.2 ns for PCG64), and a
Python call per trial; the falling-body filter needs three draws per particle and step.
Here each trial's words are drawn in one call (``bit_generator.random_raw``) and turned into
normal draws by a compiled loop: about 2 ns a draw on top of the word.

The loop is NumPy's own algorithm (``random_standard_normal`` in NumPy's
``distributions.c``): the ziggurat method of Marsaglia & Tsang (2000) with 256 strips, on
NumPy's tables (:mod:`pfx.numerics.ziggurat_tables`). A 64-bit word gives the strip (bits 0-7),
the sign (bit 8) and a 52-bit uniform; the point is accepted at once when it lies in the
strip's rectangle (99 % of the draws), else the tail beyond :math:`r = 3.6541528853610088` is sampled by Marsaglia's
method or the wedge is tested against :math:`e^{-x^2/2}`, with further words as uniforms
:math:`(w \gg 11) \cdot 2^{-53}`, which is how PCG64 makes a double.

So the draws are exactly NumPy's, word for word: a call consumes from each trial's generator
the words NumPy would, no more. Each trial's words are drawn with a margin (the rejections
need a few more words than draws); the words not used are given back by stepping the
generator back (``PCG64.advance`` with a negative count), so the generator ends where
``standard_normal`` would have left it. Generators other than PCG64, and the astronomically
rare trial whose margin runs out, are served by ``generator.standard_normal`` itself.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from pfx.numerics.compiled import compiled
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


@compiled
def normals_from_words(words, out, used):
    """out[row, :] = NumPy's standard normal draws from words[row]; used[row] = words taken.

    ``used[row]`` is -1 if the row's words ran out before ``out[row]`` was full. (The tables
    are module constants, frozen into the compiled code.)
    """
    ki, wi, fi, r, inverse_r = _KI, _WI, _FI, _R, _INVERSE_R
    rows, available = words.shape
    count = out.shape[1]
    for row in range(rows):
        p = 0
        short = False
        for j in range(count):
            value = 0.0
            while True:
                if p >= available:
                    short = True
                    break
                bits = words[row, p]
                p += 1
                strip = np.intp(bits & _STRIP)
                bits = bits >> _EIGHT
                negative = (bits & _ONE) != 0
                magnitude = (bits >> _ONE) & _MANTISSA
                x = np.float64(magnitude) * wi[strip]
                if negative:
                    x = -x
                if magnitude < ki[strip]:
                    value = x
                    break
                if strip == 0:                   # the tail beyond r
                    accepted = False
                    while p + 1 < available:
                        u1 = np.float64(words[row, p] >> _DOUBLE_SHIFT) * _DOUBLE_SCALE
                        u2 = np.float64(words[row, p + 1] >> _DOUBLE_SHIFT) * _DOUBLE_SCALE
                        p += 2
                        xx = -inverse_r * np.log1p(-u1)
                        yy = -np.log1p(-u2)
                        if yy + yy > xx * xx:
                            value = -(r + xx) if ((magnitude >> _EIGHT) & _ONE) != 0 else r + xx
                            accepted = True
                            break
                    if not accepted:
                        short = True
                    break
                if p >= available:
                    short = True
                    break
                u = np.float64(words[row, p] >> _DOUBLE_SHIFT) * _DOUBLE_SCALE
                p += 1
                if (fi[strip - 1] - fi[strip]) * u + fi[strip] < np.exp(-0.5 * x * x):   # the wedge
                    value = x
                    break
            if short:
                break
            out[row, j] = value
        used[row] = -1 if short else p


def _words_for(count: int) -> int:
    return count + count // 16 + 16


def standard_normal_rows(generators: Sequence[np.random.Generator],
                         pcg64: Optional[Sequence[np.random.PCG64]], count: int) -> np.ndarray:
    """``generator.standard_normal(count)`` for every generator: shape (len(generators), count).

    ``pcg64``: the generators' bit generators if all are PCG64, else None (NumPy's own loop).
    """
    rows = len(generators)
    out = np.empty((rows, count))
    if rows == 0 or count == 0:
        return out
    if pcg64 is None:
        for row, generator in zip(out, generators):
            generator.standard_normal(out=row)
        return out
    available = _words_for(count)
    if rows == 1:
        words = pcg64[0].random_raw(available)[None, :]
    else:
        words = np.empty((rows, available), dtype=np.uint64)
        for row, bit_generator in enumerate(pcg64):
            words[row] = bit_generator.random_raw(available)
    used = np.empty(rows, dtype=np.intp)
    normals_from_words(words, out, used)
    for row, bit_generator in enumerate(pcg64):
        if used[row] < 0:                # the margin ran out: NumPy's own loop, from the same state
            bit_generator.advance(-available)
            generators[row].standard_normal(out=out[row])
        else:                            # give back the words not used
            bit_generator.advance(int(used[row]) - available)
    return out

