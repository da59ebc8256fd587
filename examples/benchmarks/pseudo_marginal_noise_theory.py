r"""The theory behind the N-choice rule for PMMH (Pitt, Silva, Giordani & Kohn 2012; Doucet, Pitt,
Deligiannidis & Kohn 2015): the computing time per effective sample as a function of the standard
deviation sigma of the log-likelihood estimate, in the two limits the rule is built from.

pfx never imports this script; it needs only numpy and scipy. Run it from the repository root:

    python examples/benchmarks/pseudo_marginal_noise_theory.py

**The assumptions.** The estimate's error Z = log L-hat(theta) - log L(theta) is N(-sigma^2/2,
sigma^2) whatever theta (so E[exp Z] = 1: the likelihood estimate is unbiased), and sigma^2 =
delta / N: the variance falls as one over the number of particles N. Under the pseudo-marginal
chain's stationary law the error of the *current* estimate is tilted by exp(z): N(+sigma^2/2,
sigma^2). A proposal theta' with a fresh error W ~ N(-sigma^2/2, sigma^2) is accepted with
probability min(1, r(theta, theta') exp(W - z)).

**The noise's own acceptance.** Averaged over W, a current error z lets a move through with
probability (the exact-likelihood ratio r set to 1)

.. math::

    \alpha_\sigma(z) = E\,\min(1, e^{W - z})
      = \Phi\!\left(\frac{-z - \sigma^2/2}{\sigma}\right) + e^{-z}\,\Phi\!\left(\frac{z - \sigma^2/2}{\sigma}\right),

and its stationary average is :math:`E\,\alpha_\sigma(Z) = 2\Phi(-\sigma/\sqrt2)`.

**Limit 1, a perfect exact chain** (Pitt et al. 2012): the exact-likelihood chain proposes from
the posterior itself and always accepts (inefficiency IF_Q = 1). The pseudo-marginal chain then
stays at theta until a move gets through, with probability alpha(z) at each iteration, so the lag-k
autocorrelation of any function of theta is E[(1 - alpha(Z))^k] and its inefficiency (integrated
autocorrelation time) is

.. math::

    \mathrm{IF}_1(\sigma) = E\left[\frac{2 - \alpha_\sigma(Z)}{\alpha_\sigma(Z)}\right],
    \qquad Z \sim N(\sigma^2/2, \sigma^2).

**Limit 2, a very inefficient exact chain** (IF_Q large: small random-walk steps): the
pseudo-marginal chain follows the exact chain's path slowed down by the noise's mean acceptance,
IF(sigma) ~ IF_Q / (2 Phi(-sigma / sqrt 2)).

**Computing time.** The work per effective sample is IF x N, proportional to IF(sigma) / sigma^2
(N = delta / sigma^2). The script prints the relative computing time IF / (IF_Q sigma^2) of both
limits on a grid, each limit's minimiser (0.92 and 1.68), the cost of each sigma relative to each
limit's own optimum, and the sigma whose worse relative cost over the two limits is smallest.
With delta = N Var(log L-hat) measured on a model (about 45 for the bootstrap filter on the
GBP/USD returns at Pitt & Shephard's parameters, docs/benchmarks/sv-gbp-usd.md), N = delta /
sigma^2 turns each sigma into a particle count.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy import optimize, stats

NODES, WEIGHTS = np.polynomial.hermite_e.hermegauss(200)     # E f(X), X ~ N(0, 1)


def noise_acceptance(z: np.ndarray, sigma: float) -> np.ndarray:
    """alpha(z) = E min(1, exp(W - z)), W ~ N(-sigma^2/2, sigma^2)."""
    half = 0.5 * sigma**2
    return stats.norm.cdf((-z - half) / sigma) + np.exp(-z) * stats.norm.cdf((z - half) / sigma)


def stationary_mean(function, sigma: float) -> float:
    """E f(Z) for the current error Z ~ N(sigma^2/2, sigma^2), by Gauss-Hermite quadrature."""
    z = 0.5 * sigma**2 + sigma * NODES
    return float(np.sum(WEIGHTS * function(z)) / math.sqrt(2 * math.pi))


def inefficiency_perfect(sigma: float) -> float:
    """IF_1(sigma) = E[(2 - alpha(Z)) / alpha(Z)]: the exact chain draws independent posterior samples."""
    return stationary_mean(lambda z: (2.0 - noise_acceptance(z, sigma)) / noise_acceptance(z, sigma), sigma)


def relative_inefficiency_slow(sigma: float) -> float:
    """IF / IF_Q -> 1 / (2 Phi(-sigma / sqrt 2)) as the exact chain's IF_Q grows."""
    return 1.0 / (2.0 * stats.norm.cdf(-sigma / math.sqrt(2.0)))


LIMITS = {"perfect exact chain (IF_Q = 1)": inefficiency_perfect,
          "inefficient exact chain (IF_Q -> infinity)": relative_inefficiency_slow}


def relative_computing_time(limit, sigma: float) -> float:
    """IF(sigma) / (IF_Q sigma^2): proportional to the work per effective sample."""
    return limit(sigma) / sigma**2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--delta", type=float, default=45.0, help="N Var(log L-hat) of the filter, to print N")
    options = parser.parse_args()
    optimum = {}
    for name, limit in LIMITS.items():
        best = optimize.minimize_scalar(lambda s: relative_computing_time(limit, s), bounds=(0.2, 4.0),
                                        method="bounded", options={"xatol": 1e-6})
        optimum[name] = (best.x, best.fun)
        print(f"{name}: sigma_opt = {best.x:.3f}, relative computing time there {best.fun:.4f}")

    def worst_penalty(sigma: float) -> float:
        return max(relative_computing_time(limit, sigma) / optimum[name][1] for name, limit in LIMITS.items())

    compromise = optimize.minimize_scalar(worst_penalty, bounds=(0.5, 2.5), method="bounded")
    print(f"sigma minimising the worse of the two penalties: {compromise.x:.3f} "
          f"(at most {100 * (compromise.fun - 1):.1f} % above either optimum)")
    print(f"\n{'sigma':>6} {'N=delta/s^2':>11} {'2Phi(-s/r2)':>11} {'IF_1':>9} "
          f"{'RCT_1':>8} {'pen_1':>7} {'RCT_inf':>8} {'pen_inf':>8}")
    for sigma in [0.3, 0.5, 0.7, 0.8, 0.92, 1.0, 1.1, 1.2, 1.3, 1.5, 1.68, 1.8, 2.0, 2.5]:
        cells = []
        for name, limit in LIMITS.items():
            time = relative_computing_time(limit, sigma)
            cells += [time, time / optimum[name][1]]
        print(f"{sigma:6.2f} {options.delta / sigma**2:11.1f} {2 * stats.norm.cdf(-sigma / math.sqrt(2)):11.4f} "
              f"{inefficiency_perfect(sigma):9.3f} {cells[0]:8.3f} {cells[1]:7.3f} {cells[2]:8.3f} {cells[3]:8.3f}")


if __name__ == "__main__":
    main()
