r"""The Rauch-Tung-Striebel smoother: the Gaussian filters' estimates revised with later measurements.

A filter's estimate at step k uses :math:`z_{1:k}`; the *fixed-interval smoother* uses the whole
record :math:`z_{1:T}`. For a linear-Gaussian model the smoothed law
:math:`p(x_k \mid z_{1:T}) = N(m^s_k, P^s_k)` is exact, and the Rauch-Tung-Striebel (RTS)
recursion computes it backwards from the filter's output alone, without the measurements: with
the filtered moments :math:`m_k, P_k` (the trace of a ``kf``, ``ekf`` or ``ukf`` run), start at
:math:`m^s_T = m_T`, :math:`P^s_T = P_T` and, for k = T-1 down to 1,

.. math::

    m^-_{k+1} = E[x_{k+1} \mid z_{1:k}], \qquad
    P^-_{k+1} = \mathrm{Cov}[x_{k+1} \mid z_{1:k}], \qquad
    C_{k+1} = \mathrm{Cov}[x_k, x_{k+1} \mid z_{1:k}],

    G_k = C_{k+1} (P^-_{k+1})^{-1},

    m^s_k = m_k + G_k (m^s_{k+1} - m^-_{k+1}), \qquad
    P^s_k = P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top.

Why it works: :math:`x_k` and :math:`x_{k+1}` are jointly Gaussian given :math:`z_{1:k}`, and given
:math:`x_{k+1}` the later measurements tell nothing more about :math:`x_k` (the Markov property);
so :math:`E[x_k \mid x_{k+1}, z_{1:k}] = m_k + G_k (x_{k+1} - m^-_{k+1})`, averaged over the smoothed
law of :math:`x_{k+1}`. Since :math:`P^s_{k+1} \preceq P_{k+1} \preceq P^-_{k+1}`, the correction
to :math:`P_k` is negative semi-definite: smoothing never increases a variance.

The three moments of the prediction are the filter's own predict, from :math:`N(m_k, P_k)` to step
k+1 (the same function, so the same numbers):

* ``kf`` (Rauch, Tung & Striebel 1965): :math:`m^-_{k+1} = A m_k + B u_{k+1}`,
  :math:`P^-_{k+1} = A P_k A^\top + Q`, :math:`C_{k+1} = P_k A^\top`, so
  :math:`G_k = P_k A^\top (P^-_{k+1})^{-1}`. The exact smoother.
* ``ekf`` (the extended RTS smoother): :math:`m^-_{k+1} = f(m_k, u_{k+1}, 0)`,
  :math:`P^-_{k+1} = F_k P_k F_k^\top + L Q L^\top`, :math:`C_{k+1} = P_k F_k^\top`, with
  :math:`F_k = \partial f / \partial x` at :math:`m_k` (the model's, or central differences:
  :mod:`~pfx.filters.kalman.linearisation`).
* ``ukf`` (the unscented RTS smoother, Särkkä 2008): the 2d + 1 sigma points
  :math:`\mathcal X_i` of :math:`N(m_k, P_k)` with the filter's parameters, their images
  :math:`\mathcal Y_i = f(\mathcal X_i, u_{k+1}, 0)`, :math:`m^-_{k+1} = \sum_i W^m_i \mathcal Y_i`,
  :math:`P^-_{k+1} = \sum_i W^c_i (\mathcal Y_i - m^-_{k+1})(\cdot)^\top + L Q L^\top` and
  :math:`C_{k+1} = \sum_i W^c_i (\mathcal X_i - m_k)(\mathcal Y_i - m^-_{k+1})^\top` (in the
  stable form of :mod:`~pfx.filters.kalman.unscented`, the square root of :math:`P_k` repaired as
  the filter repairs it).

With substeps between measurements (:mod:`pfx.filters.kalman.prediction`), the kf and ekf
forms use the Jacobian of the whole step, :math:`C_{k+1} = P_k (F_s \cdots F_1 R)^\top`, which
is the RTS recursion run over the substeps (whose filtered moments are their predictions)
collapsed to the measurement steps; the ukf form is refused there.

For a linear model the three coincide (the EKF's Jacobian is A, the unscented transform is exact
for linear maps). For a nonlinear one, the EKF and UKF smoothers are Gaussian approximations,
as the filters are.

**Missing measurements.** A step without a measurement is predict-only in the filter, so its
filtered moments are the prediction's: :math:`m_k = m^-_k`, :math:`P_k = P^-_k`. The recursion
above needs nothing else: it never reads the measurements, and the smoothed estimate at such a
step is carried by its neighbours' measurements (for k = T, it is the prediction).

The gain is computed by solving :math:`P^-_{k+1} G_k^\top = C_{k+1}^\top` (no inverse); the
smoothed covariances are symmetrised. A singular :math:`P^-_{k+1}` (no process noise and a
degenerate filtered covariance) or a non-finite result raises
:class:`~pfx.errors.ModelNumericalError` naming the kind, the model and the step.

References: H. E. Rauch, F. Tung, C. T. Striebel, "Maximum likelihood estimates of linear
dynamic systems", AIAA Journal 3(8), 1965; S. Särkkä, "Unscented Rauch-Tung-Striebel smoother",
IEEE TAC 53(3), 2008; S. Särkkä, *Bayesian Filtering and Smoothing*, 2013, chapters 8 and 9.
"""

from __future__ import annotations

from typing import ClassVar, Literal, Optional

import numpy as np

from pfx.errors import ModelNumericalError, note_step
from pfx.filters.kalman.linear_form import linear_form
from pfx.filters.kalman.prediction import extended_prediction, linear_step_prediction
from pfx.filters.kalman.recursion import check_finite, symmetric, transpose
from pfx.filters.kalman.unscented import (
    UnscentedParameters,
    robust_square_root,
    unscented_moments,
    unscented_prediction,
)
from pfx.filters.smoothers import SMOOTHERS, Smoothed, Smoother
from pfx.filters.trace import FilterTrace

SMOOTHED_KINDS = ("kf", "ekf", "ukf")


def rts_smooth(model, trace: FilterTrace, kind: str,
               parameters: Optional[UnscentedParameters] = None) -> tuple[np.ndarray, np.ndarray]:
    r"""Smoothed means (trials, T, d) and covariances (trials, T, d, d) at steps 1..T.

    :math:`m^s_k = m_k + G_k (m^s_{k+1} - m^-_{k+1})`,
    :math:`P^s_k = P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top`,
    :math:`G_k = C_{k+1} (P^-_{k+1})^{-1}` (module docstring), from the filtered moments
    ``trace.estimates`` and ``trace.covariances`` of a run of filter ``kind`` (``kf``, ``ekf`` or
    ``ukf``) on ``model``; ``parameters`` are the ``ukf`` run's sigma-point parameters (default:
    the filter's default). Row k-1 of the step axis is step k, as in the trace; units are the
    state's (covariances: their products). Missing measurements need no argument: they are in
    the filtered moments already.
    """
    if kind not in SMOOTHED_KINDS:
        raise ValueError(f"the RTS smoother needs a Gaussian filter's run ({', '.join(SMOOTHED_KINDS)}), not {kind}")
    if trace.covariances is None:
        raise ValueError("the RTS smoother needs the filtered covariances; this trace has none")
    means, covariances = trace.estimates, trace.covariances
    trials, steps, d = means.shape
    if d != model.state_dimension or covariances.shape != (trials, steps, d, d):
        raise ValueError(f"a trace of means {means.shape} and covariances {covariances.shape} does not fit model "
                         f"{model.kind}, whose state has {model.state_dimension} components")
    prediction = _prediction(model, kind, parameters)
    smoothed_means = np.array(means, dtype=float)
    smoothed_covariances = np.array(covariances, dtype=float)
    k = steps
    try:
        for k in range(steps - 1, 0, -1):              # step k is row k - 1
            mean, covariance = means[:, k - 1], covariances[:, k - 1]
            with np.errstate(over="ignore", invalid="ignore"):      # reported by check_finite
                covariance, predicted, predicted_covariance, cross = prediction(mean, covariance, k + 1)
            check_finite(kind, model, k + 1, "RTS smoother's prediction", predicted, predicted_covariance)
            gain = _gain(kind, model, k, cross, predicted_covariance)
            smoothed_means[:, k - 1] = mean + np.einsum("rij,rj->ri", gain, smoothed_means[:, k] - predicted)
            correction = gain @ (smoothed_covariances[:, k] - predicted_covariance) @ transpose(gain)
            smoothed_covariances[:, k - 1] = symmetric(covariance + correction)
            check_finite(kind, model, k, "RTS smoother", smoothed_means[:, k - 1], smoothed_covariances[:, k - 1])
    except Exception as error:         # where it happened, for the one-line report
        note_step(error, k, "RTS smoother")
        raise
    return smoothed_means, smoothed_covariances


def _gain(kind: str, model, k: int, cross: np.ndarray, predicted_covariance: np.ndarray) -> np.ndarray:
    """G_k = C_{k+1} (P^-_{k+1})^{-1}, as the solution of P^-_{k+1} G_k' = C_{k+1}'."""
    try:
        return transpose(np.linalg.solve(symmetric(predicted_covariance), transpose(cross)))
    except np.linalg.LinAlgError:
        raise ModelNumericalError(f"filter {kind}: model {model.kind} gave a singular predicted covariance at step "
                                  f"{k + 1}, so the RTS smoother has no gain at step {k} (no process noise and a "
                                  "degenerate filtered covariance?)") from None


def _prediction(model, kind: str, parameters: Optional[UnscentedParameters]):
    """The kind's predict from N(m_k, P_k) to step k+1 as (P_k, m^-_{k+1}, P^-_{k+1}, C_{k+1}); P_k as
    the kind uses it (the UKF's, repaired where its Cholesky factorisation fails, as in the filter)."""
    if kind == "kf":
        if model.matrices is None:
            raise ValueError(f"the kf smoother needs a linear model that declares its matrices (linear_gaussian, or a "
                             f"plugin model's), not {model.kind}")
        form = linear_form(model)

        def linear(mean, covariance, step):
            predicted, predicted_covariance, F = linear_step_prediction(model, form, step, mean, covariance)
            return covariance, predicted, predicted_covariance, covariance @ transpose(F)

        return linear
    if kind == "ekf":
        def extended(mean, covariance, step):
            predicted, predicted_covariance, F = extended_prediction(model, step, mean, covariance)
            return covariance, predicted, predicted_covariance, covariance @ transpose(F)

        return extended
    parameters = parameters or UnscentedParameters()
    parameters.check(model.state_dimension)
    _, _, _, weight = parameters.weights(model.state_dimension)
    curvature = parameters.beta - parameters.alpha ** 2
    repairs = {"jitter": 0, "clipped": 0}

    def unscented(mean, covariance, step):
        square_root, covariance = robust_square_root(covariance, repairs)
        points, images, predicted, predicted_covariance = unscented_prediction(
            model, model.control(step), mean, square_root, parameters, model.substep_time(step, 0))
        _, cross = unscented_moments(points, images, weight, curvature)
        return covariance, predicted, predicted_covariance, cross

    return unscented


@SMOOTHERS.register_kind
class RauchTungStriebel(Smoother):
    """The Rauch-Tung-Striebel smoother (extended, unscented after ekf, ukf): exact for a linear-Gaussian model."""

    kind: Literal["rts"] = "rts"
    filter_kinds: ClassVar[frozenset[str]] = frozenset({"kf", "ekf", "ukf"})
    needs_history: ClassVar[bool] = False

    def check(self, filter_kind: str, model, settings) -> None:
        """Also refuses the unscented form on a model with substeps or accumulating components:
        its cross-covariance C_{k+1} is that of one unscented transform of one propagate call."""
        super().check(filter_kind, model, settings)
        if filter_kind == "ukf" and (model.propagations_per_step > 1 or tuple(model.accumulating_components)):
            raise ValueError(f"@smoothers: the rts smoother after ukf takes the cross-covariance of one unscented "
                             f"transform of one propagate call; model {model.kind} takes substeps between "
                             "measurements or resets accumulating components (use ekf, whose step Jacobian "
                             "composes the substeps)")

    def smooth_trace(self, model, trace: FilterTrace, kind: str,
                     parameters: Optional[UnscentedParameters] = None) -> Smoothed:
        """The smoothed means and standard deviations of a kf, ekf or ukf run (:func:`rts_smooth`)."""
        means, covariances = rts_smooth(model, trace, kind, parameters)
        deviations = np.sqrt(np.clip(np.diagonal(covariances, axis1=-2, axis2=-1), 0.0, None))
        return Smoothed(means, deviations)


def smooth_after(trace: FilterTrace, model, settings, kind: str,
                 parameters: Optional[UnscentedParameters] = None) -> FilterTrace:
    """The trace with the smoothers its settings ask for (``filter.smoothers``: rts) run on it."""
    for smoother in getattr(settings, "smoothers", None) or ():
        trace.smoothed[smoother.label] = smoother.smooth_trace(model, trace, kind, parameters)
    return trace
