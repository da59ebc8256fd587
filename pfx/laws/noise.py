r"""Noise families, for the true system and for the model a filter assumes.

Every family is parameterised by its **variance** so that families can be swapped at equal
second moment. A family is defined by its unit-variance standard form :math:`z`; a noise of
covariance :math:`\Sigma = L L^\top` is :math:`x = L z` with independent standard components,
whose density is

.. math:: p(x) = \prod_i f(z_i) \,/\, |\det L|, \qquad z = L^{-1} x .

=============  =====================================================  =========================
family         standard form (unit variance)                          density f(z)
=============  =====================================================  =========================
gaussian       N(0, 1)                                                exp(-z^2/2) / sqrt(2 pi)
uniform        U(-sqrt 3, sqrt 3)                                     1 / (2 sqrt 3) inside
triangular     symmetric on [-sqrt 6, sqrt 6], sqrt6 (U1 + U2 - 1)     (sqrt 6 - |z|) / 6
laplace        scale b = 1/sqrt 2, b (E1 - E2) with E ~ Exp(1)        exp(-|z|/b) / (2b)
student_t      t_nu scaled by s = sqrt((nu - 2)/nu), nu > 2           t_nu(z/s) / s
=============  =====================================================  =========================

The triangular density is Probabilistic Robotics' ``prob_triangular(a, b)`` (Table 5.2,
corrected printing) at variance ``b = 1``.

Each family also gives its tail probability :math:`\log P(z > c)` (``Noise.log_tail``): a
sensor that saturates (a sonar's maximum range) reports the censored value, whose likelihood is
that tail mass rather than a density.

``variance`` in a config is a number (the same for every component), a list (one variance per
component) or a full covariance matrix. Zero variances are allowed for noise that is only
sampled (process noise); a noise whose density is evaluated (measurement noise) must be
positive definite.

**Both backends.** :meth:`Noise.sample` draws from a trial's streams, NumPy's
(:class:`~pfx.numerics.seeding.TrialStreams`) or JAX's (:class:`~pfx.numerics.key_streams.KeyStreams`),
and returns arrays of that library in the streams' dtype; :meth:`Noise.log_density` and
:meth:`Noise.log_tail` take NumPy or JAX arrays (:mod:`pfx.numerics.arrays`). On NumPy arrays
every function computes exactly what it did before JAX was supported. The noise's own constants
(its scale, its factor L) are NumPy float64 arrays; on JAX they are cast to the dtype of the
draws or of the value, so that a float32 computation stays float32.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, StrictFloat, model_validator
from scipy.special import gammaln

from pfx.numerics.arrays import constant_like, is_jax_array, namespace, special_functions
from pfx.numerics.key_streams import Random, zero_draws
from pfx.registry import Registry


@dataclass(frozen=True)
class NoiseFamily:
    """A zero-mean, unit-variance distribution: how to draw it and its log-density."""

    sample_standard: Callable[[Random, tuple, Optional[StrictFloat]], np.ndarray]   # a new array
    log_density_standard: Callable[[np.ndarray, Optional[StrictFloat]], np.ndarray]
    description: str
    log_tail_standard: Callable[[np.ndarray, Optional[StrictFloat]], np.ndarray]   # log P(z > c)


NOISE_FAMILIES: Registry[NoiseFamily] = Registry("noise family")

_SQRT3 = math.sqrt(3.0)
_SQRT6 = math.sqrt(6.0)
_LAPLACE_SCALE = 1.0 / math.sqrt(2.0)


def _gaussian_log_density(z, df=None):
    return -0.5 * z * z - 0.5 * math.log(2.0 * math.pi)


def _gaussian_log_tail(c, df=None):
    return special_functions(namespace(c)).log_ndtr(-c)


def _uniform_sample(random, shape, df=None):
    return (2.0 * random.uniform(shape) - 1.0) * _SQRT3


def _uniform_log_density(z, df=None):
    xp = namespace(z)
    return xp.where(xp.abs(z) <= _SQRT3, -math.log(2.0 * _SQRT3), -math.inf)


def _uniform_log_tail(c, df=None):
    xp = namespace(c)
    with np.errstate(divide="ignore"):
        return xp.log(xp.clip((_SQRT3 - c) / (2.0 * _SQRT3), 0.0, 1.0))


def _triangular_sample(random, shape, df=None):
    return _SQRT6 * (random.uniform(shape) + random.uniform(shape) - 1.0)


def _triangular_log_density(z, df=None):
    xp = namespace(z)
    with np.errstate(divide="ignore"):
        return xp.log(xp.maximum(_SQRT6 - xp.abs(z), 0.0)) - math.log(6.0)


def _triangular_log_tail(c, df=None):
    # P(z > c) = (sqrt6 - c)^2 / 12 for c >= 0, by symmetry 1 - (sqrt6 + c)^2 / 12 for c < 0
    xp = namespace(c)
    c = xp.clip(c, -_SQRT6, _SQRT6)
    upper = (_SQRT6 - xp.abs(c)) ** 2 / 12.0
    with np.errstate(divide="ignore"):
        return xp.log(xp.where(c >= 0, upper, 1.0 - upper))


def _laplace_sample(random, shape, df=None):
    return _LAPLACE_SCALE * (random.standard_exponential(shape) - random.standard_exponential(shape))


def _laplace_log_density(z, df=None):
    return -namespace(z).abs(z) / _LAPLACE_SCALE - math.log(2.0 * _LAPLACE_SCALE)


def _laplace_log_tail(c, df=None):
    # P(z > c) = exp(-c/b) / 2 for c >= 0, 1 - exp(c/b) / 2 for c < 0
    xp = namespace(c)
    half_tail = xp.exp(-xp.abs(c) / _LAPLACE_SCALE) / 2.0
    return xp.where(c >= 0, -xp.abs(c) / _LAPLACE_SCALE - math.log(2.0), xp.log1p(-half_tail))


def _student_t_sample(random, shape, df):
    return math.sqrt((df - 2.0) / df) * random.standard_t(df, shape)


def _student_t_log_density(z, df):
    scale = math.sqrt((df - 2.0) / df)
    t = z / scale
    # The constant is computed on the host (df is a number), a Python float on either backend.
    constant = float(gammaln((df + 1.0) / 2.0) - gammaln(df / 2.0) - 0.5 * math.log(df * math.pi))
    return constant - (df + 1.0) / 2.0 * namespace(z).log1p(t * t / df) - math.log(scale)


def _student_t_log_tail(c, df):
    t = c / math.sqrt((df - 2.0) / df)
    xp = namespace(t)
    if xp is np:
        with np.errstate(divide="ignore"):
            return np.log(special_functions(np).stdtr(df, -t))
    # jax.scipy.special has no stdtr; the t law's tail is a regularised incomplete beta:
    # P(T > t) = I_x(df/2, 1/2) / 2 with x = df / (df + t^2) for t >= 0, 1 - that for t < 0.
    half_beta = special_functions(xp).betainc(df / 2.0, 0.5, df / (df + t * t)) / 2.0
    return xp.log(xp.where(t >= 0, half_beta, 1.0 - half_beta))


for _name, _family in {
    "gaussian": NoiseFamily(lambda r, s, df=None: r.standard_normal(s), _gaussian_log_density,
                            "normal distribution", _gaussian_log_tail),
    "uniform": NoiseFamily(_uniform_sample, _uniform_log_density,
                           "uniform on [-sqrt(3 var), sqrt(3 var)] (bounded support)", _uniform_log_tail),
    "triangular": NoiseFamily(_triangular_sample, _triangular_log_density,
                              "symmetric triangular on [-sqrt(6 var), sqrt(6 var)]", _triangular_log_tail),
    "laplace": NoiseFamily(_laplace_sample, _laplace_log_density,
                           "double exponential (heavier tails than gaussian)", _laplace_log_tail),
    "student_t": NoiseFamily(_student_t_sample, _student_t_log_density,
                             "Student t with df > 2 degrees of freedom (heavy tails)", _student_t_log_tail),
}.items():
    NOISE_FAMILIES.add(_name, _family, _family.description)

NoiseFamilyName = Literal[NOISE_FAMILIES.names()]  # type: ignore[valid-type]

Variance = Union[StrictFloat, list[StrictFloat], list[list[StrictFloat]]]


class Noise(BaseModel):
    """Zero-mean noise of a named family with a given variance (or covariance matrix)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    family: NoiseFamilyName = Field("gaussian", description="distribution family (`pfx list noises`)")
    variance: Variance = Field(
        1.0,
        description="variance: a number for every component, a list with one per component, "
                    "or a full covariance matrix")
    df: Optional[StrictFloat] = Field(
        None, gt=2.0, description="degrees of freedom (student_t only; > 2 for a finite variance)")

    _scale: Optional[np.ndarray] = PrivateAttr(None)       # per-component std (diagonal case)
    _factor: Optional[np.ndarray] = PrivateAttr(None)      # L with L L^T = covariance
    _inverse_factor: Optional[np.ndarray] = PrivateAttr(None)
    _log_det_factor: float = PrivateAttr(0.0)
    _dimension: Optional[int] = PrivateAttr(None)
    _definite: bool = PrivateAttr(True)
    _covariance: Optional[np.ndarray] = PrivateAttr(None)   # read-only, made by bind()
    _zero: bool = PrivateAttr(False)                          # no noise at all: sample() draws nothing
    _row_scale: bool = PrivateAttr(False)                     # _scale differs by row (with_row_variances)

    @model_validator(mode="after")
    def _check(self) -> "Noise":
        if self.family == "student_t" and self.df is None:
            raise ValueError("@df: student_t noise needs df (degrees of freedom, > 2)")
        if self.family != "student_t" and self.df is not None:
            raise ValueError(f"@df: df applies to student_t noise only, not {self.family}")
        variance = np.asarray(self.variance, dtype=float)
        if not np.all(np.isfinite(variance)):
            raise ValueError("@variance: must be finite")
        if variance.ndim < 2 and np.any(variance < 0):
            raise ValueError("@variance: variances must be >= 0")
        if variance.ndim == 2:
            if variance.shape[0] != variance.shape[1]:
                raise ValueError(f"@variance: covariance matrix must be square, got shape {variance.shape}")
            if not np.allclose(variance, variance.T, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(variance).max())):
                raise ValueError("@variance: covariance matrix must be symmetric")
            eigenvalues = np.linalg.eigvalsh(variance)
            if eigenvalues.min() < -1e-10 * max(1.0, eigenvalues.max()):
                raise ValueError("@variance: covariance matrix must be positive semi-definite")
        return self

    # -- binding to a dimension ---------------------------------------------------------------

    def bind(self, dimension: int, *, need_density: bool = False) -> "Noise":
        """Fix the number of components and precompute the factor L; check sizes."""
        variance = np.asarray(self.variance, dtype=float)
        if variance.ndim == 0:
            variance = np.full(dimension, float(variance))
        if variance.shape[0] != dimension:
            raise ValueError(f"@variance: expected {dimension} component(s), got {variance.shape[0]}")
        if variance.ndim == 1:
            self._scale = np.sqrt(variance)
            self._definite = bool(np.all(variance > 0))
            if self._definite:
                self._log_det_factor = float(np.sum(np.log(self._scale)))
        else:
            try:
                self._factor = np.linalg.cholesky(variance)
                self._definite = True
                self._inverse_factor = np.linalg.inv(self._factor)
                self._log_det_factor = float(np.sum(np.log(np.diag(self._factor))))
            except np.linalg.LinAlgError:
                values, vectors = np.linalg.eigh(variance)
                self._factor = vectors * np.sqrt(np.clip(values, 0.0, None))
                self._definite = False
        if need_density and not self._definite:
            raise ValueError("@variance: must be positive definite (its density is evaluated)")
        self._dimension = dimension
        # Computed once: models and filters ask for it at every step (a likelihood's R).
        covariance = np.diag(self._scale ** 2) if self._scale is not None else self._factor @ self._factor.T
        covariance.setflags(write=False)
        self._covariance = covariance
        self._zero = not np.any(self._scale if self._scale is not None else self._factor)
        return self

    @property
    def dimension(self) -> int:
        if self._dimension is None:
            raise RuntimeError("Noise.bind(dimension) must be called first")
        return self._dimension

    def covariance(self) -> np.ndarray:
        """The covariance matrix, shape (k, k), read-only (computed once, by :meth:`bind`)."""
        covariance = self.__pydantic_private__["_covariance"]
        if self.__pydantic_private__["_row_scale"]:
            raise RuntimeError("a noise with a variance per row (parameter estimation) has no one covariance matrix")
        if covariance is None:
            raise RuntimeError("Noise.bind(dimension) must be called first")
        return covariance

    def with_row_variances(self, variance: np.ndarray) -> "Noise":
        """A copy whose variance differs by trial row (or by particle): ``variance`` is an
        array whose leading axes are those of the draws, (R, 1, 1) or (R, N, 1) (one variance
        for every component) or (..., k). Parameter estimation gives each chain its own
        variance this way (:meth:`pfx.models.base.Model.with_parameter_arrays`); only
        :meth:`sample` and :meth:`log_density` are defined for it (no covariance matrix, so no
        compiled step and no Kalman filter reads it)."""
        if self._scale is None:
            raise ValueError("a noise with a covariance matrix cannot take a variance per row")
        xp = namespace(variance)
        if xp is np:
            variance = np.asarray(variance, dtype=float)
            if np.any(variance <= 0):
                raise ValueError("@variance: variances must be > 0")
        # (JAX arrays are traced values inside a compiled estimation, checked on the host before)
        copy = self.model_copy()
        scale = xp.sqrt(variance) * xp.ones(self.dimension)
        copy.__pydantic_private__ = {**self.__pydantic_private__, "_scale": scale,
                                     "_log_det_factor": xp.sum(xp.log(scale), axis=-1),
                                     "_covariance": None, "_factor": None, "_row_scale": True,
                                     "_zero": False, "_definite": True}
        return copy

    # -- the two operations -------------------------------------------------------------------

    def sample(self, random: Random, shape=()) -> np.ndarray:
        """Draws of shape ``(trials, *shape, k)``; no random numbers are used for zero noise.

        NumPy arrays from :class:`~pfx.numerics.seeding.TrialStreams`, JAX arrays of the streams'
        dtype from :class:`~pfx.numerics.key_streams.KeyStreams`."""
        # One read of pydantic's private-attribute dict: each `self._x` costs microseconds
        # (it goes through BaseModel.__getattr__), and this runs at every step of a filter.
        private = self.__pydantic_private__
        if private["_dimension"] is None:
            raise RuntimeError("Noise.bind(dimension) must be called first")
        full_shape = tuple(shape) + (private["_dimension"],)
        scale, factor = private["_scale"], private["_factor"]
        if private["_zero"]:
            return zero_draws(random, (len(random),) + full_shape)
        # Drawn component-major, (trials, k, *shape), and returned as a (trials, *shape, k) view:
        # each component is then contiguous, which NumPy's element-wise operations on one state
        # component (what a model's propagate does) run several times faster over.
        standard = NOISE_FAMILIES[self.family].sample_standard(random, full_shape[-1:] + full_shape[:-1], self.df)
        component_last = (0, *range(2, standard.ndim), 1)      # (trials, k, *shape) -> (trials, *shape, k)
        if private["_row_scale"]:
            return standard.transpose(component_last) * constant_like(scale, standard)
        if scale is not None:
            scale = constant_like(scale, standard).reshape((-1,) + (1,) * (standard.ndim - 2))
            if is_jax_array(standard):                           # JAX arrays are never written in place
                return (standard * scale).transpose(component_last)
            # x_j = s_j z_j in place, while the component axis is still the second one: NumPy's
            # inner loop then runs along a component's contiguous draws (over the short last axis
            # it would run over k = 1..3 elements, several times slower), and one call does it all.
            standard *= scale
            return standard.transpose(component_last)
        return standard.transpose(component_last) @ constant_like(factor, standard).T

    def independent_gaussian(self) -> Optional[tuple[np.ndarray, float]]:
        """(standard deviation of each component, sum of their logs) when the noise is Gaussian
        with independent components of positive variance; else None. What a compiled
        log-density (:meth:`pfx.models.base.Model.compiled_step`) needs:
        log p(v) = sum_j (-v_j^2 / (2 s_j^2)) - k log(2 pi) / 2 - sum_j log s_j."""
        private = self.__pydantic_private__
        if self.family != "gaussian" or private["_scale"] is None or not private["_definite"] or private["_row_scale"]:
            return None
        return private["_scale"].copy(), private["_log_det_factor"]

    def log_density(self, value: np.ndarray) -> np.ndarray:
        """log p(value) for ``value`` of shape (..., k), NumPy or JAX; returns shape (...)."""
        private = self.__pydantic_private__            # see sample()
        if not private["_definite"]:
            raise RuntimeError("log_density of a degenerate noise")
        if private["_scale"] is not None:
            standard = value / constant_like(private["_scale"], value)
        else:
            standard = value @ constant_like(private["_inverse_factor"], value).T
        log_f = NOISE_FAMILIES[self.family].log_density_standard(standard, self.df)
        return namespace(log_f).sum(log_f, axis=-1) - constant_like(private["_log_det_factor"], log_f)

    def log_tail(self, threshold: np.ndarray) -> np.ndarray:
        """log P(v_j > c_j for every component j), for ``threshold`` c of shape (..., k).

        Defined for independent components (a variance number or list), where it is the sum of
        the components' log tail probabilities; returns shape (...).
        """
        if self._scale is None or not self._definite:
            raise RuntimeError("log_tail needs independent components with positive variances")
        log_tail = NOISE_FAMILIES[self.family].log_tail_standard(threshold / constant_like(self._scale, threshold),
                                                                 self.df)
        return namespace(log_tail).sum(log_tail, axis=-1)
