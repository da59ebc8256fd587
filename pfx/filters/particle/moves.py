r"""Moves after resampling (``filter.move``): the particle filter's ``resample_and_move`` stage.

Resampling duplicates the heavy particles; a *move* then spreads the copies again. Unlike a
diffusion (:mod:`pfx.filters.particle.diffusion`, which sees only the resampled cloud), a move
is given the step's context by the engine (:class:`MoveContext`): the model, the measurement,
the cloud and its weights before resampling, and each particle's parent's previous state.
Only the trials that resampled at a step are moved, with draws from their own streams.

* ``none`` (default): nothing; the filter is exactly the one without this setting.
* ``regularise``: the regularised particle filter (Musso, Oudjane & Le Gland 2001). After
  resampling,

  .. math:: x_i \leftarrow x_i + h D \epsilon_i, \qquad D D^\top = \hat\Sigma
     = \sum_j w_j (x_j - \bar x)(x_j - \bar x)^\top ,

  with :math:`\hat\Sigma` the weighted covariance of the cloud *before* resampling (weights
  :math:`w_j`, mean :math:`\bar x = \sum_j w_j x_j`) and :math:`\epsilon_i` drawn from the
  kernel :math:`K`:

  - ``gaussian``: :math:`\epsilon \sim N(0, I_d)`, covariance :math:`I_d`;
  - ``epanechnikov``: :math:`K(\epsilon) = \frac{d+2}{2 c_d} (1 - \lVert\epsilon\rVert^2)` on the
    unit ball, :math:`c_d = \pi^{d/2} / \Gamma(d/2 + 1)` its volume; covariance
    :math:`I_d / (d + 4)`. Sampled exactly: the radius has :math:`r^2 \sim \mathrm{Beta}(d/2, 2)`
    and the direction is uniform, which is :math:`\epsilon = Z / \sqrt{\lVert Z\rVert^2 + 2(E_1
    + E_2)}` with :math:`Z \sim N(0, I_d)`, :math:`E_{1,2} \sim \mathrm{Exp}(1)` (since
    :math:`\lVert Z\rVert^2/2 \sim \Gamma(d/2)`, :math:`E_1 + E_2 \sim \Gamma(2)`, the ratio
    :math:`\Gamma(d/2) / (\Gamma(d/2) + \Gamma(2))` is :math:`\mathrm{Beta}(d/2, 2)`, and
    :math:`Z / \lVert Z\rVert` is uniform and independent of :math:`\lVert Z\rVert`).

  ``bandwidth: optimal`` is :math:`h = A N^{-1/(d+4)}`, optimal (mean integrated square error)
  for a Gaussian density, with

  .. math:: A_\text{gaussian} = \left(\frac{4}{d+2}\right)^{1/(d+4)}, \qquad
     A_\text{epanechnikov} = \left[8 c_d^{-1} (d+4) (2\sqrt\pi)^d\right]^{1/(d+4)} ;

  a number sets :math:`h` itself.
* ``mcmc``: resample-move (Gilks & Berzuini 2001). After resampling, ``steps`` random-walk
  Metropolis steps per particle, each leaving the step's target invariant given the particle's
  parent :math:`a_i`:

  .. math:: \pi_i(x_k) \propto p(z_k \mid x_k)\, p(x_k \mid x_{k-1}^{a_i}), \qquad
     p(x_k \mid x_{k-1}) = N(x_k - f(x_{k-1}, u_k, 0);\ 0, Q) ,

  which needs additive Gaussian process noise with one component per state component (refused
  otherwise at validation) and the Bayesian weighting (``weighting: gaussian``: with another
  weighting the filter's weights target another distribution). The proposal is
  :math:`y = x + s D \eta`, :math:`\eta \sim N(0, I_d)`, with :math:`D D^\top = \hat\Sigma` as
  above; it is accepted with probability :math:`\min(1, \pi_i(y) / \pi_i(x))`. The default
  scale :math:`s = 2.38 / \sqrt d` is Roberts, Gelman & Gilks' (1997) for Gaussian targets,
  whose proposal covariance :math:`\hat\Sigma` approximates the target's (a particle's target
  given its parent is narrower than the cloud when the process noise is small: then a smaller
  ``scale`` raises the acceptance). The mean acceptance rate over the moved steps and
  proposals is reported per trial (``move_acceptance`` in trials.csv). A step whose
  measurement is missing targets the transition density alone.

A move and a diffusion both rejuvenate the resampled cloud, so a move other than ``none``
with a diffusion other than ``none`` is refused; so is a move on ``sis``, which never resamples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt

from pfx.numerics.seeding import TrialStreams
from pfx.registry import Registry


@dataclass
class MoveContext:
    """What the engine hands a move, for the R trials that resampled at step ``step``."""

    model: object
    step: int
    resampled: np.ndarray              # (R, N, d) the resampled particles
    cloud: np.ndarray                  # (R, N, d) the particles before resampling
    weights: np.ndarray                # (R, N) their normalised weights
    measurement: np.ndarray            # (R, m) z_k (NaN where missing)
    parents: Optional[np.ndarray]      # (R, N, d) x_{k-1} of each resampled particle's parent


def weighted_covariance(weights: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """sum_j w_j (x_j - xbar)(x_j - xbar)' per trial: (R, N), (R, N, d) -> (R, d, d)."""
    mean = np.matmul(weights[:, None, :], cloud)
    centred = cloud - mean
    return np.matmul(centred.transpose(0, 2, 1) * weights[:, None, :], centred)


def square_root(covariance: np.ndarray) -> np.ndarray:
    """D with D D' = covariance, per trial, from the eigendecomposition (a collapsed cloud has a
    singular covariance, which a Cholesky factorisation refuses; its negative round-off
    eigenvalues are clipped to 0)."""
    values, vectors = np.linalg.eigh(covariance)
    return vectors * np.sqrt(np.clip(values, 0.0, None))[:, None, :]


def unit_ball_volume(dimension: int) -> float:
    """c_d = pi^(d/2) / Gamma(d/2 + 1)."""
    return math.pi ** (dimension / 2) / math.gamma(dimension / 2 + 1)


class _Move(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    needs_parents: ClassVar[bool] = False      # whether the engine keeps x_{k-1} for MoveContext.parents
    reports_acceptance: ClassVar[bool] = False

    def bind(self, model, settings) -> "_Move":
        """The move for ``model`` (ValueError('@move: reason') if it cannot run with it and the
        filter's ``settings``); a move that needs constants per cell computes them here."""
        return self

    def apply(self, context: MoveContext, random: TrialStreams) -> tuple[np.ndarray, Optional[np.ndarray]]:
        """The moved particles (R, N, d) and, for moves that accept or reject, each trial's
        acceptance rate at this step (R,); draws from ``random``, the resampled trials' streams."""
        raise NotImplementedError


MOVES: Registry[type["_Move"]] = Registry("move")


@MOVES.register_kind
class NoMove(_Move):
    """No move after resampling."""

    kind: Literal["none"] = "none"


@MOVES.register_kind
class Regularisation(_Move):
    """Regularised particle filter: x <- x + h D eps, D D' the weighted covariance before resampling (Musso et al. 2001)."""

    kind: Literal["regularise"] = "regularise"
    kernel: Literal["gaussian", "epanechnikov"] = Field("gaussian", description="the kernel eps is drawn from")
    bandwidth: Union[Literal["optimal"], Annotated[StrictFloat, Field(gt=0)]] = Field(
        "optimal", description="h: `optimal` (A N^(-1/(d+4))) or a positive number")

    def bandwidth_for(self, particles: int, dimension: int) -> float:
        """h: the given number, or h_opt = A N^(-1/(d+4)) (module docstring)."""
        if self.bandwidth != "optimal":
            return float(self.bandwidth)
        d = dimension
        if self.kernel == "gaussian":
            constant = (4.0 / (d + 2)) ** (1.0 / (d + 4))
        else:
            constant = (8.0 / unit_ball_volume(d) * (d + 4) * (2.0 * math.sqrt(math.pi)) ** d) ** (1.0 / (d + 4))
        return constant * particles ** (-1.0 / (d + 4))

    def draw_kernel(self, random: TrialStreams, particles: int, dimension: int) -> np.ndarray:
        """eps_i, (R, N, d): standard normal, or Epanechnikov on the unit ball (module docstring)."""
        normal = random.standard_normal((particles, dimension))
        if self.kernel == "gaussian":
            return normal
        exponential = random.standard_exponential((particles, 2))
        return normal / np.sqrt(np.sum(normal * normal, axis=-1, keepdims=True)
                                + 2.0 * exponential.sum(axis=-1, keepdims=True))

    def apply(self, context, random):
        _, n, d = context.resampled.shape
        root = square_root(weighted_covariance(context.weights, context.cloud))
        eps = self.draw_kernel(random, n, d)
        return context.resampled + self.bandwidth_for(n, d) * np.matmul(eps, root.transpose(0, 2, 1)), None


@MOVES.register_kind
class ResampleMove(_Move):
    """Resample-move: random-walk Metropolis steps leaving p(z_k | x_k) p(x_k | parent) invariant (Gilks & Berzuini 2001)."""

    kind: Literal["mcmc"] = "mcmc"
    steps: StrictInt = Field(1, ge=1, le=10_000, description="Metropolis steps per particle after each resampling")
    scale: Optional[StrictFloat] = Field(
        None, gt=0, description="s in the proposal N(x, s^2 Sigma), Sigma the weighted covariance before "
                                "resampling (default 2.38/sqrt(d))")

    needs_parents: ClassVar[bool] = True
    reports_acceptance: ClassVar[bool] = True

    def bind(self, model, settings) -> "BoundResampleMove":
        if not settings.weighting.is_likelihood:
            raise ValueError(f"@move: the mcmc move targets p(z | x) p(x | parent), the filter's target only with "
                             f"weighting: gaussian, not {settings.weighting.kind}")
        density = model.transition_density()
        if isinstance(density, ValueError):
            raise ValueError(f"@move: the mcmc move evaluates the transition density p(x_k | x_k-1), which needs "
                             f"additive process noise; model {model.kind} {density.reason}")
        if not density.has_density:
            raise ValueError("@move: the mcmc move evaluates the transition density, which needs a positive-definite "
                             f"process noise covariance L Q L' (model {model.kind}'s is singular)")
        return BoundResampleMove(self, density)


class BoundResampleMove:
    """The mcmc move bound to a model: its transition density derived once (ResampleMove)."""

    needs_parents: ClassVar[bool] = True
    reports_acceptance: ClassVar[bool] = True

    def __init__(self, settings: ResampleMove, density):
        self.settings, self.density = settings, density

    @property
    def kind(self) -> str:
        return self.settings.kind

    def apply(self, context, random):
        model, density, steps = context.model, self.density, self.settings.steps
        trials, n, d = context.resampled.shape
        scale = self.settings.scale if self.settings.scale is not None else 2.38 / math.sqrt(d)
        factor = scale * square_root(weighted_covariance(context.weights, context.cloud)).transpose(0, 2, 1)
        parents = context.parents
        predicted_mean = model.mean_transition(parents, context.step)
        measurement = context.measurement[:, None, :]
        observed = ~np.isnan(context.measurement).any(axis=-1)

        def log_target(state):
            """log p(z | x) + log p(x | parent), up to a constant; -inf where undefined."""
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                value = density.log_density(state, predicted_mean)
                if observed.any():
                    value = value + np.where(observed[:, None], model.log_likelihood(measurement, state), 0.0)
            return np.where(np.isnan(value), -np.inf, value)

        state = context.resampled
        current = log_target(state)
        accepted = np.zeros(trials)
        for _ in range(steps):
            proposal = state + np.matmul(random.standard_normal((n, d)), factor)
            proposed = log_target(proposal)
            with np.errstate(divide="ignore", invalid="ignore"):
                accept = np.log(random.uniform((n,))) < proposed - current    # NaN (-inf - -inf): reject
            state = np.where(accept[..., None], proposal, state)
            current = np.where(accept, proposed, current)
            accepted += accept.sum(axis=-1)
        return state, accepted / (n * steps)


Move = MOVES.kind_union()
