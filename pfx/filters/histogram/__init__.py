r"""The grid (point-mass, histogram) filter: a near-exact reference posterior in 1-D and 2-D.

The state space is cut into a regular grid of cells with centres :math:`x_j` and volume
:math:`\Delta = \prod_c \Delta_c`; the posterior is a probability :math:`\pi_{k,j}` on the
centres, i.e. the posterior density sampled at the centres, :math:`\pi_{k,j} \approx
p(x_j \mid z_{1:k})\,\Delta` (the point-mass method: Bucy & Senne 1971; Kitagawa 1987; Šimandl,
Královec & Söderström 2006). Each step k = 1..T:

1. **Predict** with the transition density of additive process noise,
   :math:`p(x_k \mid x_{k-1}) = p_w(x_k - f(x_{k-1}, u_k))`, where
   :math:`f(x, u)` is ``model.propagate(x, u, 0)`` and :math:`w` the noise on the state, :math:`L w`
   for a constant gain :math:`L` (the stochastic-volatility model's :math:`\sigma w`):

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
process noise that is not additive (:math:`x' = f(x, u) + L w` with a constant gain :math:`L`,
checked numerically), non-Gaussian noise whose gain is not diagonal, a prior with a singular covariance, cells wider than the
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

The package: :mod:`~pfx.filters.histogram.grid` (the grid's settings, its planning and the
checks that refuse a model the filter cannot run), :mod:`~pfx.filters.histogram.kernel` (the
transition kernel and the log-domain predict), :mod:`~pfx.filters.histogram.filter` (the
recursion and the registered ``histogram`` kind, which plans its grid once per cell).

May import :mod:`pfx.filters.base`, :mod:`pfx.filters.particle.engine` (log-domain
normalisation), :mod:`pfx.filters.trace`, :mod:`pfx.laws`, :mod:`pfx.numerics` and :mod:`pfx.errors`.
"""

import pfx.filters.histogram.filter  # noqa: F401  (registers histogram)
