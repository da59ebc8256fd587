r"""The reference timing for pfx's particle marginal Metropolis-Hastings (PMMH): the ``particles``
library's ``mcmc.PMMH`` on the same models, data and particle counts, one chain at a time.

pfx never imports this script. It needs ``particles`` (N. Chopin's companion library of Chopin &
Papaspiliopoulos 2020; version 0.3/0.4, numpy < 2), which ``make bench`` installs into the
repository's ``.venv-bench``. Run it from the repository root:

    .venv-bench/bin/python examples/benchmarks/pmmh_particles_reference.py \
        --models sv nile --particles 100 1000 --iterations 1000 > pmmh-particles.json

It prints one JSON document: the library versions, the machine's load, and for each model and N
the seconds per PMMH iteration (wall time, ``time.perf_counter``, the whole chain divided by its
iterations), the seconds per particle filter actually run (proposals outside the prior's support
are rejected by ``particles`` without running the filter), the acceptance rate, the posterior
means and sds after a burn-in with each parameter's integrated autocorrelation time (Sokal's
window), and the standard deviation of the log-likelihood estimate at the chain's
starting point over repeated filters (the quantity the N-choice rule of Doucet, Pitt,
Deligiannidis & Kohn 2015 is stated in). With ``--chain-out DIR`` it also writes each run's chain
after the burn-in to ``DIR/<model>-N<n>-seed<seed>.csv``, from which
``examples/benchmarks/chain_summary.py`` computes ArviZ's Monte Carlo standard errors (the
estimation-sv benchmark runs four seeds this way).

**How particles' PMMH proposes.** A Gaussian random walk on the parameters as the prior names
them (no transformation unless the prior is written on a transformed scale, e.g. a log-variance).
By default (``adaptive=True``) the walk's covariance is :math:`(2.38^2/d)\,\Sigma_n` (Roberts &
Rosenthal's scale, times ``scale``, 1 by default), with :math:`\Sigma_n` a running estimate of the
target's covariance updated after every iteration with the vanishing step
:math:`\gamma_n = (n+1)^{-0.6}` (``VanishCovTracker``: :math:`\mu_n = (1-\gamma_n)\mu_{n-1} +
\gamma_n\theta_n`, :math:`\Sigma_n = (1-\gamma_n)\Sigma_{n-1} + \gamma_n (\theta_n-\mu_n)(\theta_n-\mu_n)^\top`),
started from ``rw_cov`` (the identity if not given): an adaptive Metropolis in the manner of
Haario, Saksman & Tamminen (2001), with stochastic-approximation weights instead of Haario's
equal ones, and adapting for the whole run (no separate warm-up). With ``adaptive=False`` the
walk's covariance is ``rw_cov`` itself. The chain starts at ``theta0`` (drawn from the prior if
not given). Each iteration runs ``particles.SMC`` with its defaults: the bootstrap filter
(``fk_cls=ssms.Bootstrap``), ``Nx`` = 100 particles, systematic resampling when the ESS falls below
N/2, no summaries collected. The prior is a ``distributions.StructDist`` of independent laws, one
per named parameter; its ``logpdf`` of -inf rejects a proposal before any filter runs.

**The models.**

* ``sv``: the library's own ``StochVol`` (:math:`X_0 \sim N(\mu, \sigma^2/(1-\rho^2))`,
  :math:`X_t = \mu + \rho (X_{t-1} - \mu) + \sigma U_t`, :math:`Y_t \sim N(0, e^{X_t})`) on the first
  201 GBP/USD returns of its data set ``GBP_vs_USD_9798`` (checked against pfx's
  ``examples/data/gbp-usd-returns.csv``), with the priors of the book's scripts on these returns
  (Chopin & Papaspiliopoulos' companion code, chapters 15 and 18): :math:`\mu \sim N(0, 2^2)`,
  :math:`\rho \sim \mathrm{Beta}(9, 1)`, :math:`\sigma \sim \mathrm{Gamma}(2, \text{rate } 2)`. The
  chain starts at Pitt & Shephard's values (:math:`\mu = 2 \log 0.5992`, :math:`\rho = 0.9702`,
  :math:`\sigma = 0.178`).
* ``nile``: the local level model, defined here as a ``StateSpaceModel``: level :math:`x_k =
  x_{k-1} + w_k`, :math:`w_k \sim N(0, q)`, flow :math:`z_k = x_k + v_k`, :math:`v_k \sim N(0, r)`,
  on pfx's ``examples/data/nile.csv`` (100 years). The parameters are the log-variances
  :math:`\log r, \log q`, each with a uniform prior on :math:`[\log 10^2, \log 10^6]` (a prior
  proportional to :math:`1/r` on :math:`[10^2, 10^6]`). The initial level is pfx's
  ``configs/examples/nile.yaml`` prior :math:`x_0 \sim N(0, 10^7)`; the library's first state is
  observed, so its law is that of pfx's :math:`x_1`, :math:`N(0, 10^7 + q)`. The chain starts at
  Durbin & Koopman's maximum-likelihood variances (15099, 1469.1). The script also prints the
  Kalman filter's exact log-likelihood there, which the particle filter's estimates must match
  on average (once the log's bias of about half the variance is allowed for).

Both walks start with a diagonal ``rw_cov`` of about the posterior's scale (``--rw-sd`` can be
given); ``--fixed-proposal`` turns the adaptation off. Every run reseeds numpy's global
generator (particles draws from it) with ``--seed``, so each model and N is reproducible alone.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import particles
import scipy
from particles import datasets, mcmc
from particles import distributions as dists
from particles import state_space_models as ssms

DATA = Path(__file__).resolve().parents[1] / "data"
RETURNS, NILE = DATA / "gbp-usd-returns.csv", DATA / "nile.csv"
INITIAL_LEVEL_VARIANCE = 1.0e7          # configs/examples/nile.yaml's prior x_0 ~ N(0, 1e7)


class LocalLevel(ssms.StateSpaceModel):
    """The local level model on log-variances: x_k = x_(k-1) + N(0, q), z_k = x_k + N(0, r)."""

    default_params = {"log_measurement_variance": math.log(15099.0), "log_level_variance": math.log(1469.1)}

    def PX0(self):
        # the library observes its first state: pfx's x_1 = x_0 + w_1, x_0 ~ N(0, 1e7)
        return dists.Normal(loc=0.0, scale=math.sqrt(INITIAL_LEVEL_VARIANCE + math.exp(self.log_level_variance)))

    def PX(self, t, xp):
        return dists.Normal(loc=xp, scale=math.exp(0.5 * self.log_level_variance))

    def PY(self, t, xp, x):
        return dists.Normal(loc=x, scale=math.exp(0.5 * self.log_measurement_variance))


def kalman_log_likelihood(z: np.ndarray, measurement_variance: float, level_variance: float) -> float:
    """log p(z_1..n) of the local level model with x_0 ~ N(0, 1e7), by the Kalman filter:
    the sum of log N(z_k; m_k, P_k + r) over the one-step predictions (m_k, P_k)."""
    mean, variance, total = 0.0, INITIAL_LEVEL_VARIANCE, 0.0
    for value in z:
        variance += level_variance                      # predict
        innovation_variance = variance + measurement_variance
        innovation = value - mean
        total -= 0.5 * (math.log(2 * math.pi * innovation_variance) + innovation**2 / innovation_variance)
        gain = variance / innovation_variance           # update
        mean += gain * innovation
        variance *= 1.0 - gain
    return total


def sv_problem() -> dict:
    y = np.asarray(datasets.GBP_vs_USD_9798().data[:201], dtype=float).ravel()
    if RETURNS.exists():
        ours = np.loadtxt(RETURNS, delimiter=",", skiprows=1)[:, 1]
        assert np.max(np.abs(ours - y)) < 1e-9, "the library's returns differ from pfx's"
    prior = dists.StructDist({"mu": dists.Normal(scale=2.0), "rho": dists.Beta(a=9.0, b=1.0),
                              "sigma": dists.Gamma(a=2.0, b=2.0)})
    start = {"mu": 2 * math.log(0.5992), "rho": 0.9702, "sigma": 0.178}
    return {"model": ssms.StochVol, "data": y, "prior": prior, "start": start,
            "rw_sd": {"mu": 0.25, "rho": 0.01, "sigma": 0.05},
            "prior_text": "mu ~ N(0, 2^2), rho ~ Beta(9, 1), sigma ~ Gamma(shape 2, rate 2)",
            "data_text": "first 201 returns of particles' GBP_vs_USD_9798 (= pfx's examples/data/gbp-usd-returns.csv)",
            "exact_log_likelihood": None}


def nile_problem() -> dict:
    z = np.loadtxt(NILE, delimiter=",", skiprows=1)[:, 1]
    bounds = {"a": math.log(1e2), "b": math.log(1e6)}
    prior = dists.StructDist({"log_measurement_variance": dists.Uniform(**bounds),
                              "log_level_variance": dists.Uniform(**bounds)})
    start = dict(LocalLevel.default_params)
    return {"model": LocalLevel, "data": z, "prior": prior, "start": start,
            "rw_sd": {"log_measurement_variance": 0.2, "log_level_variance": 0.6},
            "prior_text": "log r, log q ~ Uniform(log 1e2, log 1e6) each; x_0 ~ N(0, 1e7)",
            "data_text": "examples/data/nile.csv (100 annual flows, 1871-1970)",
            "exact_log_likelihood": kalman_log_likelihood(z, 15099.0, 1469.1)}


PROBLEMS = {"sv": sv_problem, "nile": nile_problem}


class CountedPMMH(mcmc.PMMH):
    """particles' PMMH, counting the particle filters it runs."""

    filters_run = 0

    def alg_instance(self, theta):
        self.filters_run += 1
        return super().alg_instance(theta)


def integrated_autocorrelation_time(x: np.ndarray, window_factor: float = 5.0) -> float:
    """tau = 1 + 2 sum_(k=1..M) rho_k, the inefficiency of a chain's mean (its variance is tau
    times that of the mean of independent draws), with Sokal's window: the smallest M >= 5 tau(M)."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    n = len(x)
    spectrum = np.fft.rfft(x, 2 * n)
    autocovariance = np.fft.irfft(spectrum * np.conj(spectrum))[:n] / n
    if autocovariance[0] == 0.0:
        return float("nan")
    tau = 2.0 * np.cumsum(autocovariance / autocovariance[0]) - 1.0
    window = np.arange(n) >= window_factor * tau
    return float(tau[np.argmax(window)] if window.any() else tau[-1])


def start_point(prior: dists.StructDist, values: dict) -> np.ndarray:
    theta0 = np.empty(1, dtype=prior.dtype)
    for name, value in values.items():
        theta0[name] = value
    return theta0


def likelihood_spread(problem: dict, n: int, runs: int) -> dict:
    """The mean and standard deviation of log L-hat at the starting point over `runs` filters."""
    model = problem["model"](**problem["start"])
    estimates = np.empty(runs)
    for r in range(runs):
        smc = particles.SMC(fk=ssms.Bootstrap(ssm=model, data=problem["data"]), N=n, collect="off")
        smc.run()
        estimates[r] = smc.logLt
    return {"runs": runs, "mean": round(float(estimates.mean()), 4),
            "sd": round(float(estimates.std(ddof=1)), 4)}


def run(name: str, n: int, options: argparse.Namespace) -> dict:
    problem = PROBLEMS[name]()
    np.random.seed(options.seed)
    names = [field[0] for field in problem["prior"].dtype]
    # a plain dict of laws is stored in sorted key order: the walk's scales follow the prior's order
    rw_sd = dict(zip(names, options.rw_sd)) if options.rw_sd else problem["rw_sd"]
    chain = CountedPMMH(ssm_cls=problem["model"], prior=problem["prior"], data=problem["data"], Nx=n,
                        niter=options.iterations, theta0=start_point(problem["prior"], problem["start"]),
                        adaptive=not options.fixed_proposal,
                        rw_cov=np.diag(np.square([rw_sd[name] for name in names])))
    started = time.perf_counter()
    chain.run()
    seconds = time.perf_counter() - started
    burn_in = int(options.burn_in * options.iterations)
    theta = chain.chain.theta[burn_in:]
    row = {"model": name, "n_particles": n, "T": len(problem["data"]), "iterations": options.iterations,
           "seconds": round(seconds, 3),
           "seconds_per_iteration": round(seconds / options.iterations, 6),
           "filters_run": chain.filters_run,
           "seconds_per_filter": round(seconds / chain.filters_run, 6),
           "acceptance_rate": round(chain.acc_rate, 4),
           "burn_in": burn_in,
           "posterior_mean": {key: round(float(theta[key].mean()), 5) for key in theta.dtype.names},
           "posterior_sd": {key: round(float(theta[key].std(ddof=1)), 5) for key in theta.dtype.names},
           "autocorrelation_time": {key: round(integrated_autocorrelation_time(theta[key]), 1)
                                    for key in theta.dtype.names},
           "start": {key: round(value, 6) for key, value in problem["start"].items()},
           "rw_sd": rw_sd, "adaptive": not options.fixed_proposal,
           "prior": problem["prior_text"], "data": problem["data_text"]}
    if name == "nile":
        row["posterior_mean_variances"] = {
            key.removeprefix("log_"): round(float(np.exp(theta[key]).mean()), 1) for key in theta.dtype.names}
        row["exact_log_likelihood_at_start"] = round(problem["exact_log_likelihood"], 6)
    if options.chain_out:
        # the chain after the burn-in, one column per parameter: examples/benchmarks/chain_summary.py
        # gives ArviZ's Monte Carlo standard errors of its means (pfx's posterior.csv uses the same)
        path = Path(options.chain_out) / f"{name}-N{n}-seed{options.seed}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        header = ",".join(["iteration", *theta.dtype.names])
        table = np.column_stack([np.arange(burn_in, options.iterations), *[theta[key] for key in theta.dtype.names]])
        np.savetxt(path, table, delimiter=",", header=header, comments="", fmt=["%d"] + ["%.17g"] * len(names))
        row["chain_file"] = str(path)
    if options.likelihood_runs:
        np.random.seed(options.seed + 1)
        row["log_likelihood_at_start"] = likelihood_spread(problem, n, options.likelihood_runs)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=list(PROBLEMS), choices=list(PROBLEMS))
    parser.add_argument("--particles", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--burn-in", type=float, default=0.2, help="share of the chain left out of the means")
    parser.add_argument("--likelihood-runs", type=int, default=40,
                        help="filters at the starting point for the sd of log L-hat (0: none)")
    parser.add_argument("--rw-sd", type=float, nargs="+", default=None,
                        help="the random walk's initial standard deviations, one per parameter "
                             "in the prior's (alphabetical) order")
    parser.add_argument("--fixed-proposal", action="store_true", help="adaptive=False: the walk keeps rw_cov")
    parser.add_argument("--seed", type=int, default=2015, help="numpy's global seed (particles draws from it)")
    parser.add_argument("--chain-out", default=None,
                        help="folder for each run's chain after the burn-in, <model>-N<n>-seed<seed>.csv")
    options = parser.parse_args()
    rows = []
    for name in options.models:
        for n in options.particles:
            rows.append(run(name, n, options))
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)   # progress: a long run keeps what it has
    print(json.dumps({
        "library": f"particles {particles.__version__}", "numpy": np.__version__, "scipy": scipy.__version__,
        "python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count(),
        "load_average_after": [round(value, 2) for value in os.getloadavg()],
        "command": "examples/benchmarks/pmmh_particles_reference.py " + " ".join(sys.argv[1:]),
        "seed": options.seed, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
