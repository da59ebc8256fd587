r"""A Gaussian through a nonlinear function: particles against the exact law and linearisation.

Probabilistic Robotics (Thrun, Burgard & Fox 2005), Fig. 4.3 (and Fig. 3.4 for the EKF): draw
particles :math:`x^{[m]} \sim N(\mu, \sigma^2)`, push each through :math:`y = g(x)`; the
:math:`y^{[m]}` are samples of :math:`Y = g(X)`, whatever its shape. The EKF instead
linearises :math:`g` at the mean, :math:`g(x) \approx g(\mu) + g'(\mu)(x - \mu)`, and keeps
a Gaussian :math:`N(g(\mu), g'(\mu)^2 \sigma^2)`.

Here :math:`g` is a polynomial :math:`g(x) = \sum_k c_k x^k` (``coefficients``, lowest degree
first), so that the law of :math:`Y` is known exactly:

* **Exact density** by the change of variables, summed over the real roots :math:`x_r` of
  :math:`g(x) = y` (numpy's polynomial roots):
  :math:`p_Y(y) = \sum_r p_X(x_r) / |g'(x_r)|`.
* **Exact bin probabilities** (for the histogram test) from the CDF:
  :math:`P(Y \le y) = \sum_{\text{intervals } I:\ g \le y \text{ on } I} P(X \in I)`, the
  intervals bounded by consecutive real roots of :math:`g(x) = y`.
* **Exact moments** :math:`E[Y]`, :math:`\mathrm{Var}[Y]` by Gauss-Hermite quadrature, exact
  for polynomials (``QUADRATURE_NODES`` nodes integrate degree < 2 x nodes exactly).

**The fit.** The particles' histogram is compared with the exact bin probabilities by
Pearson's chi-square test (bins with an expected count below 5 merged into their
neighbours), and so is the linearised Gaussian: its bin probabilities against the same
particles. A sample of :math:`Y` passes the first test (p-values are uniform) and, when
:math:`Y` is far from Gaussian, fails the second. The total variation distance
:math:`\frac12 \sum_{\text{bins}} |p - q|` of the exact law to the particle histogram and to the
Gaussian measures the same thing without a test.

Tables: ``function`` (x, g(x), the input density), ``density`` (y, exact density, linearised
density), ``histogram`` (bins: particle count and density, exact and linearised
probabilities), ``samples`` (the first ``shown_samples`` particles x, y), ``moments``
(exact, particles, linearised mean and variance of Y) and ``fit`` (per method: chi-square,
degrees of freedom, p-value, total variation distance).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
import pandas as pd
from numpy.polynomial import Polynomial
from numpy.polynomial.hermite_e import hermegauss
from pydantic import Field, StrictFloat, StrictInt, model_validator

from pfx.studies.base import STUDIES, Study

QUADRATURE_NODES = 40
DISPLAY_POINTS = 801
MINIMUM_EXPECTED = 5.0         # Pearson's rule: merge bins expected to hold fewer draws
ROOT_IMAGINARY = 1e-7          # roots with a smaller imaginary part (relative) count as real


@STUDIES.register_kind
class NonlinearTransform(Study):
    """Particles of a Gaussian through a polynomial g against the exact law of g(X) and the EKF's Gaussian."""

    kind: Literal["nonlinear_transform"] = "nonlinear_transform"
    input_mean: StrictFloat = Field(0.5, description="mean of X")
    input_std: StrictFloat = Field(0.6, gt=0, description="standard deviation of X")
    coefficients: list[StrictFloat] = Field(
        [0.0, 1.0, 0.0, 1.0], min_length=2, max_length=8,
        description="g(x) = c0 + c1 x + c2 x^2 + ... (lowest degree first)")
    samples: StrictInt = Field(10_000, ge=100, le=10_000_000, description="particles drawn from N(mean, std^2)")
    bins: StrictInt = Field(60, ge=5, le=1000, description="histogram bins over the central range of Y")
    shown_samples: StrictInt = Field(300, ge=0, le=10_000, description="particles written to samples.csv")

    units: ClassVar[dict[str, str]] = {}

    @model_validator(mode="after")
    def _usable(self):
        g = self.polynomial
        if g.degree() < 1:
            raise ValueError("@coefficients: g must not be constant")
        if g.deriv()(self.input_mean) == 0.0:
            raise ValueError("@coefficients: g'(input_mean) = 0, so the linearised Gaussian is degenerate")
        if self.shown_samples > self.samples:
            raise ValueError("@shown_samples: cannot show more particles than `samples`")
        return self

    @property
    def polynomial(self) -> Polynomial:
        return Polynomial(np.trim_zeros(np.asarray(self.coefficients, dtype=float), "b") if any(self.coefficients)
                          else [0.0])

    # -- the exact law of Y = g(X) ----------------------------------------------------------

    def preimages(self, y: float) -> np.ndarray:
        """Real roots of g(x) = y, sorted."""
        roots = (self.polynomial - y).roots()
        scale = np.maximum(1.0, np.abs(roots))
        return np.sort(roots[np.abs(roots.imag) <= ROOT_IMAGINARY * scale].real)

    def exact_density(self, y: np.ndarray) -> np.ndarray:
        """p_Y(y) = sum over real roots x_r of g(x) = y of p_X(x_r) / |g'(x_r)|."""
        from scipy import stats

        slope = self.polynomial.deriv()
        out = np.zeros(len(y))
        for i, level in enumerate(y):
            roots = self.preimages(level)
            with np.errstate(divide="ignore"):
                out[i] = np.sum(stats.norm.pdf(roots, self.input_mean, self.input_std) / np.abs(slope(roots)))
        return out

    def exact_cdf(self, y: np.ndarray) -> np.ndarray:
        """P(g(X) <= y): the probability of the x-intervals on which g stays below y."""
        from scipy import stats

        g = self.polynomial
        out = np.empty(len(y))
        for i, level in enumerate(y):
            cuts = np.concatenate([[-np.inf], self.preimages(level), [np.inf]])
            finite = np.where(np.isfinite(cuts), cuts, 0.0)
            # a point inside each interval, to ask whether g is below the level there
            inside = np.where(np.isinf(cuts[:-1]), finite[1:] - 1.0,
                              np.where(np.isinf(cuts[1:]), finite[:-1] + 1.0, (finite[:-1] + finite[1:]) / 2))
            below = g(inside) <= level
            probability = np.diff(stats.norm.cdf(cuts, self.input_mean, self.input_std))
            out[i] = float(probability[below].sum())
        return out

    def exact_quantile(self, probability: float) -> float:
        """The y with P(g(X) <= y) = probability (bisection on the exact CDF)."""
        from scipy import optimize

        reach = self.polynomial(self.input_mean + self.input_std * np.linspace(-9.0, 9.0, 2001))
        return float(optimize.brentq(lambda level: self.exact_cdf(np.array([level]))[0] - probability,
                                     reach.min(), reach.max(), xtol=1e-12))

    def exact_moments(self) -> tuple[float, float]:
        """E[g(X)] and Var[g(X)] by Gauss-Hermite quadrature (exact for polynomials)."""
        nodes, weights = hermegauss(QUADRATURE_NODES)
        weights = weights / weights.sum()
        values = self.polynomial(self.input_mean + self.input_std * nodes)
        mean = float(weights @ values)
        return mean, float(weights @ (values - mean) ** 2)

    def linearised(self) -> tuple[float, float]:
        """The EKF's Gaussian: mean g(mu), variance g'(mu)^2 sigma^2."""
        slope = float(self.polynomial.deriv()(self.input_mean))
        return float(self.polynomial(self.input_mean)), slope * slope * self.input_std ** 2

    # -- the study --------------------------------------------------------------------------

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        from scipy import stats

        g = self.polynomial
        x = random.normal(self.input_mean, self.input_std, size=self.samples)
        y = g(x)
        linear_mean, linear_variance = self.linearised()
        linear_std = math.sqrt(linear_variance)
        exact_mean, exact_variance = self.exact_moments()

        inputs = np.linspace(self.input_mean - 4 * self.input_std, self.input_mean + 4 * self.input_std,
                             DISPLAY_POINTS)
        function = pd.DataFrame({"x": inputs, "g": g(inputs),
                                 "input_density": stats.norm.pdf(inputs, self.input_mean, self.input_std)})

        # The histogram covers Y's central 99.8 % (its exact 0.1 % and 99.9 % quantiles: bins fixed
        # before looking at the draws, as Pearson's test assumes).
        low, high = self.exact_quantile(0.001), self.exact_quantile(0.999)
        edges = np.linspace(low, high, self.bins + 1)
        counts, _ = np.histogram(y, bins=edges)
        widths = np.diff(edges)
        exact_probability = np.diff(self.exact_cdf(edges))
        linear_probability = np.diff(stats.norm.cdf(edges, linear_mean, linear_std))
        histogram = pd.DataFrame({"bin_low": edges[:-1], "bin_high": edges[1:], "count": counts,
                                  "particle_density": counts / (self.samples * widths),
                                  "exact_probability": exact_probability,
                                  "linearised_probability": linear_probability})

        shown = np.linspace(min(low, linear_mean - 3 * linear_std), max(high, linear_mean + 3 * linear_std),
                            DISPLAY_POINTS)
        density = pd.DataFrame({"y": shown, "exact_density": self.exact_density(shown),
                                "linearised_density": stats.norm.pdf(shown, linear_mean, linear_std)})
        samples = pd.DataFrame({"particle": np.arange(1, self.shown_samples + 1),
                                "x": x[:self.shown_samples], "y": y[:self.shown_samples]})
        moments = pd.DataFrame([
            {"quantity": "mean", "exact": exact_mean, "particles": float(y.mean()), "linearised": linear_mean,
             "particle_standard_error": math.sqrt(exact_variance / self.samples)},
            {"quantity": "variance", "exact": exact_variance, "particles": float(y.var(ddof=1)),
             "linearised": linear_variance, "particle_standard_error": math.nan}])

        # Pearson's test over the whole line: the histogram's bins plus the two tails.
        cdf_edges = self.exact_cdf(edges)
        all_counts = np.concatenate([[np.sum(y < edges[0])], counts, [np.sum(y >= edges[-1])]])
        exact_all = np.concatenate([[cdf_edges[0]], exact_probability, [1.0 - cdf_edges[-1]]])
        linear_cdf = stats.norm.cdf(edges, linear_mean, linear_std)
        linear_all = np.concatenate([[linear_cdf[0]], linear_probability, [1.0 - linear_cdf[-1]]])
        fit = pd.DataFrame([
            {"method": "particles", **chi_square(all_counts, exact_all),
             "total_variation": 0.5 * float(np.abs(all_counts / self.samples - exact_all).sum())},
            {"method": "linearised", **chi_square(all_counts, linear_all),
             "total_variation": 0.5 * float(np.abs(linear_all - exact_all).sum())}])
        fit["samples"] = self.samples
        return {"function": function, "density": density, "histogram": histogram, "samples": samples,
                "moments": moments, "fit": fit}


def chi_square(counts: np.ndarray, probabilities: np.ndarray) -> dict[str, float]:
    """Pearson's chi-square of counts against probabilities (bins with expected count < 5 merged).

    Bins are merged left to right until each group expects at least 5 draws (a last short
    group joins the one before it); degrees of freedom = groups - 1.
    """
    from scipy import stats

    total = counts.sum()
    expected = probabilities * total
    groups_observed, groups_expected = [], []
    observed_sum = expected_sum = 0.0
    for observed, wanted in zip(counts, expected):
        observed_sum += observed
        expected_sum += wanted
        if expected_sum >= MINIMUM_EXPECTED:
            groups_observed.append(observed_sum)
            groups_expected.append(expected_sum)
            observed_sum = expected_sum = 0.0
    if observed_sum or expected_sum:
        if groups_expected:
            groups_observed[-1] += observed_sum
            groups_expected[-1] += expected_sum
        else:
            groups_observed.append(observed_sum)
            groups_expected.append(expected_sum)
    observed, wanted = np.asarray(groups_observed), np.asarray(groups_expected)
    with np.errstate(divide="ignore"):
        statistic = float(np.sum((observed - wanted) ** 2 / wanted)) if wanted.min() > 0 else math.inf
    dof = len(observed) - 1
    return {"chi_square": statistic, "degrees_of_freedom": dof,
            "p_value": float(stats.chi2.sf(statistic, dof)) if dof > 0 else math.nan}
