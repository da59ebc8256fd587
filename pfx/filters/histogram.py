r"""The grid (point-mass, histogram) filter: a near-exact reference posterior in 1-D and 2-D.

The state space is cut into a regular grid of cells with centres :math:`x_j` and volume
:math:`\Delta = \prod_c \Delta_c`; the posterior is a probability :math:`\pi_{k,j}` on the
centres, i.e. the posterior density sampled at the centres, :math:`\pi_{k,j} \approx
p(x_j \mid z_{1:k})\,\Delta` (the point-mass method: Bucy & Senne 1971; Kitagawa 1987; Šimandl,
Královec & Söderström 2006). Each step k = 1..T:

1. **Predict** with the transition density of additive process noise,
   :math:`p(x_k \mid x_{k-1}) = p_w(x_k - f(x_{k-1}, u_k))`, where
   :math:`f(x, u)` is ``model.propagate(x, u, 0)``:

   .. math:: q_{k,j} = \sum_i \pi_{k-1,i}\, K_{ij}, \qquad
             K_{ij} = \frac{p_w(x_j - f(x_i, u_k))\,\Delta}{\sum_{n \in \text{lattice}}
                                                         p_w(y_n - f(x_i, u_k))\,\Delta}.

   Each source's kernel is normalised over the *infinite* lattice :math:`y_n` the grid belongs
   to, so each row of :math:`K` is a probability distribution on the lattice: no mass is
   created or destroyed by the discretisation, and :math:`1 - \sum_j q_{k,j}` is the
   probability that left the grid in this step. The lattice sum depends only on where
   :math:`f(x_i)` falls within a cell; for gaussian noise it is
   :math:`1 + 2\sum_{m \ge 1} e^{-2\pi^2 m^2\sigma^2/\Delta_c^2}\cos(2\pi m\varphi)` (Poisson
   summation; 1 to within :math:`3\cdot10^{-9}` once cells are narrower than :math:`\sigma`), for
   the other families a direct sum over 12 standard deviations.
2. **Update** with the measurement likelihood on the centres and normalise:
   :math:`\pi_{k,j} = q_{k,j}\, p(z_k \mid x_j) / c_k`, :math:`c_k = \sum_j q_{k,j} p(z_k \mid x_j)`;
   :math:`\sum_k \log c_k` is :math:`\log p(z_{1:T})` (from below, when mass was lost).
3. **Report** the posterior mean and covariance of the point masses, the NIS
   :math:`\nu^\top S^{-1}\nu` with :math:`\nu = z_k - E_q[h(x)]`,
   :math:`S = \mathrm{Cov}_q(h(x)) + R` from the normalised predicted masses (as the particle
   filter computes it from its predicted cloud), and the share of posterior mass within the
   convergence radius of the mean (``within_radius``; the same number whether the criterion is
   ``weighted`` or not, a grid having no particle count). ESS is NaN.

The prior enters as its density at the centres times :math:`\Delta` (gaussian), as the exact
share of each cell inside the box (uniform), or, for a point prior, as the kernel from that
point at step 1.

**Accuracy.** Sums over grid points of smooth densities are midpoint-rule integrals, and
these are accurate far beyond the :math:`\Delta_c^2/12` of a cell-average argument: on a
Gaussian of standard deviation :math:`\sigma` the error falls like
:math:`e^{-2\pi^2\sigma^2/\Delta_c^2}` (Poisson summation), :math:`10^{-8}` at
:math:`\Delta_c = \sigma` and below rounding at :math:`\Delta_c = \sigma/3`. On linear-Gaussian
models the grid filter reproduces the Kalman filter's means, covariances, NIS and
log-likelihood to 1e-12 (``tests/test_histogram.py``). What limits it is the grid's *extent*
(mass lost at the edges, recorded) and its *resolution* against the narrowest feature: the
process noise (checked: cells wider than its standard deviation are refused) and the
likelihood (not checked: a measurement of standard deviation :math:`\sigma_z` through
:math:`h` pins :math:`x` to about :math:`\sigma_z / |h'(x)|`, which the cells must resolve).

**The log domain, at matrix-product speed.** Posterior probabilities span hundreds of orders
of magnitude, so the predict step is a log-sum-exp,
:math:`\log q_j = \log \sum_i \exp(a_i + b_{ij})` with :math:`a = \log\pi`,
:math:`b = \log K`. Done literally it costs :math:`G^2` exponentials per trial and step; pfx
computes it as a matrix product of shifted exponentials,
:math:`S_j = \sum_i e^{a_i - \max a}\, e^{b_{ij} - \max_i b_{ij}}`, with every factor below
:math:`\tau` (:math:`10^{-150}` in 1-D, :math:`10^{-100}` per factor in 2-D, so that no product
is subnormal) set to zero. Each dropped term is below :math:`\tau`, so the true sum lies in
:math:`[S_j, S_j + n\tau]` for :math:`n` sources: entries with :math:`S_j \ge 10^{15} n \tau`
are exact to :math:`10^{-15}` relative. The others (far in the tails) keep the lower bound,
unless their upper bound, times the likelihood, could come within :math:`e^{-40}/G` of the
largest certified posterior entry (an outlying measurement): those are recomputed by an exact
log-sum-exp over every source. The posterior is thus the log-domain posterior to about
:math:`10^{-15}` relative error, at the cost of matrix products.

**Costs** (G cells in all, :math:`G_c` per axis; times per trial and step, everything included,
measured with 4 trials per batch on a 2-core machine). The
kernel depends on the step only through the control input: it is built once when the control
is constant (or absent) and again every step otherwise (the growth model's forcing term),
once per batch of trials the runner hands over.

* 1-D: the kernel is a :math:`G \times G` matrix (``8 G^2`` bytes: 32 MB for the default 2000
  cells; ~20 ms to build, ~20 ms per trial and step on the growth model) and the predict an :math:`(\text{trials} \times G)(G \times G)` product for
  the trials of a batch.
* 2-D: the process noise must have a diagonal covariance, so its density factorises over the
  axes, :math:`p_w(w) = p_1(w_1)\,p_2(w_2)`, and
  :math:`q_{(j_1, j_2)} = \sum_i \pi_i K^{(1)}_{i j_1} K^{(2)}_{i j_2}` with one factor per axis
  (the :math:`G \times G` matrix, 12.8 GB at 200 x 200, is never formed). Where :math:`f_c`
  depends on :math:`x_c` alone (checked on every grid point), :math:`K^{(c)}` is indexed by
  the grid coordinate on axis c (:math:`G_c \times G_c`) and the sum is contracted in the
  cheapest order:

  - both axes (random walks, odometry, diagonal linear maps): :math:`K = K_1 \otimes K_2`,
    :math:`Q = K_1^\top \Pi K_2` on the :math:`G_1 \times G_2` array :math:`\Pi`,
    :math:`O(G_1 G_2 (G_1 + G_2))` per trial and step (16 million multiply-adds; ~40 ms at
    the default 200 x 200 with four range beacons);
  - one axis (constant velocity: :math:`f_2 = v` depends on :math:`v` alone): sum over the
    other axis first, also :math:`O(G_1 G_2 (G_1 + G_2))` (~25 ms at 200 x 200);
  - neither (rotations, coupled dynamics): :math:`Q = (K^{(1)})^\top \mathrm{diag}(\pi) K^{(2)}`
    with :math:`K^{(c)}` of size :math:`G \times G_c`: :math:`G\,G_1 G_2` multiply-adds per
    trial and step (1.6e9, ~0.5 s at 200 x 200; 1e8 at 100 x 100) and
    :math:`16\,G (G_1 + G_2)` bytes of kernel (128 MB at 200 x 200).

A correlated (non-diagonal) process noise covariance in 2-D, state dimensions above 2,
process noise that is not additive (:math:`x' = f(x, u) + w`, checked numerically) or whose
dimension differs from the state's, a prior with a singular covariance, cells wider than the
process noise standard deviation and kernels over 2 GiB are refused with
:class:`~pfx.errors.ConfigError` by :func:`plan_grid`, which a plan can call before anything
runs.

**The grid.** ``filter.grid`` (:class:`GridParameters`) gives ``low``, ``high`` (one value per
state component) and ``cells`` (one count for every axis, or one per axis; default 2000 in 1-D
and 200 per axis in 2-D). Bounds left out are derived from the filter's own model and prior:
the box of the prior (mean :math:`\pm 6` standard deviations for a gaussian prior, the box of
a uniform prior, the point of a point prior) joined with the range of 1000 trajectories
simulated from the prior through the filter's model for all T steps (with a fixed private
seed, so the grid depends on the config alone), widened on each side by 10 % of its width
plus 6 process noise standard deviations (so that what the dynamics move from the edge of the
simulated range stays on the grid).
The prior alone would not do: the growth model's state wanders well beyond 6 prior standard
deviations (to about :math:`\pm 30` from a prior of standard deviation 3.2).

**Mass leaving the grid** is lost: the prior's mass outside the grid (counted at step 1) and,
each step, the predicted mass that lands outside. The filter renormalises and goes on (the
posterior is then the posterior *given that the state stayed in the grid*); the lost mass per
trial and step is returned as ``trace.grid_lost_mass`` (trials, T). It is measured before the
update, so it overstates the effect on the posterior when the measurement rules the lost
region out anyway (on the growth model a grid over [-34, 34] lost up to 1e-6 per step, yet its posterior
and log-likelihood agreed to 1e-14 with a grid over [-60, 60]; the default grid, [-53, 53],
loses nothing measurable). If all of a trial's mass
leaves the grid the run stops with :class:`~pfx.errors.ModelNumericalError`. A step whose
every posterior probability underflows (a measurement impossible under the model) is
*degenerate*, as in the particle filter: the trial keeps its predicted distribution, the step
is counted and the log-likelihood is :math:`-\infty`.

The filter draws no random numbers (``random`` is unused).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, model_validator
from scipy.special import logsumexp

from pfx.errors import ConfigError, ModelNumericalError
from pfx.filters.particle.engine import log_normalise
from pfx.filters.registry import FILTERS
from pfx.filters.trace import FilterTrace
from pfx.laws.initial import GaussianLaw, PointLaw, UniformLaw
from pfx.laws.noise import Noise
from pfx.numerics.seeding import TrialStreams

DEFAULT_CELLS = {1: 2000, 2: 200}
MAX_KERNEL_BYTES = 2 * 1024**3
PRIOR_STDS = 6.0                 # default grid: prior mean +- 6 standard deviations ...
REACH_TRAJECTORIES = 1000        # ... joined with the range of simulated trajectories ...
REACH_SEED = 20_240_601          # ... drawn with this private seed ...
MARGIN = 0.10                    # ... widened by 10 % of the width on each side ...
MARGIN_STDS = 6.0                # ... plus 6 process noise standard deviations
LATTICE_STDS = 12.0              # kernel normalisation: lattice sum over +- 12 noise std
RELATIVE = 1e-15                 # certified relative accuracy of the fast predict
NEGLIGIBLE = 40.0                # entries below e^-40 / G of the largest posterior entry
CLIP = {1: 1e-150, 2: 1e-100}    # factors below this are dropped (products stay normal)
CHUNK = 2_000_000                # elements per temporary array chunk

Cells = Annotated[StrictInt, Field(ge=2, le=1_000_000)]


class GridParameters(BaseModel):
    """The grid of the histogram filter: box [low, high] cut into cells per axis."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    low: Optional[list[StrictFloat]] = Field(
        None, description="lower corner of the grid, one value per state component (default: from the prior "
                          "and simulated trajectories, see pfx.filters.histogram)")
    high: Optional[list[StrictFloat]] = Field(
        None, description="upper corner of the grid, one value per state component (default: as low)")
    cells: Optional[Union[list[Cells], Cells]] = Field(
        None, description="cells per axis: one count for every axis or one per axis "
                          "(default 2000 in 1-D, 200 per axis in 2-D)")

    @model_validator(mode="after")
    def _ordered(self):
        if self.low is not None and self.high is not None and len(self.low) == len(self.high) \
                and any(high <= low for low, high in zip(self.low, self.high)):
            raise ValueError("@high: every high must exceed its low")
        return self


@dataclass
class Grid:
    """A resolved grid: cell centres per axis and the flattened points (C order, axis 0 slowest)."""

    low: np.ndarray
    high: np.ndarray
    cells: tuple[int, ...]

    @property
    def dimension(self) -> int:
        return len(self.cells)

    @property
    def size(self) -> int:
        return int(np.prod(self.cells))

    @property
    def widths(self) -> np.ndarray:
        return (self.high - self.low) / np.asarray(self.cells)

    @property
    def volume(self) -> float:
        return float(np.prod(self.widths))

    @property
    def axes(self) -> list[np.ndarray]:
        return [self.low[c] + (np.arange(n) + 0.5) * self.widths[c] for c, n in enumerate(self.cells)]

    @property
    def points(self) -> np.ndarray:
        mesh = np.meshgrid(*self.axes, indexing="ij")
        return np.stack(mesh, axis=-1).reshape(-1, self.dimension)


# -- planning: checks and the grid ----------------------------------------------------------------

def axis_noises(model) -> list[Noise]:
    """The process noise as independent 1-D noises, one per state axis (ConfigError if it is not)."""
    d = model.state_dimension
    if model.process_noise_dimension != d:
        raise ConfigError(f"the histogram filter needs additive process noise with one component per state "
                          f"component; model {model.kind} has {model.process_noise_dimension} noise and "
                          f"{d} state components", key="filter.kind")
    noise = model.process_noise
    covariance = noise.covariance()
    if np.any(covariance[~np.eye(d, dtype=bool)] != 0.0):
        raise ConfigError("the histogram filter needs process noise with a diagonal covariance "
                          "(independent components)", key="filter.model.process_noise.variance")
    variances = np.diag(covariance)
    if np.any(variances <= 0.0):
        raise ConfigError("the histogram filter needs a positive process noise variance on every state "
                          "component (its transition density is evaluated)", key="filter.model.process_noise.variance")
    return [Noise(family=noise.family, variance=float(v), df=noise.df).bind(1) for v in variances]


def _check_additive(model, points: np.ndarray, noises: list[Noise]) -> None:
    """propagate(x, u, w) - propagate(x, u, 0) must be w (checked on a few grid points)."""
    sample = points[np.linspace(0, len(points) - 1, min(7, len(points))).astype(int)]
    std = np.array([math.sqrt(n.covariance()[0, 0]) for n in noises])
    pattern = np.array([0.7, -1.3, 2.1, -0.4, 1.1, -2.2, 0.3])[:len(sample), None]
    noise = pattern * std * np.where(np.arange(len(std)) % 2 == 0, 1.0, -0.8)
    control = model.control(1)
    with np.errstate(all="ignore"):
        moved = model.propagate(sample, control, noise) - model.propagate(sample, control, np.zeros_like(sample))
    if not np.allclose(moved, noise, rtol=1e-6, atol=1e-9 * float(std.max())):
        raise ConfigError(f"the histogram filter needs additive process noise (x' = f(x, u) + w); "
                          f"model {model.kind}'s noise does not enter additively", key="filter.kind")


def _prior_box(prior) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(prior, UniformLaw):
        return np.asarray(prior.low, dtype=float), np.asarray(prior.high, dtype=float)
    mean = prior.mean_vector()
    std = np.sqrt(np.clip(np.diag(prior.covariance_matrix()), 0.0, None))
    return mean - PRIOR_STDS * std, mean + PRIOR_STDS * std


def _reach(model, prior) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis min and max of trajectories simulated from the prior (fixed private seed)."""
    random = TrialStreams.from_seeds([REACH_SEED])
    state = prior.sample(random, (REACH_TRAJECTORIES,))
    low, high = np.full(state.shape[-1], np.inf), np.full(state.shape[-1], -np.inf)
    for k in range(1, model.steps + 1):
        with np.errstate(all="ignore"):
            state = model.transition(state, k, random)
        finite = np.where(np.isfinite(state), state, np.nan)
        with np.errstate(all="ignore"):
            if np.isfinite(finite).any():
                low = np.fmin(low, np.nanmin(finite, axis=(0, 1)))
                high = np.fmax(high, np.nanmax(finite, axis=(0, 1)))
        state = np.where(np.isfinite(state), state, 0.0)
    return low, high


def plan_grid(model, prior, parameters: Optional[GridParameters]) -> Grid:
    """Check that the filter applies to ``model`` and resolve the grid; ConfigError if not.

    Call it at plan time to report problems before anything runs; :func:`histogram` calls it too.
    """
    parameters = parameters or GridParameters()
    d = model.state_dimension
    if d not in (1, 2):
        raise ConfigError(f"the histogram filter handles 1-D and 2-D states; model {model.kind} has {d} "
                          "components", key="filter.kind")
    noises = axis_noises(model)
    if isinstance(prior, GaussianLaw) and np.any(np.linalg.eigvalsh(prior.covariance_matrix()) <= 0.0):
        raise ConfigError("the histogram filter needs a gaussian prior with a positive-definite covariance "
                          "(or a point prior)", key="filter.initial.covariance")
    for key in ("low", "high"):
        value = getattr(parameters, key)
        if value is not None and len(value) != d:
            raise ConfigError(f"expected {d} value(s), got {len(value)}", key=f"filter.grid.{key}")
    cells = parameters.cells if parameters.cells is not None else DEFAULT_CELLS[d]
    cells = tuple(cells) if isinstance(cells, list) else (cells,) * d
    if len(cells) != d:
        raise ConfigError(f"expected one count or {d}, got {len(cells)}", key="filter.grid.cells")

    if parameters.low is None or parameters.high is None:
        low, high = _prior_box(prior)
        reach_low, reach_high = _reach(model, prior)
        low, high = np.fmin(low, reach_low), np.fmax(high, reach_high)
        width = high - low
        if not np.all(np.isfinite(width)):
            raise ConfigError("cannot derive the grid from the prior and the model (non-finite states): "
                              "give filter.grid.low and filter.grid.high", key="filter.grid")
        noise_std = np.array([math.sqrt(noise.covariance()[0, 0]) for noise in noises])
        margin = MARGIN * width + MARGIN_STDS * noise_std
        low, high = low - margin, high + margin
        if parameters.low is not None:
            low = np.asarray(parameters.low, dtype=float)
        if parameters.high is not None:
            high = np.asarray(parameters.high, dtype=float)
        if np.any(high <= low):
            raise ConfigError("the derived grid is empty on some axis: give both low and high",
                              key="filter.grid")
    else:
        low, high = np.asarray(parameters.low, dtype=float), np.asarray(parameters.high, dtype=float)
    grid = Grid(low=low, high=high, cells=cells)

    for c, noise in enumerate(noises):
        std = math.sqrt(noise.covariance()[0, 0])
        if grid.widths[c] > std:
            need = int(math.ceil((high[c] - low[c]) / std))
            raise ConfigError(f"cells are {grid.widths[c]:.4g} wide on axis {model.state_names[c]}, wider than "
                              f"the process noise standard deviation {std:.4g}: use at least {need} cells "
                              "there, or a narrower grid", key="filter.grid.cells")
    kernel_bytes = 8 * (grid.size ** 2 if d == 1 else 2 * grid.size * max(cells))
    if kernel_bytes > MAX_KERNEL_BYTES:
        raise ConfigError(f"a grid of {'x'.join(map(str, cells))} cells needs a {kernel_bytes / 1024**3:.1f} GiB "
                          "transition kernel; use fewer cells", key="filter.grid.cells")
    _check_additive(model, grid.points, noises)
    return grid


# -- the transition kernel ------------------------------------------------------------------------

@dataclass
class _Kernel:
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


class _Transition:
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

    def log_column(self, kernel: _Kernel, c: int, columns: np.ndarray) -> np.ndarray:
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

    def kernel(self, sources: np.ndarray, control, *, on_grid: bool) -> _Kernel:
        """The kernel from ``sources`` (n, d) under control u.

        On a 2-D grid, axis c's factor is indexed by the grid coordinate on axis c when f_c
        depends on x_c alone there (checked on every grid point, to 1e-12 relative).
        """
        d = self.grid.dimension
        zeros = np.zeros_like(sources)
        with np.errstate(over="ignore", invalid="ignore"):
            moved = self.model.propagate(sources, control, zeros)
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
        kernel = _Kernel(own_axis=tuple(own_axis), centres=centres, log_norms=log_norms, factors=[], shifts=[],
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

    def _sums(self, kernel: _Kernel, scaled: np.ndarray) -> np.ndarray:
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

    def predict(self, kernel: _Kernel, log_weights: np.ndarray, log_likelihood_of) -> tuple[np.ndarray, np.ndarray]:
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

    def _exact(self, kernel: _Kernel, log_weights: np.ndarray, rows: np.ndarray, cells: np.ndarray) -> np.ndarray:
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
    transition = _Transition(model, grid, noises)
    points = grid.points
    size = grid.size
    predicted_h = model.measurement_mean(points)                    # (G, m)
    R_cov = model.measurement_noise.covariance()
    position = list(model.position_components)

    estimates = np.empty((trials, steps, d))
    covariances = np.empty((trials, steps, d, d))
    nis = np.empty((trials, steps))
    log_likelihood = np.zeros(trials)
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
    for k in range(1, steps + 1):
        t = k - 1
        control = model.control(k)
        key = (on_grid, None if control is None else np.array(control, dtype=float))
        if kernel is None or not _same_key(key, kernel_key):      # rebuilt when the control changes
            kernel = transition.kernel(sources, control, on_grid=on_grid)
            kernel_key = key

        log_q, log_lik = transition.predict(
            kernel, log_weights, lambda: _grid_log_likelihood(model, measurements[:, t], points, chunk, k))
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
            nis[part, t] = np.einsum("ri,ri->r", innovation, np.linalg.solve(S, innovation[..., None])[..., 0])

        with np.errstate(invalid="ignore"):
            posterior, normaliser = log_normalise(log_q + log_lik)
        underflow = np.isneginf(normaliser)
        if underflow.any():
            degenerate[underflow, t] = True
            posterior[underflow] = q_normalised[underflow]
        log_likelihood += normaliser

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

    trace = FilterTrace.for_gaussian_filter(estimates, covariances, nis, log_likelihood, position)
    trace.degenerate = degenerate
    trace.within_radius = within
    trace.grid_lost_mass = lost
    return trace


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
    (on_grid, control), (previous_on_grid, previous_control) = key, previous
    if on_grid != previous_on_grid or (control is None) != (previous_control is None):
        return False
    return control is None or np.array_equal(control, previous_control)


@FILTERS.register("histogram")
def histogram(model, measurements, random, *, settings, prior, spread_criterion, consistency=False):
    """Grid (point-mass) filter on 1-D and 2-D states: the near-exact posterior, as a reference."""
    grid = plan_grid(model, prior, getattr(settings, "grid", None))
    return run_histogram_filter(model, measurements, prior=prior, grid=grid, spread_criterion=spread_criterion)


histogram.check = lambda model, settings, prior: plan_grid(model, prior, settings.grid)
