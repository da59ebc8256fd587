"""The reference run for the London measles benchmark: pypomp's own particle filter, on this machine.

pypomp (the JAX port of R's pomp; MIT licence) ships He, Ionides & King's (2010) measles model
as ``pypomp.models.measles.UKMeasles.pomp(town, theta, model="001")`` (the full model, with the
mixing exponent ``alpha`` and the death rate ``mu``; Euler steps of one day, 1/365.25 year), the
towns' weekly reports and covariates, and the published maximum-likelihood estimates
(``AK_mles.csv``). This script builds London's model at its MLE, on the weekly reports of
1950-1963 with He et al.'s one correction (the week of 1955-08-26: 76 cases where the record
has 0, as examples/data/london-measles-cases-he2010.csv has it), and runs pypomp's bootstrap
filter (``pfilter``: systematic resampling at every observation) ``--replicates`` times at each
``--particles`` J. It prints, per J:

* the mean of the log-likelihood estimates, its standard error (sd / sqrt(replicates)) and sd,
* their log-mean-exp (the log of the mean of the likelihood estimates, which are unbiased),
* the wall time of one filter run, **excluding JAX's compilation**: one warm-up call per J is
  timed separately (compilation plus its runs) and left out; every replicate after it is one
  ``pfilter(J, reps=1)`` call timed on its own. With ``--batch B`` each timed call is
  ``pfilter(J, reps=B)``, ``--replicates`` calls make B x ``--replicates`` estimates, and a run's
  time is its call's over B (on a GPU, the replicates side by side: ``make gpu-check``).

It needs pypomp in its own environment (pfx never imports pypomp or JAX)::

    python -m venv /tmp/venv-pypomp && /tmp/venv-pypomp/bin/pip install pypomp==1.1.0
    nice -n 19 /tmp/venv-pypomp/bin/python examples/benchmarks/measles_pypomp_reference.py \
        --particles 2000 --replicates 40

The numbers it printed on the machine of the recorded run are in
configs/benchmarks/measles-london/paper.yaml (``reference_run``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from importlib.metadata import version

PUBLISHED_LOG_LIKELIHOOD = -3804.9
TOWN = "London"
CORRECTED_DATE, CORRECTED_CASES = "1955-08-26", 76.0      # He et al.'s value for a recorded 0


def log_mean_exp(values: list[float]) -> float:
    """log((1/n) sum_i exp(v_i)), computed from the largest value."""
    largest = max(values)
    return largest + math.log(sum(math.exp(v - largest) for v in values) / len(values))


def london_model():
    """pypomp's He et al. model for London at the published MLE, on the corrected reports."""
    import pandas as pd
    from pypomp.core.parameters import PompParameters
    from pypomp.models.measles.uk_measles import UKMeasles

    mles = pd.read_csv(os.path.join(UKMeasles._data_dir, "AK_mles.csv"), index_col="town").loc[TOWN]
    names = UKMeasles._MODELS["001"].param_names
    model = UKMeasles.pomp(TOWN, PompParameters({name: float(mles[name]) for name in names}), model="001")
    corrected_time = 1950.0 + (pd.Timestamp(CORRECTED_DATE) - pd.Timestamp("1950-01-01")).days / 365.25
    row = int(abs(model.ys.index - corrected_time).argmin())
    if model.ys.iloc[row, 0] != 0.0:
        raise SystemExit(f"expected 0 cases on {CORRECTED_DATE}, found {model.ys.iloc[row, 0]}")
    model.ys.iloc[row, 0] = CORRECTED_CASES
    return model


def filter_runs(model, particles: int, key, batch: int) -> tuple[list[float], float]:
    """(the log-likelihood estimates, the wall seconds) of one pfilter call of ``batch`` runs of
    ``particles`` (pypomp runs a call's replicates side by side, as pfx runs a cell's trials)."""
    started = time.perf_counter()
    model.pfilter(J=particles, key=key, reps=batch)
    estimates = [float(value) for value in model.results_history[-1].logLiks.values.ravel()]   # on the host: finished
    return estimates, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[2000])
    parser.add_argument("--replicates", type=int, default=40)
    parser.add_argument("--seed", type=int, default=2010)
    parser.add_argument("--batch", type=int, default=1,
                        help="runs per pfilter call (reps); a run's time is the call's over the batch")
    arguments = parser.parse_args()

    import jax

    print(json.dumps({"pypomp": version("pypomp"), "jax": version("jax"), "jaxlib": version("jaxlib"),
                      "python": platform.python_version(), "machine": platform.machine(),
                      "cpu_count": os.cpu_count(), "devices": [str(device) for device in jax.devices()]}))
    key = jax.random.key(arguments.seed)
    for particles in arguments.particles:
        model = london_model()
        key, warm_up_key = jax.random.split(key)
        warm_up_estimates, warm_up_seconds = filter_runs(model, particles, warm_up_key, arguments.batch)
        estimates, seconds = [], []
        for _ in range(arguments.replicates):
            key, run_key = jax.random.split(key)
            batch_estimates, elapsed = filter_runs(model, particles, run_key, arguments.batch)
            estimates += batch_estimates
            seconds.append(elapsed / arguments.batch)
        sd = statistics.stdev(estimates)
        print(json.dumps({
            "particles": particles,
            "replicates": len(estimates),
            "log_likelihood_mean": round(statistics.fmean(estimates), 3),
            "log_likelihood_standard_error": round(sd / math.sqrt(len(estimates)), 3),
            "log_likelihood_sd": round(sd, 3),
            "log_mean_exp": round(log_mean_exp(estimates), 3),
            "published": PUBLISHED_LOG_LIKELIHOOD,
            "seconds_per_run_median": round(statistics.median(seconds), 3),
            "seconds_per_run_mean": round(statistics.fmean(seconds), 3),
            "first_run_seconds_with_compilation": round(warm_up_seconds, 3),
            "first_run_estimate": round(warm_up_estimates[0], 3),
            "batch": arguments.batch,
            "estimates": [round(value, 3) for value in estimates],
        }), flush=True)


if __name__ == "__main__":
    main()
