"""Time pfx beside pypomp on pomp's two models, back to back in one session on one machine.

The pomp models' speed goal (docs/benchmarks/measles-london.md, "Time per run") is pfx's wall
time per likelihood evaluation at most pypomp's, on the same machine in the same session, for
He et al.'s measles (N = 2000) and King et al.'s cholera (N = 1000 and 5000). Load on a shared
machine moves both by tens of percent from one hour to the next, so the two are timed here one
after the other, in one command:

1. pypomp's reference scripts (``measles_pypomp_reference.py``, ``dacca_pypomp_reference.py``),
   run by the Python of an environment that has pypomp 1.1.0 (``--pypomp-python``): the median
   time of ``--replicates`` filter runs after a warm-up run that compiles;
2. ``pfx run`` on the benchmarks' configs (numpy backend) with ``--trials`` runs in one batch
   (pfx's usual way: a cell's trials are rows of one batch, and the time per run is the batch's
   wall time divided by the runs) and with one run alone;
3. for the models named after ``--jax``, the batch on pfx's jax backend too (one ``pfx run``:
   the compilation included, shared by the batch's runs).

It prints one Markdown table, seconds per run and the ratio to pypomp, with the machine's load
average before and after. From the repository's root:

    python examples/benchmarks/pomp_speed_session.py --pypomp-python /path/to/pypomp-env/bin/python
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


def pypomp_seconds(python: str, script: str, particles: list[int], replicates: int) -> dict[int, float]:
    """The median seconds per run of pypomp's reference script at each N (its JSON lines)."""
    command = [python, str(REPOSITORY / "examples" / "benchmarks" / script), "--particles",
               *map(str, particles), "--replicates", str(replicates)]
    output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    rows = [json.loads(line) for line in output.splitlines() if line.startswith("{")]
    return {row["particles"]: row["seconds_per_run_median"] for row in rows if "particles" in row}


def pfx_seconds(config: Path, particles: int, trials: int, backend: str) -> float:
    """pfx's wall seconds per run: ``trials`` runs at N = ``particles`` in one batch (trials.csv's
    ``run_time_s``, each run's share of its batch)."""
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "pfx", "run", str(config), "--trials", str(trials), "--out", folder,
                   "--set", f"filter.particles={particles}", "--set", f"filter.backend={backend}",
                   "--set", "outputs.figures=[]", "--quiet"]     # the particle count replaces a sweep's
        subprocess.run(command, check=True, capture_output=True, text=True)
        trials_csv = next(Path(folder).rglob("trials.csv"))
        return float(pd.read_csv(trials_csv)["run_time_s"].mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pypomp-python", required=True, help="the python of an environment with pypomp 1.1.0")
    parser.add_argument("--replicates", type=int, default=10, help="pypomp's timed runs after its warm-up")
    parser.add_argument("--trials", type=int, default=8, help="pfx's runs in one batch")
    parser.add_argument("--jax", nargs="*", default=[], choices=sorted(CASES),
                        help="models also timed on pfx's jax backend (compilation included)")
    arguments = parser.parse_args()
    load_before = os.getloadavg()
    rows = []
    for model, (script, config, counts) in CASES.items():
        theirs = pypomp_seconds(arguments.pypomp_python, script, counts, arguments.replicates)
        for particles in counts:
            timings = {f"pfx numpy, {arguments.trials} runs in a batch":
                       pfx_seconds(config, particles, arguments.trials, "numpy"),
                       "pfx numpy, one run": pfx_seconds(config, particles, 1, "numpy")}
            if model in arguments.jax:
                timings[f"pfx jax, {arguments.trials} runs in a batch"] = pfx_seconds(
                    config, particles, arguments.trials, "jax")
            row = {"model": model, "N": particles, "pypomp": theirs[particles]}
            for label, seconds in timings.items():
                row[label] = f"{seconds:.2f} ({seconds / theirs[particles]:.2f}x)"
            rows.append(row)
            print(json.dumps(row), flush=True)
    load_after = os.getloadavg()
    print(f"\nSeconds per run (ratio to pypomp's); load average {load_before[0]:.1f} before, {load_after[0]:.1f} after, "
          f"{os.cpu_count()} CPUs\n")
    print(markdown_table(pd.DataFrame(rows)))


if __name__ == "__main__":
    main()
