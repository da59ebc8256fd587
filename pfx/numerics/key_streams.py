"""Counter-based random streams for the JAX backend: one threefry key per trial.

The :class:`Random` protocol is what a model, a noise law or a resampler draws from: batched
draws of shape ``(trials, *shape)`` whose slice ``r`` belongs to trial ``r`` alone. The NumPy
backend's implementation is :class:`~pfx.numerics.seeding.TrialStreams` (one NumPy generator
per trial, stepped in place); the JAX backend's is :class:`KeyStreams`.

A JAX key is not a generator with a state: a draw is a pure function of a key. So the key of
every draw is *derived* from the trial's key by folding in counters (threefry is a counter-based
generator: Salmon et al. 2011):

    key(trial, step, draw) = fold_in(fold_in(key_trial, step), draw)

* ``key_trial`` is made from the trial's filter seed, the same 63-bit integer that seeds the
  trial's NumPy generator (``filter_seed`` in trials.csv), so it depends on (seed, cell, trial)
  only: batching and chunking change nothing;
* ``step`` is the filter step (0 for the prior), folded in by :meth:`KeyStreams.at`;
* ``draw`` counts the draws made within the step, in the order the code makes them: the
  counter is a Python integer, advanced while JAX traces the step, so the compiled step holds
  the counters as constants and no key is carried from step to step.

The same keys give the same draws on a CPU and a GPU (threefry is defined bit for bit); what
is computed from them may differ in the last bits between devices.
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, Iterator, Optional, Protocol, Sequence

import numpy as np

from pfx.numerics.parameter_checks import (
    BINOMIAL_COUNT,
    BINOMIAL_PROBABILITY,
    GAMMA_SCALE,
    GAMMA_SHAPE,
    POISSON_RATE,
    check,
)

# The passes of the compiled loops a draw is made in (pfx.repeat's, innermost last): a loop body is
# traced once, so without them every pass would draw from the same keys.
_LOOP_PASSES: ContextVar[tuple] = ContextVar("loop_passes", default=())


@contextmanager
def loop_pass(index: Any) -> Iterator[None]:
    """Within the block, each draw's keys also fold in ``index`` (a traced loop counter): the
    body of a compiled loop draws new numbers at every pass, as a Python loop on NumPy does."""
    token = _LOOP_PASSES.set(_LOOP_PASSES.get() + (index,))
    try:
        yield
    finally:
        _LOOP_PASSES.reset(token)


class Random(Protocol):
    """Batched draws, one independent stream per trial (leading axis): what a model's
    transition, a noise law and a resampler draw from, on either backend."""

    def __len__(self) -> int: ...

    def standard_normal(self, shape) -> Any: ...

    def uniform(self, shape) -> Any: ...

    def standard_exponential(self, shape) -> Any: ...

    def standard_t(self, degrees_of_freedom: float, shape) -> Any: ...


def threefry_keys(seeds: Sequence[int]) -> np.ndarray:
    """The raw threefry keys (trials, 2) of 64-bit seeds: the high and low 32-bit words, which
    is what ``jax.random.PRNGKey(seed)`` makes of a seed when 64-bit types are enabled."""
    seeds = np.asarray([int(seed) for seed in seeds], dtype=np.uint64)
    return np.stack([seeds >> np.uint64(32), seeds & np.uint64(0xFFFFFFFF)], axis=-1).astype(np.uint32)


class KeyStreams:
    """The JAX implementation of :class:`Random`: one threefry key per trial (module docstring).

    ``keys`` is a (trials, 2) uint32 array (a JAX array, or a tracer inside a compiled step);
    draws are made in ``dtype`` (float64, or float32 for ``precision: float32``).
    """

    def __init__(self, keys: Any, dtype: Any = None, *, counter: int = 0, count_draws: str = "exact"):
        import jax.numpy as jnp

        self.keys = keys
        self.dtype = jnp.float64 if dtype is None else dtype
        self.counter = counter
        self.count_draws = count_draws      # how binomial, poisson and gamma draw (seeding.COUNT_DRAWS)

    @classmethod
    def from_seeds(cls, seeds: Sequence[int], dtype: Any = None) -> "KeyStreams":
        import jax.numpy as jnp

        return cls(jnp.asarray(threefry_keys(seeds)), dtype)

    def __len__(self) -> int:
        return int(self.keys.shape[0])

    def at(self, *counters: Any) -> "KeyStreams":
        """The streams of a place in the run (a step, a stage): each counter folded into every
        trial's key, the draw counter back at 0. Counters may be traced integers."""
        import jax

        keys = self.keys
        for counter in counters:
            keys = jax.vmap(jax.random.fold_in, in_axes=(0, None))(keys, counter)
        return KeyStreams(keys, self.dtype, count_draws=self.count_draws)

    def with_count_draws(self, count_draws: str) -> "KeyStreams":
        """The same keys, with binomial, Poisson and gamma draws made the ``count_draws`` way."""
        return KeyStreams(self.keys, self.dtype, counter=self.counter, count_draws=count_draws)

    def derived(self, purpose: int) -> "KeyStreams":
        """Each trial's streams for a purpose beside the filter (``SCORE_STREAM``,
        ``FORECAST_STREAM`` of :mod:`pfx.numerics.seeding`): the trial's key folded with
        2^31 - purpose, a counter no step reaches, so its draws are apart from the filter's;
        call :meth:`at` on it for a step. Made from the trials' keys, not from a step's."""
        return self.at(2**31 - int(purpose))

    def _next_keys(self) -> Any:
        """The keys of the next draw (one per trial), and the counter advanced; within a compiled
        loop's pass (:func:`loop_pass`), folded with the pass too."""
        import jax

        keys = jax.vmap(jax.random.fold_in, in_axes=(0, None))(self.keys, self.counter)
        for index in _LOOP_PASSES.get():         # inside pfx.repeat's compiled loop: this pass's keys
            keys = jax.vmap(jax.random.fold_in, in_axes=(0, None))(keys, index)
        self.counter += 1
        return keys

    def _draw(self, sample, shape) -> Any:
        import jax

        shape = tuple(int(size) for size in shape)
        return jax.vmap(lambda key: sample(key, shape))(self._next_keys())

    def standard_normal(self, shape) -> Any:
        import jax

        return self._draw(lambda key, size: jax.random.normal(key, size, self.dtype), shape)

    def uniform(self, shape, dtype: Any = None) -> Any:
        """U[0, 1), in the streams' dtype or the one given (the resamplers' points are float64
        whatever the precision: :mod:`pfx.filters.particle.jax_resampling`)."""
        import jax

        dtype = self.dtype if dtype is None else dtype
        return self._draw(lambda key, size: jax.random.uniform(key, size, dtype), shape)

    def standard_exponential(self, shape) -> Any:
        import jax

        return self._draw(lambda key, size: jax.random.exponential(key, size, self.dtype), shape)

    def standard_t(self, degrees_of_freedom: float, shape) -> Any:
        import jax

        return self._draw(lambda key, size: jax.random.t(key, degrees_of_freedom, size, self.dtype), shape)

    def normal(self, mean: Any = 0.0, sd: Any = 1.0, *, shape: Optional[Sequence[int]] = None) -> Any:
        """N(mean, sd^2), parameters broadcast as in :class:`~pfx.numerics.seeding.TrialStreams`
        (leading axis the trial axis)."""
        import jax.numpy as jnp

        mean, sd = jnp.asarray(mean, self.dtype), jnp.asarray(sd, self.dtype)
        if shape is None:
            shape = jnp.broadcast_shapes(mean.shape, sd.shape)[1:] if max(mean.ndim, sd.ndim) else ()
        draws = self.standard_normal(shape)
        return _trial_leading(mean, draws.ndim) + _trial_leading(sd, draws.ndim) * draws

    def exponential(self, scale: Any = 1.0, *, shape: Optional[Sequence[int]] = None) -> Any:
        import jax.numpy as jnp

        scale = jnp.asarray(scale, self.dtype)
        draws = self.standard_exponential(scale.shape[1:] if shape is None and scale.ndim else (shape or ()))
        return _trial_leading(scale, draws.ndim) * draws

    # -- the count-valued laws: the parameters laid out as TrialStreams reads them -------------

    def binomial(self, count: Any, probability: Any, *, shape: Optional[Sequence[int]] = None) -> Any:
        """Binomial draws, P(k) = C(n, k) p^k (1 - p)^(n - k), as floats of the streams' dtype
        (NumPy's are float64 too); ``count`` n and ``probability`` p laid out as in
        :meth:`pfx.numerics.seeding.TrialStreams.binomial` (the trial axis first). Parameters
        are checked as NumPy's are (:mod:`pfx.numerics.parameter_checks`: at once, or traced,
        by the engine after its scan), as are Poisson's and gamma's."""
        import jax

        check(BINOMIAL_COUNT, count)
        check(BINOMIAL_PROBABILITY, probability)
        if self.count_draws == "inverse_cdf":
            return self._by_inverse_cdf("binomial", [count, probability], shape)
        return self._with_parameters(
            lambda key, n, p, size: jax.random.binomial(key, n, p, size, self.dtype), [count, probability], shape)

    def poisson(self, rate: Any, *, shape: Optional[Sequence[int]] = None) -> Any:
        """Poisson draws, P(k) = rate^k e^(-rate) / k!, as floats of the streams' dtype."""
        import jax

        check(POISSON_RATE, rate)
        if self.count_draws == "inverse_cdf":
            return self._by_inverse_cdf("poisson", [rate], shape)
        return self._with_parameters(
            lambda key, rate, size: jax.random.poisson(key, rate, size).astype(self.dtype), [rate], shape)

    def gamma(self, shape_parameter: Any, scale: Any = 1.0, *, shape: Optional[Sequence[int]] = None) -> Any:
        """Gamma draws of shape k and scale theta (mean k theta, variance k theta^2)."""
        import jax

        check(GAMMA_SHAPE, shape_parameter)
        check(GAMMA_SCALE, scale)
        if self.count_draws == "inverse_cdf":
            return self._by_inverse_cdf("gamma", [shape_parameter, scale], shape)
        return self._with_parameters(
            lambda key, k, theta, size: theta * jax.random.gamma(key, k, size, self.dtype),
            [shape_parameter, scale], shape)

    def _by_inverse_cdf(self, law: str, parameters: list, shape: Optional[Sequence[int]]) -> Any:
        """``count_draws: inverse_cdf``: each draw's uniforms from its trial's key, turned into the
        law's variate by its branch-free inverse CDF (:func:`pfx.numerics.count_quantiles.inverse_cdf_law`)."""
        import jax

        from pfx.numerics.count_quantiles import inverse_cdf_law

        per_draw, variate = inverse_cdf_law(law)
        return self._with_parameters(
            lambda key, *own: variate(jax.random.uniform(key, (per_draw,) + tuple(own[-1]), self.dtype), *own[:-1]),
            parameters, shape)

    def _with_parameters(self, sample, parameters: list, shape: Optional[Sequence[int]]) -> Any:
        """Trial r's draws from trial r's key and trial r's slice of each parameter: a scalar is
        shared, an array's leading axis is the trial axis (length R, or 1: shared) and its other
        axes broadcast against the others' after trailing axes of length 1 are added (the layout
        of :class:`~pfx.numerics.seeding.TrialStreams`). Draws (R, *shape); ``shape`` defaults to
        the parameters' broadcast shape without the trial axis."""
        import jax
        import jax.numpy as jnp

        trials = len(self)
        parameters = [jnp.asarray(parameter, self.dtype) for parameter in parameters]
        arrays = [parameter for parameter in parameters if parameter.ndim > 0]
        axes = 1 + (len(shape) if shape is not None else max((array.ndim - 1 for array in arrays), default=0))
        padded = [parameter if parameter.ndim == 0 else
                  parameter.reshape(parameter.shape + (1,) * (axes - parameter.ndim)) for parameter in parameters]
        if shape is not None:
            trial_shape = tuple(int(size) for size in shape)
        else:
            trial_shape = tuple(jnp.broadcast_shapes(*(p.shape[1:] for p in padded if p.ndim > 0))) if arrays else ()
        per_trial = [parameter if parameter.ndim == 0 else jnp.broadcast_to(parameter, (trials,) + parameter.shape[1:])
                     for parameter in padded]
        axes_in = tuple(None if parameter.ndim == 0 else 0 for parameter in per_trial)

        def one_trial(key, *own):
            return sample(key, *(jnp.broadcast_to(value, trial_shape) for value in own), trial_shape)

        return jax.vmap(one_trial, in_axes=(0, *axes_in))(self._next_keys(), *per_trial)

    def __getattr__(self, name: str):
        if name == "subset":
            raise NotImplementedError("random.subset is not available on the jax backend: every trial draws, and "
                                      "a mask selects")
        raise AttributeError(name)


def _trial_leading(parameter: Any, dimensions: int) -> Any:
    """A parameter with trailing axes of length 1 added up to ``dimensions`` (a scalar as is):
    its leading axis stays the trial axis, as TrialStreams reads parameters."""
    if parameter.ndim == 0:
        return parameter
    return parameter.reshape(parameter.shape + (1,) * (dimensions - parameter.ndim))


def draws_namespace(random: Random) -> tuple[Any, Any]:
    """(array module, dtype) of ``random``'s draws: ``jax.numpy`` and the streams' dtype for
    :class:`~pfx.numerics.key_streams.KeyStreams`, ``numpy`` and float64 else."""
    if isinstance(random, KeyStreams):
        import jax.numpy as jnp

        return jnp, random.dtype
    return np, np.float64


def zero_draws(random: Random, shape: tuple) -> Any:
    """Zeros of ``shape`` in the library and dtype of ``random``'s draws (:func:`draws_namespace`)."""
    xp, dtype = draws_namespace(random)
    return xp.zeros(shape, dtype)
