"""Seeding: one root seed, one independent random stream per (role, cell, trial).

Every random number pfx draws comes from an explicit :class:`numpy.random.Generator`.
Streams are derived with :class:`numpy.random.SeedSequence` from the experiment's root seed:

* the **truth** stream of trial ``t`` depends only on ``(seed, t)``, so trial ``t`` of every
  arm and every sweep cell sees the same true trajectory and the same measurements (common
  random numbers make comparisons between arms paired);
* the **filter** stream of trial ``t`` in a cell depends on ``(seed, cell key, t)``, where the
  cell key is a hash of the cell's resolved settings; adding an arm to a config therefore
  changes nothing in the other arms' results.

Each stream is reduced to one 63-bit integer (written to ``trials.csv`` as ``truth_seed`` and
``filter_seed``): ``numpy.random.default_rng(that_integer)`` recreates the trial's generator.

Because each trial owns its generator, a batch of trials draws exactly the numbers those trials
would draw one by one: :class:`TrialStreams` hands each trial's slice of a batched array to that
trial's own generator. Normal and uniform draws are exactly ``Generator.standard_normal``'s and
``Generator.random``'s, made by compiled loops that step each generator in place
(:mod:`pfx.numerics.pcg64`, :mod:`pfx.numerics.ziggurat`), for a whole batch in one call.

Draws of other laws (binomial, Poisson, gamma; exponential and normal with parameters) take
parameter arrays whose **leading axis is the trial axis**, so that a count-valued model can draw
``random.binomial(state, probability)`` for its ``(R, N)`` particles in one call: trial ``r``'s
slice is one vectorised call of generator ``r``'s own NumPy method on trial ``r``'s parameters,
hence exactly NumPy's numbers, whatever the batching.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from pfx.numerics.parameter_checks import (
    BINOMIAL_COUNT,
    BINOMIAL_PROBABILITY,
    EXPONENTIAL_SCALE,
    GAMMA_SCALE,
    GAMMA_SHAPE,
    NORMAL_SD,
    POISSON_RATE,
    Rule,
    numbers,
    refuse_unless_valid,
)

TRUTH_ROLE = 0
FILTER_ROLE = 1
STUDY_ROLE = 2
ESTIMATION_ROLE = 3
SPREAD_ROLE = 4
RESTART_ROLE = 5
POSTERIOR_FORECAST_ROLE = 6
# the streams derived from a trial's filter seed (TrialStreams.derived): apart from the filter's
# own draws, so that asking for scores or forecasts changes no number of the filter
SCORE_STREAM = 1
FORECAST_STREAM = 2


def stream_seed(root_seed: int, role: int, trial: int, cell_key: int = 0) -> int:
    """The 63-bit integer seed of one (role, cell, trial) stream."""
    sequence = np.random.SeedSequence(root_seed, spawn_key=(role, cell_key, trial))
    return int(sequence.generate_state(1, np.uint64)[0] >> np.uint64(1))


def truth_seed(root_seed: int, trial: int, datasets: int | None = None) -> int:
    """Seed of trial ``trial``'s truth stream (shared by every cell of an experiment).

    With ``datasets`` (the config's key of that name) the trials share that many truths: trial
    ``t`` sees dataset ``t mod datasets``, whose stream is the one trial ``t mod datasets`` would
    have without the key, so ``datasets: 5`` repeats the first five trials' truths.
    """
    return stream_seed(root_seed, TRUTH_ROLE, trial if datasets is None else trial % datasets)


def filter_seed(root_seed: int, cell_key: int, trial: int) -> int:
    """Seed of trial ``trial``'s filter stream in the cell with key ``cell_key``."""
    return stream_seed(root_seed, FILTER_ROLE, trial, cell_key)


def chain_seeds(root_seed: int, cell_key: int, chain: int, iteration: int) -> tuple[int, int]:
    """The two seeds of one iteration of one chain of parameter estimation (PMMH, or an IF2
    replicate) in a cell: its filter's stream and its move's (the proposal and the accept
    draw). Each depends only on (seed, cell, chain, iteration), so a chain's numbers do not
    depend on the other chains, on batching, or on where an interrupted run resumed."""
    sequence = np.random.SeedSequence(root_seed, spawn_key=(ESTIMATION_ROLE, cell_key, chain, iteration))
    filter_state, move_state = sequence.generate_state(2, np.uint64) >> np.uint64(1)
    return int(filter_state), int(move_state)


def spread_seed(root_seed: int, cell_key: int, particles: int, run: int) -> int:
    """Seed of run ``run`` of a cell's filter at ``particles`` particles when measuring the spread
    of its log-likelihood estimate (:mod:`pfx.estimation.likelihood_spread`); apart from every
    trial's and chain's stream, and the same whatever else the measurement runs."""
    sequence = np.random.SeedSequence(root_seed, spawn_key=(SPREAD_ROLE, cell_key, particles, run))
    return int(sequence.generate_state(1, np.uint64)[0] >> np.uint64(1))


def restart_seed(root_seed: int, cell_key: int, chain: int) -> int:
    """Seed of the one filter run that estimates a PMMH chain's likelihood again at its current
    point when the chain changes particle count after its warm-up (``particles: auto``)."""
    sequence = np.random.SeedSequence(root_seed, spawn_key=(RESTART_ROLE, cell_key, chain))
    return int(sequence.generate_state(1, np.uint64)[0] >> np.uint64(1))


def posterior_forecast_seed(root_seed: int, cell_key: int, draw: int) -> int:
    """Seed of the filter run (and its forecasts) at posterior draw ``draw`` of a PMMH cell
    (:mod:`pfx.estimation.posterior_forecasts`)."""
    sequence = np.random.SeedSequence(root_seed, spawn_key=(POSTERIOR_FORECAST_ROLE, cell_key, draw))
    return int(sequence.generate_state(1, np.uint64)[0] >> np.uint64(1))


def derived_seed(seed: int, purpose: int) -> int:
    """The seed of a stream derived from a trial's seed for a purpose (TrialStreams.derived)."""
    sequence = np.random.SeedSequence(int(seed), spawn_key=(purpose,))
    return int(sequence.generate_state(1, np.uint64)[0] >> np.uint64(1))


def study_generator(root_seed: int) -> np.random.Generator:
    """The one generator a study (:mod:`pfx.studies`) draws from."""
    return np.random.default_rng(stream_seed(root_seed, STUDY_ROLE, 0))


COUNT_DRAWS = ("exact", "inverse_cdf")
"""How the streams draw binomial, Poisson and gamma variates (``filter.count_draws``): ``exact``,
NumPy's (or JAX's) exact samplers; ``inverse_cdf``, branch-free inverse CDFs of uniforms
(:mod:`pfx.numerics.count_quantiles`; its accuracy is in docs/plugins.md)."""


class TrialStreams:
    """One generator per trial; batched draws of shape ``(trials, *shape)``.

    Slice ``r`` of every array returned comes from generator ``r`` alone, in the order the
    calls are made, so results do not depend on how trials are grouped into batches. Normal
    and uniform draws of PCG64 generators (all of pfx's own) are made by compiled loops that
    step every trial's generator in place, in one call for the batch
    (:mod:`pfx.numerics.pcg64`, :mod:`pfx.numerics.ziggurat`); other draws, and other
    generators, by NumPy trial by trial. Either way the numbers are NumPy's.

    The laws with parameters (:meth:`binomial`, :meth:`poisson`, :meth:`gamma`,
    :meth:`exponential`, :meth:`normal`) read each parameter as a scalar, shared by every trial,
    or as an array whose leading axis is the trial axis, of length ``len(self)`` (or 1: shared);
    its other axes broadcast with the other parameters' as NumPy's do, after the parameters with
    fewer axes are given trailing axes of length 1: a ``(R,)`` count and a ``(R, N)``
    probability mean one count per trial, one probability per particle. A parameter that varies
    per particle but not per trial is therefore written ``(1, N)``, never ``(N,)``. The draws
    have shape ``(R, *shape)``: ``shape`` is the shape of each trial's draws, like NumPy's
    ``size`` without the trial axis; by default it is the parameters' broadcast shape (without
    the trial axis), so scalar parameters and no ``shape`` give one draw per trial, ``(R,)``.
    """

    def __init__(self, generators: Sequence[np.random.Generator], *, addresses=None, count_draws: str = "exact"):
        self.generators = list(generators)
        self.seeds: Optional[list[int]] = None      # the trials' seeds, when made from them (from_seeds)
        self.count_draws = count_draws              # COUNT_DRAWS: how binomial, poisson and gamma draw
        # The generators' PCG64 state addresses for the compiled loops: found on the first
        # draw (that imports numba), None if some generator is not a PCG64.
        self._addresses = addresses
        self._addresses_known = addresses is not None

    def __getstate__(self) -> dict:
        # The addresses are this process's memory of these very generators: a copy (pickled to
        # another process, or deep-copied with new generators) finds its own.
        return {"generators": self.generators, "_addresses": None, "_addresses_known": False,
                "seeds": self.seeds, "count_draws": self.count_draws}

    @classmethod
    def from_seeds(cls, seeds: Sequence[int]) -> "TrialStreams":
        streams = cls([np.random.default_rng(int(seed)) for seed in seeds])
        # the JAX backend makes each trial's threefry key from the same seed (pfx.numerics.key_streams)
        streams.seeds = [int(seed) for seed in seeds]
        return streams

    def __len__(self) -> int:
        return len(self.generators)

    def derived(self, purpose: int) -> "TrialStreams":
        """Each trial's stream for a purpose beside the filter (:data:`SCORE_STREAM`,
        :data:`FORECAST_STREAM`): seeded from the trial's own seed and the purpose, so it
        depends on (seed, cell, trial) only and leaves the filter's draws as they were. Streams
        made from generators without seeds spawn a child of each (NumPy's ``Generator.spawn``,
        which does not advance the parent)."""
        if self.seeds is None:
            derived = TrialStreams([generator.spawn(1)[0] for generator in self.generators])
        else:
            derived = TrialStreams.from_seeds([derived_seed(seed, purpose) for seed in self.seeds])
        return derived.with_count_draws(self.count_draws)

    def with_count_draws(self, count_draws: str) -> "TrialStreams":
        """The same streams (the same generators: drawing from one advances the other) with
        binomial, Poisson and gamma draws made the ``count_draws`` way (:data:`COUNT_DRAWS`)."""
        if count_draws not in COUNT_DRAWS:
            raise ValueError(f"count_draws must be one of {', '.join(COUNT_DRAWS)}, not {count_draws!r}")
        streams = TrialStreams(self.generators, addresses=self._addresses if self._addresses_known else None,
                               count_draws=count_draws)
        streams.seeds = self.seeds
        return streams

    def subset(self, trial_indices) -> "TrialStreams":
        """The streams of the given trials (positions in this batch): the same generators."""
        trial_indices = np.asarray(trial_indices, dtype=np.intp)
        addresses = self._addresses[trial_indices] if self._addresses_known and self._addresses is not None \
            else None
        return TrialStreams([self.generators[i] for i in trial_indices.tolist()], addresses=addresses,
                            count_draws=self.count_draws)

    def compiled_addresses(self):
        """The PCG64 state addresses the compiled loops step (None: NumPy's methods, trial by trial)."""
        if not self._addresses_known:
            from pfx.numerics.pcg64 import state_addresses

            self._addresses = state_addresses([generator.bit_generator for generator in self.generators])
            self._addresses_known = True
        return self._addresses

    def _fill(self, shape, method: str) -> np.ndarray:
        shape = tuple(shape)
        if math.prod(shape) == 1:
            # One draw per trial: a scalar call per generator costs about a third of filling a
            # one-element row.
            draws = [getattr(generator, method)() for generator in self.generators]
            return np.array(draws, dtype=float).reshape((len(self.generators),) + shape)
        out = np.empty((len(self.generators),) + shape)
        for row, generator in zip(out, self.generators):
            getattr(generator, method)(out=row)
        return out

    def standard_normal(self, shape) -> np.ndarray:
        """Standard normal draws: each trial's ``generator.standard_normal``, compiled (pfx.numerics.ziggurat)."""
        from pfx.numerics.ziggurat import standard_normal_rows

        shape = tuple(shape)
        draws = standard_normal_rows(self.generators, self.compiled_addresses(), math.prod(shape))
        return draws.reshape((len(self.generators),) + shape)

    def uniform(self, shape) -> np.ndarray:
        """Uniform draws on [0, 1): each trial's ``generator.random``, compiled (pfx.numerics.pcg64)."""
        addresses = self.compiled_addresses()
        if addresses is None:
            return self._fill(shape, "random")
        from pfx.numerics.pcg64 import uniforms

        shape = tuple(shape)
        out = np.empty((len(self.generators), math.prod(shape)))
        if out.size:
            uniforms(addresses, out)
        return out.reshape((len(self.generators),) + shape)

    def standard_exponential(self, shape) -> np.ndarray:
        return self._fill(shape, "standard_exponential")

    def standard_t(self, degrees_of_freedom: float, shape) -> np.ndarray:
        shape = tuple(shape)
        return np.stack([g.standard_t(degrees_of_freedom, size=shape) for g in self.generators]) \
            if self.generators else np.empty((0,) + shape)

    def binomial(self, count: ArrayLike, probability: ArrayLike, *,
                 shape: Optional[Sequence[int]] = None) -> np.ndarray:
        """Binomial draws, ``P(k) = C(n, k) p^k (1 - p)^(n - k)`` for k = 0..n, as floats.

        ``count`` is n (non-negative integers; integer-valued floats welcome, as a count-valued
        model keeps them), ``probability`` is p in [0, 1]; each trial's ``generator.binomial``.
        """
        count = _checked(BINOMIAL_COUNT, count)
        probability = _checked(BINOMIAL_PROBABILITY, probability)
        if self.count_draws == "inverse_cdf":
            return self._by_inverse_cdf("binomial", [count, probability], shape)
        return self._draw("binomial", [count.astype(np.int64), probability], shape)

    def poisson(self, rate: ArrayLike, *, shape: Optional[Sequence[int]] = None) -> np.ndarray:
        """Poisson draws, ``P(k) = λ^k e^{-λ} / k!`` for k = 0, 1, ..., as floats.

        ``rate`` is λ >= 0 (at most NumPy's bound, about 9.2e18); each trial's ``generator.poisson``.
        """
        rate = _checked(POISSON_RATE, rate)
        if self.count_draws == "inverse_cdf":
            return self._by_inverse_cdf("poisson", [rate], shape)
        return self._draw("poisson", [rate], shape)

    def gamma(self, shape_parameter: ArrayLike, scale: ArrayLike = 1.0, *,
              shape: Optional[Sequence[int]] = None) -> np.ndarray:
        """Gamma draws, density ``x^(k-1) e^(-x/θ) / (Γ(k) θ^k)`` for x > 0.

        ``shape_parameter`` is the law's shape k >= 0 (named so, as ``shape`` is the draws'
        shape), ``scale`` is θ >= 0: mean kθ, variance kθ²; each trial's ``generator.gamma``.
        """
        shape_parameter = _checked(GAMMA_SHAPE, shape_parameter)
        scale = _checked(GAMMA_SCALE, scale)
        if self.count_draws == "inverse_cdf":
            return self._by_inverse_cdf("gamma", [shape_parameter, scale], shape)
        return self._draw("gamma", [shape_parameter, scale], shape)

    def exponential(self, scale: ArrayLike = 1.0, *, shape: Optional[Sequence[int]] = None) -> np.ndarray:
        """Exponential draws, density ``e^(-x/θ) / θ`` for x >= 0 (mean θ = ``scale``).

        θ E with E from :meth:`standard_exponential`: exactly ``generator.exponential(scale)``,
        which is that product.
        """
        scale = _checked(EXPONENTIAL_SCALE, scale)
        (scale,), trial_shape = self._aligned("exponential", [scale], shape)
        return scale * self.standard_exponential(trial_shape)

    def normal(self, mean: ArrayLike = 0.0, sd: ArrayLike = 1.0, *,
               shape: Optional[Sequence[int]] = None) -> np.ndarray:
        """Normal draws, ``mean + sd Z`` with Z from :meth:`standard_normal` (compiled).

        Exactly ``generator.normal(mean, sd)``, which is that sum; ``sd`` >= 0 (finite).
        """
        mean = np.asarray(mean, dtype=float)
        sd = _checked(NORMAL_SD, sd)
        (mean, sd), trial_shape = self._aligned("normal", [mean, sd], shape)
        return mean + sd * self.standard_normal(trial_shape)

    def _aligned(self, law: str, parameters: list[np.ndarray],
                 shape: Optional[Sequence[int]]) -> tuple[list[np.ndarray], tuple]:
        """The parameters with the trial axis first and equally many axes, and each trial's shape.

        A scalar stays a scalar; an array's leading axis must be the trial axis (length R or 1),
        and it gets trailing axes of length 1 up to the others' (or ``shape``'s) number of axes.
        """
        trials = len(self.generators)
        arrays = [parameter for parameter in parameters if parameter.ndim > 0]
        for parameter in arrays:
            if parameter.shape[0] not in (trials, 1):
                raise ValueError(f"{law}: a parameter of shape {parameter.shape} must have the trial "
                                 f"axis first, of length {trials} (or 1)")
        axes = 1 + (len(shape) if shape is not None else max((a.ndim - 1 for a in arrays), default=0))
        if any(a.ndim > axes for a in arrays):
            raise ValueError(f"{law}: parameters of shapes {[a.shape for a in arrays]} have more axes "
                             f"than draws of shape {(trials,) + tuple(shape)}")
        padded = [parameter if parameter.ndim == 0 else
                  parameter.reshape(parameter.shape + (1,) * (axes - parameter.ndim))
                  for parameter in parameters]
        try:
            broadcast = np.broadcast_shapes(*(p.shape[1:] for p in padded if p.ndim > 0))
            if shape is not None:
                trial_shape = tuple(int(length) for length in shape)
                if np.broadcast_shapes(broadcast, trial_shape) != trial_shape:
                    raise ValueError
            else:
                trial_shape = broadcast
        except ValueError:
            wanted = f"draws of shape {(trials,) + tuple(shape)}" if shape is not None else "one shape"
            raise ValueError(f"{law}: parameters of shapes {[p.shape for p in parameters]} do not "
                             f"broadcast to {wanted}") from None
        return padded, trial_shape

    def _by_inverse_cdf(self, law: str, parameters: list[np.ndarray], shape) -> np.ndarray:
        """``count_draws: inverse_cdf``: each draw's uniforms from its trial's stream, turned into
        the law's variate by its branch-free inverse CDF (:func:`pfx.numerics.count_quantiles.inverse_cdf_law`)."""
        from pfx.numerics.count_quantiles import inverse_cdf_law

        per_draw, variate = inverse_cdf_law(law)
        parameters, trial_shape = self._aligned(law, parameters, shape)
        uniforms = np.moveaxis(self.uniform((per_draw,) + trial_shape), 1, 0)
        return np.asarray(variate(uniforms, *parameters), dtype=float)

    def _draw(self, law: str, parameters: list[np.ndarray], shape) -> np.ndarray:
        """Trial r's slice: one call of generator r's NumPy method ``law`` on trial r's parameters."""
        parameters, trial_shape = self._aligned(law, parameters, shape)
        out = np.empty((len(self.generators),) + trial_shape)
        for row, generator in enumerate(self.generators):
            own = [parameter if parameter.ndim == 0 else parameter[row if len(parameter) > 1 else 0]
                   for parameter in parameters]
            try:
                out[row] = getattr(generator, law)(*own, size=trial_shape)
            except ValueError as error:             # what the checks above do not foresee
                raise ValueError(f"{law}: {error}") from error
        return out


def _checked(rule: Rule, values: ArrayLike) -> np.ndarray:
    """``values`` as a float64 array, or a ValueError naming the law, the parameter and a bad
    value (the rule's, :mod:`pfx.numerics.parameter_checks`).

    Checked before any draw, so that a refused call leaves every generator where it was.
    """
    values = np.asarray(numbers(rule, values), dtype=float)
    refuse_unless_valid(rule, values)
    return values
