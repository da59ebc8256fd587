r"""Exact references for estimating the Nile local level model's two variances: Durbin & Koopman's
maximum of the diffuse log-likelihood, and the posterior of the log-variances on a grid, both
from the Kalman filter's exact likelihood.

pfx never imports this script; it needs only numpy and scipy. Run it from the repository root:

    python examples/benchmarks/nile_posterior_grid.py

The model: level x_k = x_(k-1) + w_k, w_k ~ N(0, q); flow z_k = x_k + v_k, v_k ~ N(0, r), on the 100
flows of examples/data/nile.csv.

**The diffuse maximum.** With a diffuse initial level the level after z_1 is N(z_1, r), and Durbin
& Koopman's diffuse log-likelihood is the sum over k = 2..n of log N(z_k; m_k, P_k + r), less
n/2 log 2 pi (their constant counts all n observations; R's KFAS counts n - 1, which is 0.919
higher). The script maximises it over (log r, log q) and prints the maximiser and the maximum.

**The posterior.** The prior of pmmh_particles_reference.py: log r and log q independent and
uniform on [log 1e2, log 1e6], and the initial level of configs/examples/nile.yaml, x_0 ~ N(0,
1e7). The posterior of (log r, log q) is the likelihood (Kalman filter, started at that prior)
restricted to the box, normalised on a grid of cell midpoints; the script prints means, sds and
2.5/50/97.5 % quantiles of log r, log q, r and q on two grids (their difference bounds the grid's
error). These are what PMMH on the same model and prior must reproduce within Monte Carlo error.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import optimize

NILE = Path(__file__).resolve().parents[1] / "data" / "nile.csv"
INITIAL_LEVEL_VARIANCE = 1.0e7
LOG_BOUNDS = (math.log(1e2), math.log(1e6))


def kalman_log_likelihood(z, measurement_variance, level_variance, mean=0.0, variance=INITIAL_LEVEL_VARIANCE):
    """sum_k log N(z_k; m_k, P_k + r) over the Kalman filter's one-step predictions (m_k, P_k) of the
    level, started at x_0 ~ N(mean, variance); the variances may be arrays of one shape (a grid)."""
    r = np.asarray(measurement_variance, dtype=float)
    q = np.asarray(level_variance, dtype=float)
    mean = np.full(np.broadcast(r, q).shape, mean)
    variance = np.full(mean.shape, variance)
    total = np.zeros(mean.shape)
    for value in z:
        variance = variance + q                       # predict the level
        innovation_variance = variance + r
        innovation = value - mean
        total -= 0.5 * (np.log(2 * np.pi * innovation_variance) + innovation**2 / innovation_variance)
        gain = variance / innovation_variance         # update with the flow
        mean = mean + gain * innovation
        variance = variance * (1.0 - gain)
    return total


def diffuse_log_likelihood(z, measurement_variance, level_variance):
    """Durbin & Koopman's diffuse log-likelihood: the level after z_1 is N(z_1, r); the constant
    counts n observations."""
    after_first = kalman_log_likelihood(z[1:], measurement_variance, level_variance,
                                        mean=z[0], variance=measurement_variance)
    return float(after_first) - 0.5 * math.log(2 * math.pi)


def grid_posterior(z, cells: int) -> dict:
    edges = np.linspace(*LOG_BOUNDS, cells + 1)
    midpoints = 0.5 * (edges[1:] + edges[:-1])
    log_r, log_q = np.meshgrid(midpoints, midpoints, indexing="ij")
    log_likelihood = kalman_log_likelihood(z, np.exp(log_r), np.exp(log_q))
    weight = np.exp(log_likelihood - log_likelihood.max())
    weight /= weight.sum()
    summary = {}
    for name, values in {"log r": log_r, "log q": log_q, "r": np.exp(log_r), "q": np.exp(log_q)}.items():
        mean = float(np.sum(weight * values))
        sd = math.sqrt(float(np.sum(weight * values**2)) - mean**2)
        order = np.argsort(values, axis=None)
        cumulative = np.cumsum(weight.ravel()[order])
        quantiles = [float(np.interp(p, cumulative, values.ravel()[order])) for p in (0.025, 0.5, 0.975)]
        summary[name] = (mean, sd, quantiles)
    return summary


def main() -> None:
    z = np.loadtxt(NILE, delimiter=",", skiprows=1)[:, 1]
    published = diffuse_log_likelihood(z, 15099.0, 1469.1)
    print(f"diffuse log-likelihood at Durbin & Koopman's (15099, 1469.1): {published:.6f} "
          f"(KFAS's constant: {published + 0.5 * math.log(2 * math.pi):.6f})")
    best = optimize.minimize(lambda p: -diffuse_log_likelihood(z, math.exp(p[0]), math.exp(p[1])),
                             [math.log(15000.0), math.log(1500.0)], method="Nelder-Mead",
                             options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000})
    r, q = np.exp(best.x)
    print(f"its maximum: r = {r:.3f}, q = {q:.3f}, log-likelihood {-best.fun:.6f}")
    print(f"log-likelihood with x_0 ~ N(0, 1e7) at (15099, 1469.1): {float(kalman_log_likelihood(z, 15099.0, 1469.1)):.6f}")
    for cells in (400, 800):
        print(f"\nposterior on a {cells} x {cells} grid (prior uniform on log r, log q in [log 1e2, log 1e6]):")
        for name, (mean, sd, quantiles) in grid_posterior(z, cells).items():
            print(f"  {name:6s} mean {mean:12.4f}  sd {sd:10.4f}  2.5/50/97.5 % "
                  + " ".join(f"{value:.4f}" for value in quantiles))


if __name__ == "__main__":
    main()
