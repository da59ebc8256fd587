"""What ``pfx bench`` prints: the machine line, the table, the goals."""

from __future__ import annotations

import os
import platform
from typing import Optional

import numpy as np

from pfx.bench.timing import Timing

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
    return "\n".join(lines)


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


def format_goals(timings: list[Timing], workers: Optional[dict], memory: Optional[dict]) -> str:
    """The benchmark's goals (from the issue that set them), as measured ratios; never asserted by a test."""
    def ratio(particles, trials, numerator, denominator):
        a, b = _find(timings, particles, trials, numerator), _find(timings, particles, trials, denominator)
        return a.seconds / b.seconds if a and b else None

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
    return "\n".join(lines)
