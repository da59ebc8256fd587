r"""The reference implementation of the sv-gbp-usd benchmark: the ``particles`` library on the same
returns, parameters and particle counts (docs/benchmarks/sv-gbp-usd.md).

pfx never imports this script. It needs ``particles`` (N. Chopin's companion library of Chopin &
Papaspiliopoulos 2020; version 0.3/0.4, numpy < 2), which ``make bench`` installs into the
repository's ``.venv-bench``. Run it from the repository root:

    .venv-bench/bin/python examples/benchmarks/sv_particles_reference.py --runs 1000 > particles.yaml

It prints a YAML block, ``particles_reference:``, that goes into
``configs/benchmarks/sv-gbp-usd/paper.yaml`` (the benchmark's report reads it from there, never
from this script). For each filter and N: the mean and variance of the log-likelihood estimate
over the runs, the mean of :math:`\exp(\log \hat L - \log L)` and its standard error, the share of
runs more than 5 below :math:`\log L` ("collapsed"), the lowest ESS of any run and the step where
the runs' ESS is lowest on average, and the time per run (one run at a time, one core).

The filters are the library's own: ``Bootstrap``, ``GuidedPF`` and ``AuxiliaryPF`` on its
``StochVol`` model, whose ``proposal`` and ``logeta`` are Pitt & Shephard's first-order
expansion; systematic resampling when the ESS (of the auxiliary weights, for the APF) falls
below N/2. Two more auxiliary filters are defined here on subclasses of ``StochVol`` (this
script's own code, written from the formulas of docs/benchmarks/sv-gbp-usd.md), to check pfx's
auxiliary filter against an independent implementation of the same method:
``auxiliary_second_order`` (the second-order proposal and look-ahead) and ``auxiliary_point``
(the bootstrap proposal and the likelihood at the point prediction as look-ahead, pfx's default).

The data are the library's own copy (``datasets.GBP_vs_USD_9798``, its first 201 returns),
checked against pfx's ``examples/data/gbp-usd-returns.csv`` when that file is found. The
library's time 0 observes its first state, drawn from the stationary law (pfx's x_0 is a prior
and x_1, also stationary, is its first observed state): the returns have the same likelihood.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import particles
from particles import datasets
from particles import distributions as dists
from particles import state_space_models as ssms

MU, RHO, SIGMA = 2 * math.log(0.5992), 0.9702, 0.178       # Pitt & Shephard (1999)
EXACT = -160.940264          # log p(y_1..201): pfx's histogram filter and an independent quadrature
RETURNS = Path(__file__).resolve().parents[1] / "data" / "gbp-usd-returns.csv"


def log_likelihood(y, x):
    """log N(y; 0, e^x)."""
    return -0.5 * (math.log(2 * math.pi) + x + y**2 * np.exp(-x))


def expansion(y, mean, variance, second_order):
    """The prior N(mean, variance) times the Taylor expansion of log N(y; 0, e^x) about the prior
    mean: (log-predictive density under the expansion, proposal mean, proposal variance)."""
    ratio = y**2 * np.exp(-mean)
    slope = 0.5 * (ratio - 1.0)
    posterior_variance = 1.0 / (1.0 / variance + 0.5 * ratio) if second_order else variance + 0.0 * ratio
    log_predictive = (log_likelihood(y, mean) + 0.5 * np.log(posterior_variance / variance)
                      + 0.5 * slope**2 * posterior_variance)
    return log_predictive, mean + posterior_variance * slope, posterior_variance


class StochVolSecondOrder(ssms.StochVol):
    """StochVol with the second-order proposal and look-ahead."""

    def proposal0(self, data):
        _, mean, variance = expansion(data[0], self.mu, self.sig0() ** 2, True)
        return dists.Normal(loc=mean, scale=np.sqrt(variance))

    def proposal(self, t, xp, data):
        _, mean, variance = expansion(data[t], self.EXt(xp), self.sigma**2, True)
        return dists.Normal(loc=mean, scale=np.sqrt(variance))

    def logeta(self, t, x, data):
        return expansion(data[t + 1], self.EXt(x), self.sigma**2, True)[0]


class StochVolPointLookAhead(ssms.StochVol):
    """StochVol whose auxiliary filter proposes from the transition and looks ahead with the
    likelihood at the point prediction."""

    def proposal0(self, data):
        return self.PX0()

    def proposal(self, t, xp, data):
        return self.PX(t, xp)

    def logeta(self, t, x, data):
        return log_likelihood(data[t + 1], self.EXt(x))


FILTERS = {
    "bootstrap": (ssms.Bootstrap, ssms.StochVol),
    "guided": (ssms.GuidedPF, ssms.StochVol),
    "auxiliary": (ssms.AuxiliaryPF, ssms.StochVol),
    "auxiliary_second_order": (ssms.AuxiliaryPF, StochVolSecondOrder),
    "auxiliary_point": (ssms.AuxiliaryPF, StochVolPointLookAhead),
}


def returns() -> np.ndarray:
    y = np.asarray(datasets.GBP_vs_USD_9798().data[:201], dtype=float).ravel()
    if RETURNS.exists():
        ours = np.loadtxt(RETURNS, delimiter=",", skiprows=1)[:, 1]
        assert np.max(np.abs(ours - y)) < 1e-9, "the library's returns differ from pfx's"
    return y


def run(name: str, n: int, runs: int, y: np.ndarray) -> dict:
    feynman_kac, model_class = FILTERS[name]
    model = model_class(mu=MU, sigma=SIGMA, rho=RHO)
    estimates, ess = np.empty(runs), np.empty((runs, len(y)))
    started = time.perf_counter()
    for r in range(runs):
        smc = particles.SMC(fk=feynman_kac(ssm=model, data=y), N=n, resampling="systematic", ESSrmin=0.5,
                            collect=[])
        smc.run()
        estimates[r] = smc.logLt
        ess[r] = smc.summaries.ESSs
    seconds = (time.perf_counter() - started) / runs
    ratio = np.exp(estimates - EXACT)
    worst = int(np.argmin(ess.mean(axis=0)))
    return {"filter": name, "n_particles": n, "runs": runs,
            "mean": round(float(estimates.mean()), 5), "variance": round(float(estimates.var(ddof=1)), 6),
            "mean_ratio": round(float(ratio.mean()), 5),
            "ratio_standard_error": round(float(ratio.std(ddof=1) / math.sqrt(runs)), 5),
            "collapsed_share": round(float(np.mean(estimates < EXACT - 5.0)), 4),
            "minimum_ess": round(float(ess.min()), 2),
            # the library's time t is pfx's step t + 1
            "lowest_mean_ess_step": worst + 1, "lowest_mean_ess": round(float(ess[:, worst].mean()), 1),
            "seconds_per_run": round(seconds, 5)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--particles", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--filters", nargs="+", default=list(FILTERS), choices=list(FILTERS))
    parser.add_argument("--seed", type=int, default=1998, help="numpy's global seed (particles draws from it)")
    options = parser.parse_args()
    np.random.seed(options.seed)
    y = returns()
    print("particles_reference:")
    print(f"  library: particles {particles.__version__}")
    print(f"  numpy: {np.__version__}")
    print(f"  seed: {options.seed}")
    print("  command: .venv-bench/bin/python examples/benchmarks/sv_particles_reference.py "
          f"--runs {options.runs} --seed {options.seed} --filters {' '.join(options.filters)}")
    print("  rows:", flush=True)
    for name in options.filters:          # each row as soon as it is done: a long run keeps what it has
        for n in options.particles:
            row = run(name, n, options.runs, y)
            print("    - {" + ", ".join(f"{key}: {value}" for key, value in row.items()) + "}", flush=True)


if __name__ == "__main__":
    main()
