"""Replayed random numbers: a test-only ``Random`` that serves the same draws to both backends.

The NumPy driver (:class:`pfx.filters.particle.engine.ParticleFilter`) draws from
:class:`~pfx.numerics.seeding.TrialStreams` and the JAX driver
(:class:`pfx.filters.particle.jax_engine.JaxParticleFilter`) from
:class:`~pfx.numerics.key_streams.KeyStreams`: different generators, so their results agree only in
distribution. Both run the same kernel (:mod:`pfx.filters.particle.kernel`), which makes the same
calls in the same order; served the same numbers, the two drivers must compute the same filter, up
to floating-point round-off.

A replay serves those numbers by place: the j-th call (0-based) made in step k, whatever its method,
returns an array of shape ``(trials,) + shape`` drawn from a NumPy generator seeded by
``(seed, k, j)``, of the law the method names (standard normal, uniform on [0, 1), standard
exponential). The test announces each step (:meth:`begin`), as ``KeyStreams.at(k)`` folds the step
into the keys: a stage that draws on one backend and not on the other (the injection, when no trial
injects) then shifts nothing in the steps after. Two replays with the same seed hand out the same
arrays as long as they are asked the same sequence of (method, shape) per step, which each records
in :attr:`calls` (step, method, shape) so that a test can show that they were.

:meth:`ReplayStreams.subset` serves the given rows of the full draws (and records the rows in
:attr:`subsets`): the JAX driver draws for every trial where the NumPy driver draws for some rows
only, so the rows a subset gets are the rows the JAX driver keeps. At ESS threshold 1 only the
injection takes a subset (the trials whose injection probability is positive); a test of any other
stage asserts that none was taken.

:class:`JaxReplayStreams` is the same for the JAX driver: a
:class:`~pfx.numerics.key_streams.KeyStreams` (the laws ask ``draws_namespace`` which array library
to draw in) whose draws are the replayed arrays as float64 JAX arrays. Its ``at`` refuses: the
kernel folds nothing into the streams within a step except a model's substeps, scanned with
``random.at(index)`` inside a ``lax.scan`` whose body is traced once; a replay would serve every
substep the same numbers where NumPy draws new ones, so it cannot serve that.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfx.numerics.key_streams import KeyStreams

# the laws of the replayed draws, by the method that asks for them
_LAWS = {
    "standard_normal": lambda generator, size: generator.standard_normal(size),
    "uniform": lambda generator, size: generator.random(size),
    "standard_exponential": lambda generator, size: generator.standard_exponential(size),
}


class _Replay:
    """What both replays share: the place (step, call), the draws of a place, the record."""

    def _start(self, trials: int, seed: int) -> None:
        self.trials, self.seed = trials, seed
        self.step, self.index = 0, 0          # the prior's draws are step 0's
        self.calls: list[tuple[int, str, tuple]] = []
        self.subsets: list[tuple[int, tuple]] = []

    def __len__(self) -> int:
        return self.trials

    def begin(self, step) -> None:
        """Step ``step``'s draws from here on, from its first call."""
        self.step, self.index = int(step), 0

    def draws(self, method: str, shape) -> np.ndarray:
        """The next call's draws for every trial, (trials, *shape), float64; recorded."""
        shape = tuple(int(size) for size in shape)
        generator = np.random.default_rng([self.seed, self.step, self.index])
        self.calls.append((self.step, method, shape))
        self.index += 1
        return _LAWS[method](generator, (self.trials,) + shape)

    def derived(self, purpose: int):
        raise AssertionError(f"the replay was asked for a derived stream ({purpose}): not replayed")


class ReplayStreams(_Replay):
    """Replayed draws for the NumPy driver (module docstring)."""

    def __init__(self, trials: int, seed: int = 0):
        self._start(trials, seed)

    def standard_normal(self, shape) -> np.ndarray:
        return self.draws("standard_normal", shape)

    def uniform(self, shape) -> np.ndarray:
        return self.draws("uniform", shape)

    def standard_exponential(self, shape) -> np.ndarray:
        return self.draws("standard_exponential", shape)

    def subset(self, rows) -> "_Rows":
        rows = np.asarray(rows, dtype=np.intp)
        self.subsets.append((self.step, tuple(rows.tolist())))
        return _Rows(self, rows)


class _Rows:
    """Some trials' streams of a :class:`ReplayStreams`: those rows of its draws, from its place."""

    def __init__(self, replay: ReplayStreams, rows: np.ndarray):
        self.replay, self.rows = replay, rows

    def __len__(self) -> int:
        return len(self.rows)

    def standard_normal(self, shape) -> np.ndarray:
        return self.replay.draws("standard_normal", shape)[self.rows]

    def uniform(self, shape) -> np.ndarray:
        return self.replay.draws("uniform", shape)[self.rows]

    def standard_exponential(self, shape) -> np.ndarray:
        return self.replay.draws("standard_exponential", shape)[self.rows]

    def subset(self, rows) -> "_Rows":
        return self.replay.subset(self.rows[np.asarray(rows, dtype=np.intp)])


class JaxReplayStreams(_Replay, KeyStreams):
    """Replayed draws for the JAX driver: the same arrays as float64 JAX arrays (module docstring)."""

    def __init__(self, trials: int, seed: int = 0):
        import jax.numpy as jnp

        KeyStreams.__init__(self, jnp.zeros((trials, 2), jnp.uint32), jnp.float64)
        self._start(trials, seed)

    def at(self, *counters: Any):
        raise AssertionError("random.at() within a step (a model's substeps, scanned with random.at(index)): a "
                             "traced scan body draws once for every substep, which a replay cannot serve")

    def _as_jax(self, draws: np.ndarray, dtype=None):
        import jax.numpy as jnp

        return jnp.asarray(draws, self.dtype if dtype is None else dtype)

    def standard_normal(self, shape):
        return self._as_jax(self.draws("standard_normal", shape))

    def uniform(self, shape, dtype: Any = None):
        return self._as_jax(self.draws("uniform", shape), dtype)

    def standard_exponential(self, shape):
        return self._as_jax(self.draws("standard_exponential", shape))

    def standard_t(self, degrees_of_freedom: float, shape):
        raise AssertionError("standard_t is not replayed")

    def _with_parameters(self, sample, parameters, shape):
        raise AssertionError("the count laws (binomial, poisson, gamma) are not replayed")

    def __getattr__(self, name: str):
        if name == "subset":
            raise AssertionError("the jax driver took a subset of its streams")
        raise AttributeError(name)
