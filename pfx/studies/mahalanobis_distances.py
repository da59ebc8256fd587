r"""Euclidean and Mahalanobis distances of test points from a Gaussian sample (park-mpf, Table 1).

Draw :math:`n` samples :math:`y_1..y_n \sim \mathcal N(\mu, \Sigma)`; with the sample mean
:math:`m = \tfrac1n \sum_i y_i` and the sample covariance
:math:`C = \tfrac1{n-1} \sum_i (y_i - m)(y_i - m)^\top`, the **squared** distances of a point
:math:`p` are

.. math::

   d_E^2(p) = (p - m)^\top (p - m), \qquad d_M^2(p) = (p - m)^\top C^{-1} (p - m),

(MATLAB's ``mahal(p, Y)`` is :math:`d_M^2` exactly so: squared, sample mean, sample covariance
with :math:`n - 1`), and their exact counterparts use :math:`\mu` and :math:`\Sigma`. park-mpf
prints squared distances (its text: "sqrt(2)^2 = 2.0"): for
:math:`\Sigma = \begin{bmatrix}1 & .9\\ .9 & 1\end{bmatrix}` the points (1, 1) and (-1, -1) have
:math:`d_M^2 = 0.2 / 0.19 = 1.053` and (1, -1), (-1, 1) have :math:`3.8 / 0.19 = 20`, all four
having :math:`d_E^2 = 2`.

A single draw differs from the exact values by sampling error. To say how much, the study
repeats the whole draw ``replications`` times (from the same generator, after the reported
sample) and writes the mean and standard deviation of each distance over the replications: the
sampling distribution of the statistic for samples of size :math:`n`. (To first order,
:math:`d_E^2(p) \approx \lVert p - \mu\rVert^2 - 2 (p - \mu)^\top (m - \mu)`, whose standard
deviation is :math:`2\sqrt{(p-\mu)^\top \Sigma (p-\mu) / n}`: 0.123 for (1, 1) and 0.028 for
(1, -1) at n = 1000.)

Tables: ``distances``, one row per point (``point`` as text, ``x``, ``y``; ``euclidean_sample``,
``euclidean_exact``, ``mahalanobis_sample``, ``mahalanobis_exact`` (all squared);
``euclidean_sampling_mean``, ``euclidean_sampling_sd``, ``mahalanobis_sampling_mean``,
``mahalanobis_sampling_sd``; ``samples``, ``replications``), and ``samples`` (``x``, ``y``:
the reported draw, for the scatter of Fig. 1).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import pandas as pd
from pydantic import Field, PrivateAttr, StrictFloat, StrictInt, ValidationError, model_validator

from pfx.laws.initial import GaussianLaw
from pfx.numerics.seeding import TrialStreams
from pfx.studies.base import STUDIES, Study

REPLICATION_CHUNK = 250           # replications drawn at once (bounds memory; same numbers whatever the chunk)


def squared_euclidean(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    r""":math:`(p - m)^\top (p - m)` for points (k, d) and centres (..., d) -> (..., k)."""
    offset = points - centre[..., None, :]
    return np.einsum("...kd,...kd->...k", offset, offset)


def squared_mahalanobis(points: np.ndarray, centre: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    r""":math:`(p - m)^\top C^{-1} (p - m)` for points (k, d), centres (..., d), covariances (..., d, d)."""
    offset = points - centre[..., None, :]
    solved = np.linalg.solve(covariance[..., None, :, :], offset[..., None])[..., 0]
    return np.einsum("...kd,...kd->...k", offset, solved)


def sample_moments(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample mean and covariance (divisor n - 1) of samples (..., n, d)."""
    mean = samples.mean(axis=-2)
    centred = samples - mean[..., None, :]
    covariance = np.einsum("...nd,...ne->...de", centred, centred) / (samples.shape[-2] - 1)
    return mean, covariance


@STUDIES.register_kind
class MahalanobisDistances(Study):
    """Squared Euclidean and Mahalanobis distances of test points from a Gaussian sample (park-mpf Table 1)."""

    kind: Literal["mahalanobis_distances"] = "mahalanobis_distances"
    samples: StrictInt = Field(1000, ge=3, le=1_000_000, description="sample size n")
    mean: list[StrictFloat] = Field([0.0, 0.0], min_length=1, max_length=10, description="mean of the normal law")
    covariance: list[list[StrictFloat]] = Field(
        [[1.0, 0.9], [0.9, 1.0]], description="covariance matrix of the normal law (positive definite)")
    points: list[list[StrictFloat]] = Field(
        [[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]], min_length=1, max_length=100,
        description="test points whose distances from the sample are measured")
    replications: StrictInt = Field(
        4000, ge=0, le=100_000,
        description="repetitions of the whole draw, for the sampling mean and sd of each distance (0: none)")

    _law: GaussianLaw = PrivateAttr()

    @model_validator(mode="after")
    def _consistent(self):
        dimension = len(self.mean)
        try:
            law = GaussianLaw(mean=self.mean, covariance=self.covariance).bind(dimension)
        except ValidationError as error:
            raise ValueError(error.errors()[0]["msg"].removeprefix("Value error, ")) from None
        if np.linalg.eigvalsh(law.covariance_matrix()).min() <= 0:
            raise ValueError("@covariance: must be positive definite (its inverse defines the distance)")
        for index, point in enumerate(self.points):
            if len(point) != dimension:
                raise ValueError(f"@points.{index}: expected {dimension} coordinates (the mean's), got {len(point)}")
        self._law = law
        return self

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        points = np.asarray(self.points, dtype=float)
        mu, sigma = self._law.mean_vector(), self._law.covariance_matrix()
        draw = self._law.sample(TrialStreams([random]), (self.samples,))[0]       # (n, d)
        mean, covariance = sample_moments(draw)
        euclidean_samples, mahalanobis_samples = [], []
        for start in range(0, self.replications, REPLICATION_CHUNK):
            count = min(REPLICATION_CHUNK, self.replications - start)
            batch = self._law.sample(TrialStreams([random] * count), (self.samples,))
            batch_mean, batch_covariance = sample_moments(batch)
            euclidean_samples.append(squared_euclidean(points, batch_mean))
            mahalanobis_samples.append(squared_mahalanobis(points, batch_mean, batch_covariance))
        table = pd.DataFrame({
            "point": ["(" + ", ".join(f"{c:g}" for c in point) + ")" for point in points],
            **({"x": points[:, 0], "y": points[:, 1]} if points.shape[1] == 2 else {}),
            "euclidean_sample": squared_euclidean(points, mean),
            "euclidean_exact": squared_euclidean(points, mu),
            "mahalanobis_sample": squared_mahalanobis(points, mean, covariance),
            "mahalanobis_exact": squared_mahalanobis(points, mu, sigma),
        })
        for name, values in (("euclidean", euclidean_samples), ("mahalanobis", mahalanobis_samples)):
            stacked = np.concatenate(values) if values else np.full((0, len(points)), np.nan)
            table[f"{name}_sampling_mean"] = stacked.mean(axis=0) if len(stacked) else np.nan
            table[f"{name}_sampling_sd"] = stacked.std(axis=0, ddof=1) if len(stacked) > 1 else np.nan
        table["samples"] = self.samples
        table["replications"] = self.replications
        columns = [f"x{j + 1}" for j in range(draw.shape[1])] if draw.shape[1] != 2 else ["x", "y"]
        return {"distances": table, "samples": pd.DataFrame(draw, columns=columns)}
