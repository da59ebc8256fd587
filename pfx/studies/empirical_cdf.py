r"""The empirical distribution function of normal samples, and how fast it approaches the true CDF.

From n draws :math:`x_1..x_n` of :math:`N(\mu, \sigma^2)` the empirical CDF is

.. math:: \hat F_n(x) = \frac{1}{n} \sum_{i=1}^n \mathbf{1}\{x_i \le x\},

a step function rising by 1/n at every sample (bayes-blog, "empirical distribution function";
the density form is :math:`\hat p(x) = \frac1n \sum_i \delta(x - x_i)`). Its distance from the
true CDF F is measured by the Kolmogorov-Smirnov statistic, computed exactly from the sorted
sample :math:`x_{(1)} \le .. \le x_{(n)}`:

.. math:: D_n = \sup_x |\hat F_n(x) - F(x)| = \max_i \max\left(\tfrac{i}{n} - F(x_{(i)}),\;
          F(x_{(i)}) - \tfrac{i-1}{n}\right).

Because F is continuous, :math:`D_n` has the same law whatever the normal (it is the law of
the uniform case), known exactly for every n (Marsaglia, Tsang & Wang 2003; ``scipy.stats.kstwo``),
and :math:`\sqrt n D_n` tends to the Kolmogorov distribution, whose mean is
:math:`\sqrt{\pi/2}\,\ln 2 \approx 0.8687`: the distance shrinks like :math:`1/\sqrt n`
(Glivenko-Cantelli, with the Kolmogorov rate).

For each sample size the study draws ``repetitions`` independent samples; the first is the one
shown. Tables:

* ``ecdf``: the shown samples, sorted: ``size``, ``rank`` i, ``x``, ``ecdf`` = i/n (the value
  from x on), ``true_cdf`` = F(x).
* ``true_cdf``: F and the density on a grid over :math:`\mu \pm 4\sigma` (``normal_mean``,
  ``normal_std``, ``x``, ``cdf``, ``density``).
* ``ks_distance``: per size, the shown sample's ``ks_distance`` and where it is attained
  (``ks_at``; there the step value ``ks_ecdf_value`` is farthest from ``ks_true_cdf``); the
  mean, standard deviation and standard error of :math:`D_n` over the repetitions
  (``ks_mean``, ``ks_std``, ``ks_sem``); the exact expectation ``expected_ks`` (numerical
  integration of the exact survival function, :math:`E D_n = \int_0^1 P(D_n > t)\,dt`, for n up
  to :data:`EXACT_EXPECTATION_LIMIT`; the asymptotic value above it, as ``expected_method``
  says); ``asymptotic_ks`` = :math:`0.8687/\sqrt n`; ``scaled_ks_mean`` =
  :math:`\sqrt n\,\overline{D_n}`; and ``z_score`` = (mean - expected) / standard error.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import pandas as pd
from pydantic import Field, StrictFloat, StrictInt, field_validator

from pfx.studies.base import STUDIES, Study

KOLMOGOROV_MEAN = math.sqrt(math.pi / 2) * math.log(2)    # E of the limit law of sqrt(n) D_n
EXACT_EXPECTATION_LIMIT = 5000                           # exact E[D_n] up to this n (its cost grows with n)


def ks_distance(sorted_sample: np.ndarray, cdf_values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """D_n of each row of sorted samples, from F at the samples; also the index attaining it.

    ``cdf_values`` = F(x_(i)), shape (..., n). The supremum over x of |F_n - F| is reached just
    before or at a sample point: max(i/n - F(x_(i)), F(x_(i)) - (i-1)/n).
    """
    n = cdf_values.shape[-1]
    ranks = np.arange(1, n + 1)
    gaps = np.maximum(ranks / n - cdf_values, cdf_values - (ranks - 1) / n)
    return gaps.max(axis=-1), gaps.argmax(axis=-1)


def expected_ks_distance(n: int) -> tuple[float, str]:
    r"""E[D_n]: exact (:math:`\int P(D_n > t) dt` by Simpson's rule) up to the limit, else asymptotic."""
    if n > EXACT_EXPECTATION_LIMIT:
        return KOLMOGOROV_MEAN / math.sqrt(n), "asymptotic"
    from scipy import integrate, stats

    # D_n >= 1/(2n) always, and P(sqrt(n) D_n > 7) < 1e-40: integrate the survival function between.
    grid = np.linspace(1 / (2 * n), min(1.0, 7 / math.sqrt(n)), 401)
    return float(grid[0] + integrate.simpson(stats.kstwo.sf(grid, n), x=grid)), "exact"


@STUDIES.register_kind
class EmpiricalCdf(Study):
    """Empirical CDFs of normal samples at several sizes against the true CDF, with KS distances."""

    kind: Literal["empirical_cdf"] = "empirical_cdf"
    mean: StrictFloat = Field(0.0, description="mean mu of the sampled normal")
    std: StrictFloat = Field(1.0, gt=0, description="standard deviation sigma of the sampled normal")
    sizes: list[StrictInt] = Field([10, 100, 1000], min_length=1, max_length=8,
                                   description="sample sizes n (one empirical CDF each)")
    repetitions: StrictInt = Field(1000, ge=2, le=100_000,
                                   description="independent samples per size for the KS statistics (the first is drawn)")
    grid_points: StrictInt = Field(401, ge=11, le=100_001, description="points of the true-CDF grid (mu +- 4 sigma)")

    @field_validator("sizes")
    @classmethod
    def _sizes(cls, sizes: list[int]) -> list[int]:
        if any(n < 1 or n > 100_000 for n in sizes):
            raise ValueError("every sample size must be between 1 and 100000")
        if len(set(sizes)) != len(sizes):
            raise ValueError("sample sizes must be distinct")
        return sorted(sizes)

    def cdf(self, x: np.ndarray) -> np.ndarray:
        from scipy.special import ndtr

        return ndtr((x - self.mean) / self.std)

    def density(self, x: np.ndarray) -> np.ndarray:
        standard = (x - self.mean) / self.std
        return np.exp(-0.5 * standard * standard) / (self.std * math.sqrt(2 * math.pi))

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        shown, distances = [], []
        for n in self.sizes:
            samples = np.sort(random.normal(self.mean, self.std, size=(self.repetitions, n)), axis=1)
            cdf_values = self.cdf(samples)
            distance, where = ks_distance(samples, cdf_values)
            shown.append(pd.DataFrame({"size": n, "rank": np.arange(1, n + 1), "x": samples[0],
                                       "ecdf": np.arange(1, n + 1) / n, "true_cdf": cdf_values[0]}))
            # the step value farthest from F at the worst sample: just after its jump, or just before
            worst, at = int(where[0]), float(cdf_values[0, where[0]])
            step_value = max(((worst + 1) / n, worst / n), key=lambda value: abs(value - at))
            expected, method = expected_ks_distance(n)
            mean, std = float(distance.mean()), float(distance.std(ddof=1))
            sem = std / math.sqrt(self.repetitions)
            distances.append({
                "size": n, "ks_distance": float(distance[0]), "ks_at": float(samples[0, worst]),
                "ks_ecdf_value": step_value, "ks_true_cdf": at,
                "repetitions": self.repetitions, "ks_mean": mean, "ks_std": std, "ks_sem": sem,
                "expected_ks": expected, "expected_method": method,
                "asymptotic_ks": KOLMOGOROV_MEAN / math.sqrt(n), "scaled_ks_mean": math.sqrt(n) * mean,
                "z_score": (mean - expected) / sem if sem > 0 else 0.0})
        grid = np.linspace(self.mean - 4 * self.std, self.mean + 4 * self.std, self.grid_points)
        true = pd.DataFrame({"normal_mean": self.mean, "normal_std": self.std, "x": grid,
                             "cdf": self.cdf(grid), "density": self.density(grid)})
        return {"ecdf": pd.concat(shown, ignore_index=True), "true_cdf": true,
                "ks_distance": pd.DataFrame(distances)}
