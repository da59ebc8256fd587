r"""The histogram filter's transition: per-axis kernel factors normalised over the grid's lattice,
and the certified log-domain predict (see :mod:`pfx.filters.histogram`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from pfx.errors import ModelNumericalError
from pfx.filters.histogram.grid import Grid
from pfx.laws.noise import Noise

LATTICE_STDS = 12.0              # kernel normalisation: lattice sum over +- 12 noise std
RELATIVE = 1e-15                 # certified relative accuracy of the fast predict
NEGLIGIBLE = 40.0                # entries below e^-40 / G of the largest posterior entry
CLIP = {1: 1e-150, 2: 1e-100}    # factors below this are dropped (products stay normal)
CHUNK = 2_000_000                # elements per temporary array chunk


@dataclass
class Kernel:
    """Per-axis factors of the lattice-normalised transition kernel from a set of sources.

    Axis c's factor has one row per source (``own_axis[c]`` False), or, when the sources are
    the grid and f_c depends on x_c alone, one row per grid coordinate on axis c (True);
    ``factors[c]`` holds exp(b - shift) clipped at tau, ``shifts[c]`` the per-column maximum of
    b, the log kernel.
    """

    own_axis: tuple[bool, ...]
    centres: list[np.ndarray]    # f_c at each row, (rows_c,)
    log_norms: list[np.ndarray]  # log of the lattice sum per row, (rows_c,)
    factors: list[np.ndarray]    # (rows_c, G_c)
    shifts: list[np.ndarray]     # (G_c,), may hold -inf
    sources: int                 # number of source points n

    @property
    def separable(self) -> bool:
        return len(self.own_axis) == 2 and all(self.own_axis)


class Transition:
    """Builds kernels for a model on a grid and applies the certified log-domain predict."""

    def __init__(self, model, grid: Grid, noises: list[Noise]):
        self.model = model
        self.grid = grid
        self.noises = noises
        self.axes = grid.axes
        self.tau = CLIP[grid.dimension]

    def axis_log_density(self, c: int, offsets: np.ndarray) -> np.ndarray:
        """log p_c(offsets), elementwise (in place for gaussian noise, the common case)."""
        noise = self.noises[c]
        if noise.family == "gaussian":
            variance = noise.covariance()[0, 0]
            offsets *= offsets
            offsets *= -0.5 / variance
            offsets -= 0.5 * math.log(2.0 * math.pi * variance)
            return offsets
        return noise.log_density(offsets[..., None])

    def log_column(self, kernel: Kernel, c: int, columns: np.ndarray) -> np.ndarray:
        """b_c for the given grid columns of axis c: (rows_c, len(columns))."""
        offsets = self.axes[c][columns][None, :] - kernel.centres[c][:, None]
        return (self.axis_log_density(c, offsets) + math.log(self.grid.widths[c])
                - kernel.log_norms[c][:, None])

    def _lattice_log_norm(self, c: int, centres: np.ndarray) -> np.ndarray:
        """log sum_n p_c(y_n - centre) Delta_c over the axis-c lattice y_n = y_0 + n Delta_c.

        The sum depends on the centre only through its phase phi within a cell,
        y_n - centre = (n - phi) Delta_c. Gaussian noise: Poisson summation gives it in closed
        form, 1 + 2 sum_k exp(-2 pi^2 k^2 sigma^2 / Delta^2) cos(2 pi k phi). Other families:
        the direct sum over the lattice points within 12 standard deviations.
        """
        width = self.grid.widths[c]
        std = math.sqrt(self.noises[c].covariance()[0, 0])
        phase = (centres - self.axes[c][0]) / width
        phase = phase - np.floor(phase)
        if self.noises[c].family == "gaussian":
            ratio = 2.0 * math.pi ** 2 * std ** 2 / width ** 2
            total = np.ones(len(centres))
            k = 1
            while ratio * k * k < 45.0:                    # exp(-45) ~ 3e-20: below rounding
                total += 2.0 * math.exp(-ratio * k * k) * np.cos(2.0 * math.pi * k * phase)
                k += 1
            return np.log(total)
        reach = int(math.ceil(LATTICE_STDS * std / width)) + 1
        steps = np.arange(-reach, reach + 1, dtype=float)
        out = np.empty(len(centres))
        chunk = max(1, CHUNK // len(steps))
        for start in range(0, len(centres), chunk):
            part = phase[start:start + chunk]
            offsets = (steps[None, :] - part[:, None]) * width
            with np.errstate(under="ignore"):
                density = np.exp(self.axis_log_density(c, offsets))
            with np.errstate(divide="ignore"):
                out[start:start + chunk] = np.log(np.sum(density, axis=1) * width)
        return out

    def kernel(self, sources: np.ndarray, step: int, *, on_grid: bool) -> Kernel:
        """The kernel from ``sources`` (n, d) at step k, about the noise-free transition
        f(x, u_k, 0) over the step (:meth:`~pfx.models.base.Model.mean_transition`).

        On a 2-D grid, axis c's factor is indexed by the grid coordinate on axis c when f_c
        depends on x_c alone there (checked on every grid point, to 1e-12 relative).
        """
        d = self.grid.dimension
        with np.errstate(over="ignore", invalid="ignore"):
            moved = self.model.mean_transition(sources, step)
        if not np.all(np.isfinite(moved)):
            bad = sources[~np.isfinite(moved).all(axis=-1)][0]
            raise ModelNumericalError(f"model {self.model.kind} maps the grid point {bad.tolist()} to a NaN or "
                                      "infinite state (narrow the grid: filter.grid)")
        own_axis = [False] * d
        centres = [moved[:, c].copy() for c in range(d)]
        if on_grid and d == 2:
            shaped = moved.reshape(*self.grid.cells, 2)
            scale = 1e-12 * (np.abs(moved).max() + 1.0)
            if np.all(np.abs(shaped[..., 0] - shaped[:, :1, 0]) <= scale):    # f_1 depends on x_1 alone
                own_axis[0], centres[0] = True, shaped[:, 0, 0].copy()
            if np.all(np.abs(shaped[..., 1] - shaped[:1, :, 1]) <= scale):    # f_2 depends on x_2 alone
                own_axis[1], centres[1] = True, shaped[0, :, 1].copy()
        log_norms = [self._lattice_log_norm(c, centres[c]) for c in range(d)]
        kernel = Kernel(own_axis=tuple(own_axis), centres=centres, log_norms=log_norms, factors=[], shifts=[],
                         sources=len(sources))
        for c in range(d):
            rows, columns = len(centres[c]), self.grid.cells[c]
            factor = np.empty((rows, columns))
            chunk = max(1, CHUNK // columns)
            for start in range(0, rows, chunk):
                part = slice(start, start + chunk)
                block = factor[part]                  # a view: gaussian densities are computed in place
                np.subtract(self.axes[c][None, :], centres[c][part, None], out=block)
                factor[part] = self.axis_log_density(c, block)
                factor[part] += math.log(self.grid.widths[c]) - log_norms[c][part, None]
            shift = factor.max(axis=0)
            finite_shift = np.where(np.isfinite(shift), shift, 0.0)
            with np.errstate(invalid="ignore", under="ignore"):
                factor -= finite_shift
                np.exp(factor, out=factor)
            factor[factor < self.tau] = 0.0                  # no NaN here: -inf - 0 gives exp 0
            kernel.factors.append(factor)
            kernel.shifts.append(shift)
        return kernel

    def _sums(self, kernel: Kernel, scaled: np.ndarray) -> np.ndarray:
        """S = sum_i scaled_i K1[i, j1] K2[i, j2] per trial, contracted in the cheapest order."""
        if self.grid.dimension == 1:
            return scaled @ kernel.factors[0]
        trials = scaled.shape[0]
        A1, A2 = kernel.factors
        sums = np.empty((trials, self.grid.size))
        if kernel.own_axis == (False, False):                   # general f: O(n G1 G2)
            for r in range(trials):
                active = np.flatnonzero(scaled[r])              # sources with weight >= tau
                if active.size > kernel.sources // 2:
                    sums[r] = ((A1 * scaled[r, :, None]).T @ A2).ravel()
                else:
                    sums[r] = ((A1[active] * scaled[r, active, None]).T @ A2[active]).ravel()
            return sums
        G1, G2 = self.grid.cells
        for r in range(trials):
            weights = scaled[r].reshape(G1, G2)
            if kernel.own_axis == (True, True):                 # K = K1 (x) K2: O(G1 G2 (G1 + G2))
                sums[r] = (A1.T @ (weights @ A2)).ravel()
            elif kernel.own_axis == (False, True):              # sum over i1 first, then i2
                inner = np.einsum("ab,abj->bj", weights, A1.reshape(G1, G2, G1))     # (G2, G1)
                sums[r] = (inner.T @ A2).ravel()
            else:                                               # (True, False): sum over i2 first
                inner = np.einsum("ab,abk->ak", weights, A2.reshape(G1, G2, G2))     # (G1, G2)
                sums[r] = (A1.T @ inner).ravel()
        return sums

    def predict(self, kernel: Kernel, log_weights: np.ndarray, log_likelihood_of) -> tuple[np.ndarray, np.ndarray]:
        """log q (trials, G) for source log-probabilities (trials, n); certified, see the module docstring.

        ``log_likelihood_of`` gives the log-likelihood (trials, G) used to decide which uncertain
        entries matter; returns (log q, log-likelihood).
        """
        d = self.grid.dimension
        peak = log_weights.max(axis=1)
        with np.errstate(under="ignore"):
            scaled = np.exp(log_weights - peak[:, None])
        scaled[~(scaled >= self.tau)] = 0.0
        sums = self._sums(kernel, scaled)
        shift = kernel.shifts[0] if d == 1 else np.add.outer(kernel.shifts[0], kernel.shifts[1]).ravel()
        bound = kernel.sources * self.tau
        certified = sums >= bound / RELATIVE
        with np.errstate(divide="ignore", invalid="ignore"):
            log_q = np.log(sums) + peak[:, None] + shift[None, :]
            upper = np.log(sums + bound) + peak[:, None] + shift[None, :]
        log_q = np.where(np.isnan(log_q), -np.inf, log_q)
        likelihood = log_likelihood_of()
        with np.errstate(invalid="ignore"):
            candidate = log_q + likelihood
            best = np.max(np.where(certified, candidate, -np.inf), axis=1)
            threshold = best - NEGLIGIBLE - math.log(self.grid.size)
            recompute = ~certified & (upper + likelihood > threshold[:, None])
        # upper is -inf where no source reaches the cell (shift -inf): exactly zero, nothing to do
        recompute &= np.isfinite(upper)
        if recompute.any():
            rows, cells = np.nonzero(recompute)
            log_q[rows, cells] = self._exact(kernel, log_weights, rows, cells)
        return log_q, likelihood

    def _exact(self, kernel: Kernel, log_weights: np.ndarray, rows: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """log sum_i exp(a_ri + b_i,cell) for each (row, cell) pair, by log-sum-exp over the sources."""
        d = self.grid.dimension
        index = np.unravel_index(cells, self.grid.cells)
        source_axis = np.unravel_index(np.arange(kernel.sources), self.grid.cells) if any(kernel.own_axis) else None
        out = np.empty(len(rows))
        per = max(1, CHUNK // max(kernel.sources, 1))
        for start in range(0, len(rows), per):
            part = slice(start, start + per)
            terms = log_weights[rows[part]].copy()
            for c in range(d):
                column = self.log_column(kernel, c, index[c][part]).T          # (k, rows_c)
                terms += column[:, source_axis[c]] if kernel.own_axis[c] else column
            with np.errstate(divide="ignore", invalid="ignore"):
                out[part] = logsumexp(terms, axis=1)
        return np.where(np.isnan(out), -np.inf, out)

