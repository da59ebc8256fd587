r"""Proposals: how the particle filter's ``predict`` stage draws :math:`x_k` (``filter.proposal``).

The bootstrap filter draws from the transition, :math:`q = p(x_k \mid x_{k-1}, u_k)`, and the
weight update multiplies by the likelihood alone. A *guided* proposal
:math:`q(x_k \mid x_{k-1}, z_k)` looks at the measurement first; the weight then carries the
importance correction, in the log domain,

.. math::

    \log \tilde w_{k,i} = \log w_{k-1,i} + \log p(z_k \mid x_{k,i})
        + \log p(x_{k,i} \mid x_{k-1,i}) - \log q(x_{k,i} \mid x_{k-1,i}, z_k).

``predict`` returns the last two terms as a per-particle *weight adjustment* that
``update_weights`` adds to the likelihood.

Every guided proposal here is a Gaussian :math:`q = N(m_i, P_i)` built around the particle's
prediction :math:`f_i = f(x_{k-1,i}, u_k, 0)` with the process noise covariance in state
coordinates :math:`Q = L Q_w L^\top` as prior covariance, and needs
:math:`p(x_k \mid x_{k-1}) = N(x_k; f(x_{k-1}, u_k, 0), Q)`: gaussian process noise, additive
(:math:`f(x, u, w) = f(x, u, 0) + L w` with a constant :math:`L`; a model declares it by giving
``process_noise_jacobian``, the same at every state), and :math:`Q` positive definite (a density).

=================  ==============================================================================
name               proposal
=================  ==============================================================================
bootstrap          the transition (the default; the weight adjustment is 0 and is not computed)
locally_optimal    :math:`p(x_k \mid x_{k-1}, z_k)` in closed form, for :math:`z = H x + v`,
                   :math:`v \sim N(0, R)` (a model with ``matrices`` (A, H), e.g. linear_gaussian,
                   and gaussian measurement noise): :math:`P = (Q^{-1} + H^\top R^{-1} H)^{-1}`,
                   :math:`m_i = P (Q^{-1} f_i + H^\top R^{-1} z_k)`; its weight adjustment plus the
                   likelihood is :math:`\log N(z_k; H f_i, H Q H^\top + R)`, a function of
                   :math:`x_{k-1,i}` alone (Doucet, Godsill & Andrieu 2000)
ekf                one extended Kalman update per particle from :math:`N(f_i, Q)`, with
                   :math:`H_i = \partial h / \partial x` at :math:`f_i` (the model's Jacobian or
                   central differences, :mod:`pfx.filters.kalman.linearisation`): the PF-EKF
ukf                one unscented Kalman update per particle from :math:`N(f_i, Q)`
                   (:mod:`pfx.filters.kalman.unscented`): the unscented particle filter of van der
                   Merwe, Doucet, de Freitas & Wan (2000)
=================  ==============================================================================

The Kalman updates are :math:`S_i = H_i Q H_i^\top + R`, :math:`K_i = Q H_i^\top S_i^{-1}`,
:math:`m_i = f_i + K_i (z_k - h(f_i))` and, in Joseph's form (positive definite by construction),
:math:`P_i = (I - K_i H_i) Q (I - K_i H_i)^\top + K_i R K_i^\top`; the locally optimal proposal is
the same update with the exact H (the two forms of m and P are equal by the matrix inversion
lemma). The unscented one takes :math:`h(f_i)`, :math:`S_i` and the cross-covariance from the
2d + 1 sigma points of :math:`N(f_i, Q)` and :math:`P_i = Q - K_i S_i K_i^\top` (on NumPy,
repaired like the UKF's covariances where Cholesky fails; on JAX, see below). The draw is
:math:`x = m_i + C_i \epsilon`, :math:`C_i C_i^\top = P_i`, :math:`\epsilon \sim N(0, I)` from the
trial's stream, so that
:math:`\log q = -\tfrac12 \epsilon^\top \epsilon - \log |C_i| - \tfrac d2 \log 2\pi` exactly.

A trial whose measurement is missing at step k draws from the transition
(:math:`m_i = f_i`, :math:`P = Q`) and gets no adjustment: its step is predict-only as in the
bootstrap filter. The weighting must be ``gaussian`` (the model's likelihood): any other
weighting is not :math:`p(z \mid x)`, and the ratio above would not be an importance weight.

The Kalman updates read the measurement as :math:`z = h(x) + v`, :math:`v \sim N(0, R)`, with the
innovation's angular components wrapped and the unscented images of an angle averaged on the
circle (:mod:`pfx.filters.kalman.measurement_form`). The weights stay correct whatever the
model's likelihood (they divide by q), but a proposal built on a law that is not the model's
would lead the particles astray: a model whose own ``log_likelihood`` is not of that form
(another noise family, an undeclared bearing that wraps) is refused by the guided proposals
here, before the run, and pointed to the bootstrap proposal.

The drawing is written once, against the array namespace (:mod:`pfx.numerics.arrays`):
:meth:`BoundGaussianProposal.propose_from` runs on NumPy arrays in the NumPy driver and on JAX
arrays in the compiled step (:mod:`pfx.filters.particle.jax_engine`), which applies it to every
trial with ``observed`` a mask. All three guided proposals run on both backends (the unscented
transform's sigma points and moments are written against the namespace too). On JAX a Cholesky
factorisation does not raise where the covariance is not positive definite (round-off, in
float32): it returns NaN, and that particle's factor falls back to Q's by a select; the draw is
then :math:`N(m_i, Q)` and :math:`\log q` is computed from the factor used, so the weight stays
an exact importance weight. That is also what ``ukf`` does on JAX where NumPy repairs
:math:`P_i` (jitter, clipped eigenvalues: :func:`pfx.filters.kalman.unscented.robust_square_root`,
which catches NumPy's exception and writes rows in place); :func:`proposal_square_root` is the
one place the two backends part.
"""

from __future__ import annotations

from typing import ClassVar, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat

from pfx.filters.backends import BOTH, Backends
from pfx.filters.kalman.linear_form import check_linear_form
from pfx.filters.kalman.linearisation import measurement_jacobian
from pfx.filters.kalman.measurement_form import check_measurement_form, measurement_angles, measurement_innovation
from pfx.filters.kalman.recursion import transpose
from pfx.filters.kalman.unscented import (
    UnscentedParameters,
    robust_square_root,
    unscented_moments,
    unscented_sigma_points,
)
from pfx.laws.transition_density import LOG_TWO_PI, AdditiveTransition
from pfx.numerics.arrays import constant_like, namespace
from pfx.registry import Registry


class ProposalBase(BaseModel):
    """A proposal's settings (``filter.proposal``); :meth:`bind` makes the object the engine calls.

    A plugin's proposal (``pfx.register_proposal``, docs/plugins.md) subclasses this class (as
    ``pfx.Proposal``), declares ``kind: Literal["name"] = "name"`` and its settings, and defines
    :meth:`propose`; :meth:`check` refuses a model it cannot run on.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    #: False for the bootstrap proposal only: the engine then runs the transition itself
    guided: ClassVar[bool] = True
    #: where it runs (pfx.filters.backends)
    backends: ClassVar[Backends] = Backends(what="guided proposals", why="it is written for the NumPy engine's step")

    def check(self, model) -> None:
        """Raise ValueError('@proposal: reason') if this proposal cannot run on ``model``."""

    def bind(self, model) -> "BoundProposal":
        """The proposal for ``model``, checked, with whatever it computes once per cell."""
        self.check(model)
        return BoundProposal(self, model)

    def propose(self, model, previous: np.ndarray, step: int, measurement: np.ndarray,
                observed: Optional[np.ndarray], random) -> tuple[np.ndarray, np.ndarray]:
        """Draw x_k for particles ``previous`` (R, N, d) given z_k (``measurement``, (R, m)).

        ``observed`` is None when every trial has its measurement, else a boolean (R,) mask.
        Returns the new particles and the weight adjustment
        log p(x_k | x_{k-1}) - log q(x_k | x_{k-1}, z_k), shape (R, N); every draw from
        ``random`` (the trials' streams). ``model.transition_log_density`` gives the first term.
        """
        raise NotImplementedError


class BoundProposal:
    """A proposal bound to a model: ``propose(previous, step, measurement, observed, random)``."""

    def __init__(self, settings: ProposalBase, model):
        self.settings, self.model = settings, model

    def propose(self, previous, step, measurement, observed, random):
        return self.settings.propose(self.model, previous, step, measurement, observed, random)


PROPOSALS: Registry[type["ProposalBase"]] = Registry("proposal")


@PROPOSALS.register_kind
class BootstrapProposal(ProposalBase):
    """The transition p(x_k | x_{k-1}, u_k) (the bootstrap filter)."""

    kind: Literal["bootstrap"] = "bootstrap"
    guided: ClassVar[bool] = False
    backends: ClassVar[Backends] = Backends(BOTH)


def gaussian_transition(model) -> AdditiveTransition:
    """The model's transition density N(x_k; f(x_{k-1}, u_k, 0), Q), Q = L Q_w L', which every
    guided proposal here needs (:meth:`pfx.models.base.Model.transition_density`);
    ValueError('@proposal: ...') when the model's transition density is not that."""
    density = model.transition_density()
    remedy = "use the bootstrap proposal, which needs no transition density"
    if isinstance(density, ValueError):
        reason = density.reason
    elif density.noise.family != "gaussian":
        reason = f"has {density.noise.family} process noise"
    elif density.factor is None:
        reason = "has no transition density: its process noise covariance L Q L' is singular"
        remedy += ", or give the model a process noise of full rank (L Q L' positive definite)"
    else:
        return density
    raise ValueError(f"@proposal: a guided proposal needs the transition density "
                     f"N(x_k; f(x_prev), Q) of additive gaussian process noise; model {model.kind} {reason}: "
                     f"{remedy}")


# What a guided proposal's refusal of a model's own likelihood suggests instead.
BOOTSTRAP_REMEDY = "use the bootstrap proposal (proposal: bootstrap), which weighs by the model's own log_likelihood"


class _GaussianProposal(ProposalBase):
    """q = N(m_i, P_i) around each particle's prediction (module docstring)."""

    def check(self, model):
        gaussian_transition(model)
        self.check_measurement(model)

    def check_measurement(self, model) -> None:
        """ValueError('@proposal: ...') when the model's own log_likelihood is not the
        z = h(x) + v form the proposal's Kalman update assumes (:mod:`pfx.filters.kalman.measurement_form`)."""
        check_measurement_form(model, f"the {self.kind} proposal", "proposal", BOOTSTRAP_REMEDY)

    def bind(self, model) -> "BoundGaussianProposal":
        self.check(model)
        return BoundGaussianProposal(self, model, gaussian_transition(model))

    def moments(self, model, predicted: np.ndarray, noise: np.ndarray, measurement: np.ndarray):
        """(m, C): the proposal's mean (R, N, d) and a factor C of its covariance, C C' = P
        ((R, N, d, d), or (d, d) shared by every particle); ``noise`` is Q."""
        raise NotImplementedError


class BoundGaussianProposal(BoundProposal):
    """A Gaussian proposal bound to a model, with Q and its Cholesky factor computed once."""

    def __init__(self, settings: _GaussianProposal, model, density: AdditiveTransition):
        super().__init__(settings, model)
        self.density = density

    def propose(self, previous, step, measurement, observed, random):
        """The NumPy engine's call: the predictions f(x_{k-1}, u_k, 0) from the step number, then
        :meth:`propose_from`."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            predicted = self.model.mean_transition(previous, step)
            return self.propose_from(predicted, measurement, observed, random)

    def propose_from(self, predicted, measurement, observed, random):
        """Draw x_k ~ N(m_i, P_i) around the predictions ``predicted`` (R, N, d); (x_k, the weight
        adjustment (R, N)). NumPy or JAX alike (:mod:`pfx.numerics.arrays`): the jax engine calls
        it with the predictions it makes from the compiled step's control and substep times, and
        ``observed`` always a mask (R,); NumPy passes None when every trial has its measurement."""
        model, density = self.model, self.density
        xp = namespace(predicted)
        noise, noise_factor = density.covariance, constant_like(density.factor, predicted)
        # A particle whose prediction left the model's domain keeps a NaN state (the engine
        # parks it at weight zero); the others must not see its NaN in the batched algebra.
        finite = xp.isfinite(predicted).all(axis=-1)
        safe = xp.where(finite[..., None], predicted, 0.0)
        if observed is not None:          # a missing measurement: any finite stand-in; see below
            measurement = xp.where(observed[:, None], measurement, 0.0)
        mean, factor = self.settings.moments(model, safe, noise, measurement[:, None, :])
        if xp is not np:                  # jax cannot raise: a failed factorisation falls back to Q's
            factor = xp.where(xp.isfinite(factor).all(axis=(-2, -1), keepdims=True), factor, noise_factor)
            mean, factor = xp.asarray(mean, predicted.dtype), xp.asarray(factor, predicted.dtype)
        if observed is not None:          # missing measurement: the transition, no adjustment
            mean = xp.where(observed[:, None, None], mean, safe)
            factor = xp.where(observed[:, None, None, None], factor, noise_factor)
        standard = random.standard_normal(predicted.shape[1:])       # (R, N, d)
        state = mean + xp.einsum("...ij,...j->...i", factor, standard)
        d = state.shape[-1]
        log_proposal = -0.5 * xp.sum(standard * standard, axis=-1) \
            - xp.sum(xp.log(xp.diagonal(factor, axis1=-2, axis2=-1)), axis=-1) - 0.5 * d * LOG_TWO_PI
        log_transition = density.log_density(state, safe)
        adjustment = log_transition - log_proposal
        if observed is not None:
            adjustment = xp.where(observed[:, None], adjustment, 0.0)
        state = xp.where(finite[..., None], state, xp.nan)
        return state, adjustment


def cholesky_factor(covariance):
    """C with C C' = the symmetrised ``covariance``: NumPy's Cholesky (which raises where it is
    not positive definite), or JAX's, which returns NaN there instead, for
    :meth:`BoundGaussianProposal.propose_from` to repair by a select."""
    xp = namespace(covariance)
    return xp.linalg.cholesky(0.5 * (covariance + transpose(covariance)))


def proposal_square_root(covariance):
    """A factor C of each covariance (..., d, d), C C' = P: on NumPy the UKF's
    :func:`~pfx.filters.kalman.unscented.robust_square_root`, repaired where Cholesky fails (its
    repair counts are dropped: a proposal has no diagnostics to report them in); on JAX :func:`cholesky_factor`, NaN there, for :meth:`BoundGaussianProposal.propose_from` to
    replace by Q's factor (a traced step cannot catch an exception or write a row in place)."""
    if namespace(covariance) is np:
        factor, repaired = robust_square_root(covariance, {"jitter": 0, "clipped": 0})
        # log q takes log |det C| as the sum of log diag C, true of a triangular factor only. The
        # repair's last resort (clipped eigenvalues) returns a full one: such a row is factored
        # again, by Cholesky of the repaired covariance, positive definite by construction.
        full = np.any(np.triu(factor, 1) != 0, axis=(-2, -1))
        for row in zip(*np.nonzero(full)):
            try:
                factor[row] = np.linalg.cholesky(repaired[row])
            except np.linalg.LinAlgError:      # a zero variance: no density to correct, left as it is
                pass
        return factor
    return cholesky_factor(covariance)


def kalman_update(predicted, noise, jacobian, innovation, measurement_noise):
    """The Kalman update from N(f, Q) with innovation z - h(f): (m, C) with
    P = (I - K H) Q (I - K H)' + K R K' = C C'. NumPy or JAX alike."""
    xp = namespace(predicted, jacobian, innovation)
    cross = noise @ transpose(jacobian)                                        # Q H'
    innovation_covariance = jacobian @ cross + measurement_noise               # H Q H' + R
    gain = transpose(xp.linalg.solve(innovation_covariance, transpose(cross)))  # Q H' S^-1 (S symmetric)
    mean = predicted + xp.einsum("...dm,...m->...d", gain, innovation)
    reduction = np.eye(predicted.shape[-1]) - gain @ jacobian
    covariance = reduction @ noise @ transpose(reduction) + gain @ measurement_noise @ transpose(gain)
    return mean, cholesky_factor(covariance)


@PROPOSALS.register_kind
class LocallyOptimalProposal(_GaussianProposal):
    """p(x_k | x_k-1, z_k) in closed form: linear-gaussian measurement, additive gaussian process noise."""

    kind: Literal["locally_optimal"] = "locally_optimal"
    backends: ClassVar[Backends] = Backends(BOTH)

    def check(self, model):
        gaussian_transition(model)
        if model.matrices is None:
            raise ValueError(f"@proposal: the locally_optimal proposal needs a measurement linear in the state, "
                             f"z = H x + v (a model that declares its `matrices`, e.g. linear_gaussian); model "
                             f"{model.kind} has none (use ekf or ukf)")
        check_linear_form(model, "the locally_optimal proposal", "proposal", transition=False)
        if model.measurement_noise.family != "gaussian":
            raise ValueError(f"@proposal: the locally_optimal proposal needs gaussian measurement noise; model "
                             f"{model.kind} has {model.measurement_noise.family} (use ekf or ukf)")
        self.check_measurement(model)

    def moments(self, model, predicted, noise, measurement):
        H = np.asarray(model.matrices[1], dtype=float)
        R = model.measurement_noise.covariance()
        # K and P are the same for every particle: one (d, d) factor, no per-particle algebra.
        gain = np.linalg.solve(H @ noise @ H.T + R, H @ noise).T               # Q H' (H Q H' + R)^-1
        reduction = np.eye(H.shape[1]) - gain @ H
        covariance = reduction @ noise @ reduction.T + gain @ R @ gain.T         # Joseph's form of P
        factor = cholesky_factor(covariance)       # a constant, on the host, on either backend
        return predicted + measurement_innovation(model, measurement, predicted @ H.T) @ gain.T, factor


@PROPOSALS.register_kind
class ExtendedKalmanProposal(_GaussianProposal):
    """One EKF update per particle from N(f(x_k-1), Q): the PF-EKF."""

    kind: Literal["ekf"] = "ekf"
    backends: ClassVar[Backends] = Backends(BOTH)

    def moments(self, model, predicted, noise, measurement):
        jacobian = measurement_jacobian(model, predicted, noise)
        return kalman_update(predicted, noise, jacobian,
                             measurement_innovation(model, measurement, model.measurement_mean(predicted)),
                             model.measurement_noise.covariance())


@PROPOSALS.register_kind
class UnscentedProposal(_GaussianProposal):
    """One UKF update per particle from N(f(x_k-1), Q): the unscented particle filter."""

    kind: Literal["ukf"] = "ukf"
    backends: ClassVar[Backends] = Backends(BOTH)
    alpha: StrictFloat = Field(1.0, gt=0.0, le=1.0, description="spread of the sigma points (0 < alpha <= 1)")
    beta: StrictFloat = Field(2.0, ge=0.0, description="prior knowledge of the distribution (2: gaussian)")
    kappa: StrictFloat = Field(0.0, ge=-1e6, le=1e6, description="secondary scaling; needs d + kappa > 0")

    def check(self, model):
        gaussian_transition(model)
        try:
            self.parameters().check(model.state_dimension)
        except ValueError as error:
            raise ValueError(f"@proposal.{str(error)[1:]}") from None
        self.check_measurement(model)

    def parameters(self) -> UnscentedParameters:
        return UnscentedParameters(alpha=self.alpha, beta=self.beta, kappa=self.kappa)

    def moments(self, model, predicted, noise, measurement):
        """NumPy or JAX alike: Q's factor and R are the host's constants (:func:`constant_like`)."""
        xp = namespace(predicted, measurement)
        leading, d = predicted.shape[:-1], predicted.shape[-1]
        spread, _, _, weight = self.parameters().weights(d)
        curvature = self.beta - self.alpha ** 2
        flat = predicted.reshape(-1, d)                                     # (R N, d): one row per particle
        points = unscented_sigma_points(flat, constant_like(np.linalg.cholesky(noise), flat), spread)
        images = model.measurement_mean(points)
        angles = measurement_angles(model)
        predicted_measurement, measurement_spread = unscented_moments(images, images, weight, curvature, angles, angles)
        _, cross = unscented_moments(points, images, weight, curvature, value_angles=angles)
        innovation_covariance = measurement_spread + constant_like(model.measurement_noise.covariance(), flat)
        gain = transpose(xp.linalg.solve(innovation_covariance, transpose(cross)))
        innovation = measurement_innovation(
            model, xp.broadcast_to(measurement, leading + measurement.shape[-1:]).reshape(flat.shape[0], -1),
            predicted_measurement)
        mean = flat + xp.einsum("rdm,rm->rd", gain, innovation)
        covariance = constant_like(noise, flat) - gain @ innovation_covariance @ transpose(gain)
        return mean.reshape(predicted.shape), proposal_square_root(covariance).reshape(leading + (d, d))


Proposal = PROPOSALS.kind_union()
