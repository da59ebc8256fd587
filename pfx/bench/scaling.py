"""Local parallelism and memory, measured the way a user meets them.

* :func:`workers_speedup`: the same sweep of 8 cells run by :func:`pfx.run.runner.run_plan` into
  a temporary folder with ``workers=1`` and ``workers=2`` (best of ``repeats`` each,
  interleaved); the speed-up is the ratio of the wall times, CSV writing included (figures
  off, so that the serial rendering at the end does not hide the parallel part). The CPU
  time of each run (this process and its workers) is reported beside it: equal CPU times
  with a poor speed-up mean that the machine's cores were busy with other work.
* :func:`bytes_per_particle`: tracemalloc's peak over one trial of the engine, per particle
  (NumPy's allocations: the particle arrays and their temporaries).
* :func:`peak_rss`: the peak resident memory of a fresh process that runs one trial of N
  particles (interpreter, libraries and compiled code included): what "fits in 1 GiB" means.
"""

from __future__ import annotations

import copy
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

from pfx.bench.problem import CONFIG, make_case
from pfx.bench.timing import run_pfx
from pfx.config.plan import build_plan

SWEEP_CELLS = 8


def sweep_config(particles: int, trials: int) -> dict:
    """The bench problem as an 8-cell sweep (particle counts N, N + N/8, ..., N + 7N/8)."""
    raw = copy.deepcopy(CONFIG)
    raw.update(name="bench-workers", trials=trials)
    raw["filter"]["particles"] = particles
    raw["sweep"] = {"filter.particles": [particles + i * particles // SWEEP_CELLS for i in range(SWEEP_CELLS)]}
    return raw


def workers_speedup(particles: int, trials: int, repeats: int = 2) -> dict:
    """Wall time of the sweep with 1 and with 2 worker processes; see the module docstring."""
    from pfx.run.runner import run_plan

    plan = build_plan(sweep_config(particles, trials), "<pfx bench>")
    best = {1: float("inf"), 2: float("inf")}
    cpu = {1: float("inf"), 2: float("inf")}
    with tempfile.TemporaryDirectory(prefix="pfx-bench-") as folder:
        for repeat in range(repeats):
            for workers in ((1, 2) if repeat % 2 == 0 else (2, 1)):
                started, cpu_started = time.perf_counter(), _cpu_seconds()
                run_plan(plan, Path(folder) / f"workers-{workers}-{repeat}", workers=workers, fresh=True)
                elapsed = time.perf_counter() - started
                if elapsed < best[workers]:
                    best[workers], cpu[workers] = elapsed, _cpu_seconds() - cpu_started
    return {"cells": len(plan.cells), "trials": trials, "one": best[1], "two": best[2],
            "cpu_one": cpu[1], "cpu_two": cpu[2], "speedup": best[1] / best[2]}


def _cpu_seconds() -> float:
    """CPU time of this process and of its finished children (the worker processes)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def bytes_per_particle(particles: int) -> float:
    case = make_case(particles, 1)
    tracemalloc.start()
    try:
        run_pfx(None, case)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / particles


def peak_rss(particles: int) -> int:
    """Peak resident bytes of a fresh Python process running one trial of N particles."""
    code = ("import resource, numpy\n"
            "from pfx.run.memory import keep_freed_memory\n"
            "keep_freed_memory()\n"
            "from pfx.bench.problem import make_case\n"
            "from pfx.bench.timing import run_pfx\n"
            f"run_pfx(None, make_case({int(particles)}, 1))\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ),
                          timeout=600, check=True)
    return int(done.stdout.split()[-1]) * 1024          # ru_maxrss is in KiB on Linux
