r"""The motion models' error distributions: Probabilistic Robotics Tables 5.2 and 5.4 (corrected).

Thrun, Burgard & Fox write the motion error as a zero-mean distribution given by its
**variance** :math:`b`: ``prob(a, b)`` is its density at :math:`a`, ``sample(b)`` a draw from it.
Two families are offered, ``normal`` and ``triangular``.

**Table 5.2**, the densities:

.. math::

    \mathrm{prob\_normal}(a, b) = \frac{1}{\sqrt{2\pi b}}\, e^{-a^2 / (2b)}, \qquad
    \mathrm{prob\_triangular}(a, b) = \max\Big(0,\ \frac{1}{\sqrt{6b}} - \frac{|a|}{6b}\Big).

Both are pfx's own noise families (:mod:`pfx.laws.noise`, ``gaussian`` and ``triangular``) at
variance :math:`b`: :math:`f(a/\sqrt b)/\sqrt b` with the family's unit-variance density
:math:`f`. They are evaluated through that one definition, never written a second time.

**Table 5.4** (corrected printing), the samplers, take a **standard deviation** :math:`s`;
``rand(-s, s)`` is a uniform draw on :math:`[-s, s]`:

.. math::

    \mathrm{sample\_normal}(s) = \tfrac12 \sum_{i=1}^{12} \mathrm{rand}(-s, s), \qquad
    \mathrm{sample\_triangular}(s) = \tfrac{\sqrt 6}{2}\,\big(\mathrm{rand}(-s, s) + \mathrm{rand}(-s, s)\big).

Each ``rand(-s, s)`` has variance :math:`s^2/3`, so both draws have variance exactly
:math:`s^2`. The sum of two uniforms is exactly triangular on :math:`[-\sqrt 6 s, \sqrt 6 s]`
(the density above); the sum of twelve is the Irwin-Hall approximation of the normal (bounded
by :math:`\pm 6s`; its CDF is within 0.0024 of the normal CDF everywhere). Hence
:math:`\mathrm{sample}(b) = \mathrm{sample\_x}(\sqrt b)`. The first printing had
:math:`b/6 \sum` and :math:`b \cdot \mathrm{rand} \cdot \mathrm{rand}` (not triangular), and passing
a variance where a standard deviation is meant is the bug ROS amcl shipped (issue 20 of
ros-planning/navigation).

**A zero variance** (the motion models' variance terms vanish when the robot is commanded to
stand still) is a point mass: ``sample(0)`` is exactly 0, and ``prob(a, 0)`` is :math:`+\infty`
at :math:`a = 0` and 0 elsewhere (the limit of the densities). A negative variance is an error.

Every draw comes from an explicit :class:`numpy.random.Generator`, or from per-trial streams
(the :class:`~pfx.numerics.key_streams.Random` protocol: :class:`pfx.numerics.seeding.TrialStreams`
on the NumPy backend, :class:`pfx.numerics.key_streams.KeyStreams` on the JAX backend); with
streams the leading axis of the draw is the trial axis, and each trial's slice comes from its own
stream.

Every function takes NumPy or JAX arrays (:mod:`pfx.numerics.arrays`) and computes in their
namespace: the same operations, so NumPy's numbers are what they always were. A negative
variance is refused on NumPy only: inside a compiled JAX step there is no value to test (the
motion models' variances are sums of squares times alphas >= 0, never negative).
"""

from __future__ import annotations

from typing import Literal, Union

import numpy as np

from pfx.laws.noise import NOISE_FAMILIES
from pfx.numerics.arrays import namespace
from pfx.numerics.key_streams import Random as TrialRandom

MotionNoise = Literal["normal", "triangular"]
Random = Union[np.random.Generator, TrialRandom]

# The book's family names, and pfx's noise family holding each one's unit-variance density.
_FAMILY = {"normal": "gaussian", "triangular": "triangular"}


def as_float_array(value):
    """``value`` as a float64 NumPy array if it is NumPy (or numbers, or lists of them); a JAX
    array as it is (in the precision its backend runs, which a cast to float would override)."""
    return np.asarray(value, dtype=float) if namespace(value) is np else value


def _checked_variance(variance) -> np.ndarray:
    """The variance as a float array, refused if negative (NumPy; a JAX array as it is)."""
    if namespace(variance) is not np:
        return variance
    variance = np.asarray(variance, dtype=float)
    if np.any(variance < 0):
        raise ValueError("a variance must be >= 0")
    return variance


def log_prob(a, variance, noise: MotionNoise = "normal") -> np.ndarray:
    """log prob(a, b): the log-density at ``a`` of the zero-mean ``noise`` of variance ``b``.

    Broadcasts ``a`` against ``variance``; a zero variance gives +inf at a = 0, -inf elsewhere.
    """
    xp = namespace(a, variance)
    a = as_float_array(a)
    variance = _checked_variance(variance)
    a, variance = xp.broadcast_arrays(a, variance)
    standard_log_density = NOISE_FAMILIES[_FAMILY[noise]].log_density_standard
    with np.errstate(divide="ignore", invalid="ignore"):
        std = xp.sqrt(variance)
        log_density = standard_log_density(a / std) - xp.log(std)
    return xp.where(variance > 0, log_density, xp.where(a == 0, np.inf, -np.inf))


def log_product(*log_factors) -> np.ndarray:
    """The log of a product of densities from their logs: -inf wherever one factor is 0.

    A zero factor wins over a point mass's infinite one (0 * inf is 0 here, not NaN).
    """
    xp = namespace(*log_factors)
    stacked = xp.stack(xp.broadcast_arrays(*log_factors))
    with np.errstate(invalid="ignore"):
        total = stacked.sum(axis=0)
    return xp.where(xp.isneginf(stacked).any(axis=0), -np.inf, total)


def prob(a, variance, noise: MotionNoise = "normal") -> np.ndarray:
    """prob(a, b) of Table 5.2 for the named family (``normal`` or ``triangular``)."""
    log_density = log_prob(a, variance, noise)
    return namespace(log_density).exp(log_density)


def prob_normal(a, variance) -> np.ndarray:
    r"""Table 5.2: :math:`\exp(-a^2 / 2b) / \sqrt{2\pi b}`, the normal density of variance b at a."""
    return prob(a, variance, "normal")


def prob_triangular(a, variance) -> np.ndarray:
    r"""Table 5.2: :math:`\max(0, 1/\sqrt{6b} - |a| / 6b)`, the triangular density of variance b at a."""
    return prob(a, variance, "triangular")


def uniform_draws(random: Random, shape) -> np.ndarray:
    """Uniform draws on [0, 1) of the given shape; with per-trial streams (TrialStreams or
    KeyStreams) shape[0] is the trial axis."""
    shape = tuple(shape)
    if isinstance(random, np.random.Generator):
        return random.random(shape)
    if not shape or shape[0] != len(random):
        raise ValueError(f"draws from {len(random)} trial streams need the trial axis first, "
                         f"got shape {shape}")
    return random.uniform(shape[1:])


def sample_normal(std, random: Random) -> np.ndarray:
    r"""Table 5.4: :math:`\tfrac12 \sum_{i=1}^{12} \mathrm{rand}(-s, s)`, one draw per entry of ``std``.

    With :math:`\mathrm{rand}(-s, s) = s (2U - 1)` this is :math:`s (\sum_i U_i - 6)`: mean 0,
    variance :math:`s^2`.
    """
    std = as_float_array(std)
    uniforms = uniform_draws(random, tuple(std.shape) + (12,))
    return std * (uniforms.sum(axis=-1) - 6.0)


def sample_triangular(std, random: Random) -> np.ndarray:
    r"""Table 5.4: :math:`\tfrac{\sqrt6}{2} (\mathrm{rand}(-s, s) + \mathrm{rand}(-s, s))`, one draw per entry.

    Equal to :math:`\sqrt 6\, s\, (U_1 + U_2 - 1)`: triangular on :math:`[-\sqrt6 s, \sqrt6 s]`,
    variance :math:`s^2`.
    """
    std = as_float_array(std)
    uniforms = uniform_draws(random, tuple(std.shape) + (2,))
    return np.sqrt(6.0) * std * (uniforms.sum(axis=-1) - 1.0)


_SAMPLERS = {"normal": sample_normal, "triangular": sample_triangular}


def sample(variance, random: Random, noise: MotionNoise = "normal") -> np.ndarray:
    """sample(b) = sample_x(sqrt(b)): a zero-mean draw of VARIANCE b per entry of ``variance``."""
    variance = _checked_variance(variance)
    return _SAMPLERS[noise](namespace(variance).sqrt(variance), random)
