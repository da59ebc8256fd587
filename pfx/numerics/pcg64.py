r"""Each trial's own PCG64 generator, stepped in place by compiled code.

Every trial owns a NumPy generator (:mod:`pfx.numerics.seeding`), and a batch holds hundreds of
them. Asking each for its numbers in turn costs a Python call per trial and per draw request
(a microsecond or two each, more than the draws of a small trial). Here a compiled loop steps
the generators themselves, all trials in one call: it reads and writes each generator's state
where NumPy keeps it, so the words are exactly the ones NumPy's ``random_raw`` would give, and
the generator is left exactly where NumPy would leave it. Nothing is copied back and forth:
NumPy's own methods may be called on the same generators before or after.

PCG64 (O'Neill 2014, NumPy's default) is a 128-bit linear congruential generator with a
permuted output:

.. math::

    s_{k} = a\, s_{k-1} + c \pmod{2^{128}}, \qquad
    \mathrm{word}_k = \mathrm{rotr}_{64}\big(\mathrm{hi}(s_k) \oplus \mathrm{lo}(s_k),\;
    s_k \gg 122\big),

with NumPy's multiplier :math:`a` and the stream's odd increment :math:`c`. The 128-bit
arithmetic is written in LLVM's 128-bit integers (numba's own integers stop at 64 bits). A uniform double is
:math:`(\mathrm{word} \gg 11)\, 2^{-53}`, as NumPy's ``Generator.random`` makes it.

Where the state lives: NumPy's PCG64 object holds a pointer to a struct of two 128-bit
integers, the state and the increment, little-endian. That layout is NumPy's, not a public
promise, so it is checked once per process (:func:`layout_matches`: uniforms drawn here against
``Generator.random``'s); where it does not match, or for other bit generators, :class:`TrialStreams`
uses NumPy's own methods, trial by trial.

This module imports numba; :mod:`pfx.numerics.seeding` imports it on the first draw only.
"""

from __future__ import annotations

import ctypes
import functools
from typing import Optional, Sequence

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from pfx.numerics.compiled import compiled_now

_MULTIPLIER = 0x2360ED051FC65DA44385DF649FCCF645       # NumPy's PCG64 multiplier a
_ELEVEN = np.uint64(11)
_FIFTY_EIGHT = np.uint64(58)
_SIXTY_THREE = np.uint64(63)
_SIXTY_FOUR = np.uint64(64)
_DOUBLE_SCALE = 1.0 / 9007199254740992.0          # 2^-53


@intrinsic
def _words_at(typing_context, address):
    """The memory at ``address`` (a uint64) as a pointer to 64-bit words."""
    pointer = types.CPointer(types.uint64)

    def generate(context, builder, signature, arguments):
        return builder.inttoptr(arguments[0], context.get_value_type(pointer))

    return pointer(types.uint64), generate


@compiled_now
def state_of(address):
    """The generator's (state low, state high, increment low, increment high) words, as an array
    that writes through to the generator."""
    return numba.carray(_words_at(address), 4)


@intrinsic
def _advance(typing_context, low, high, increment_low, increment_high):
    """s <- a s + c mod 2^128, on the halves of s and c: (new low, new high).

    Written in LLVM's 128-bit integers, which the compiler turns into the machine's 64 x 64 -> 128
    multiply (NumPy's C code gets the same from ``__uint128_t``).
    """
    signature = types.UniTuple(types.uint64, 2)(types.uint64, types.uint64, types.uint64, types.uint64)

    def generate(context, builder, signature, arguments):
        wide, narrow = ir.IntType(128), ir.IntType(64)
        sixty_four = ir.Constant(wide, 64)

        def join(low_half, high_half):
            return builder.or_(builder.zext(low_half, wide), builder.shl(builder.zext(high_half, wide), sixty_four))

        state, increment = join(arguments[0], arguments[1]), join(arguments[2], arguments[3])
        advanced = builder.add(builder.mul(state, ir.Constant(wide, _MULTIPLIER)), increment)
        halves = [builder.trunc(advanced, narrow), builder.trunc(builder.lshr(advanced, sixty_four), narrow)]
        return context.make_tuple(builder, signature.return_type, halves)

    return signature, generate


@compiled_now
def step(low, high, increment_low, increment_high):
    """One PCG64 step: (new state low, new state high, output word)."""
    new_low, new_high = _advance(low, high, increment_low, increment_high)
    # XSL-RR: xor the halves, rotate right by the top six bits
    folded = new_high ^ new_low
    rotation = new_high >> _FIFTY_EIGHT
    word = (folded >> rotation) | (folded << ((_SIXTY_FOUR - rotation) & _SIXTY_THREE))
    return new_low, new_high, word


@compiled_now
def uniforms(addresses, out):
    """out[row, :] = uniform doubles on [0, 1) of generator ``addresses[row]`` (``Generator.random``:
    (word >> 11) 2^-53, exact in floating point)."""
    for row in range(out.shape[0]):
        state = state_of(addresses[row])
        low, high, increment_low, increment_high = state[0], state[1], state[2], state[3]
        for j in range(out.shape[1]):
            low, high, word = step(low, high, increment_low, increment_high)
            out[row, j] = np.float64(np.int64(word >> _ELEVEN)) * _DOUBLE_SCALE   # < 2^53: exact
        state[0], state[1] = low, high


def _state_address(bit_generator: np.random.PCG64) -> int:
    """Where the generator's state and increment live: NumPy's state struct starts with a pointer to them."""
    return ctypes.c_void_p.from_address(bit_generator.ctypes.state_address).value


@functools.lru_cache(maxsize=None)
def layout_matches() -> bool:
    """Whether this NumPy keeps PCG64's state as this module reads it (checked once per process:
    1000 uniforms, i.e. the top 53 bits of 1000 words, and the state after them)."""
    ours, numpys = np.random.PCG64(20240611), np.random.PCG64(20240611)
    draws = np.empty((1, 1000))
    uniforms(np.array([_state_address(ours)], dtype=np.uint64), draws)
    return bool(np.array_equal(draws[0], np.random.Generator(numpys).random(1000))) and ours.state == numpys.state


def state_addresses(bit_generators: Sequence[np.random.BitGenerator]) -> Optional[np.ndarray]:
    """The state addresses of the generators, for the compiled loops; None unless every one is
    a PCG64 laid out as :func:`layout_matches` checks (and numba compiles: not under
    ``NUMBA_DISABLE_JIT``)."""
    if numba.config.DISABLE_JIT:         # NUMBA_DISABLE_JIT=1: the loops would run as Python, without the pointer
        return None
    if not all(type(bit_generator) is np.random.PCG64 for bit_generator in bit_generators) or not layout_matches():
        return None
    return np.array([_state_address(bit_generator) for bit_generator in bit_generators], dtype=np.uint64)
