r"""Weightings: how a particle's weight is updated from the measurement.

With innovation :math:`\nu_i = z - h(x_i)` and measurement noise covariance :math:`R`:

==============  ===============================================================================
name            log-weight increment (up to a constant)
==============  ===============================================================================
gaussian        :math:`\log p(z \mid x_i)`: the model's own likelihood (the Bayesian weight; for
                gaussian noise this already is the Mahalanobis distance under R)
euclidean       :math:`-\lVert \nu_i \rVert_2^2 / (2 s^2)`: a gaussian kernel of the L2 distance,
                isotropic, :math:`s^2` = ``scale``\ ² or the mean of diag(R)
manhattan       :math:`-\lVert \nu_i \rVert_1 / b`: a Laplace kernel of the L1 distance,
                :math:`b` = ``scale`` or :math:`\sqrt{\bar R / 2}` (same variance as R's mean)
mahalanobis     ``form: paper``: park-mpf eq. (6) as printed, :math:`M_i = \Sigma^{-1/2}\nu_i` and
                :math:`-\tfrac12 M_i^\top \Sigma^{-1} M_i = -\tfrac12 \nu_i^\top \Sigma^{-2} \nu_i`,
                with :math:`\Sigma` the weighted covariance of :math:`h(x_i)` over the predicted
                cloud (the filter never sees the true state, which the paper's M refers to).
                ``form: innovation``: :math:`-\tfrac12 \nu_i^\top S^{-1} \nu_i` with
                :math:`S = R + \mathrm{Cov}_w(h(x))`: a tempered likelihood that counts the
                prior spread twice (flatter weights, over-dispersed posterior).
==============  ===============================================================================

Only ``gaussian`` is the Bayesian update; the others are the heuristics found in the papers,
implemented as described and named honestly in every table.
"""

from __future__ import annotations

from typing import ClassVar, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat

from pfx.filters.backends import BOTH, Backends
from pfx.numerics.arrays import namespace
from pfx.registry import Registry


class _Weighting(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    #: whether the log-weight increment is the model's log-likelihood log p(z | x), the Bayesian
    #: weight: guided proposals, the auxiliary filter, the mcmc move and a model's compiled step
    #: need it (their importance weights and targets are ratios of densities)
    is_likelihood: ClassVar[bool] = False
    #: where it runs (pfx.filters.backends)
    backends: ClassVar[Backends] = Backends(what="the weighting", why="it is written for the NumPy engine's step")

    def label(self) -> str:
        """Short name for tables: the kind, plus the form where there is one."""
        return self.kind

    def log_weights(self, model, measurement: np.ndarray, particles: np.ndarray,
                    weights: np.ndarray) -> np.ndarray:
        """Log-weight increments, shape (trials, N).

        ``measurement`` has shape (trials, 1, m), ``particles`` (trials, N, d) and ``weights``
        the normalised weights of the predicted cloud, (trials, N).
        """
        raise NotImplementedError


def _mean_measurement_variance(model) -> float:
    return float(np.mean(np.diag(model.measurement_noise.covariance())))


WEIGHTINGS: Registry[type["_Weighting"]] = Registry("weighting")


@WEIGHTINGS.register_kind
class GaussianWeighting(_Weighting):
    """The model's measurement likelihood p(z | x) (the Bayesian weight)."""

    kind: Literal["gaussian"] = "gaussian"
    is_likelihood: ClassVar[bool] = True
    backends: ClassVar[Backends] = Backends(BOTH)

    def log_weights(self, model, measurement, particles, weights):
        return model.log_likelihood(measurement, particles)


@WEIGHTINGS.register_kind
class EuclideanWeighting(_Weighting):
    """Gaussian kernel of the Euclidean (L2) innovation distance, isotropic."""

    kind: Literal["euclidean"] = "euclidean"
    backends: ClassVar[Backends] = Backends(BOTH)
    scale: Optional[StrictFloat] = Field(None, gt=0, description="kernel std s (default: sqrt of mean diag R)")

    def log_weights(self, model, measurement, particles, weights):
        xp = namespace(particles)
        innovation = measurement - model.measurement_mean(particles)
        variance = self.scale ** 2 if self.scale else _mean_measurement_variance(model)
        return -0.5 * xp.sum(innovation * innovation, axis=-1) / variance


@WEIGHTINGS.register_kind
class ManhattanWeighting(_Weighting):
    """Laplace kernel of the Manhattan (L1) innovation distance."""

    kind: Literal["manhattan"] = "manhattan"
    backends: ClassVar[Backends] = Backends(BOTH)
    scale: Optional[StrictFloat] = Field(None, gt=0, description="kernel scale b (default: sqrt(mean diag R / 2))")

    def log_weights(self, model, measurement, particles, weights):
        xp = namespace(particles)
        innovation = measurement - model.measurement_mean(particles)
        scale = self.scale or np.sqrt(_mean_measurement_variance(model) / 2.0)
        return -xp.sum(xp.abs(innovation), axis=-1) / scale


@WEIGHTINGS.register_kind
class MahalanobisWeighting(_Weighting):
    """Mahalanobis weighting of park-mpf: form paper (eq. 6 as printed) or innovation."""

    kind: Literal["mahalanobis"] = "mahalanobis"
    backends: ClassVar[Backends] = Backends(BOTH)
    form: Literal["paper", "innovation"] = Field(
        "paper", description="paper: eq. (6) as printed; innovation: S = R + Cov(h(x))")

    def label(self):
        return f"mahalanobis-{self.form}"

    def log_weights(self, model, measurement, particles, weights):
        xp = namespace(particles, weights)
        predicted = model.measurement_mean(particles)                     # (R, N, m)
        # Particles with zero weight or an overflowing prediction take no part in the statistics.
        usable = xp.isfinite(predicted).all(axis=-1) & (weights > 0)
        weights = xp.where(usable, weights, 0.0)
        weights = weights / weights.sum(axis=-1, keepdims=True)
        predicted = xp.where(usable[..., None], predicted, 0.0)
        mean = xp.einsum("rn,rnm->rm", weights, predicted)[:, None, :]
        centred = predicted - mean
        cloud = xp.einsum("rn,rnm,rnk->rmk", weights, centred, centred)    # (R, m, m)
        noise = model.measurement_noise.covariance()
        innovation = measurement - predicted
        if self.form == "innovation":
            metric = xp.linalg.inv(cloud + noise)
        else:
            # A collapsed cloud has zero covariance; a vanishing fraction of R keeps it invertible.
            inverse = xp.linalg.inv(cloud + 1e-9 * noise)
            metric = inverse @ inverse
        log_weights = -0.5 * xp.einsum("rnm,rmk,rnk->rn", innovation, metric, innovation)
        return xp.where(usable, log_weights, -np.inf)


Weighting = WEIGHTINGS.kind_union()
