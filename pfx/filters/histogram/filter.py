"""The histogram filter's recursion (predict on the grid, update, report) and its registered kind
(see :mod:`pfx.filters.histogram`)."""

from __future__ import annotations

import math

import numpy as np

from pfx.errors import ModelNumericalError, note_step
from pfx.filters.base import FILTERS, FilterKind
from pfx.filters.histogram.grid import Grid, GridParameters, axis_noises, plan_grid
from pfx.filters.histogram.kernel import CHUNK, Transition
from pfx.filters.trace import FilterTrace
from pfx.laws.initial import PointLaw, UniformLaw
from pfx.numerics.log_weights import log_normalise
from pfx.numerics.quadratic_forms import normalised_squares

# -- the prior on the grid -----------------------------------------------------------------------

def _prior_masses(prior, grid: Grid) -> np.ndarray:
    """Log probabilities of the grid centres under the prior (not normalised: mass outside is lost)."""
    points = grid.points
    if isinstance(prior, UniformLaw):
        low, high = np.asarray(prior.low), np.asarray(prior.high)
        overlap = np.ones(len(points))
        for c, width in enumerate(grid.widths):
            left = np.maximum(points[:, c] - width / 2, low[c])
            right = np.minimum(points[:, c] + width / 2, high[c])
            overlap *= np.clip(right - left, 0.0, None) / (high[c] - low[c])
        with np.errstate(divide="ignore"):
            return np.log(overlap)
    mean, covariance = prior.mean_vector(), prior.covariance_matrix()
    factor = np.linalg.cholesky(covariance)
    standard = np.linalg.solve(factor, (points - mean).T).T
    log_density = (-0.5 * np.sum(standard * standard, axis=1) - np.sum(np.log(np.diag(factor)))
                   - 0.5 * grid.dimension * math.log(2 * math.pi))
    return log_density + math.log(grid.volume)


# -- the filter ----------------------------------------------------------------------------------

def run_histogram_filter(model, measurements: np.ndarray, *, prior, grid: Grid,
                         spread_criterion=None) -> FilterTrace:
    """Run the grid filter on measurements (trials, T, m); see the module docstring."""
    trials, steps, m = measurements.shape
    d = grid.dimension
    noises = axis_noises(model)
    transition = Transition(model, grid, noises)
    timed = model.propagate_reads_time        # its transition changes with time: a kernel per step
    points = grid.points
    size = grid.size
    predicted_h = model.measurement_mean(points)                    # (G, m)
    R_cov = model.measurement_noise.covariance()
    position = list(model.position_components)

    estimates = np.empty((trials, steps, d))
    covariances = np.empty((trials, steps, d, d))
    nis = np.empty((trials, steps))
    log_likelihood = np.zeros(trials)
    increments = np.zeros((trials, steps))      # each step's normaliser: log p(z_k | z_1:k-1) on the grid
    degenerate = np.zeros((trials, steps), dtype=bool)
    lost = np.zeros((trials, steps))
    within = np.empty((trials, steps)) if spread_criterion is not None else None

    if isinstance(prior, PointLaw):
        sources, on_grid = np.asarray(prior.state, dtype=float)[None, :], False
        log_weights = np.zeros((trials, 1))
    else:
        sources, on_grid = points, True
        masses = _prior_masses(prior, grid)
        normalised, total = log_normalise(masses[None, :])
        if not np.isfinite(total[0]):
            raise ModelNumericalError("the filter's prior puts no mass on the histogram filter's grid "
                                      "(filter.grid)")
        lost[:, 0] = max(0.0, 1.0 - math.exp(total[0]))
        log_weights = np.broadcast_to(normalised, (trials, size)).copy()

    kernel, kernel_key = None, None
    chunk = max(1, CHUNK // (size * max(m, d)))
    missing = np.isnan(measurements).any(axis=-1)          # (trials, T): predict-only steps
    k = 0
    try:
        for k in range(1, steps + 1):
            t = k - 1
            control = model.control(k)
            key = (on_grid, None if control is None else np.array(control, dtype=float), k if timed else None)
            if kernel is None or not _same_key(key, kernel_key):      # rebuilt when the control (or time) changes
                kernel = transition.kernel(sources, k, on_grid=on_grid)
                kernel_key = key

            log_q, log_lik = transition.predict(
                kernel, log_weights, lambda: _observed_log_likelihood(model, measurements[:, t], missing[:, t],
                                                                      points, chunk, k))
            q_normalised, q_total = log_normalise(log_q)
            if np.isneginf(q_total).any():
                raise ModelNumericalError(f"every bit of probability mass left the histogram filter's grid at step "
                                          f"{k} (widen filter.grid)")
            lost[:, t] += np.clip(1.0 - np.exp(q_total), 0.0, None)

            q = np.exp(q_normalised)
            for start in range(0, trials, chunk):
                part = slice(start, start + chunk)
                mean_h = q[part] @ predicted_h
                centred = predicted_h[None, :, :] - mean_h[:, None, :]
                S = np.einsum("rg,rgi,rgj->rij", q[part], centred, centred) + R_cov
                innovation = measurements[part, t] - mean_h
                nis[part, t] = normalised_squares(innovation, S)     # NaN where S is not reliably invertible

            with np.errstate(invalid="ignore"):
                posterior, normaliser = log_normalise(log_q + log_lik)
            underflow = np.isneginf(normaliser)
            if underflow.any():
                degenerate[underflow, t] = True
                posterior[underflow] = q_normalised[underflow]
            if missing[:, t].any():
                # predict-only (a likelihood of 1): the posterior is the prediction and the
                # increment 0, not the mass left on the grid (that is grid_lost_mass's business)
                normaliser = np.where(missing[:, t], 0.0, normaliser)
            log_likelihood += normaliser
            increments[:, t] = normaliser

            weights = np.exp(posterior)
            mean = weights @ points
            estimates[:, t] = mean
            for start in range(0, trials, chunk):
                part = slice(start, start + chunk)
                centred = points[None, :, :] - mean[part, None, :]
                covariances[part, t] = np.einsum("rg,rgi,rgj->rij", weights[part], centred, centred)
                if within is not None:
                    distance = np.sum(centred[..., position] ** 2, axis=-1)
                    within[part, t] = np.sum(weights[part] * (distance <= spread_criterion.radius ** 2), axis=-1)

            log_weights = posterior
            if not on_grid:
                sources, on_grid = points, True
    except Exception as error:        # where it happened, for the one-line report
        note_step(error, k, "filter")
        raise
    trace = FilterTrace.for_gaussian_filter(estimates, covariances, nis, log_likelihood, position,
                                            log_likelihood_increments=increments)
    trace.degenerate = degenerate
    trace.within_radius = within
    trace.grid_lost_mass = lost
    return trace


def _observed_log_likelihood(model, measurement: np.ndarray, missing: np.ndarray, points: np.ndarray,
                             chunk: int, step: int) -> np.ndarray:
    """The grid log-likelihood (trials, G), 0 (no information) for trials whose measurement is missing."""
    if not missing.any():
        return _grid_log_likelihood(model, measurement, points, chunk, step)
    out = np.zeros((len(measurement), len(points)))
    if not missing.all():
        out[~missing] = _grid_log_likelihood(model, measurement[~missing], points, chunk, step)
    return out


def _grid_log_likelihood(model, measurement: np.ndarray, points: np.ndarray, chunk: int, step: int) -> np.ndarray:
    """log p(z | x_j) for every trial's measurement (trials, m) and grid point: (trials, G), in chunks of trials."""
    out = np.empty((len(measurement), len(points)))
    for start in range(0, len(measurement), chunk):
        z = measurement[start:start + chunk, None, :]
        with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
            out[start:start + chunk] = model.log_likelihood(z, points[None])
    if np.isnan(out).any() or np.isposinf(out).any():
        raise ModelNumericalError(f"model {model.kind} gave a NaN or infinite log-likelihood on the "
                                  f"histogram filter's grid at step {step}")
    return out


def _same_key(key, previous) -> bool:
    (on_grid, control, step), (previous_on_grid, previous_control, previous_step) = key, previous
    if on_grid != previous_on_grid or step != previous_step or (control is None) != (previous_control is None):
        return False
    return control is None or np.array_equal(control, previous_control)



@FILTERS.register_kind
class HistogramFilter(FilterKind):
    """Grid (point-mass) filter on 1-D and 2-D states: the near-exact posterior, as a reference."""

    kind = "histogram"
    settings = {"grid": (GridParameters, "kind histogram: the grid (box and cells per axis)")}

    def __init__(self, grid: Grid):
        self.grid = grid

    @classmethod
    def plan(cls, model, settings, prior) -> "HistogramFilter":
        """Plan the grid (once per cell: every batch of the cell reuses it)."""
        return cls(plan_grid(model, prior, getattr(settings, "grid", None)))

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None, consistency=False,
            snapshot=None):
        return run_histogram_filter(model, measurements, prior=prior, grid=self.grid,
                                    spread_criterion=spread_criterion)
