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
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

TRUTH_ROLE = 0
FILTER_ROLE = 1
STUDY_ROLE = 2


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


def study_generator(root_seed: int) -> np.random.Generator:
    """The one generator a study (:mod:`pfx.studies`) draws from."""
    return np.random.default_rng(stream_seed(root_seed, STUDY_ROLE, 0))


class TrialStreams:
    """One generator per trial; batched draws of shape ``(trials, *shape)``.

    Slice ``r`` of every array returned comes from generator ``r`` alone, in the order the
    calls are made, so results do not depend on how trials are grouped into batches. Normal
    and uniform draws of PCG64 generators (all of pfx's own) are made by compiled loops that
    step every trial's generator in place, in one call for the batch
    (:mod:`pfx.numerics.pcg64`, :mod:`pfx.numerics.ziggurat`); other draws, and other
    generators, by NumPy trial by trial. Either way the numbers are NumPy's.
    """

    def __init__(self, generators: Sequence[np.random.Generator], *, addresses=None):
        self.generators = list(generators)
        # The generators' PCG64 state addresses for the compiled loops: found on the first
        # draw (that imports numba), None if some generator is not a PCG64.
        self._addresses = addresses
        self._addresses_known = addresses is not None

    def __getstate__(self) -> dict:
        # The addresses are this process's memory of these very generators: a copy (pickled to
        # another process, or deep-copied with new generators) finds its own.
        return {"generators": self.generators, "_addresses": None, "_addresses_known": False}

    @classmethod
    def from_seeds(cls, seeds: Sequence[int]) -> "TrialStreams":
        return cls([np.random.default_rng(int(seed)) for seed in seeds])

    def __len__(self) -> int:
        return len(self.generators)

    def subset(self, trial_indices) -> "TrialStreams":
        """The streams of the given trials (positions in this batch): the same generators."""
        trial_indices = np.asarray(trial_indices, dtype=np.intp)
        addresses = self._addresses[trial_indices] if self._addresses_known and self._addresses is not None \
            else None
        return TrialStreams([self.generators[i] for i in trial_indices.tolist()], addresses=addresses)

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
