r"""Gaussian filters: the Kalman filter (``kf``), the extended (``ekf``) and the unscented (``ukf``).

Each carries, per trial, a Gaussian belief :math:`N(\hat x_k, P_k)` instead of particles, batched
over the trials of a batch like the particle engine (means (trials, d), covariances (trials, d, d)). Every step
k = 1..T has two halves.

**Predict** through the transition :math:`x_k = f(x_{k-1}, u_k, w_k)`, :math:`w_k \sim (0, Q)`:

.. math::

    \hat x_k^- = f(\hat x_{k-1}, u_k, 0), \qquad
    P_k^- = F_k P_{k-1} F_k^\top + L_k Q L_k^\top,

with :math:`F_k = \partial f / \partial x` and :math:`L_k = \partial f / \partial w` at
:math:`(\hat x_{k-1}, u_k, 0)`. :math:`L Q L^\top` is the process noise in state coordinates
(:math:`L = I` for the additive noise of every current pfx model).

**Update** with the measurement :math:`z_k = h(x_k) + v_k`, :math:`v_k \sim (0, R)`:

.. math::

    \hat z_k = h(\hat x_k^-), \quad \nu_k = z_k - \hat z_k, \quad
    S_k = H_k P_k^- H_k^\top + R, \quad K_k = P_k^- H_k^\top S_k^{-1},

    \hat x_k = \hat x_k^- + K_k \nu_k, \qquad
    P_k = (I - K_k H_k) P_k^- (I - K_k H_k)^\top + K_k R K_k^\top

(Joseph's form: symmetric and positive semi-definite by construction, equal to the textbook
:math:`(I - K H) P^-` for the optimal gain; the result is also symmetrised). The estimate at step k
is the updated mean :math:`\hat x_k`. Two by-products: the normalised innovation squared
:math:`\mathrm{NIS}_k = \nu_k^\top S_k^{-1} \nu_k` (chi-square with m degrees of freedom when
the filter is consistent), and the log-likelihood
:math:`\log p(z_{1:T}) = \sum_k \log N(z_k; \hat z_k, S_k)`, computed from a Cholesky factor of
:math:`S_k` (:math:`\log|S_k| = 2 \sum_i \log (L_S)_{ii}`).

``kf`` (Kalman 1960): f and h are linear, :math:`f = A x + c_k + L w`, :math:`h = H x`, with
:math:`(A, H)` the matrices a model declares (:attr:`~pfx.models.base.Model.matrices`:
``linear_gaussian``, or a plugin's, checked against its ``propagate`` and ``measurement_mean``)
and :math:`c_k = f(0, u_k, 0)` (:mod:`~pfx.filters.kalman.linear_form`). With gaussian noise it
is the exact posterior; with another noise family, the best linear (minimum-variance affine)
estimator, and its log-likelihood that of the Gaussian approximation. It refuses every other model.

**The measurement** is read as :math:`z = h(x) + v` with the innovation's angular components
wrapped; a plugin model whose own ``log_likelihood`` is not of that form is refused by all three
kinds before they run (:mod:`~pfx.filters.kalman.measurement_form`).

**Non-finite values**: a mean or covariance that becomes NaN or infinite, or an innovation
covariance that is not positive definite, raises :class:`~pfx.errors.ModelNumericalError`
naming the filter kind, the model and the step.

References: R. E. Kalman, "A new approach to linear filtering and prediction problems", 1960;
S. J. Julier, J. K. Uhlmann, "A new extension of the Kalman filter to nonlinear systems", 1997;
S. J. Julier, "The scaled unscented transformation", ACC 2002; E. A. Wan, R. van der Merwe,
"The unscented Kalman filter for nonlinear estimation", AS-SPCC 2000; Julier, Uhlmann &
Durrant-Whyte, IEEE TAC 45(3), 2000 (the falling-body comparison of EKF and UKF).

The package: :mod:`~pfx.filters.kalman.recursion` (the predict/update recursion and the linear
update every kind shares), :mod:`~pfx.filters.kalman.measurement_form` (what the kinds assume of
the measurement: the wrapped innovation, and the probe of a plugin's likelihood),
:mod:`~pfx.filters.kalman.linear_form` (the kf's matrices, read from a model and checked),
:mod:`~pfx.filters.kalman.prediction` (the kf's and ekf's predict),
:mod:`~pfx.filters.kalman.linearisation` (the EKF's Jacobians),
:mod:`~pfx.filters.kalman.unscented` (the unscented transform and its covariance repair),
:mod:`~pfx.filters.kalman.kinds` (the three registered kinds and their predict steps),
:mod:`~pfx.filters.kalman.smoothing` (the Rauch-Tung-Striebel smoother of each kind's run, after filtering).

May import :mod:`pfx.filters.base`, :mod:`pfx.filters.trace`, :mod:`pfx.filters.smoothers`,
:mod:`pfx.laws`, :mod:`pfx.numerics` and :mod:`pfx.errors`.
"""

from pfx.filters.kalman import kinds  # noqa: F401  (registers kf, ekf, ukf)
