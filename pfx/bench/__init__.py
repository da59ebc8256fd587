"""``pfx bench``: pfx against a plain NumPy filter and the Python particle-filter libraries.

The problem (:mod:`pfx.bench.problem`) is the falling-body bootstrap filter with systematic
resampling at every step, T = 100, on measurements simulated once per trial and shared by
every implementation. :mod:`pfx.bench.timing` times pfx, the reference filter
(:mod:`pfx.bench.reference`) and each importable peer (:mod:`pfx.bench.peers`) in this one
process, interleaved, best of several repeats, and reports nanoseconds per particle-step
(wall time / (trials x N x T)) with the altitude RMSE that shows equal work;
:mod:`pfx.bench.algorithms` times pfx's other particle algorithms (guided proposals, the
auxiliary filter, moves, KLD-sampling, injection) against its bootstrap filter on one case;
:mod:`pfx.bench.small_filters` times one trial of a plugin-style model (no compiled step), where
the engine's fixed cost per step counts, against ``particles`` and a NumPy loop, and the Python
entry point against the config path; :mod:`pfx.bench.pmmh` times an iteration of particle
marginal Metropolis-Hastings (1 chain, and 16 chains as one batch) against ``particles``' PMMH;
:mod:`pfx.bench.scaling` measures ``--workers 2`` against 1 and the memory per particle;
:mod:`pfx.bench.report` prints it all with the machine line and the goals as ratios.
While it runs, one progress line per case and implementation (and per repeat) goes to
stderr, unless the caller's ``progress`` drops them (``pfx bench --quiet``, or CI).

``pfx bench --backend jax`` (:func:`run_jax_bench`) is the GPU's benchmark instead: pfx's numpy
and jax backends beside a plain JAX filter (:mod:`pfx.bench.jax_reference`), timed by
:mod:`pfx.bench.jax_bench`, measured against the device's memory-bandwidth limit
(:mod:`pfx.bench.jax_device`) and printed by :mod:`pfx.bench.jax_report`.

Speed is measured here and only here: no test asserts a timing.
"""

from __future__ import annotations

import os
import time
from typing import Callable, Optional

from pfx.bench.peers import PEERS, peer_version

FULL_CASES = [(1_000, 1), (10_000, 1), (100_000, 1), (1_000_000, 1), (100, 1000), (1_000, 100)]
QUICK_CASES = [(100, 1), (1_000, 1), (50, 20)]


def run_bench(*, quick: bool = False, repeats: int = 3, budget: float = 20.0, peers: bool = True,
              workers: bool = True, memory: bool = True, algorithms: bool = True, pmmh: bool = True, echo: Callable[[str], None] = print,
              progress: Callable[[str], None] = lambda message: None) -> None:
    from pfx.bench import report, scaling
    from pfx.bench.problem import STEPS, make_case
    from pfx.bench.timing import run_pfx, time_case
    from pfx.bench.warm_up import warm_up
    from pfx.run.memory import keep_freed_memory

    allocator = keep_freed_memory()       # the same allocator for every implementation timed here
    echo(f"pfx bench: falling body (Simon, feet, Euler dt = 0.1 s), bootstrap filter, systematic "
         f"resampling every step, T = {STEPS}{' (--quick sizes)' if quick else ''}")
    echo(report.machine_line())
    ready = warm_up()
    started = time.perf_counter()
    run_pfx(None, make_case(20, 2))       # compiles (or loads) what the engine calls, before any timing
    ready["seconds"] += time.perf_counter() - started
    echo(f"numba: compiled loops ready in {ready['seconds']:.2f} s ({ready['loaded']} loaded from the cache, "
         f"{ready['compiled']} compiled); allocator: "
         f"{'glibc keeps freed memory (mallopt)' if allocator else 'default'}")
    implementations = ["pfx", "numpy"]
    versions = {name: peer_version(name) for name in PEERS} if peers else {}
    implementations += [name for name, version in versions.items() if version]
    if peers:
        echo("peers: " + ", ".join(f"{name} {version}" if version else f"{name} (not installed)"
                                   for name, version in versions.items()))
    else:
        echo("peers: not run (--no-peers)")
    echo("")

    timings = []
    for particles, trials in (QUICK_CASES if quick else FULL_CASES):
        case = make_case(particles, trials)
        timings += time_case(case, implementations, repeats, budget, progress)
    echo(report.format_table(timings))
    echo("")

    if algorithms:
        from pfx.bench.algorithms import run_algorithms

        echo(report.format_algorithms(run_algorithms(quick=quick, repeats=repeats, budget=budget,
                                                     progress=progress)))
        echo("")

    from pfx.bench.small_filters import entry_point_overhead, time_small_filters

    progress("small filters: a plugin-style model, one trial")
    small = time_small_filters(quick=quick, repeats=repeats if quick else max(repeats, 5), peers=peers,
                               progress=progress)
    overhead = entry_point_overhead(particles=100 if quick else 1_000, repeats=3 if quick else 20)
    echo(report.format_small_filters(small, overhead))
    echo("")

    if pmmh:
        from pfx.bench import pmmh as pmmh_case

        if pmmh_case.examples_found():
            progress("pmmh: the stochastic-volatility and Nile problems")
            load_before = os.getloadavg()[0]
            timings_pmmh = pmmh_case.time_pmmh(quick=quick, repeats=repeats if quick else max(repeats, 5), peers=peers,
                                               progress=progress)
            load = (load_before, os.getloadavg()[0])
            exact = {problem: pmmh_case.exact_start_log_likelihood(make()) for problem, make in pmmh_case.PROBLEMS.items()}
            echo(report.format_pmmh(timings_pmmh, exact, load))
        else:
            echo(f"pmmh: not run (its problems read {pmmh_case.EXAMPLES}, which this installation lacks: run "
                 "pfx bench from a source tree)")
        echo("")

    memory_result = None
    if memory:
        particles = 10_000 if quick else 1_000_000
        progress(f"memory: N={particles}")
        per_particle = scaling.bytes_per_particle(particles)
        rss = scaling.peak_rss(particles)
        memory_result = {"particles": particles, "bytes_per_particle": per_particle, "peak_rss": rss}
        echo(f"memory, N={particles}, 1 trial: {per_particle:.0f} bytes per particle (tracemalloc peak of the "
             f"engine's arrays); peak resident memory of the process {rss / 1024**2:.0f} MiB")
    workers_result = None
    if workers:
        # --quick: each worker count up to --repeats times (--repeats 1, a smoke run: once each; a
        # pool of 2 workers starts fresh processes, seconds of imports where JAX is loaded)
        particles, trials, rounds = (50, 2, min(repeats, 2)) if quick else (2_000, 24, 2)
        progress("workers: --workers 1 and 2")
        workers_result = scaling.workers_speedup(particles, trials, rounds)
        echo(f"workers, sweep of {workers_result['cells']} cells x {trials} trials (N = {particles}..): "
             f"1 worker {workers_result['one']:.2f} s ({workers_result['cpu_one']:.2f} s CPU), 2 workers "
             f"{workers_result['two']:.2f} s ({workers_result['cpu_two']:.2f} s CPU), "
             f"speed-up {workers_result['speedup']:.2f}")
    echo("")
    echo(report.format_goals(timings, workers_result, memory_result, small, overhead))
    echo("Wall times; on a machine shared with other work they vary from run to run (best of "
         f"up to {repeats} runs, interleaved).")


def run_jax_bench(*, quick: bool = False, repeats: int = 3, budget: float = 20.0, bandwidth: Optional[float] = None,
                  cases: Optional[list[tuple[int, int]]] = None,
                  implementations: Optional[list] = None, pmmh: bool = True, echo: Callable[[str], None] = print,
                  progress: Callable[[str], None] = lambda message: None) -> list:
    """``pfx bench --backend jax`` (:mod:`pfx.bench.jax_bench`): the cases (``cases``, (N, trials)
    pairs, else its CASES or QUICK_CASES) and the implementations (default: all five rows), the
    machine line, the table and the goals printed; then (``pmmh``) PMMH on the stochastic-volatility
    model, N = 1000, numpy against jax, with the chain-iterations goal; returns the rows."""
    from pfx.bench import report
    from pfx.bench.jax_bench import CASES, IMPLEMENTATIONS, QUICK_CASES, time_jax_case
    from pfx.bench.jax_device import jax_device, machine_line
    from pfx.bench.jax_report import format_jax_goals, format_jax_table
    from pfx.bench.problem import STEPS, make_case
    from pfx.bench.timing import run_pfx

    device = jax_device(bandwidth)
    cases = cases or (QUICK_CASES if quick else CASES)
    implementations = implementations or IMPLEMENTATIONS
    echo(f"pfx bench --backend jax: falling body, bootstrap filter, systematic resampling every step, T = {STEPS}"
         f"{' (--quick sizes)' if quick else ''}")
    echo(machine_line(device) + ("" if device.is_gpu else "; no GPU: JAX runs on the CPU"))
    run_pfx(None, make_case(20, 2))       # numba compiles (or loads) the numpy backend's loops before any timing
    rows, seconds_per_step = [], {}
    for particles, trials in cases:
        rows += time_jax_case(make_case(particles, trials), implementations, device, repeats, budget,
                              seconds_per_step, progress)
    echo("")
    echo(format_jax_table(rows, device))
    echo("")
    echo(format_jax_goals(rows, device))
    echo(f"Wall times, best of up to {repeats} runs after an untimed first call (JAX rows), interleaved; on a "
         "machine shared with other work they vary from run to run.")
    if pmmh:
        from pfx.bench import pmmh as pmmh_case

        if pmmh_case.examples_found():       # PMMH's chains compiled on the device, against numpy on one core
            echo("")
            progress("pmmh: the stochastic-volatility problem, numpy and jax")
            timings = pmmh_case.time_pmmh(quick=quick, repeats=repeats, peers=False, progress=progress,
                                          problems=("sv",), sizes=pmmh_case.QUICK_SIZES if quick else (1_000,))
            echo(report.format_pmmh(timings))
            echo(report.format_pmmh_goal(timings, machine_line(device)))
    return rows
