"""Timing: every implementation on the same case, interleaved, best of several repeats.

Implementations: ``pfx`` (the engine, exactly as ``pfx run`` calls it for a batch of trials),
``numpy`` (the reference filter of :mod:`pfx.bench.reference`, looped over the trials) and
the peers of :mod:`pfx.bench.peers` that can be imported. Within a repeat each runs once, in
an order that rotates from repeat to repeat, so that a slow phase of a shared machine does
not fall on one implementation only; the best time counts. An implementation whose runs
have taken ``budget`` seconds in a case is not repeated there (the slow peers at N = 1e6).
The estimates of the last run give its altitude RMSE, which shows that all did the same work.

:func:`time_case` takes the runners by name (default :data:`RUNNERS`, the implementations
above); :mod:`pfx.bench.algorithms` passes pfx's engine with one filter setting per name.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Callable, Mapping, Optional

import numpy as np

from pfx.bench.peers import ADAPTERS
from pfx.bench.problem import Case, FallingBodyProblem
from pfx.bench.reference import reference_filter
from pfx.filtering import Filter
from pfx.filters.trace import FilterTrace


def run_filter(bound: Filter, case: Case) -> FilterTrace:
    """pfx's filter, bound once, on the case's measurements, one stream per trial from the
    case's filter seeds: the engine as ``pfx run`` calls it for a batch of trials."""
    return bound(case.measurements, seeds=case.filter_seeds).trace


def run_pfx(problem: FallingBodyProblem, case: Case) -> np.ndarray:
    return run_filter(case.filter, case).estimates


def run_numpy(problem: FallingBodyProblem, case: Case) -> np.ndarray:
    return np.stack([reference_filter(problem, case.measurements[r], case.particles,
                                      np.random.default_rng(case.filter_seeds[r])) for r in range(case.trials)])


Runner = Callable[[FallingBodyProblem, Case], np.ndarray]     # the estimates, (R, T, 3)
RUNNERS: dict[str, Runner] = {"pfx": run_pfx, "numpy": run_numpy, **ADAPTERS}


@dataclass
class Timing:
    case: Case
    implementation: str
    seconds: float = float("inf")     # best run
    runs: int = 0
    spent: float = 0.0
    rmse: float = float("nan")
    error: Optional[str] = None

    @property
    def ns_per_particle_step(self) -> float:
        return self.seconds * 1e9 / self.case.particle_steps


def time_case(case: Case, implementations: list[str], repeats: int, budget: float,
              progress: Callable[[str], None] = lambda message: None,
              runners: Mapping[str, Runner] = RUNNERS) -> list[Timing]:
    """Best-of-``repeats`` wall time of each implementation on ``case`` (see the module docstring)."""
    problem = FallingBodyProblem.from_filter(case.filter)
    timings = {name: Timing(case, name) for name in implementations}
    for repeat in range(repeats):
        shift = repeat % len(implementations)
        for name in implementations[shift:] + implementations[:shift]:
            timing = timings[name]
            if timing.error or (timing.runs and timing.spent >= budget):
                continue
            progress(f"{case.label}: {name} (run {timing.runs + 1})")
            started = time.perf_counter()
            try:
                # A peer's underflowing weights (and NumPy's warnings about them) are its own business.
                with np.errstate(all="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    estimates = runners[name](problem, case)
            except Exception as error:               # a peer that breaks is reported, not fatal
                timing.error = f"{type(error).__name__}: {error}".splitlines()[0][:80]
                continue
            elapsed = time.perf_counter() - started
            timing.runs += 1
            timing.spent += elapsed
            timing.seconds = min(timing.seconds, elapsed)
            timing.rmse = case.altitude_rmse(estimates)
    return [timings[name] for name in implementations]
