r"""Count-valued transitions: the draws a compartmental model (pomp's family) makes at each substep.

A model of individuals moving between compartments (susceptible, infected, recovered, ...)
moves whole individuals: its transition draws counts. The three laws pomp's models are written
with, batched over trials and particles and drawn from the trial's streams on either backend
(:class:`~pfx.numerics.seeding.TrialStreams` on numpy, :class:`~pfx.numerics.key_streams.KeyStreams`
on jax, through their ``binomial`` and ``gamma``):

* :func:`multinomial`: n individuals split among k categories of probabilities p_1..p_k, by
  sequential conditional binomials,

  .. math:: n_1 \sim \mathrm{Bin}(n, p_1), \quad
            n_j \sim \mathrm{Bin}\Big(n - \sum_{i<j} n_i,\ \frac{p_j}{1 - \sum_{i<j} p_i}\Big),

  the last category taking what is left when the probabilities sum to 1;
* :func:`euler_multinomial`: pomp's ``reulermultinom``. The n individuals of a compartment with
  competing exits at rates r_1..r_k (per unit time) over a step h: each leaves with probability
  :math:`1 - e^{-R h}` (:math:`R = \sum_j r_j`, the exits' total rate), and one that leaves takes
  exit j with probability :math:`r_j / R`. The counts leaving by each exit are a multinomial
  of n over k + 1 outcomes (the k exits and staying), with
  :math:`E[n_j] = n q_j`, :math:`\mathrm{Var}[n_j] = n q_j (1 - q_j)`,
  :math:`\mathrm{Cov}[n_i, n_j] = -n q_i q_j`, :math:`q_j = (1 - e^{-R h}) r_j / R`;
* :func:`gamma_white_noise`: pomp's ``rgammawn``, the increment over h of a gamma process with
  intensity 1 and variance :math:`\sigma^2` per unit time: :math:`dW \sim
  \Gamma(\text{shape } h / \sigma^2, \text{scale } \sigma^2)`, so that :math:`E[dW] = h` and
  :math:`\mathrm{Var}[dW] = \sigma^2 h`. Multiplying a rate by :math:`dW / h` gives it
  extra-demographic noise (Bretó et al. 2009; He et al. 2010's measles model).

Counts are floats (NumPy's binomial draws come back as float64, JAX's in the filter's dtype),
whole numbers the model keeps in its state. The parameters follow the streams' layout: the trial
axis first, (R, N) for one value per particle.
"""

from __future__ import annotations

from typing import Any

from pfx.numerics.arrays import namespace


def multinomial(random, count: Any, probabilities: Any) -> Any:
    """``count`` (R, ...) split among the k categories of ``probabilities`` (R, ..., k), which sum
    to 1 along the last axis (module docstring): the counts per category, (R, ..., k)."""
    xp = namespace(count, probabilities)
    categories = probabilities.shape[-1]
    remaining, remaining_probability = count, 1.0
    counts = []
    for category in range(categories - 1):
        probability = probabilities[..., category]
        conditional = xp.where(remaining_probability > 0.0,
                               probability / xp.where(remaining_probability > 0.0, remaining_probability, 1.0), 0.0)
        drawn = random.binomial(remaining, xp.clip(conditional, 0.0, 1.0))
        counts.append(drawn)
        remaining = remaining - drawn
        remaining_probability = remaining_probability - probability
    counts.append(remaining)
    return xp.stack(counts, axis=-1)


def euler_multinomial(random, count: Any, rates: Any, step: float) -> Any:
    r"""pomp's ``reulermultinom``: how many of the ``count`` (R, ...) individuals of a compartment
    leave by each of its k exits, of ``rates`` (R, ..., k) per unit time, over a step of ``step``
    time units (module docstring): (R, ..., k).

    One binomial for the individuals leaving, :math:`\mathrm{Bin}(n, 1 - e^{-R h})`, then a
    multinomial of them over the exits in proportion to their rates."""
    xp = namespace(count, rates)
    total = xp.sum(rates, axis=-1)
    leaving = random.binomial(count, -xp.expm1(-total * step))
    shares = rates / xp.where(total > 0.0, total, 1.0)[..., None]
    if rates.shape[-1] == 1:
        return leaving[..., None]
    return multinomial(random, leaving, shares)


def gamma_white_noise(random, sigma: Any, step: float, *, shape=None) -> Any:
    r"""pomp's ``rgammawn``: gamma process increments over ``step`` with intensity 1 and
    variance ``sigma``\ :sup:`2` per unit time: Gamma(shape step / sigma^2, scale sigma^2),
    mean ``step``, variance sigma^2 step (module docstring). ``sigma`` > 0, a number or laid out
    as the streams' parameters; ``shape`` the draws' per-trial shape."""
    variance = sigma * sigma
    return random.gamma(step / variance, variance, shape=shape)
