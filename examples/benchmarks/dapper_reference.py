r"""Reference runs of DAPPER's own particle filters and EKF on its Lorenz benchmarks.

pfx never imports this script: it imports DAPPER (``pip install dapper==1.7.1``, in a virtual
environment of its own, outside pfx's), runs DAPPER's methods on DAPPER's own model files and
writes what DAPPER scores, so that pfx's numbers on the same setups (the configs beside
``configs/benchmarks/dapper-lorenz/dapper-reference.csv``) stand beside a reference run on the
same machine, not only beside the numbers printed in DAPPER's comments.

Run it (from the repository's root, with DAPPER installed in ``VENV``)::

    VENV/bin/python examples/benchmarks/dapper_reference.py --seeds 1-120 \
        --output configs/benchmarks/dapper-lorenz/dapper-reference.csv

The cases (``--cases`` picks some; default all):

==============  =====================================  =========================================
case            DAPPER method                          model file (DAPPER 1.7.1)
==============  =====================================  =========================================
l63-pf100       ``PartFilt(N=100, reg=2.4, NER=0.3)``  ``mods/Lorenz63/sakov2012.py``
l63-pf800       ``PartFilt(N=800, reg=0.9, NER=0.2)``  ``mods/Lorenz63/sakov2012.py``
l63-ekf         ``ExtKF(infl=180)``                    ``mods/Lorenz63/sakov2012.py``
l96-pf50-r*     ``PartFilt(N=50, reg=1.7, NER=0.3)``   ``mods/Lorenz96/bocquet2010.py``
l96-pf100-r*    ``PartFilt(N=100, reg=1.3, NER=0.2)``  ``mods/Lorenz96/bocquet2010.py``
l96-pf800-r*    ``PartFilt(N=800, reg=0.8, NER=0.2)``  ``mods/Lorenz96/bocquet2010.py``
==============  =====================================  =========================================

The Lorenz-96 cases come in two measurement noises: ``-r1.5`` with R = 1.5 I, as the file of
the PyPI release 1.7.1 has it, and ``-r2.25`` with R = 1.5^2 I, as DAPPER's GitHub master has
it since its commit "Boc used 1.5 std (not var)" (the two give different published numbers).

Each (case, seed) is one DAPPER experiment run as DAPPER's own ``xpList.launch`` runs one
(``xp_launch.run_experiment``): seed DAPPER's generator with ``seed``, simulate the truth and
the observations, assimilate, and average in time. Within a seed every case of the same model
and measurement noise filters the same truth and observations. The score is DAPPER's
``rmse.a``:

.. math::

    \mathrm{rmse.a} = \frac{1}{|\mathcal K|} \sum_{k \in \mathcal K}
        \sqrt{\frac{1}{d} \sum_{i=1}^{d} (\bar x_{k,i} - x_{k,i})^2},
    \qquad \mathcal K = \{k : t_k > \text{BurnIn}\},

with :math:`\bar x_k` the analysis mean (for a particle filter the weighted mean after the
reweighting and before any resampling) and :math:`t_k` the observation times (DAPPER's
``tseq.masko``; there is no observation at t = 0). The script also recomputes this mean from the
stored series and stops if it differs from DAPPER's own average. ``seconds`` is the wall time
of the assimilation alone (DAPPER's default statistics included; the truth simulation and the
time averaging excluded).

One CSV row per (case, seed): case, method, N, reg, NER, R, seed, rmse_a, seconds. Rows are
appended as they finish (an interrupted run keeps its rows; ``--skip-done`` resumes it), and
``--summary`` prints per case the mean rmse.a with its standard error, the median, the
number of lost runs (rmse.a above a threshold, see :data:`LOST_ABOVE`) and the mean and median
seconds per run (the median is the steadier figure on a machine shared with other jobs).
"""

from __future__ import annotations

import argparse
import copy
import csv
import math
import os
import statistics
import sys
import time
from pathlib import Path

COLUMNS = ("case", "method", "N", "reg", "NER", "R", "seed", "rmse_a", "seconds")

# (case, model, R, method, N, reg, NER); R is the measurement noise variance per component.
CASES = (
    ("l63-pf100", "l63", 2.0, "PartFilt", 100, 2.4, 0.3),
    ("l63-pf800", "l63", 2.0, "PartFilt", 800, 0.9, 0.2),
    ("l63-ekf", "l63", 2.0, "ExtKF", None, None, None),
    ("l96-pf50-r1.5", "l96", 1.5, "PartFilt", 50, 1.7, 0.3),
    ("l96-pf100-r1.5", "l96", 1.5, "PartFilt", 100, 1.3, 0.2),
    ("l96-pf800-r1.5", "l96", 1.5, "PartFilt", 800, 0.8, 0.2),
    ("l96-pf50-r2.25", "l96", 2.25, "PartFilt", 50, 1.7, 0.3),
    ("l96-pf100-r2.25", "l96", 2.25, "PartFilt", 100, 1.3, 0.2),
    ("l96-pf800-r2.25", "l96", 2.25, "PartFilt", 800, 0.8, 0.2),
)

# A run is "lost" when its rmse.a exceeds this: the filter has left the attractor's wing the
# truth is on and does not come back. Lorenz-63: the threshold of the outside check (1.5, about
# four times the working filters' 0.3-0.4, far below the climatological 7.6). Lorenz-96
# (Nx = 10, F = 8): the climatological standard deviation per component is about 3.6, so an
# analysis that has lost the truth scores near 3.6 * sqrt(2) ~ 5 once its ensemble has
# decorrelated; 2.0 lies well above the published 1.15 of the worst filter and well below that.
LOST_ABOVE = {"l63": 1.5, "l96": 2.0}

EKF_INFLATION = 180.0     # ExtKF(infl=180): sakov2012.py's tuning, per unit time

# No window: DAPPER imports matplotlib, and this script plots nothing.
os.environ.setdefault("MPLBACKEND", "Agg")


def hidden_markov_model(model: str, variance: float):
    """DAPPER's HMM of ``model`` with the measurement noise R = ``variance`` I."""
    import dapper.mods as modelling

    if model == "l63":
        from dapper.mods.Lorenz63.sakov2012 import HMM
    else:
        from dapper.mods.Lorenz96.bocquet2010 import HMM
    hmm = copy.deepcopy(HMM)
    operator = hmm.Obs(0)              # a constant operator: the same at every observation time
    if not math.isclose(float(operator.noise.C.diag[0]), variance):
        operator.noise = modelling.GaussRV(C=variance, M=operator.M)
    hmm.liveplotters = []
    return hmm


def method(name: str, particles, reg, ner):
    """The DAPPER experiment object ("xp") of one case."""
    import dapper.da_methods as methods

    if name == "ExtKF":
        return methods.ExtKF(infl=EKF_INFLATION)
    return methods.PartFilt(N=particles, reg=reg, NER=ner)


def run_one(case, seed: int) -> dict:
    """Seed, simulate, assimilate and score one case (DAPPER's run_experiment, timed)."""
    import numpy as np
    from dapper.tools.seeding import set_seed

    name, model, variance, method_name, particles, reg, ner = case
    hmm = hidden_markov_model(model, variance)
    xp = method(method_name, particles, reg, ner)
    set_seed(seed)
    truth, observations = hmm.simulate()
    start = time.perf_counter()
    xp.assimilate(hmm, truth, observations, desc=name)
    seconds = time.perf_counter() - start
    xp.stats.average_in_time()
    rmse_a = float(xp.avrgs.err.rms.a.val)
    # The same mean from the stored series: the analysis RMS at observation times after BurnIn.
    scored = np.asarray(xp.stats.err.rms.a)[hmm.tseq.masko]
    if not math.isclose(rmse_a, float(np.mean(scored)), rel_tol=1e-12):
        raise RuntimeError(f"{name} seed {seed}: DAPPER's rmse.a {rmse_a} is not the mean of its series")
    return {"case": name, "method": method_name, "N": particles if particles else "",
            "reg": reg if reg is not None else "", "NER": ner if ner is not None else "",
            "R": variance, "seed": seed, "rmse_a": f"{rmse_a:.6f}", "seconds": f"{seconds:.3f}"}


def seeds_from(text: str) -> list[int]:
    """'1-40' or '1,2,5' or '3-5,9' -> the seeds (DAPPER refuses seed 0)."""
    seeds = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        seeds.extend(range(int(low), int(high or low) + 1))
    return seeds


def summarise(path: Path) -> list[dict]:
    """Per case: runs, mean rmse.a, its standard error, median, lost runs, seconds per run."""
    rows = list(csv.DictReader(path.open()))
    summaries = []
    for name, model, *_ in CASES:
        scores = [float(row["rmse_a"]) for row in rows if row["case"] == name]
        if not scores:
            continue
        seconds = [float(row["seconds"]) for row in rows if row["case"] == name]
        error = statistics.stdev(scores) / math.sqrt(len(scores)) if len(scores) > 1 else float("nan")
        summaries.append({"case": name, "runs": len(scores), "mean": statistics.fmean(scores),
                          "standard_error": error, "median": statistics.median(scores),
                          "lost": sum(score > LOST_ABOVE[model] for score in scores),
                          "lost_above": LOST_ABOVE[model], "seconds_per_run": statistics.fmean(seconds),
                          "seconds_median": statistics.median(seconds)})
    return summaries


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default="all", help="comma-separated case names, or 'all'")
    parser.add_argument("--seeds", default="1-120", help="seeds, e.g. 1-120 or 1,2,7")
    parser.add_argument("--output", type=Path, default=Path("dapper-reference.csv"))
    parser.add_argument("--skip-done", action="store_true", help="skip (case, seed) rows the output has")
    parser.add_argument("--summary", action="store_true", help="only print the output's summary")
    arguments = parser.parse_args(argv)
    if arguments.summary:
        for summary in summarise(arguments.output):
            print("{case:16} runs {runs:4d}  mean {mean:.4f}  SE {standard_error:.4f}  median {median:.4f}  "
                  "lost {lost} (> {lost_above})  {seconds_per_run:.2f} s/run (median {seconds_median:.2f})".format(**summary))
        return 0
    import dapper
    import dapper.tools.progressbar as progressbar

    progressbar.disable_progbar = True
    wanted = None if arguments.cases == "all" else set(arguments.cases.split(","))
    cases = [case for case in CASES if wanted is None or case[0] in wanted]
    if wanted is not None and len(cases) != len(wanted):
        parser.error(f"unknown case among {sorted(wanted)}; cases: {[case[0] for case in CASES]}")
    done = set()
    if arguments.skip_done and arguments.output.exists():
        done = {(row["case"], int(row["seed"])) for row in csv.DictReader(arguments.output.open())}
    new_file = not arguments.output.exists()
    with arguments.output.open("a", newline="") as handle:
        writer = csv.DictWriter(handle, COLUMNS)
        if new_file:
            writer.writeheader()
        for seed in seeds_from(arguments.seeds):
            for case in cases:
                if (case[0], seed) in done:
                    continue
                row = run_one(case, seed)
                writer.writerow(row)
                handle.flush()
                print(f"dapper {dapper.__version__} {row['case']} seed {seed}: rmse.a {row['rmse_a']} "
                      f"in {row['seconds']} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
