"""The Gaussian filters' shared recursion: alternate predict and update over steps 1..T, the
linear (Joseph-form) update, the innovation's NIS and log-likelihood (see :mod:`pfx.filters.kalman`).

A trial whose measurement is missing at step k (a NaN row: recorded data) skips the update
there: the posterior is the prediction, the log-likelihood increment 0 and the NIS NaN. The
update runs on the trials that have a measurement only, so a kind's update never sees a NaN.
"""

from __future__ import annotations

import math

import numpy as np

from pfx.errors import ConfigError, ModelNumericalError, note_step
from pfx.filters.kalman.measurement_form import measurement_innovation
from pfx.filters.trace import FilterTrace, Predictive
from pfx.numerics.proper_scores import gaussian_crps, gaussian_pit


def gaussian_recursion(kind: str, model, measurements: np.ndarray, prior, predict, update,
                       update_skipped=None, scores: bool = False) -> FilterTrace:
    """Alternate predict(mean, cov, k) and update(mean, cov, z, k) over steps 1..T; build the trace.

    ``update`` returns the posterior mean and covariance, the NIS, the log-likelihood increment
    and the innovation with its covariance :math:`(\nu_k, S_k)`. At a step where some trials have
    no measurement, ``update`` gets the other trials' rows only (or is not called), and then
    ``update_skipped()`` (if given) tells the kind, whose update may keep state for the next
    prediction (the UKF's square root). With ``scores``, the trace's ``predictive`` holds the
    exact scores of the predictive law :math:`N(z_k - \nu_k, S_k)` (:func:`gaussian_scores`).
    """
    trials, steps, _ = measurements.shape
    missing = np.isnan(measurements).any(axis=-1)        # (trials, T): predict-only steps
    mean, covariance = prior_moments(prior, trials, model.state_dimension)
    d = mean.shape[-1]
    estimates = np.empty((trials, steps, d))
    covariances = np.empty((trials, steps, d, d))
    nis = np.empty((trials, steps))
    log_likelihood = np.zeros(trials)
    increments = np.zeros((trials, steps))          # log N(nu_k; 0, S_k) per step (0: no measurement)
    predictive = Predictive.empty(trials, steps, model.measurement_dimension, energy=False) if scores else None
    k = 0
    try:
        for k in range(1, steps + 1):
            with np.errstate(over="ignore", invalid="ignore"):   # reported by check_finite
                mean, covariance = predict(mean, covariance, k)
            check_finite(kind, model, k, "prediction", mean, covariance)
            if not missing[:, k - 1].any():
                with np.errstate(over="ignore", invalid="ignore"):
                    mean, covariance, nis[:, k - 1], increment, innovation = update(
                        mean, covariance, measurements[:, k - 1], k)
            else:
                mean, covariance, nis[:, k - 1], increment, innovation = _update_observed(
                    update, mean, covariance, measurements[:, k - 1], k, ~missing[:, k - 1])
                if update_skipped is not None:
                    update_skipped()
            if predictive is not None:
                gaussian_scores(predictive, k, measurements[:, k - 1], *innovation, increment, ~missing[:, k - 1])
            check_finite(kind, model, k, "update", mean, covariance)
            log_likelihood += increment
            increments[:, k - 1] = increment
            estimates[:, k - 1] = mean
            covariances[:, k - 1] = covariance
    except Exception as error:        # where it happened, for the one-line report
        note_step(error, k, "filter")
        raise
    trace = FilterTrace.for_gaussian_filter(estimates, covariances, nis, log_likelihood,
                                            position=list(model.position_components),
                                            log_likelihood_increments=increments)
    trace.predictive = predictive
    return trace


def gaussian_scores(predictive: Predictive, k: int, z: np.ndarray, innovation: np.ndarray,
                    innovation_covariance: np.ndarray, increment: np.ndarray, observed: np.ndarray) -> None:
    r"""Step k's exact predictive scores of a Gaussian filter, into ``predictive``: the predictive
    law of :math:`z_k` is :math:`N(\hat z_k, S_k)` with :math:`\hat z_k = z_k - \nu_k` (an angle's
    innovation wrapped, so :math:`\hat z_k` is the prediction on the cut through :math:`z_k`);
    each component's CRPS and PIT are those of its marginal :math:`N(\hat z_{k,j}, S_{k,jj})`
    (:mod:`pfx.numerics.proper_scores`), the log score is :math:`-\log N(\nu_k; 0, S_k)`. The
    energy score of a vector has no closed form: it is left empty."""
    t = k - 1
    sd = np.sqrt(np.diagonal(innovation_covariance, axis1=-2, axis2=-1))
    mean = z - innovation
    rows = observed[:, None]
    predictive.mean[:, t] = np.where(rows, mean, np.nan)
    predictive.sd[:, t] = np.where(rows, sd, np.nan)
    predictive.crps[:, t] = np.where(rows, gaussian_crps(mean, sd, z), np.nan)
    predictive.pit[:, t] = np.where(rows, gaussian_pit(mean, sd, z), np.nan)
    predictive.log_score[:, t] = np.where(observed, -increment, np.nan)


def _update_observed(update, mean, covariance, z, k, observed):
    """The update for the trials with a measurement (``observed``); the others keep the
    prediction, with NIS NaN, log-likelihood increment 0, and an innovation (NaN) and its
    covariance (the identity) that score nothing."""
    mean, covariance = mean.copy(), covariance.copy()
    nis = np.full(len(mean), np.nan)
    increment = np.zeros(len(mean))
    m = z.shape[-1]
    innovation = np.full((len(mean), m), np.nan)
    innovation_covariance = np.broadcast_to(np.eye(m), (len(mean), m, m)).copy()
    if observed.any():
        with np.errstate(over="ignore", invalid="ignore"):
            (mean[observed], covariance[observed], nis[observed], increment[observed],
             (innovation[observed], innovation_covariance[observed])) = update(
                mean[observed], covariance[observed], z[observed], k)
    return mean, covariance, nis, increment, (innovation, innovation_covariance)


def prior_moments(prior, trials: int, dimension: int) -> tuple[np.ndarray, np.ndarray]:
    mean = np.asarray(prior.mean_vector(), dtype=float)
    covariance = np.asarray(prior.covariance_matrix(), dtype=float)
    if mean.shape != (dimension,) or covariance.shape != (dimension, dimension):
        raise ConfigError(f"the prior has dimension {mean.shape[-1] if mean.ndim else 0}, the model {dimension}",
                          key="filter.initial")
    return (np.broadcast_to(mean, (trials, dimension)).copy(),
            np.broadcast_to(symmetric(covariance), (trials, dimension, dimension)).copy())


def check_finite(kind: str, model, k: int, stage: str, mean: np.ndarray, covariance: np.ndarray) -> None:
    if not (np.isfinite(mean).all() and np.isfinite(covariance).all()):
        what = "mean" if not np.isfinite(mean).all() else "covariance"
        raise ModelNumericalError(f"filter {kind}: model {model.kind} gave a NaN or infinite {what} in the "
                                  f"{stage} at step {k} (check the prior, the noise and the model's domain)")


def transpose(matrices: np.ndarray) -> np.ndarray:
    return np.swapaxes(matrices, -1, -2)


def symmetric(matrices: np.ndarray) -> np.ndarray:
    return 0.5 * (matrices + transpose(matrices))


def innovation_terms(kind: str, model, k: int, innovation: np.ndarray, innovation_covariance: np.ndarray):
    """(S^-1 nu, NIS, log N(nu; 0, S)) per trial; raises if S is not positive definite."""
    S = symmetric(innovation_covariance)
    try:
        factor = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise ModelNumericalError(f"filter {kind}: model {model.kind} gave an innovation covariance that is "
                                  f"not positive definite at step {k}") from None
    solved = np.linalg.solve(S, innovation[..., None])[..., 0]
    nis = np.einsum("rm,rm->r", innovation, solved)
    log_determinant = 2.0 * np.sum(np.log(np.diagonal(factor, axis1=-2, axis2=-1)), axis=-1)
    log_density = -0.5 * (nis + log_determinant + innovation.shape[-1] * math.log(2.0 * math.pi))
    return S, nis, log_density


def linear_update(kind, model, k, mean, covariance, z, predicted_measurement, H, noise_r):
    """Kalman update with measurement matrix H (trials, m, d), Joseph form; returns (mean, P, NIS,
    log p(z_k), (innovation, its covariance S)).
    The innovation's angular components are wrapped (:func:`~pfx.filters.kalman.measurement_form.measurement_innovation`)."""
    innovation = measurement_innovation(model, z, predicted_measurement)
    S, nis, log_density = innovation_terms(kind, model, k, innovation, H @ covariance @ transpose(H) + noise_r)
    cross = covariance @ transpose(H)                                   # P H'  (trials, d, m)
    gain = transpose(np.linalg.solve(S, transpose(cross)))             # P H' S^-1 (S symmetric)
    mean = mean + np.einsum("rdm,rm->rd", gain, innovation)
    complement = np.eye(mean.shape[-1]) - gain @ H
    covariance = complement @ covariance @ transpose(complement) + gain @ noise_r @ transpose(gain)
    return mean, symmetric(covariance), nis, log_density, (innovation, S)

