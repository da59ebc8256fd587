r"""The one-dimensional Kalman filter, step by step: Probabilistic Robotics, Fig. 3.2 (a)-(f).

A robot moves along a line. Its belief about its position is a Gaussian
:math:`N(\mu, \sigma^2)`, and the Kalman filter (Thrun, Burgard & Fox 2005, Table 3.1) keeps
it Gaussian through a measurement, a motion and a second measurement. In one dimension, with
the book's names (:math:`R_t` the *motion* noise variance, :math:`Q_t` the *measurement* noise
variance; pfx elsewhere calls them process and measurement noise), Table 3.1 reads

.. math::

    \bar\mu_t = a\,\mu_{t-1} + b\,u_t, \qquad \bar\sigma_t^2 = a^2 \sigma_{t-1}^2 + R_t
    \qquad \text{(lines 2-3: prediction)}

    K_t = \frac{\bar\sigma_t^2\, c}{c^2 \bar\sigma_t^2 + Q_t}, \qquad
    \mu_t = \bar\mu_t + K_t (z_t - c\,\bar\mu_t), \qquad
    \sigma_t^2 = (1 - K_t c)\, \bar\sigma_t^2 \qquad \text{(lines 4-6: measurement update)}

The six panels of Fig. 3.2: (a) the initial belief; (b) a first measurement, drawn as the
likelihood :math:`p(z_1 \mid x)` normalised over :math:`x`, i.e. :math:`N(x; z_1/c, Q/c^2)`;
(c) the belief after the update, between the two and narrower than both; (d) the belief after
moving right by :math:`b\,u`, wider; (e) a second measurement; (f) the belief after it.

**The check.** Bayes' rule does not know Table 3.1: on a fine grid the update is the pointwise
product prior x likelihood, normalised (:math:`bel(x) = \eta\, p(z \mid x)\,\overline{bel}(x)`),
and the prediction is the convolution :math:`\overline{bel}(x') = \int p(x' \mid u, x)\,
bel(x)\,dx`, both computed numerically (midpoint sums; on Gaussians much wider than a cell
these are exact to rounding). The table ``steps`` gives, for each panel, the Kalman filter's
mean and variance beside the grid's moments, and the largest difference between the two
densities: the Gaussian product and convolution formulas made visible.

Tables: ``steps`` (one row per curve of the figure: panel, curve, role, mean, variance,
Kalman gain, grid mean and variance, largest density difference) and ``densities`` (the
curves on a display grid: ``x`` and one column per curve).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
import pandas as pd
from pydantic import Field, StrictFloat, StrictInt, model_validator

from pfx.studies.base import STUDIES, Study

CHECK_POINTS = 2001           # grid of the numerical Bayes check (cells far narrower than any curve)
DISPLAY_POINTS = 601          # grid of the densities table
GRID_STDS = 10.0              # the check grid spans every curve's mean +- 10 standard deviations


def gaussian_density(x: np.ndarray, mean: float, variance: float) -> np.ndarray:
    """N(x; mean, variance)."""
    return np.exp(-0.5 * (x - mean) ** 2 / variance) / math.sqrt(2.0 * math.pi * variance)


def kalman_predict(mean: float, variance: float, control: float, *, a: float, b: float,
                   motion_variance: float) -> tuple[float, float]:
    r"""Table 3.1 lines 2-3 in 1-D: :math:`\bar\mu = a\mu + bu`, :math:`\bar\sigma^2 = a^2\sigma^2 + R`."""
    return a * mean + b * control, a * a * variance + motion_variance


def kalman_update(mean: float, variance: float, measurement: float, *, c: float,
                  measurement_variance: float) -> tuple[float, float, float]:
    r"""Table 3.1 lines 4-6 in 1-D: gain :math:`K`, then :math:`\mu = \bar\mu + K(z - c\bar\mu)`,
    :math:`\sigma^2 = (1 - Kc)\bar\sigma^2`. Returns (mean, variance, gain)."""
    gain = variance * c / (c * c * variance + measurement_variance)
    return mean + gain * (measurement - c * mean), (1.0 - gain * c) * variance, gain


def moments(x: np.ndarray, density: np.ndarray) -> tuple[float, float]:
    """Mean and variance of a density sampled on a regular grid (midpoint sums)."""
    mass = density.sum()
    mean = float((x * density).sum() / mass)
    return mean, float(((x - mean) ** 2 * density).sum() / mass)


@STUDIES.register_kind
class KalmanSteps(Study):
    """The 1-D Kalman filter's prior, measurement, update, motion, measurement, update (Fig. 3.2)."""

    kind: Literal["kalman_1d_steps"] = "kalman_1d_steps"
    prior_mean: StrictFloat = Field(8.0, description="mean of the initial belief (panel a)")
    prior_variance: StrictFloat = Field(9.0, gt=0, description="variance of the initial belief")
    measurements: list[StrictFloat] = Field([6.0, 23.5], min_length=2, max_length=2,
                                            description="z_1 (panel b) and z_2 (panel e)")
    measurement_variance: StrictFloat = Field(4.0, gt=0, description="Q_t, variance of the measurement noise")
    control: StrictFloat = Field(14.0, description="u_t, the commanded motion between the measurements (panel d)")
    motion_variance: StrictFloat = Field(8.0, gt=0, description="R_t, variance of the motion noise")
    a: StrictFloat = Field(1.0, description="A_t of Table 3.1 in 1-D (1: the position carries over)")
    b: StrictFloat = Field(1.0, description="B_t of Table 3.1 in 1-D (1: the control is a displacement)")
    c: StrictFloat = Field(1.0, description="C_t of Table 3.1 in 1-D (1: the sensor measures the position)")
    display_points: StrictInt = Field(DISPLAY_POINTS, ge=51, le=20_001,
                                      description="points of the densities table (the figure's curves)")

    units: ClassVar[dict[str, str]] = {"x": "m", "mean": "m", "variance": "m^2"}

    @model_validator(mode="after")
    def _measurable(self):
        if self.c == 0.0:
            raise ValueError("@c: c = 0 makes the measurement independent of the position")
        return self

    def kalman_curves(self) -> list[tuple[str, str, str, float, float, float]]:
        """(curve, panel, role, mean, variance, gain) of every curve, by Table 3.1."""
        q = self.measurement_variance
        z1, z2 = self.measurements
        def as_density(z):                  # p(z | x) normalised over x
            return z / self.c, q / self.c ** 2

        mean, variance = self.prior_mean, self.prior_variance
        rows = [("prior", "a", "belief", mean, variance, math.nan)]
        rows.append(("measurement_1", "b", "measurement", *as_density(z1), math.nan))
        mean, variance, gain = kalman_update(mean, variance, z1, c=self.c, measurement_variance=q)
        rows.append(("posterior_1", "c", "belief", mean, variance, gain))
        mean, variance = kalman_predict(mean, variance, self.control, a=self.a, b=self.b,
                                        motion_variance=self.motion_variance)
        rows.append(("predicted", "d", "belief", mean, variance, math.nan))
        rows.append(("measurement_2", "e", "measurement", *as_density(z2), math.nan))
        mean, variance, gain = kalman_update(mean, variance, z2, c=self.c, measurement_variance=q)
        rows.append(("posterior_2", "f", "belief", mean, variance, gain))
        return rows

    def grid_curves(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The same beliefs by Bayes' rule on the grid x: products and a convolution, numerically."""
        dx = x[1] - x[0]
        q = self.measurement_variance
        z1, z2 = self.measurements

        def likelihood(z):            # p(z | x) as a function of x
            return gaussian_density(z - self.c * x, 0.0, q)

        def update(belief, z):
            product = likelihood(z) * belief
            return product / (product.sum() * dx)

        prior = gaussian_density(x, self.prior_mean, self.prior_variance)
        posterior_1 = update(prior, z1)
        # p(x' | u, x) = N(x'; a x + b u, R): predicted(x') = sum_x p(x' | u, x) bel(x) dx
        moved = self.a * x + self.b * self.control
        predicted = (gaussian_density(x[:, None], moved[None, :], self.motion_variance) @ posterior_1) * dx
        curves = {"prior": prior, "measurement_1": likelihood(z1) / (likelihood(z1).sum() * dx),
                  "posterior_1": posterior_1, "predicted": predicted,
                  "measurement_2": likelihood(z2) / (likelihood(z2).sum() * dx)}
        curves["posterior_2"] = update(predicted, z2)
        return curves

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        kalman = self.kalman_curves()
        means = np.array([row[3] for row in kalman])
        stds = np.sqrt([row[4] for row in kalman])
        x = np.linspace((means - GRID_STDS * stds).min(), (means + GRID_STDS * stds).max(), CHECK_POINTS)
        grid = self.grid_curves(x)
        rows = []
        for curve, panel, role, mean, variance, gain in kalman:
            grid_mean, grid_variance = moments(x, grid[curve])
            difference = np.abs(grid[curve] - gaussian_density(x, mean, variance)).max()
            rows.append({"panel": panel, "curve": curve, "role": role, "mean": mean, "variance": variance,
                         "std": math.sqrt(variance), "kalman_gain": gain, "grid_mean": grid_mean,
                         "grid_variance": grid_variance, "max_density_difference": difference,
                         "peak_density": 1.0 / math.sqrt(2 * math.pi * variance)})
        # Display range: every curve's mean +- 4 standard deviations.
        shown = np.linspace((means - 4 * stds).min(), (means + 4 * stds).max(), self.display_points)
        densities = pd.DataFrame({"x": shown, **{curve: gaussian_density(shown, mean, variance)
                                                 for curve, _, _, mean, variance, _ in kalman}})
        return {"steps": pd.DataFrame(rows), "densities": densities}
