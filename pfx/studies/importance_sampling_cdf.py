r"""Importance sampling: the normal CDF estimated from samples of a uniform proposal.

bayes-blog's example: the target :math:`p = N(\mu, \sigma^2)` is never sampled; instead n
points are drawn from the proposal :math:`q = U(a, b)`, :math:`q(x) = 1/(b - a)`, and each is
weighted by :math:`w(x) = p(x) / q(x) = (b - a)\,p(x)`. Two estimators of
:math:`F(x) = P_p(X \le x)` follow:

* ``plain``, the formula the post prints,
  :math:`E_p[f] \approx \frac1n \sum_i f(x_i)\,w(x_i)` with :math:`f = \mathbf 1\{\cdot \le x\}`:

  .. math:: \hat F(x) = \frac1n \sum_{i=1}^n w(x_i)\,\mathbf 1\{x_i \le x\};

* ``self_normalised``, the particle filter's form (the weights normalised to sum to 1, so p
  need only be known up to a constant):

  .. math:: \tilde F(x) = \sum_{i=1}^n \bar w_i\,\mathbf 1\{x_i \le x\},\quad
            \bar w_i = w(x_i) / \textstyle\sum_j w(x_j).

Exact moments under q, with :math:`t = (x - \mu)/\sigma`, :math:`\Phi` the standard normal CDF
and :math:`p^2 = N(\mu, \sigma^2/2) / (2\sigma\sqrt\pi)`:

.. math:: m(x) = E_q[w\,\mathbf 1\{X \le x\}] = \Phi(t_x) - \Phi(t_a),\qquad
          M(x) = E_q[w^2\,\mathbf 1\{X \le x\}] = \frac{b - a}{2\sigma\sqrt\pi}
                 \left[\Phi(\sqrt2\,t_x) - \Phi(\sqrt2\,t_a)\right].

So the plain estimator has mean m(x) and variance :math:`(M(x) - m(x)^2)/n`; the
self-normalised one tends to :math:`r(x) = m(x)/Z`, :math:`Z = m(b)`, with asymptotic
variance :math:`[(1 - r)^2 M(x) + r^2 (M(b) - M(x))] / (n Z^2)` (delta method). Both miss the
target's mass outside [a, b]: the ``truncation_bias`` columns (m(x) - F(x) and r(x) - F(x)) show
how little that is for a proposal a few sigma wide. The weights' effective sample size
:math:`(\sum w)^2 / \sum w^2` tends to :math:`n Z^2 / M(b)`.

``repetitions`` independent samples are drawn (the first is the one shown), so the root mean
square error of each estimator over them can be set beside its theoretical standard error.
Tables:

* ``samples``: the shown sample sorted by x: ``x``, ``target_density`` p(x),
  ``proposal_density`` q(x), ``weight`` w(x), ``normalised_weight``.
* ``cdf``: on the grid ``x``: ``true_cdf``, ``target_density``, ``proposal_density``, and for
  each estimator E in (self_normalised, plain): ``estimate_E`` (the shown sample), ``error_E``
  (estimate - true CDF), ``standard_error_E`` (theory), ``z_E`` (error / standard error; empty
  where the standard error is 0), ``rms_error_E`` (over the repetitions), ``truncation_bias_E``.
* ``summary``: per estimator: the set-up (``target_mean``, ``target_std``, ``proposal_low``,
  ``proposal_high``, ``samples``), ``repetitions``, ``max_abs_error`` of the shown
  sample and where (``x_at_max``), ``max_abs_z`` over the ``z_points`` grid points with a
  z-score, ``mean_sup_error`` (mean over the repetitions of the sup error on the grid),
  ``ess`` of the shown weights and ``expected_ess``.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import pandas as pd
from pydantic import Field, StrictFloat, StrictInt, model_validator

from pfx.studies.base import STUDIES, Study

ESTIMATORS = ("self_normalised", "plain")


@STUDIES.register_kind
class ImportanceSamplingCdf(Study):
    """The normal CDF estimated by importance sampling from a uniform proposal (plain and self-normalised)."""

    kind: Literal["importance_sampling_cdf"] = "importance_sampling_cdf"
    mean: StrictFloat = Field(0.0, description="mean mu of the target normal")
    std: StrictFloat = Field(1.0, gt=0, description="standard deviation sigma of the target normal")
    proposal_low: StrictFloat = Field(-5.0, description="a: the uniform proposal's lower end")
    proposal_high: StrictFloat = Field(5.0, description="b: the uniform proposal's upper end")
    samples: StrictInt = Field(1000, ge=2, le=1_000_000, description="n: draws from the proposal")
    repetitions: StrictInt = Field(500, ge=2, le=100_000,
                                   description="independent samples for the RMS error (the first is shown)")
    grid_low: StrictFloat = Field(-4.0, description="lower end of the grid the CDF is estimated on")
    grid_high: StrictFloat = Field(4.0, description="upper end of the grid")
    grid_points: StrictInt = Field(161, ge=3, le=100_001, description="points of the grid")

    @model_validator(mode="after")
    def _ranges(self):
        if self.proposal_high <= self.proposal_low:
            raise ValueError("@proposal_high: must exceed proposal_low")
        if self.grid_high <= self.grid_low:
            raise ValueError("@grid_high: must exceed grid_low")
        if self.grid_low < self.proposal_low:
            raise ValueError("@grid_low: the grid must lie inside the proposal's interval (grid_low >= proposal_low)")
        if self.grid_high > self.proposal_high:
            raise ValueError("@grid_high: the grid must lie inside the proposal's interval (grid_high <= proposal_high)")
        return self

    # The mathematics: densities, the weight, and the exact moments under q.
    def target_density(self, x):
        standard = (np.asarray(x, dtype=float) - self.mean) / self.std
        return np.exp(-0.5 * standard * standard) / (self.std * math.sqrt(2 * math.pi))

    def proposal_density(self, x):
        x = np.asarray(x, dtype=float)
        inside = (x >= self.proposal_low) & (x <= self.proposal_high)
        return np.where(inside, 1.0 / (self.proposal_high - self.proposal_low), 0.0)

    def weight(self, x):
        """w(x) = p(x) / q(x) on the proposal's support."""
        return self.target_density(x) * (self.proposal_high - self.proposal_low)

    def true_cdf(self, x):
        from scipy.special import ndtr

        return ndtr((np.asarray(x, dtype=float) - self.mean) / self.std)

    def first_moment(self, x):
        """m(x) = E_q[w 1{X <= x}] = Phi(t_x) - Phi(t_a)."""
        return self.true_cdf(np.clip(x, self.proposal_low, self.proposal_high)) - self.true_cdf(self.proposal_low)

    def second_moment(self, x):
        """M(x) = E_q[w^2 1{X <= x}] = (b - a) / (2 sigma sqrt(pi)) [Phi(sqrt2 t_x) - Phi(sqrt2 t_a)]."""
        from scipy.special import ndtr

        def scaled(value):
            return ndtr(math.sqrt(2) * (np.asarray(value, dtype=float) - self.mean) / self.std)

        x = np.clip(x, self.proposal_low, self.proposal_high)
        width = self.proposal_high - self.proposal_low
        return width / (2 * self.std * math.sqrt(math.pi)) * (scaled(x) - scaled(self.proposal_low))

    def limits_and_standard_errors(self, x):
        """Per estimator: the value it tends to, and its (asymptotic) standard error, at x."""
        n = self.samples
        m, second = self.first_moment(x), self.second_moment(x)
        total, second_total = self.first_moment(self.proposal_high), self.second_moment(self.proposal_high)
        ratio = m / total
        self_normalised_variance = ((1 - ratio) ** 2 * second + ratio ** 2 * (second_total - second)) / (n * total ** 2)
        return {"plain": (m, np.sqrt(np.maximum(second - m * m, 0.0) / n)),
                "self_normalised": (ratio, np.sqrt(np.maximum(self_normalised_variance, 0.0)))}

    def expected_ess(self) -> float:
        """Limit of (sum w)^2 / sum w^2: n Z^2 / M(b)."""
        return self.samples * float(self.first_moment(self.proposal_high)) ** 2 / float(
            self.second_moment(self.proposal_high))

    def estimates(self, sample: np.ndarray, grid: np.ndarray) -> dict[str, np.ndarray]:
        """Both estimators on the grid from one sample: cumulative weights up to each grid point."""
        order = np.argsort(sample)
        weights = self.weight(sample[order])
        below = np.searchsorted(sample[order], grid, side="right")
        cumulative = np.concatenate([[0.0], np.cumsum(weights)])[below]
        return {"plain": cumulative / sample.size, "self_normalised": cumulative / weights.sum()}

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        grid = np.linspace(self.grid_low, self.grid_high, self.grid_points)
        draws = random.uniform(self.proposal_low, self.proposal_high, size=(self.repetitions, self.samples))
        truth = self.true_cdf(grid)
        squared = {name: np.zeros_like(grid) for name in ESTIMATORS}
        sup_errors = {name: np.empty(self.repetitions) for name in ESTIMATORS}
        shown: dict[str, np.ndarray] = {}
        for repetition, sample in enumerate(draws):
            for name, estimate in self.estimates(sample, grid).items():
                error = estimate - truth
                squared[name] += error * error
                sup_errors[name][repetition] = np.abs(error).max()
                if repetition == 0:
                    shown[name] = estimate
        theory = self.limits_and_standard_errors(grid)
        cdf = pd.DataFrame({"x": grid, "true_cdf": truth, "target_density": self.target_density(grid),
                            "proposal_density": self.proposal_density(grid)})
        sample = np.sort(draws[0])
        weights = self.weight(sample)
        ess = float(weights.sum() ** 2 / (weights * weights).sum())
        summary = []
        for name in ESTIMATORS:
            limit, standard_error = theory[name]
            error = shown[name] - truth
            with np.errstate(divide="ignore", invalid="ignore"):
                z = np.where(standard_error > 0, error / standard_error, np.nan)
            cdf[f"estimate_{name}"] = shown[name]
            cdf[f"error_{name}"] = error
            cdf[f"standard_error_{name}"] = standard_error
            cdf[f"z_{name}"] = z
            cdf[f"rms_error_{name}"] = np.sqrt(squared[name] / self.repetitions)
            cdf[f"truncation_bias_{name}"] = limit - truth
            worst = int(np.abs(error).argmax())
            summary.append({"estimator": name, "target_mean": self.mean, "target_std": self.std,
                            "proposal_low": self.proposal_low, "proposal_high": self.proposal_high,
                            "samples": self.samples, "repetitions": self.repetitions,
                            "max_abs_error": float(np.abs(error[worst])), "x_at_max": float(grid[worst]),
                            "max_abs_z": float(np.nanmax(np.abs(z))), "z_points": int(np.isfinite(z).sum()),
                            "mean_sup_error": float(sup_errors[name].mean()),
                            "ess": ess, "expected_ess": self.expected_ess()})
        samples = pd.DataFrame({"x": sample, "target_density": self.target_density(sample),
                                "proposal_density": self.proposal_density(sample), "weight": weights,
                                "normalised_weight": weights / weights.sum()})
        return {"samples": samples, "cdf": cdf, "summary": pd.DataFrame(summary)}
