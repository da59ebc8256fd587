r"""Moves after resampling (``filter.move``), in the resampling stage of the particle filter's step
(:meth:`pfx.filters.particle.kernel.ParticleKernel.resample`).

Resampling duplicates the heavy particles; a *move* then spreads the copies again. Unlike a
diffusion (:mod:`pfx.filters.particle.diffusion`, which sees only the resampled cloud), a move
is given the step's context by the engine (:class:`MoveContext`): the model, the measurement,
the cloud and its weights before resampling, each resampled particle's parent (its index in
the cloud) and that parent's previous state.
Only the trials that resampled at a step are moved, with draws from their own streams.

* ``none`` (default): nothing; the filter is exactly the one without this setting.
* ``regularise``: the regularised particle filter (Musso, Oudjane & Le Gland 2001). After
  resampling,

  .. math:: x_i \leftarrow x_i + h D \epsilon_i, \qquad D D^\top = \hat\Sigma
     = \frac{\sum_j w_j (x_j - \bar x)(x_j - \bar x)^\top}{1 - \sum_j w_j^2} ,

  with :math:`\hat\Sigma` the *unbiased* weighted covariance of the cloud *before* resampling
  (weights :math:`w_j`, mean :math:`\bar x = \sum_j w_j x_j`; :func:`unbiased_weighted_covariance`)
  and :math:`\epsilon_i` drawn from the kernel :math:`K`:

  - ``gaussian``: :math:`\epsilon \sim N(0, I_d)`, covariance :math:`I_d`;
  - ``epanechnikov``: :math:`K(\epsilon) = \frac{d+2}{2 c_d} (1 - \lVert\epsilon\rVert^2)` on the
    unit ball, :math:`c_d = \pi^{d/2} / \Gamma(d/2 + 1)` its volume; covariance
    :math:`I_d / (d + 4)`. Sampled exactly: the radius has :math:`r^2 \sim \mathrm{Beta}(d/2, 2)`
    and the direction is uniform, which is :math:`\epsilon = Z / \sqrt{\lVert Z\rVert^2 + 2(E_1
    + E_2)}` with :math:`Z \sim N(0, I_d)`, :math:`E_{1,2} \sim \mathrm{Exp}(1)` (since
    :math:`\lVert Z\rVert^2/2 \sim \Gamma(d/2)`, :math:`E_1 + E_2 \sim \Gamma(2)`, the ratio
    :math:`\Gamma(d/2) / (\Gamma(d/2) + \Gamma(2))` is :math:`\mathrm{Beta}(d/2, 2)`, and
    :math:`Z / \lVert Z\rVert` is uniform and independent of :math:`\lVert Z\rVert`).

  The denominator :math:`1 - \sum_j w_j^2 = 1 - 1/N_\text{eff}` makes :math:`\hat\Sigma` the
  reliability-weights estimator (unbiased for independent draws of one law under weights that do
  not depend on them; a factor :math:`N_\text{eff} / (N_\text{eff} - 1)` over the plain weighted
  covariance); with equal weights it is the usual :math:`N/(N-1)` sample covariance. Where one weight
  holds all the mass to round-off (:math:`1 - \max_j w_j < 10^{-10}`, the test of DAPPER's
  ``weight_degeneracy``), the weighted covariance is zero to round-off and a filter without
  process noise would never spread its copies again: :math:`\hat\Sigma` is then the unweighted
  (:math:`M/(M-1)`) covariance of the cloud's :math:`M` members, the particles with a finite
  log-weight (a lost particle, parked at 0, an adaptive count's inactive particle and one the
  measurement rules out have log-weight :math:`-\infty`); with a single member it is 0.

  ``bandwidth`` gives the base :math:`h_0` and ``bandwidth_scale`` :math:`c` (default 1)
  multiplies it, :math:`h = c\, h_0`. ``optimal`` is :math:`h_0 = A N^{-1/(d+4)}`, optimal (mean
  integrated square error) for a Gaussian density, with

  .. math:: A_\text{gaussian} = \left(\frac{4}{d+2}\right)^{1/(d+4)}, \qquad
     A_\text{epanechnikov} = \left[8 c_d^{-1} (d+4) (2\sqrt\pi)^d\right]^{1/(d+4)} ;

  ``scott`` (Gaussian kernel only) is Scott's rule of thumb :math:`h_0 = N^{-1/(d+4)}`, which is
  DAPPER's ``auto_bandw(N, d)``: DAPPER's ``PartFilt(N, reg, ...)`` jitters with
  :math:`h = \mathrm{reg}\, N^{-1/(d+4)}`, i.e. ``bandwidth: scott, bandwidth_scale: reg``
  (its bandwidth lacks the factor :math:`A_\text{gaussian} < 1`, so ``optimal`` would need
  ``bandwidth_scale`` :math:`= \mathrm{reg} / A_\text{gaussian}`); a number sets :math:`h_0`.

  ``jitter`` says which resampled particles move: ``all`` (default; Musso et al.: every
  particle), or ``duplicates`` (DAPPER's ``PartFilt``, whose default ``nuj=True`` its published
  Lorenz tables use): only the particles whose parent was drawn more than once, *every* copy of
  such a parent (DAPPER's ``mask_unique_of_sorted``); a parent drawn once keeps its single
  offspring where it is. The kernel is drawn for every particle either way
  (the stream advances by the same count whatever the ancestry, and the two forms move a shared
  particle by the same draw); the unmoved particles' draws are discarded.
* ``mcmc``: resample-move (Gilks & Berzuini 2001). After resampling, ``steps`` random-walk
  Metropolis steps per particle, each leaving the step's target invariant given the particle's
  parent :math:`a_i`:

  .. math:: \pi_i(x_k) \propto p(z_k \mid x_k)\, p(x_k \mid x_{k-1}^{a_i}), \qquad
     p(x_k \mid x_{k-1}) = N(x_k - f(x_{k-1}, u_k, 0);\ 0, Q) ,

  which needs additive Gaussian process noise with one component per state component (refused
  otherwise at validation) and the Bayesian weighting (``weighting: gaussian``: with another
  weighting the filter's weights target another distribution). The proposal is
  :math:`y = x + s D \eta`, :math:`\eta \sim N(0, I_d)`, with :math:`D D^\top = \sum_j w_j
  (x_j - \bar x)(x_j - \bar x)^\top` the weighted covariance before resampling (without the
  unbiasing and the fallback of ``regularise``: the proposal's scale changes no target); it is
  accepted with probability :math:`\min(1, \pi_i(y) / \pi_i(x))`. The default scale
  :math:`s = 2.38 / \sqrt d` is Roberts, Gelman & Gilks' (1997) for Gaussian targets, whose
  proposal covariance approximates the target's (a particle's target given its parent is
  narrower than the cloud when the process noise is small: then a smaller
  ``scale`` raises the acceptance). The mean acceptance rate over the moved steps and
  proposals is reported per trial (``move_acceptance`` in trials.csv). A step whose
  measurement is missing targets the transition density alone.

A move and a diffusion both rejuvenate the resampled cloud, so a move other than ``none``
with a diffusion other than ``none`` is refused; so is a move on ``sis``, which never resamples.

Both moves are written once against the array namespace (:func:`pfx.numerics.arrays.namespace`):
the kernel's resampling stage (:mod:`pfx.filters.particle.kernel`) calls them on the resampled
trials (on JAX on every trial, keeping the moved particles where a trial resampled). On
jax a singular covariance is repaired as on NumPy (:func:`square_root`'s clipped eigenvalues),
never raised, and the mcmc move's Metropolis steps are one compiled loop
(:func:`pfx.numerics.arrays.repeat`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, model_validator

from pfx.filters.backends import BOTH, Backends
from pfx.numerics.arrays import namespace, repeat
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
    indices: np.ndarray                # (R, N) each resampled particle's parent, an index into cloud
    log_weights: np.ndarray            # (R, N) the cloud's log-weights (-inf: lost, or inactive)
    # (R, N, d) f(x_{k-1}, u_k, 0) of each parent, for a move that needs parents; None: the move
    # computes it (model.mean_transition, on the host's step number); the jax engine gives it,
    # from the compiled step's control and substep times
    parent_means: Optional[np.ndarray] = None


def weighted_covariance(weights: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """sum_j w_j (x_j - xbar)(x_j - xbar)' per trial: (R, N), (R, N, d) -> (R, d, d); NumPy or JAX."""
    xp = namespace(weights, cloud)
    mean = xp.matmul(weights[:, None, :], cloud)
    centred = cloud - mean
    return xp.matmul(centred.transpose(0, 2, 1) * weights[:, None, :], centred)


# 1 - max_j w_j below this: one particle holds all the mass to round-off (DAPPER's weight_degeneracy)
DEGENERATE_WEIGHTS = 1e-10


def unbiased_weighted_covariance(weights: np.ndarray, cloud: np.ndarray, members: np.ndarray) -> np.ndarray:
    r"""The reliability-weights covariance per trial, (R, N), (R, N, d), (R, N) -> (R, d, d):

    .. math:: \hat\Sigma = \frac{\sum_j w_j (x_j - \bar x)(x_j - \bar x)^\top}{1 - \sum_j w_j^2},
       \qquad \bar x = \sum_j w_j x_j ,

    unbiased for independent draws weighted by fixed weights (equal weights: the N/(N-1) sample
    covariance). In a trial where :math:`1 - \max_j w_j <` ``DEGENERATE_WEIGHTS`` the weights are
    replaced by 1/M over its M ``members`` (the unweighted covariance of the cloud), since
    otherwise :math:`\hat\Sigma` is zero to round-off; a trial with a single member has
    :math:`\hat\Sigma = 0` (no spread to estimate). NumPy or JAX (which cannot skip the
    fallback where no trial needs it: it computes it and selects).
    """
    xp = namespace(weights, cloud)
    degenerate = 1.0 - weights.max(axis=-1) < DEGENERATE_WEIGHTS
    if xp is not np or degenerate.any():
        uniform = members / xp.maximum(members.sum(axis=-1, keepdims=True), 1)
        weights = xp.where(degenerate[:, None], uniform.astype(weights.dtype), weights)
    spread = 1.0 - xp.sum(weights * weights, axis=-1)
    if xp is np:
        unbiasing = np.divide(1.0, spread, out=np.zeros_like(spread), where=spread > 0)
    else:           # a select: 1 / spread where positive, 0 where not (a division by 0 never taken)
        unbiasing = xp.where(spread > 0, 1.0 / xp.where(spread > 0, spread, 1.0), 0.0)
    return weighted_covariance(weights, cloud) * unbiasing[:, None, None]


def shared_parents(indices: np.ndarray) -> np.ndarray:
    """(R, N) True where a resampled particle's parent index appears more than once in its row;
    NumPy (a bincount) or JAX (a scatter-add, the bincount of a fixed shape)."""
    trials, n = indices.shape
    xp = namespace(indices)
    if xp is np:
        flat = indices + n * np.arange(trials)[:, None]
        offspring = np.bincount(flat.ravel(), minlength=trials * n).reshape(trials, n)
    else:
        offspring = xp.zeros((trials, n), xp.int32).at[xp.arange(trials)[:, None], indices].add(1)
    return xp.take_along_axis(offspring, indices, axis=-1) > 1


def square_root(covariance: np.ndarray) -> np.ndarray:
    """D with D D' = covariance, per trial, from the eigendecomposition (a collapsed cloud has a
    singular covariance, which a Cholesky factorisation refuses; its negative round-off
    eigenvalues are clipped to 0). NumPy or JAX alike: nothing raises, so a compiled step
    repairs a singular covariance by the same clip (a zero covariance: D = 0, no move)."""
    xp = namespace(covariance)
    values, vectors = xp.linalg.eigh(covariance)
    return vectors * xp.sqrt(xp.clip(values, 0.0, None))[:, None, :]


def unit_ball_volume(dimension: int) -> float:
    """c_d = pi^(d/2) / Gamma(d/2 + 1)."""
    return math.pi ** (dimension / 2) / math.gamma(dimension / 2 + 1)


class _Move(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    needs_parents: ClassVar[bool] = False      # whether the engine keeps x_{k-1} for MoveContext.parents
    reports_acceptance: ClassVar[bool] = False
    #: where it runs (pfx.filters.backends)
    backends: ClassVar[Backends] = Backends(what="moves after resampling", why="it is written for the NumPy engine's step")

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
    backends: ClassVar[Backends] = Backends(BOTH)


@MOVES.register_kind
class Regularisation(_Move):
    """Regularised particle filter: x <- x + h D eps, D D' the unbiased weighted covariance before resampling (Musso et al. 2001)."""

    kind: Literal["regularise"] = "regularise"
    backends: ClassVar[Backends] = Backends(BOTH)
    kernel: Literal["gaussian", "epanechnikov"] = Field("gaussian", description="the kernel eps is drawn from")
    bandwidth: Union[Literal["optimal", "scott"], Annotated[StrictFloat, Field(gt=0)]] = Field(
        "optimal", description="h before bandwidth_scale: `optimal` (A N^(-1/(d+4))), `scott` (N^(-1/(d+4)), "
                               "DAPPER's; gaussian kernel only) or a positive number")
    bandwidth_scale: Annotated[StrictFloat, Field(gt=0)] = Field(
        1.0, description="c in h = c h_0 (DAPPER's reg, with bandwidth: scott)")
    jitter: Literal["all", "duplicates"] = Field(
        "all", description="which resampled particles move: all (Musso et al.), or duplicates: every copy of a "
                           "parent drawn more than once (DAPPER's default)")

    @model_validator(mode="after")
    def _scott_is_gaussian(self) -> "Regularisation":
        if self.bandwidth == "scott" and self.kernel != "gaussian":
            raise ValueError("@bandwidth: scott (h = N^(-1/(d+4)), Scott's rule of thumb) is a bandwidth for the "
                             "gaussian kernel; with kernel: epanechnikov use optimal or a number")
        return self

    def bandwidth_for(self, particles: int, dimension: int) -> float:
        r"""h = c h_0: c = ``bandwidth_scale``; h_0 the given number, h_opt = A N^(-1/(d+4)), or
        Scott's N^(-1/(d+4)) (module docstring). DAPPER's ``reg * auto_bandw(N, d)`` is
        ``bandwidth: scott, bandwidth_scale: reg``."""
        d = dimension
        if self.bandwidth == "optimal":
            if self.kernel == "gaussian":
                constant = (4.0 / (d + 2)) ** (1.0 / (d + 4))
            else:
                constant = (8.0 / unit_ball_volume(d) * (d + 4) * (2.0 * math.sqrt(math.pi)) ** d) ** (1.0 / (d + 4))
            base = constant * particles ** (-1.0 / (d + 4))
        elif self.bandwidth == "scott":
            base = particles ** (-1.0 / (d + 4))
        else:
            base = float(self.bandwidth)
        return self.bandwidth_scale * base

    def draw_kernel(self, random: TrialStreams, particles: int, dimension: int) -> np.ndarray:
        """eps_i, (R, N, d): standard normal, or Epanechnikov on the unit ball (module docstring);
        from TrialStreams or KeyStreams."""
        normal = random.standard_normal((particles, dimension))
        if self.kernel == "gaussian":
            return normal
        exponential = random.standard_exponential((particles, 2))
        xp = namespace(normal)
        return normal / xp.sqrt(xp.sum(normal * normal, axis=-1, keepdims=True)
                                + 2.0 * exponential.sum(axis=-1, keepdims=True))

    def apply(self, context, random):
        """NumPy or JAX (the context's arrays and the streams of either engine)."""
        _, n, d = context.resampled.shape
        xp = namespace(context.resampled)
        members = xp.isfinite(context.log_weights)
        root = square_root(unbiased_weighted_covariance(context.weights, context.cloud, members))
        eps = self.draw_kernel(random, n, d)      # every particle's, moved or not: one count per step
        moved = context.resampled + self.bandwidth_for(n, d) * xp.matmul(eps, root.transpose(0, 2, 1))
        if self.jitter == "duplicates":
            moved = xp.where(shared_parents(context.indices)[..., None], moved, context.resampled)
        return moved, None


@MOVES.register_kind
class ResampleMove(_Move):
    """Resample-move: random-walk Metropolis steps leaving p(z_k | x_k) p(x_k | parent) invariant (Gilks & Berzuini 2001)."""

    kind: Literal["mcmc"] = "mcmc"
    backends: ClassVar[Backends] = Backends(BOTH)
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
                             f"process noise covariance L Q L' (model {model.kind}'s is singular); use a move that "
                             "needs no transition density (diffusion, roughening, regularisation), or give the model "
                             "a process noise of full rank")
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
        """NumPy or JAX: on JAX the Metropolis steps are one compiled loop (:func:`~pfx.numerics.arrays.repeat`,
        new keys at every pass) and the context gives the parents' predictions."""
        model, density, steps = context.model, self.density, self.settings.steps
        trials, n, d = context.resampled.shape
        xp = namespace(context.resampled)
        scale = self.settings.scale if self.settings.scale is not None else 2.38 / math.sqrt(d)
        factor = scale * square_root(weighted_covariance(context.weights, context.cloud)).transpose(0, 2, 1)
        predicted_mean = context.parent_means
        if predicted_mean is None:
            predicted_mean = model.mean_transition(context.parents, context.step)
        measurement = context.measurement[:, None, :]
        observed = ~xp.isnan(context.measurement).any(axis=-1)
        # NumPy skips the likelihood where no trial has a measurement; a compiled step cannot ask
        weigh = xp is not np or observed.any()

        def log_target(state):
            """log p(z | x) + log p(x | parent), up to a constant; -inf where undefined."""
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                value = density.log_density(state, predicted_mean)
                if weigh:
                    value = value + xp.where(observed[:, None], model.log_likelihood(measurement, state), 0.0)
            return xp.where(xp.isnan(value), -xp.inf, value)

        def metropolis_step(carried):
            state, current, accepted = carried
            proposal = state + xp.matmul(random.standard_normal((n, d)), factor)
            proposed = log_target(proposal)
            with np.errstate(divide="ignore", invalid="ignore"):
                accept = xp.log(random.uniform((n,))) < proposed - current    # NaN (-inf - -inf): reject
            return (xp.where(accept[..., None], proposal, state), xp.where(accept, proposed, current),
                    accepted + accept.sum(axis=-1))

        state = context.resampled
        current = log_target(state)
        state, current, accepted = repeat(steps, metropolis_step, (state, current, xp.zeros(trials, current.dtype)))
        return state, accepted / (n * steps)


Move = MOVES.kind_union()
