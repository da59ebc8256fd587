"""What ``pfx bench`` prints: the machine line, the tables, the goals."""

from __future__ import annotations

import math
import os
import platform
from typing import TYPE_CHECKING, Optional

import numpy as np

from pfx.bench.timing import Timing

if TYPE_CHECKING:
    from pfx.bench.algorithms import AlgorithmResult

GIB = 1024 ** 3


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_line() -> str:
    import numba

    threads = os.environ.get("OPENBLAS_NUM_THREADS", "default")
    return (f"machine: {cpu_model()}, {os.cpu_count()} cores, {platform.system()} {platform.release()}; "
            f"Python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__}, "
            f"BLAS threads {threads}")


def format_table(timings: list[Timing]) -> str:
    """One row per (case, implementation): ns per particle-step, ratio to pfx, altitude RMSE."""
    header = f"{'case':<16} {'implementation':<15} {'ns/particle-step':>16} {'x pfx':>7} {'altitude RMSE (ft)':>19} {'runs':>5}"
    lines = [header, "-" * len(header)]
    pfx_time = {t.case.label: t.seconds for t in timings if t.implementation == "pfx" and t.runs}
    previous = None
    for timing in timings:
        label = timing.case.label if timing.case.label != previous else ""
        previous = timing.case.label
        name = timing.implementation
        if timing.error:
            lines.append(f"{label:<16} {name:<15} failed: {timing.error}")
            continue
        ratio = timing.seconds / pfx_time[timing.case.label] if timing.case.label in pfx_time else float("nan")
        lines.append(f"{label:<16} {name:<15} {timing.ns_per_particle_step:>16.1f} {ratio:>7.2f} "
                     f"{timing.rmse:>19.1f} {timing.runs:>5}")
    notes = [_rmse_note(case) for case in _cases_whose_rmse_disagree(timings)]
    if notes:                         # under the table, after a blank line
        lines += ["", *notes]
    return "\n".join(lines)


# Two implementations' altitude RMSEs further apart than this factor get a note under the table.
RMSE_DISAGREEMENT = 2.0


def _cases_whose_rmse_disagree(timings: list[Timing]) -> list[str]:
    cases: dict[str, list[float]] = {}
    for timing in timings:
        if not timing.error and timing.runs and math.isfinite(timing.rmse) and timing.rmse > 0:
            cases.setdefault(timing.case.label, []).append(timing.rmse)
    return [case for case, values in cases.items() if max(values) > RMSE_DISAGREEMENT * min(values)]


def _rmse_note(case: str) -> str:
    return (f"({case}: the altitude RMSEs differ because each implementation draws its own random numbers, and "
            "with few particles one trial's filter may lose the falling body (at N = 100 about a quarter of the "
            "trials do, whatever the implementation). The column shows that every row ran the whole filter, not "
            "which is more accurate: `pfx run` over many trials compares accuracy.)")


ALGORITHM_WIDTH = 26


def format_algorithms(results: list["AlgorithmResult"]) -> str:
    """One row per algorithm: ns per particle-step (N the configured count, KLD's maximum),
    ratio of wall times to the bootstrap's, altitude RMSE, mean particles, runs; a row pfx
    refuses for this model reads "not applicable: <reason>"."""
    from pfx.bench.algorithms import BASELINE

    timed = [result.timing for result in results if result.timing is not None]
    case = timed[0].case if timed else None
    title = (f"algorithms against the bootstrap, {case.label}, T = {case.truth.shape[1]} (pfx's engine; the same "
             f"measurements and filter seeds in every row):" if case else "algorithms against the bootstrap:")
    header = (f"{'algorithm':<{ALGORITHM_WIDTH}} {'ns/particle-step':>16} {'x bootstrap':>11} "
              f"{'altitude RMSE (ft)':>19} {'mean particles':>14} {'runs':>5}")
    lines = [title, header, "-" * len(header)]
    baseline = next((result.timing for result in results if result.name == BASELINE), None)
    base_seconds = baseline.seconds if baseline is not None and baseline.runs and not baseline.error else None
    notes = []
    for result in results:
        name, timing = result.name, result.timing
        if timing is None:
            lines.append(f"{name:<{ALGORITHM_WIDTH}} not applicable: {result.not_applicable}")
            continue
        if timing.error or not timing.runs:
            lines.append(f"{name:<{ALGORITHM_WIDTH}} failed: {timing.error or 'not run'}")
            continue
        ratio = timing.seconds / base_seconds if base_seconds else float("nan")
        lines.append(f"{name:<{ALGORITHM_WIDTH}} {timing.ns_per_particle_step:>16.1f} {ratio:>11.2f} "
                     f"{timing.rmse:>19.1f} {result.mean_particles:>14.1f} {timing.runs:>5}")
        if result.injected is not None:
            notes.append(f"{name}: {result.injected} particles injected over all trials and steps"
                         + (" (the likelihood's fast average never fell far enough below its slow one: the row "
                            "times the bookkeeping of the averages)" if result.injected == 0 else ""))
    return "\n".join(lines + notes)


def _find(timings: list[Timing], particles: int, trials: int, name: str) -> Optional[Timing]:
    for timing in timings:
        if (timing.case.particles, timing.case.trials, timing.implementation) == (particles, trials, name) \
                and timing.runs and not timing.error:
            return timing
    return None


def _goal_line(value: Optional[float], limit: float, at_most: bool, text: str, missing: str) -> str:
    """'  TEXT: goal met (0.47 vs <= 1)', 'goal not met (...)', or 'not measured (why; goal <= 1)'."""
    goal = f"{'<=' if at_most else '>='} {limit:g}"
    if value is None:
        return f"  {text}: not measured ({missing + '; ' if missing else ''}goal {goal})"
    met = value <= limit if at_most else value >= limit
    return f"  {text}: {'goal met' if met else 'goal not met'} ({value:.2f} vs {goal})"


def format_small_filters(timings: list, overhead: Optional[dict]) -> str:
    """The small-filter table (:mod:`pfx.bench.small_filters`): ms per run, us per step, ratio to
    pfx, log-variance RMSE; and the Python entry point against the config path."""
    if not timings:
        return "small filters: not run"
    steps = len(timings[0].case.returns)
    title = (f"small filters: stochastic volatility written as a plugin (plain NumPy, no compiled step), one trial, "
             f"T = {steps}, bootstrap filter, systematic resampling every step:")
    header = f"{'case':<16} {'implementation':<18} {'ms/run':>8} {'us/step':>8} {'x pfx':>7} {'RMSE':>7} {'runs':>5}"
    lines = [title, header, "-" * len(header)]
    pfx_time = {t.case.label: t.seconds for t in timings if t.implementation == "pfx" and t.runs}
    previous = None
    for timing in timings:
        label = timing.case.label if timing.case.label != previous else ""
        previous = timing.case.label
        if timing.error:
            lines.append(f"{label:<16} {timing.implementation:<18} failed: {timing.error}")
            continue
        ratio = timing.seconds / pfx_time[timing.case.label] if timing.case.label in pfx_time else float("nan")
        rmse = f"{timing.rmse:>7.3f}" if np.isfinite(timing.rmse) else f"{'-':>7}"
        lines.append(f"{label:<16} {timing.implementation:<18} {timing.seconds * 1e3:>8.2f} "
                     f"{timing.seconds / steps * 1e6:>8.1f} {ratio:>7.2f} {rmse} {timing.runs:>5}")
    lines.append("(particles: its cheapest run, no collector, so no estimates to score; particles+moments: with "
                 "its Moments collector, the filtered means)")
    if overhead:
        lines.append(f"one falling-body filter, N={overhead['particles']}, 1 trial: through the Python entry point "
                     f"{overhead['python'] * 1e3:.2f} ms, through a config's planned cell {overhead['config'] * 1e3:.2f} "
                     f"ms (ratio {overhead['ratio']:.2f}; the one-off binding not counted)")
    return "\n".join(lines)


def format_goals(timings: list[Timing], workers: Optional[dict], memory: Optional[dict],
                 small: Optional[list] = None, overhead: Optional[dict] = None) -> str:
    """The benchmark's goals (from the issues that set them), as measured ratios; never asserted by a test."""
    def ratio(particles, trials, numerator, denominator):
        a, b = _find(timings, particles, trials, numerator), _find(timings, particles, trials, denominator)
        return a.seconds / b.seconds if a and b else None

    def small_ratio(particles, numerator, denominator):
        found = {t.implementation: t for t in small or [] if t.case.particles == particles and t.runs and not t.error}
        return found[numerator].seconds / found[denominator].seconds if {numerator, denominator} <= set(found) else None

    lines = ["goals (ratios of best wall times on this machine):"]
    lines.append(_goal_line(ratio(1_000, 1, "pfx", "numpy"), 1.0, True,
                            "N=1e3, 1 trial: pfx time / numpy reference time", "case not run"))
    lines.append(_goal_line(ratio(100_000, 1, "pfx", "numpy"), 0.5, True,
                            "N=1e5, 1 trial: pfx time / numpy reference time", "case not run"))
    lines.append(_goal_line(ratio(100_000, 1, "particles", "pfx"), 2.5, False,
                            "N=1e5, 1 trial: particles time / pfx time", "particles not installed or case not run"))
    lines.append(_goal_line(ratio(100, 1000, "particles", "pfx"), 10.0, False,
                            "1000 x N=100: particles.multiSMC time / pfx time",
                            "particles not installed or case not run"))
    lines.append(_goal_line(ratio(100, 1000, "numpy", "pfx"), 3.0, False,
                            "1000 x N=100: numpy reference loop time / pfx time", "case not run"))
    lines.append(_goal_line(workers["speedup"] if workers else None, 1.8, False,
                            "--workers 2 vs 1 on an 8-cell sweep: speed-up", "skipped"))
    measured = memory and memory.get("particles") == 1_000_000
    lines.append(_goal_line(memory["peak_rss"] / GIB if measured else None, 1.0, True,
                            "N=1e6, 1 trial: peak memory of the process (GiB)", "--quick or skipped"))
    lines.append(_goal_line(small_ratio(100, "pfx", "particles"), 1.0, True,
                            "plugin-style model, N=100, 1 trial: pfx time / particles time",
                            "particles not installed or case not run"))
    # the entry point runs the same engine: within the machine's noise of the config path
    lines.append(_goal_line(overhead["ratio"] if overhead else None, 1.05, True,
                            "one filter: Python entry point time / config path time", "skipped"))
    return "\n".join(lines)


PMMH_CASE_WIDTH = 22
PMMH_NAME_WIDTH = 20


def format_pmmh(timings: list, exact: Optional[dict] = None, load: Optional[tuple] = None) -> str:
    """The PMMH table (:mod:`pfx.bench.pmmh`): ms per iteration and per chain-iteration, particles'
    time per chain-iteration over the row's, filters run per chain-iteration, acceptance; per
    problem and N, the log-likelihood estimates at the start and where a pfx iteration goes; ``load``:
    the machine's 1-minute load average before and after the timing (PMMH's rounds are long)."""
    from pfx.bench.pmmh import CHAINS, STAGES, START_RUNS

    if not timings:
        return "pmmh: not run"
    first = timings[0]
    iterations = first.chain_iterations // max(first.rounds * first.chains, 1)
    title = (f"PMMH: milliseconds per iteration, bootstrap filter (systematic resampling when ESS < N/2), a fixed "
             f"random walk, {iterations} iterations per round after untimed ones, best of {first.rounds} rounds"
             + (f"; load average {load[0]:.2f} before, {load[1]:.2f} after" if load else "") + ":")
    header = (f"{'case':<{PMMH_CASE_WIDTH}} {'implementation':<{PMMH_NAME_WIDTH}} {'ms/iteration':>12} "
              f"{'ms/chain-iter':>13} {'particles/pfx':>13} {'filters/iter':>12} {'accepted':>8} {'rounds':>6}")
    lines = [title, header, "-" * len(header)]
    groups: dict[str, list] = {}
    for timing in timings:
        groups.setdefault(timing.label, []).append(timing)
    for label, rows in groups.items():
        peer = next((row for row in rows if row.implementation.startswith("particles") and row.rounds), None)
        for index, row in enumerate(rows):
            case = label if index == 0 else ""
            if row.error or not row.rounds:
                lines.append(f"{case:<{PMMH_CASE_WIDTH}} {row.implementation:<{PMMH_NAME_WIDTH}} "
                             f"failed: {row.error or 'not run'}")
                continue
            ratio = peer.per_chain_iteration / row.per_chain_iteration if peer else float("nan")
            lines.append(f"{case:<{PMMH_CASE_WIDTH}} {row.implementation:<{PMMH_NAME_WIDTH}} "
                         f"{row.seconds * 1e3:>12.2f} {row.per_chain_iteration * 1e3:>13.3f} {ratio:>13.2f} "
                         f"{row.filters_per_chain_iteration:>12.2f} {row.acceptance:>8.2f} {row.rounds:>6}")
        if peer is None:
            lines.append(f"{'':<{PMMH_CASE_WIDTH}} particles: not installed or not run (--no-peers)")
        by_name = {row.implementation: row for row in rows if row.rounds and not row.error}
        speeds = [f"{label} {by_name['pfx, ' + label].per_chain_iteration / by_name['pfx jax, ' + label].per_chain_iteration:.2f}x"
                  for label in ("1 chain", f"{CHAINS} chains")
                  if f"pfx, {label}" in by_name and f"pfx jax, {label}" in by_name]
        if speeds:
            per_second = ", ".join(f"{row.implementation} {1.0 / row.per_chain_iteration:.0f}"
                                   for row in by_name.values() if row.implementation.startswith("pfx"))
            lines.append(f"  jax over numpy, chain-iterations per second: {', '.join(speeds)} ({per_second})")
        estimates = [(row.implementation.split(",")[0], row.start_log_likelihoods) for row in rows
                     if row.start_log_likelihoods is not None and len(row.start_log_likelihoods) == START_RUNS]
        if estimates:
            parts = [f"{name} {np.mean(values):.2f} +- {np.std(values, ddof=1) / np.sqrt(len(values)):.2f} "
                     f"(sd {np.std(values, ddof=1):.2f})" for name, values in estimates]
            known = (exact or {}).get(rows[0].problem.name)
            lines.append(f"  log-likelihood estimates at the start, {START_RUNS} filters each: " + ", ".join(parts)
                         + (f"; exact (Kalman) {known:.2f}" if known is not None else ""))
        for row in rows:
            if row.stages and row.rounds:
                stages = ", ".join(f"{name} {row.stages[name] * 1e3:.2f}" for name in STAGES)
                lines.append(f"  where a pfx iteration goes, {row.implementation} (ms): {stages}")
    lines.append(f"(particles' PMMH runs one chain per sampler: {CHAINS} of its chains cost {CHAINS} times one chain's "
                 "time; particles/pfx divides its ms per chain-iteration by the row's)")
    return "\n".join(lines)


PMMH_GOAL = 20.0        # issue: 16 chains x N = 1000 on a GPU, 20 x numpy's chain-iterations per second on one core


def format_pmmh_goal(timings: list, machine: str) -> str:
    """The compiled chains' goal: pfx jax with 16 chains over pfx numpy with 1 chain (one core),
    in chain-iterations per second, for each case the table holds."""
    from pfx.bench.pmmh import CHAINS

    lines = []
    groups: dict[str, dict] = {}
    for row in timings:
        if row.rounds and not row.error:
            groups.setdefault(row.label, {})[row.implementation] = row
    for label, rows in groups.items():
        numpy_row, jax_row = rows.get("pfx, 1 chain"), rows.get(f"pfx jax, {CHAINS} chains")
        if numpy_row is None or jax_row is None:
            continue
        ratio = numpy_row.per_chain_iteration / jax_row.per_chain_iteration
        lines.append(f"goal, PMMH {label}: pfx jax with {CHAINS} chains {1 / jax_row.per_chain_iteration:.0f} "
                     f"chain-iterations/s = {ratio:.1f} x pfx numpy with 1 chain on one core "
                     f"({1 / numpy_row.per_chain_iteration:.0f}/s); goal {PMMH_GOAL:.0f} x on a GPU: "
                     f"{'met' if ratio >= PMMH_GOAL else 'not met'} ({machine})")
    return "\n".join(lines) if lines else "goal, PMMH: not measured (a row failed or JAX is missing)"
