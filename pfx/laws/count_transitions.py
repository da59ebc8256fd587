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

Every argument is checked before anything is drawn, and a bad one is named by a ValueError
(``euler_multinomial: rates must be finite and non-negative, got nan``): ``random`` the trials'
streams; counts whole and non-negative; rates finite and non-negative, with the k >= 1 exits on
the last axis; probabilities in [0, 1], summing to 1 along the last axis (to 1e-9; 1e-5 in
float32: the last category takes what is left, so a shortfall would be silently given to it);
``sigma`` finite and positive; ``step`` finite and non-negative (a step of length 0 is a step
in which nothing happens, as in pomp; a negative one has no meaning); shapes that do not
broadcast, with both shapes. The rules, and how a traced value (JAX, inside a compiled step) is
checked and refused after the run's scan, are :mod:`pfx.numerics.parameter_checks`'s; each is a
few vectorised reductions over its argument, and draws nothing.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from pfx.numerics.arrays import namespace
from pfx.numerics.parameter_checks import (
    EULER_COUNT,
    EULER_RATES,
    EULER_STEP,
    MULTINOMIAL_COUNT,
    MULTINOMIAL_PROBABILITIES,
    MULTINOMIAL_TOTAL,
    NOISE_SIGMA,
    NOISE_STEP,
    Rule,
    check,
    numbers,
)


def multinomial(random, count: Any, probabilities: Any) -> Any:
    """``count`` (R, ...) split among the k categories of ``probabilities`` (R, ..., k), which sum
    to 1 along the last axis (module docstring): the counts per category, (R, ..., k)."""
    _check_streams("multinomial", random, "binomial")
    count, probabilities = _as_array(MULTINOMIAL_COUNT, count), _as_array(MULTINOMIAL_PROBABILITIES, probabilities)
    _check_categories("multinomial", "probabilities", probabilities, "categories")
    _check_layout("multinomial", len(random), [("count", count, 0), ("probabilities", probabilities, 1)])
    check(MULTINOMIAL_COUNT, count)
    check(MULTINOMIAL_PROBABILITIES, probabilities, event_axes=1)
    check(MULTINOMIAL_TOTAL, probabilities)
    return _split(random, count, probabilities)


def _split(random, count: Any, probabilities: Any) -> Any:
    """:func:`multinomial`'s sequential conditional binomials, on arguments already checked."""
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
    _check_streams("euler_multinomial", random, "binomial")
    count, rates = _as_array(EULER_COUNT, count), _as_array(EULER_RATES, rates)
    _check_categories("euler_multinomial", "rates", rates, "exits")
    _check_layout("euler_multinomial", len(random), [("count", count, 0), ("rates", rates, 1), ("step", step, 0)])
    check(EULER_COUNT, count)
    check(EULER_RATES, rates, event_axes=1)
    check(EULER_STEP, step)
    xp = namespace(count, rates)
    total = xp.sum(rates, axis=-1)
    leaving = random.binomial(count, -xp.expm1(-total * step))
    shares = rates / xp.where(total > 0.0, total, 1.0)[..., None]
    if rates.shape[-1] == 1:
        return leaving[..., None]
    return _split(random, leaving, shares)        # shares of no exit at all (total 0) are 0: nobody leaves


def gamma_white_noise(random, sigma: Any, step: float, *, shape: Optional[Sequence[int]] = None) -> Any:
    r"""pomp's ``rgammawn``: gamma process increments over ``step`` with intensity 1 and
    variance ``sigma``\ :sup:`2` per unit time: Gamma(shape step / sigma^2, scale sigma^2),
    mean ``step``, variance sigma^2 step (module docstring). ``sigma`` > 0, a number or laid out
    as the streams' parameters; ``shape`` the draws' per-trial shape."""
    _check_streams("gamma_white_noise", random, "gamma")
    if shape is not None:
        shape = _draws_shape("gamma_white_noise", shape)
    sigma = _as_array(NOISE_SIGMA, sigma)
    _check_layout("gamma_white_noise", len(random), [("sigma", sigma, 0), ("step", step, 0)], shape)
    check(NOISE_SIGMA, sigma)
    check(NOISE_STEP, step)
    variance = sigma * sigma
    return random.gamma(step / variance, variance, shape=shape)


# -- the arguments' forms (their values: pfx.numerics.parameter_checks) -----------------------------


def _check_streams(law: str, random: Any, method: str) -> None:
    """``random`` must be the trials' streams (TrialStreams or KeyStreams), not a NumPy generator."""
    if not (hasattr(random, method) and hasattr(random, "__len__")):
        raise ValueError(f"{law}: random must be the trials' streams (the random argument pfx gives "
                         f"sample_substep), got {type(random).__name__}")


def _as_array(rule: Rule, values: Any) -> Any:
    """An array argument as given (NumPy or JAX arrays, and numbers, which stay weakly typed for
    JAX); a list or tuple as a NumPy array."""
    return numbers(rule, values) if isinstance(values, (list, tuple)) else values


def _check_categories(law: str, argument: str, values: Any, what: str) -> None:
    shape = tuple(np.shape(values))
    if not shape or shape[-1] < 1:
        raise ValueError(f"{law}: {argument} must hold its {what} on its last axis, (..., k) with k >= 1; "
                         f"got shape {shape}")


def _draws_shape(law: str, shape: Any) -> tuple:
    try:
        sizes = tuple(shape)
    except TypeError:
        sizes = None
    if sizes is None or not all(isinstance(size, (int, np.integer)) and not isinstance(size, bool) and size >= 0
                                for size in sizes):
        raise ValueError(f"{law}: shape must be a tuple of non-negative integers (each trial's draws), got {shape!r}")
    return tuple(int(size) for size in sizes)


def _check_layout(law: str, trials: int, parameters: list[tuple[str, Any, int]],
                  per_trial: Optional[tuple] = None) -> None:
    """The parameters (name, values, trailing axes of one draw: a law's categories) laid out as
    the streams read them: an array's leading axis is the trial axis (``trials`` long, or 1),
    and they broadcast once trailing axes of length 1 give them equally many axes (and, with
    ``per_trial``, broadcast to the draws' shape (trials, *per_trial)). Shapes only: no pass
    over the values."""
    shapes = [tuple(getattr(values, "shape", ())) for _, values, _ in parameters]
    own = [shape[:len(shape) - event_axes] for shape, (_, _, event_axes) in zip(shapes, parameters)]
    for (name, _, _), shape, axes in zip(parameters, shapes, own):
        if axes and axes[0] not in (trials, 1):
            raise ValueError(f"{law}: {name} of shape {shape} must have the trial axis first, of length {trials} "
                             "(or 1: shared by the trials)")
    draws = None if per_trial is None else (trials, *per_trial)
    broadcast = _broadcast(own + ([draws] if draws is not None else []))
    if broadcast is None or (draws is not None and broadcast != draws):
        named = [f"{name} of shape {shape}" for (name, _, _), shape in zip(parameters, shapes) if shape]
        target = f"draws of shape {draws}" if draws is not None else "one shape"
        raise ValueError(f"{law}: {' and '.join(named)} {'do' if len(named) > 1 else 'does'} not broadcast to "
                         f"{target} (the trial axis first, trailing axes of length 1 added to the fewer axes; a "
                         "category axis last)")


def _broadcast(shapes: list[tuple]) -> Optional[tuple]:
    """The shape ``shapes`` broadcast to once trailing axes of length 1 give them equally many
    axes (the streams' rule, NumPy's from the left), or None if they do not."""
    result = [1] * max((len(shape) for shape in shapes), default=0)
    for shape in shapes:
        for position, length in enumerate(shape):
            if result[position] == 1:
                result[position] = length
            elif length not in (1, result[position]):
                return None
    return tuple(result)
