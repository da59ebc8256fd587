"""Time pfx beside pypomp on pomp's two models, back to back in one session on one machine.

The pomp models' speed goal (docs/benchmarks/measles-london.md, "Time per run") is pfx's wall
time per likelihood evaluation at most pypomp's, on the same machine in the same session, for
He et al.'s measles (N = 2000) and King et al.'s cholera (N = 1000 and 5000). Load on a shared
machine moves both by tens of percent from one hour to the next, so the two are timed here one
after the other, in one command:

1. pypomp's reference scripts (``measles_pypomp_reference.py``, ``dacca_pypomp_reference.py``),
   run by the Python of an environment that has pypomp 1.1.0 (``--pypomp-python``): the median
   time of ``--replicates`` filter runs after a warm-up run that compiles (with
   ``--pypomp-batch B``, of calls of B runs side by side, over B: a GPU's way);
2. ``pfx run`` on the benchmarks' configs (numpy backend) with ``--trials`` runs in one batch
   (pfx's usual way: a cell's trials are rows of one batch, and the time per run is the batch's
   wall time divided by the runs) and with one run alone;
3. for the models named after ``--jax``, pfx's jax backend too, in the precision of
   ``--jax-precision`` (float32 by default, the precision pypomp computes in), timed two ways:
   the batch of ``--trials`` runs with its compilation included (shared by the batch's runs, as
   a ``pfx run`` pays it), and the time a run adds to a batch once compiled, comparable to
   pypomp's time, which leaves its compilation out: the difference between a batch of
   3 x ``--trials`` runs and one of ``--trials``, divided by the 2 x ``--trials`` runs between them.

It prints one Markdown table, seconds per run and the ratio to pypomp (and, for the jax
backend, replicates per second once compiled: one over a run's added time), with the machine
(CPUs, load average, JAX's devices) before and after. From the repository's root:

    python examples/benchmarks/pomp_speed_session.py --pypomp-python /path/to/pypomp-env/bin/python --jax cholera

Without ``--pypomp-python`` it times pfx alone. ``make gpu-check`` runs it on a GPU with
``--no-numpy --models measles cholera --jax measles cholera --trials 16``, and with pypomp's
calls of 64 replicates side by side (``--pypomp-batch 64``) where pypomp imports, for the
replicates per second there.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd

from pfx.papers.base import markdown_table

REPOSITORY = Path(__file__).resolve().parents[2]
BENCHMARKS = REPOSITORY / "configs" / "benchmarks"
CASES = {   # model: (pypomp script, pfx config, particle counts)
    "measles": ("measles_pypomp_reference.py", BENCHMARKS / "measles-london" / "measles.yaml", [2000]),
    "cholera": ("dacca_pypomp_reference.py", BENCHMARKS / "dacca-cholera" / "dacca.yaml", [1000, 5000]),
}


def pypomp_seconds(python: str, script: str, particles: list[int], replicates: int, batch: int) -> dict[int, float]:
    """The median seconds per run of pypomp's reference script at each N (its JSON lines), ``batch``
    runs per pfilter call; {} with a line saying why where pypomp failed (pfx's rows still come)."""
    command = [python, str(REPOSITORY / "examples" / "benchmarks" / script), "--particles",
               *map(str, particles), "--replicates", str(replicates), "--batch", str(batch)]
    finished = subprocess.run(command, capture_output=True, text=True)
    if finished.returncode != 0:
        last = (finished.stderr.strip().splitlines() or ["no output"])[-1]
        print(f"pypomp's {script} failed (exit {finished.returncode}): {last}", flush=True)
        return {}
    rows = [json.loads(line) for line in finished.stdout.splitlines() if line.startswith("{")]
    for row in rows:
        print(json.dumps({"pypomp": script, **{key: value for key, value in row.items() if key != "estimates"}}),
              flush=True)
    return {row["particles"]: row["seconds_per_run_median"] for row in rows if "particles" in row}


COUNT_DRAWS = "exact"      # filter.count_draws of pfx's runs (--count-draws)


def pfx_seconds(config: Path, particles: int, trials: int, backend: str, precision: str = "float64") -> float:
    """pfx's wall seconds per run: ``trials`` runs at N = ``particles`` in one batch (trials.csv's
    ``run_time_s`` and, on jax, ``compile_time_s``: each run's share of its batch)."""
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "pfx", "run", str(config), "--trials", str(trials), "--out", folder,
                   "--set", f"filter.particles={particles}", "--set", f"filter.backend={backend}",
                   "--set", f"filter.precision={precision}", "--set", f"filter.count_draws={COUNT_DRAWS}",
                   "--set", "outputs.figures=[]", "--quiet"]     # the particle count replaces a sweep's
        subprocess.run(command, check=True, capture_output=True, text=True)
        trials = pd.read_csv(next(Path(folder).rglob("trials.csv")))
        # the jax backend's compilation is its own column (compile_time_s): counted here, as the
        # batch's wall time is what this measures
        compiled = trials["compile_time_s"] if "compile_time_s" in trials else 0.0
        return float((trials["run_time_s"] + compiled).mean())


def jax_timings(config: Path, particles: int, trials: int, precision: str) -> dict[str, float]:
    """pfx's jax backend: seconds per run in a batch of ``trials`` with its compilation, and the
    seconds a run adds to a compiled batch (a batch of 3 x ``trials`` against one of ``trials``)."""
    batch = pfx_seconds(config, particles, trials, "jax", precision)
    larger = pfx_seconds(config, particles, 3 * trials, "jax", precision)
    return {f"pfx jax {precision}, {trials} runs in a batch": batch,
            f"pfx jax {precision}, a run added once compiled": (3 * trials * larger - trials * batch) / (2 * trials)}


def machine_line() -> str:
    """The CPUs, the load average and the devices JAX sees (when it imports)."""
    try:
        import jax

        devices = f"; jax {jax.__version__} on {', '.join(str(device) for device in jax.devices())}"
    except Exception:          # JAX absent or broken: the numpy timings still stand
        devices = ""
    return f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}{devices}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pypomp-python", help="the python of an environment with pypomp 1.1.0 (without it: pfx only)")
    parser.add_argument("--replicates", type=int, default=10, help="pypomp's timed calls after its warm-up")
    parser.add_argument("--pypomp-batch", type=int, default=1,
                        help="pypomp's runs per call (its reps), side by side as pfx's batch (a GPU: --trials)")
    parser.add_argument("--trials", type=int, default=8, help="pfx's runs in one batch")
    parser.add_argument("--models", nargs="+", default=sorted(CASES), choices=sorted(CASES), help="the models timed")
    parser.add_argument("--particles", nargs="+", type=int,
                        help="particle counts instead of the benchmarks' (measles 2000, cholera 1000 and 5000)")
    parser.add_argument("--no-numpy", action="store_true", help="leave out pfx's numpy backend (the GPU check)")
    parser.add_argument("--jax", nargs="*", default=[], choices=sorted(CASES),
                        help="models also timed on pfx's jax backend (with and without its compilation)")
    parser.add_argument("--jax-precision", default="float32", choices=["float32", "float64"],
                        help="the jax backend's precision (pypomp's is float32)")
    parser.add_argument("--count-draws", default="exact", choices=["exact", "inverse_cdf"],
                        help="pfx's filter.count_draws (pypomp's draws are inverse CDFs)")
    arguments = parser.parse_args()
    global COUNT_DRAWS
    COUNT_DRAWS = arguments.count_draws
    print(f"before: {machine_line()}; pfx's count draws: {COUNT_DRAWS}", flush=True)
    rows = []
    for model in arguments.models:
        script, config, counts = CASES[model]
        counts = arguments.particles or counts
        theirs = (pypomp_seconds(arguments.pypomp_python, script, counts, arguments.replicates, arguments.pypomp_batch)
                  if arguments.pypomp_python else {})
        for particles in counts:
            timings = {}
            if not arguments.no_numpy:
                timings[f"pfx numpy, {arguments.trials} runs in a batch"] = pfx_seconds(
                    config, particles, arguments.trials, "numpy")
                timings["pfx numpy, one run"] = pfx_seconds(config, particles, 1, "numpy")
            if model in arguments.jax:
                timings.update(jax_timings(config, particles, arguments.trials, arguments.jax_precision))
            row = {"model": model, "N": particles}
            if theirs:
                row["pypomp"] = theirs[particles]
                if arguments.pypomp_batch > 1:
                    row["pypomp replicates per second, once compiled"] = f"{1.0 / theirs[particles]:.3g}"
            for label, seconds in timings.items():
                row[label] = f"{seconds:.3g}" + (f" ({seconds / theirs[particles]:.2f}x)" if theirs else "")
                if label.endswith("once compiled"):
                    row["pfx jax replicates per second, once compiled"] = f"{1.0 / seconds:.3g}"
            rows.append(row)
            print(json.dumps(row), flush=True)
    print(f"after: {machine_line()}")
    print("\nSeconds per run" + (" (ratio to pypomp's)" if arguments.pypomp_python else "") + "\n")
    print(markdown_table(pd.DataFrame(rows)))


if __name__ == "__main__":
    main()
