"""The reference run for the Dhaka cholera benchmark: pypomp's own particle filter, on this machine.

pypomp (the JAX port of R's pomp; MIT licence) ships King et al.'s (2008) cholera model as
``pypomp.models.dacca()``, at the maximum-likelihood parameters, with Euler steps of 1/240 year
between monthly observations. Its test suite asks that the log-mean-exp of 6 replicate
log-likelihood estimates at J = 1000 particles land within 2.5 of -3748.6 (R pomp's value at
the MLE). This script runs that filter (the bootstrap filter, resampling at every observation:
``pfilter``'s default ``thresh=0``) ``--replicates`` times at each ``--particles`` J and prints,
per J:

* the mean of the log-likelihood estimates and its standard error (sd / sqrt(replicates)),
  the figure pfx's trials give beside it (pfx reports the mean over trials),
* their log-mean-exp (pypomp's own summary: the log of the mean of the likelihood estimates,
  which are unbiased for the likelihood),
* the wall time of one filter run, **excluding JAX's compilation**: one warm-up call per J is
  timed separately (compilation plus its runs) and left out; every replicate after it is one
  ``pfilter(J, reps=1)`` call timed on its own. With ``--batch B`` each timed call is
  ``pfilter(J, reps=B)``, ``--replicates`` calls make B x ``--replicates`` estimates, and a run's
  time is its call's over B (on a GPU, the replicates side by side: ``make gpu-check``).

It needs pypomp in its own environment (pfx never imports pypomp or JAX)::

    python -m venv /tmp/venv-pomp && /tmp/venv-pomp/bin/pip install pypomp==1.1.0
    /tmp/venv-pomp/bin/python examples/benchmarks/dacca_pypomp_reference.py \
        --particles 1000 5000 --replicates 20

The numbers it printed on the machine of the recorded run are in
configs/benchmarks/dacca-cholera/paper.yaml (``reference_run``).
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

PUBLISHED_LOG_LIKELIHOOD = -3748.6


def log_mean_exp(values: list[float]) -> float:
    """log((1/n) sum_i exp(v_i)), computed from the largest value."""
    largest = max(values)
    return largest + math.log(sum(math.exp(v - largest) for v in values) / len(values))


def filter_runs(model, particles: int, key, batch: int) -> tuple[list[float], float]:
    """(the log-likelihood estimates, the wall seconds) of one pfilter call of ``batch`` runs of
    ``particles`` (pypomp runs a call's replicates side by side, as pfx runs a cell's trials)."""
    started = time.perf_counter()
    model.pfilter(J=particles, key=key, reps=batch)
    estimates = [float(value) for value in model.results_history[-1].logLiks.values.ravel()]   # on the host: finished
    return estimates, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[1000])
    parser.add_argument("--replicates", type=int, default=20)
    parser.add_argument("--seed", type=int, default=2008)
    parser.add_argument("--batch", type=int, default=1,
                        help="runs per pfilter call (reps); a run's time is the call's over the batch")
    arguments = parser.parse_args()

    import jax
    import pypomp

    print(json.dumps({"pypomp": version("pypomp"), "jax": version("jax"), "jaxlib": version("jaxlib"),
                      "python": platform.python_version(), "machine": platform.machine(),
                      "cpu_count": os.cpu_count(), "devices": [str(device) for device in jax.devices()]}))
    key = jax.random.key(arguments.seed)
    for particles in arguments.particles:
        model = pypomp.models.dacca()
        key, warm_up_key = jax.random.split(key)
        warm_up_estimates, warm_up_seconds = filter_runs(model, particles, warm_up_key, arguments.batch)
        estimates, seconds = [], []
        for _ in range(arguments.replicates):
            key, run_key = jax.random.split(key)
            batch_estimates, elapsed = filter_runs(model, particles, run_key, arguments.batch)
            estimates += batch_estimates
            seconds.append(elapsed / arguments.batch)
        mean = statistics.fmean(estimates)
        standard_error = statistics.stdev(estimates) / math.sqrt(len(estimates))
        print(json.dumps({
            "particles": particles,
            "replicates": len(estimates),
            "log_likelihood_mean": round(mean, 3),
            "log_likelihood_standard_error": round(standard_error, 3),
            "log_likelihood_sd": round(statistics.stdev(estimates), 3),
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
