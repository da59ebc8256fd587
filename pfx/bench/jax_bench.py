"""``pfx bench --backend jax``: pfx's two backends beside a plain JAX filter, on the bench's falling body.

Each case (trials x N, T = 100; :data:`CASES`, ``--quick``: :data:`QUICK_CASES`) runs, on the
same measurements and filter seeds:

* ``pfx numpy``: pfx's numpy backend in this one process, through the Python door
  (:func:`pfx.filtering.particle_filter`), as ``pfx run`` runs a batch. It runs at most
  :data:`NUMPY_PARTICLES_PER_STEP` particles a step: a larger case runs the first trials only
  (the row says how many), since its cost per particle-step no longer changes with the count;
* ``pfx jax float64`` and ``pfx jax float32``: the same door with ``backend="jax"`` and the
  precision. Where this pfx has no jax backend (or refuses the settings) the row reads
  "not available: <why>";
* ``jax reference float64`` and ``float32``: the plain JAX filter of :mod:`pfx.bench.jax_reference`.

A JAX row is called once untimed first (it compiles for the case's shapes: the "first call"
column), then timed ``repeats`` times, interleaved with the other rows and stopped once its runs
have taken ``budget`` seconds; the best run counts. Each row prints particle-steps per second,
ns per particle-step, the fraction of the device's memory-bandwidth limit
(:mod:`pfx.bench.jax_device`), the altitude RMSE and the mean log-likelihood (equal work), and
pfx jax's rate over the reference's. A row is skipped, and says why, where its arrays would not
fit in the device's memory or one run would take longer than ``3 x budget`` seconds (predicted
from its rate in the smaller cases before it). Timings are never asserted by a test.
"""

from __future__ import annotations

import importlib.util
import time
import warnings
from dataclasses import dataclass, replace
from typing import Callable, Optional

import numpy as np

from pfx.bench.jax_device import Device, working_set_bytes
from pfx.bench.problem import STEPS, Case, FallingBodyProblem, bench_filter

# (N, trials), in the order of their particles a step (trials x N): each case's predicted times
# come from the cases before it.
CASES = [(1_000, 1), (100, 1_000), (100_000, 1), (1_000_000, 1), (10_000, 1_000), (100_000, 1_000)]
QUICK_CASES = CASES[:2]
NUMPY_PARTICLES_PER_STEP = 1_000_000
RUN_LIMIT_BUDGETS = 3          # a run predicted to take more than this many budgets is skipped
MISSING_JAX = "pfx bench --backend jax needs JAX, which is not installed: pip install 'pfx[jax]'"

Outcome = tuple[np.ndarray, np.ndarray]          # estimates (R, T, 3), log-likelihoods (R,)


@dataclass(frozen=True)
class Implementation:
    """One row of each case: ``kind`` "pfx" (pfx's door on ``backend``) or "reference" (the plain JAX filter)."""

    name: str
    kind: str
    backend: str
    precision: str

    @property
    def on_device(self) -> bool:
        """Runs on JAX's device (and compiles for each shape), not with NumPy on the CPU."""
        return self.backend == "jax"


IMPLEMENTATIONS = [
    Implementation("pfx numpy", "pfx", "numpy", "float64"),
    Implementation("pfx jax float64", "pfx", "jax", "float64"),
    Implementation("pfx jax float32", "pfx", "jax", "float32"),
    Implementation("jax reference float64", "reference", "jax", "float64"),
    Implementation("jax reference float32", "reference", "jax", "float32"),
]


@dataclass
class Row:
    """One implementation's timing on one case (``trials`` of the case's trials run)."""

    case: Case
    implementation: Implementation
    trials: int
    seconds: float = float("inf")          # best timed run
    first_call: float = float("nan")       # the untimed first call (compilation included)
    runs: int = 0
    spent: float = 0.0
    rmse: float = float("nan")
    log_likelihood: float = float("nan")   # mean over the trials run
    note: Optional[str] = None             # "not available: ...", "skipped: ...", "failed: ..."

    @property
    def particle_steps(self) -> int:
        return self.trials * self.case.particles * STEPS

    @property
    def rate(self) -> float:
        """Particle-steps per second of the best run."""
        return self.particle_steps / self.seconds if self.runs else float("nan")


def jax_missing() -> Optional[str]:
    """The one line to print where JAX is not installed, else None."""
    return MISSING_JAX if importlib.util.find_spec("jax") is None else None


def prepare(implementation: Implementation, case: Case) -> Callable[[], Outcome]:
    """The call that runs ``implementation`` on ``case`` (raises where pfx refuses its settings)."""
    if implementation.kind == "reference":
        from pfx.bench.jax_reference import jax_reference_filter

        problem = FallingBodyProblem.from_filter(case.filter)
        return lambda: jax_reference_filter(problem, case.measurements, case.particles, case.filter_seeds,
                                            implementation.precision)
    settings = {} if implementation.backend == "numpy" else {"backend": implementation.backend,
                                                             "precision": implementation.precision}
    bound = bench_filter(case.particles, settings)

    def run() -> Outcome:
        result = bound(case.measurements, seeds=case.filter_seeds)
        return np.asarray(result.estimates), np.asarray(result.log_likelihood)
    return run


def first_line(error: BaseException) -> str:
    return (f"{type(error).__name__}: {error}".splitlines() or [type(error).__name__])[0][:160]


def time_jax_case(case: Case, implementations: list[Implementation], device: Device, repeats: int, budget: float,
                  seconds_per_step: dict, progress: Callable[[str], None] = lambda message: None) -> list[Row]:
    """Every implementation on ``case`` (module docstring). ``seconds_per_step`` holds each
    implementation's seconds per particle-step in the cases before (read for the predictions, updated)."""
    rows, calls = [], {}
    for implementation in implementations:
        trials = case.trials
        if not implementation.on_device:
            trials = max(1, min(case.trials, NUMPY_PARTICLES_PER_STEP // case.particles))
        row = Row(case, implementation, trials)
        rows.append(row)
        row.note = _reason_to_skip(row, device, budget, seconds_per_step.get(implementation.name))
        if row.note:
            continue
        sub_case = case if trials == case.trials else _first_trials(case, trials)
        try:
            calls[implementation.name] = prepare(implementation, sub_case)
        except Exception as error:
            row.note = f"not available: {first_line(error)}"
            continue
        if implementation.on_device:
            progress(f"{case.label}: {implementation.name} (first call: compiles)")
            started = time.perf_counter()
            if _call(row, calls[implementation.name]) is not None:
                row.first_call = time.perf_counter() - started
                progress(f"{case.label}: {implementation.name} first call {row.first_call:.3g} s")

    live = [row for row in rows if not row.note]
    for repeat in range(repeats):
        shift = repeat % max(len(live), 1)
        for row in live[shift:] + live[:shift]:
            if row.note or (row.runs and row.spent >= budget):
                continue
            progress(f"{case.label}: {row.implementation.name} (run {row.runs + 1})")
            started = time.perf_counter()
            outcome = _call(row, calls[row.implementation.name])
            if outcome is None:
                continue
            elapsed = time.perf_counter() - started
            row.runs += 1
            row.spent += elapsed
            row.seconds = min(row.seconds, elapsed)
            # the numbers as they come, so that a run stopped before its table still reports them
            progress(f"{case.label}: {row.implementation.name} run {row.runs}: {elapsed:.3g} s, "
                     f"{elapsed / row.particle_steps * 1e9:.3g} ns per particle-step")
            estimates, log_likelihoods = outcome
            row.rmse = float(np.sqrt(np.mean((estimates[..., 0] - case.truth[:row.trials, :, 0]) ** 2)))
            row.log_likelihood = float(np.mean(log_likelihoods))
    for row in rows:
        if row.runs:
            seconds_per_step[row.implementation.name] = row.seconds / row.particle_steps
    return rows


def _reason_to_skip(row: Row, device: Device, budget: float, seconds_per_step: Optional[float]) -> Optional[str]:
    implementation = row.implementation
    if implementation.on_device and device.memory:
        needed = working_set_bytes(row.trials * row.case.particles, implementation.precision)
        if needed > 0.9 * device.memory:
            return (f"skipped: needs about {needed / 1024 ** 3:.0f} GiB, the device has {device.memory / 1024 ** 3:.0f}"
                    " GiB")
    if seconds_per_step is not None and seconds_per_step * row.particle_steps > RUN_LIMIT_BUDGETS * budget:
        return (f"skipped: one run would take about {seconds_per_step * row.particle_steps:.0f} s (more than "
                f"{RUN_LIMIT_BUDGETS} x --budget)")
    return None


def _call(row: Row, call: Callable[[], Outcome]) -> Optional[Outcome]:
    """The call's outcome, or None with the row's note saying how it failed (the other rows go on)."""
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return call()
    except Exception as error:
        row.note = f"failed: {first_line(error)}"
        return None


def _first_trials(case: Case, trials: int) -> Case:
    return replace(case, trials=trials, truth=case.truth[:trials], measurements=case.measurements[:trials],
                   filter_seeds=case.filter_seeds[:trials])
