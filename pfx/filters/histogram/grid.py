"""The histogram filter's grid: its settings (``filter.grid``), the resolved :class:`Grid`, and
:func:`plan_grid`, which derives the box from the prior and simulated trajectories and refuses
what the filter cannot run (see :mod:`pfx.filters.histogram`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, model_validator

from pfx.errors import ConfigError
from pfx.laws.initial import GaussianLaw, UniformLaw
from pfx.laws.noise import Noise
from pfx.numerics.seeding import TrialStreams

DEFAULT_CELLS = {1: 2000, 2: 200}
MAX_KERNEL_BYTES = 2 * 1024**3
PRIOR_STDS = 6.0                 # default grid: prior mean +- 6 standard deviations ...
REACH_TRAJECTORIES = 1000        # ... joined with the range of simulated trajectories ...
REACH_SEED = 20_240_601          # ... drawn with this private seed ...
MARGIN = 0.10                    # ... widened by 10 % of the width on each side ...
MARGIN_STDS = 6.0                # ... plus 6 process noise standard deviations

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
    r"""The process noise on the state, :math:`L w`, as independent 1-D noises, one per state axis
    (ConfigError if it is not).

    The noise must enter additively, :math:`x' = f(x, u) + L w` with a constant gain :math:`L`
    (the model's transition density, :meth:`pfx.models.base.Model.transition_density`). Gaussian
    noise needs a diagonal :math:`Q = L \Sigma_w L^\top`, whose diagonal gives the axis variances;
    another family, a diagonal :math:`L` and :math:`\Sigma_w`, axis c's noise being
    :math:`L_{cc} w_c` (variance :math:`L_{cc}^2 \Sigma_{w,cc}`, as every family is parameterised by
    its variance). A constant gain such as the stochastic-volatility model's :math:`\sigma w`
    is therefore allowed."""
    d = model.state_dimension
    density = _whole_step_density(model)
    noise = model.process_noise
    gain = density.gain
    square_diagonal = gain.shape == (d, d) and not np.any(gain[~np.eye(d, dtype=bool)])
    if noise.family == "gaussian":
        covariance = density.covariance
    elif square_diagonal:
        covariance = gain @ noise.covariance() @ gain.T
    else:
        raise ConfigError(f"the histogram filter needs process noise with one component per state component; "
                          f"model {model.kind}'s {noise.family} noise of {model.process_noise_dimension} "
                          f"component(s) enters its {d} state components through a gain that is not diagonal",
                          key="filter.kind")
    if np.any(covariance[~np.eye(d, dtype=bool)] != 0.0):
        raise ConfigError("the histogram filter needs process noise with a diagonal covariance "
                          "(independent components)", key="filter.model.process_noise.variance")
    variances = np.diag(covariance)
    if np.any(variances <= 0.0):
        raise ConfigError("the histogram filter needs a positive process noise variance on every state "
                          "component (its transition density is evaluated)", key="filter.model.process_noise.variance")
    return [Noise(family=noise.family, variance=float(v), df=noise.df).bind(1) for v in variances]


def _whole_step_density(model):
    """The additive transition of a whole step, x' = f(x, u) + L w (ConfigError if there is none)."""
    if model.propagations_per_step > 1:
        raise ConfigError(f"the histogram filter needs the transition density of a whole step; model {model.kind} "
                          f"takes {model.propagations_per_step} substeps between measurements (model.substeps), "
                          "whose composition has none pfx can evaluate", key="filter.kind")
    density = model.transition_density()
    if isinstance(density, ValueError):
        raise ConfigError(f"the histogram filter needs additive process noise (x' = f(x, u) + L w); "
                          f"model {model.kind} {density.reason}", key="filter.kind")
    return density


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
        raise ConfigError(f"a grid of {'x'.join(map(str, cells))} cells needs a transition kernel of "
                          f"{kernel_bytes / 1024**3:.1f} GiB; use fewer cells", key="filter.grid.cells")
    return grid

