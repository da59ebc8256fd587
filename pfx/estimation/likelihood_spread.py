r"""How noisy a particle filter's log-likelihood estimate is at one parameter point.

PMMH (:mod:`pfx.estimation.pmmh`) targets the exact posterior whatever the particle count N, but
how fast its chains mix depends on the noise of :math:`\hat\ell = \log \hat p_\theta(z_{1:T})`.
For a filter whose estimate is unbiased, :math:`\operatorname{Var}\hat\ell \approx c_\theta / N`
for N large enough, and Doucet, Pitt, Deligiannidis & Kohn (2015) show that the computing time
per independent draw is smallest near :math:`\operatorname{sd}\hat\ell \approx 1.2` at the
posterior's centre (Pitt, Silva, Giordani & Kohn 2012 give 0.92 under other assumptions; both
flat between about 1 and 1.7). The spread is measured the only way a general model allows: R
independent runs of the cell's filter at one point :math:`\theta`, each from its own stream
(:func:`pfx.numerics.seeding.spread_seed`), and the sample sd of their :math:`\hat\ell`. The
sample sd of R draws has a relative standard error of about :math:`1/\sqrt{2(R-1)}` (for a
near-normal :math:`\hat\ell`): 11 % at R = 40.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from pfx.estimation.target import EstimationTarget
from pfx.numerics.seeding import spread_seed


@dataclass(frozen=True)
class Spread:
    """R runs of the filter at one point and N: the mean and sd of their log-likelihood estimates
    (over the runs with a finite one; ``finite`` counts them), and the seconds they took."""

    particles: int
    runs: int
    finite: int
    mean: float
    sd: float
    seconds: float

    @classmethod
    def of(cls, particles: int, estimates: np.ndarray, seconds: float) -> "Spread":
        """The spread of ``estimates`` (R,), R runs' log-likelihood estimates at ``particles``."""
        finite = estimates[np.isfinite(estimates)]
        mean = float(finite.mean()) if finite.size else -np.inf
        sd = float(finite.std(ddof=1)) if finite.size > 1 else np.nan
        return cls(int(particles), len(estimates), int(finite.size), mean, sd, seconds)

    @property
    def relative_standard_error(self) -> float:
        """The sd's relative standard error, about 1 / sqrt(2 (R - 1)) for a near-normal estimate."""
        return 1.0 / np.sqrt(2.0 * (self.finite - 1)) if self.finite > 1 else np.nan

    def columns(self) -> dict:
        """The measurement as a table row: particles, runs, finite, mean, sd, sd_standard_error
        and run_time_s, its seconds (particle_count.csv's and likelihood_spread.csv's columns)."""
        return {"particles": self.particles, "runs": self.runs, "finite": self.finite, "mean": self.mean,
                "sd": self.sd, "sd_standard_error": self.sd * self.relative_standard_error,
                "run_time_s": round(self.seconds, 3)}


def log_likelihood_spread(target: EstimationTarget, point: np.ndarray, particles: int, runs: int,
                          root_seed: int) -> Spread:
    """sd of the cell's log-likelihood estimate at parameters ``point`` (p,) (natural scale) and
    ``particles`` particles, over ``runs`` runs (module docstring); batched where the target is."""
    started = time.perf_counter()
    at_size = target.with_particles(particles)
    seeds = [spread_seed(root_seed, target.cell.stream_key, int(particles), run) for run in range(runs)]
    values = np.repeat(np.asarray(point, dtype=float)[None, :], runs, axis=0)
    estimates = at_size.log_likelihoods(values, seeds)
    return Spread.of(particles, estimates, time.perf_counter() - started)
