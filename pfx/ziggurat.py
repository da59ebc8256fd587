r"""Standard normal draws by the ziggurat method (Marsaglia & Tsang 2000), from 64-bit words.

The half-normal curve :math:`f(x) = e^{-x^2/2}` on :math:`[0, \infty)` is covered by 256
horizontal strips of equal area :math:`v`. Strip :math:`i \ge 1` is the rectangle
:math:`[0, x_i] \times [f(x_i), f(x_{i+1})]`; strip 0 is the rectangle :math:`[0, r] \times
[0, f(r)]` together with the tail beyond :math:`r = x_1`, of total area
:math:`v = r f(r) + \int_r^\infty f`, handled as a rectangle of width :math:`x_0 = v / f(r)`.
The edges follow from :math:`x_{i+1} = f^{-1}(f(x_i) + v / x_i)`, :math:`x_{256} = 0`;
:math:`r = 3.6541528853610088` (Marsaglia & Tsang's value for 256 strips) makes them close.

One draw takes a strip :math:`i` uniformly and :math:`x = U x_i` with :math:`U \sim U[0, 1)`:

* :math:`x < x_{i+1}`: the point is under the curve whatever its height: accept
  (98.8 % of draws, one word, no transcendental function);
* :math:`i = 0` and :math:`x \ge r`: draw from the tail by Marsaglia's method,
  :math:`a = -\log(U_1) / r`, :math:`b = -\log U_2`, until :math:`2b > a^2`; return :math:`r + a`;
* otherwise (the wedge): accept :math:`x` if :math:`f(x_i) + U_2 (f(x_{i+1}) - f(x_i)) < f(x)`,
  else start over;

and a random sign turns the half-normal draw into a standard normal one. A 64-bit word gives
the strip (bits 0-7), the sign (bit 8) and the uniform (bits 11-63, 53 bits).

Why not ``Generator.standard_normal``: on the machines pfx is benchmarked on, NumPy's normal
generator costs about 10 ns a draw, four times the cost of the 64-bit word underneath it
(about 2.2 ns for PCG64); the falling-body filter needs three draws per particle and step.
This compiled loop costs about 1 ns on top of the word.

Reproducibility: trial ``r``'s draws use only words of trial ``r``'s generator. Every call
draws ``count + count // 16 + 16`` words per trial (the rejections need about 2 % more words
than draws); in the rare case that a trial runs short, it draws more words from its own
generator. The words left over are discarded. So a trial's draws depend only on its own
generator and the sequence of calls, never on the other trials in the batch.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from pfx.compiled import compiled

STRIPS = 256
TAIL_START = 3.6541528853610088          # r for 256 strips (Marsaglia & Tsang 2000, Table 1)


def _f(x):
    return math.exp(-0.5 * x * x)


def ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The strip edges x_0..x_255, the ratios x_{i+1} / x_i, and the heights f(x_0..x_256).

    ``heights[0]`` is 0: the wedge test is never used for strip 0 (the tail is).
    """
    r = TAIL_START
    area = r * _f(r) + math.sqrt(math.pi / 2.0) * math.erfc(r / math.sqrt(2.0))
    edges = np.empty(STRIPS + 1)
    edges[0] = area / _f(r)
    edges[1] = r
    for i in range(1, STRIPS - 1):
        edges[i + 1] = math.sqrt(-2.0 * math.log(_f(edges[i]) + area / edges[i]))
    edges[STRIPS] = 0.0
    ratios = edges[1:] / edges[:-1]
    heights = np.exp(-0.5 * edges * edges)
    heights[0] = 0.0
    return np.ascontiguousarray(edges[:-1]), ratios, heights


_EDGES, _RATIOS, _HEIGHTS = ziggurat_tables()

_STRIP_MASK = np.uint64(STRIPS - 1)
_SIGN_SHIFT = np.uint64(8)
_UNIFORM_SHIFT = np.uint64(11)
_UNIFORM_SCALE = 2.0 ** -53


@compiled
def normals_from_words(words, out, done):
    """Fill ``out[row, done[row]:]`` with normal draws made from ``words[row]``; set ``done``.

    Two passes per row, so that the common case runs as a branch-free (vectorised) loop:

    1. draw ``j`` starts from word ``j``; if that word's point lies in its strip's rectangle
       it is the draw, else the draw is marked NaN;
    2. each marked draw goes on (tail or wedge test, new attempts) with the words after the
       first ``count``, in order.

    Every word is used once, so the draws are independent. A row whose words run out in
    pass 2 gets ``done[row]`` = the first unfinished draw; the caller redraws from there with
    fresh words. (The tables are module constants, frozen into the compiled code.)
    """
    edges, ratios, heights = _EDGES, _RATIOS, _HEIGHTS
    rows, available = words.shape
    count = out.shape[1]
    for row in range(rows):
        start = done[row]
        need = count - start
        row_words = words[row, :need]
        row_out = out[row, start:]
        for j in range(need):
            word = row_words[j]
            strip = np.intp(word & _STRIP_MASK)
            u = np.float64(word >> _UNIFORM_SHIFT) * _UNIFORM_SCALE
            x = u * edges[strip]
            x = x - 2.0 * np.float64((word >> _SIGN_SHIFT) & np.uint64(1)) * x
            row_out[j] = x if u < ratios[strip] else np.nan
        p = need                              # next unused word
        finished = count
        for j in range(need):
            if not np.isnan(out[row, start + j]):
                continue
            word = words[row, j]
            value = np.nan
            exhausted = False
            while True:
                strip = np.intp(word & _STRIP_MASK)
                u = np.float64(word >> _UNIFORM_SHIFT) * _UNIFORM_SCALE
                x = u * edges[strip]
                if u < ratios[strip]:
                    value = x
                elif strip == 0:
                    # The tail beyond r; U in (0, 1) strictly, so the logarithms are finite.
                    exhausted = True
                    while p + 1 < available:
                        u1 = (np.float64(words[row, p] >> _UNIFORM_SHIFT) + 0.5) * _UNIFORM_SCALE
                        u2 = (np.float64(words[row, p + 1] >> _UNIFORM_SHIFT) + 0.5) * _UNIFORM_SCALE
                        p += 2
                        a = -np.log(u1) / edges[1]
                        if -2.0 * np.log(u2) > a * a:
                            value = edges[1] + a
                            exhausted = False
                            break
                elif p < available:
                    u2 = np.float64(words[row, p] >> _UNIFORM_SHIFT) * _UNIFORM_SCALE
                    p += 1
                    low = heights[strip]
                    if low + u2 * (heights[strip + 1] - low) < np.exp(-0.5 * x * x):
                        value = x
                else:
                    exhausted = True
                if exhausted or not np.isnan(value):
                    break
                if p >= available:               # rejected, and no word left for a new attempt
                    exhausted = True
                    break
                word = words[row, p]             # rejected: a new attempt
                p += 1
            if exhausted:
                finished = start + j
                break
            out[row, start + j] = -value if (word >> _SIGN_SHIFT) & np.uint64(1) else value
        done[row] = finished


def _words_for(count: int) -> int:
    return count + count // 16 + 16


def standard_normal_rows(bit_generators: Sequence[np.random.BitGenerator], count: int) -> np.ndarray:
    """``count`` standard normal draws per generator: shape (len(bit_generators), count)."""
    rows = len(bit_generators)
    out = np.empty((rows, count))
    done = np.zeros(rows, dtype=np.intp)
    if rows == 0 or count == 0:
        return out
    if rows == 1:
        words = bit_generators[0].random_raw(_words_for(count))[None, :]
    else:
        words = np.empty((rows, _words_for(count)), dtype=np.uint64)
        for row, bit_generator in enumerate(bit_generators):
            words[row] = bit_generator.random_raw(words.shape[1])
    normals_from_words(words, out, done)
    if done.min() < count:                 # rare: a trial ran short of words
        for row in np.flatnonzero(done < count):
            while done[row] < count:
                more = bit_generators[row].random_raw(_words_for(count - int(done[row])))[None, :]
                normals_from_words(more, out[row:row + 1], done[row:row + 1])
    return out
