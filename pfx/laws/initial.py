"""Initial laws p(x_0): where the truth starts, and the prior a filter starts from.

A config names one of three forms::

    initial: {kind: point, state: [3.0e5, -2.0e4, 1.0e-3]}
    initial: {kind: gaussian, mean: [3.0e5, -2.0e4, 1.0e-3], covariance: [1.0e6, 4.0e6, 10.0]}
    initial: {kind: uniform, low: [-20, -15], high: [20, 25]}

``covariance`` takes the same forms as a noise variance (number, list or matrix).

Each law draws from a trial's streams, NumPy's or JAX's (:class:`~pfx.numerics.key_streams.Random`),
and returns arrays of that library, in the streams' dtype (:mod:`pfx.laws.noise`, "Both backends").
"""

from __future__ import annotations

from typing import Annotated, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, StrictFloat, ValidationError, model_validator

from pfx.errors import split_location
from pfx.laws.noise import Noise, Variance
from pfx.numerics.arrays import constant_like
from pfx.numerics.key_streams import Random, draws_namespace


class _InitialLaw(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    def bind(self, dimension: int) -> "_InitialLaw":
        raise NotImplementedError

    def sample(self, random: Random, shape=()) -> np.ndarray:
        """Draws of shape (trials, *shape, d), NumPy or JAX as ``random``'s draws."""
        raise NotImplementedError

    def mean_vector(self) -> np.ndarray:
        raise NotImplementedError

    def covariance_matrix(self) -> np.ndarray:
        raise NotImplementedError


def _check_length(values, dimension: int, key: str) -> None:
    if len(values) != dimension:
        raise ValueError(f"@{key}: expected {dimension} value(s), got {len(values)}")


class PointLaw(_InitialLaw):
    """A known initial state (a point mass)."""

    kind: Literal["point"] = "point"
    state: list[StrictFloat] = Field(description="the initial state")

    def bind(self, dimension):
        _check_length(self.state, dimension, "state")
        return self

    def sample(self, random, shape=()):
        xp, dtype = draws_namespace(random)
        value = xp.asarray(self.state, dtype=dtype)
        return xp.broadcast_to(value, (len(random),) + tuple(shape) + value.shape).copy()

    def mean_vector(self):
        return np.asarray(self.state, dtype=float)

    def covariance_matrix(self):
        return np.zeros((len(self.state), len(self.state)))


class GaussianLaw(_InitialLaw):
    """A normal distribution with the given mean and covariance."""

    kind: Literal["gaussian"] = "gaussian"
    mean: list[StrictFloat] = Field(description="mean vector")
    covariance: Variance = Field(description="variance(s) or covariance matrix")

    _noise: Optional[Noise] = PrivateAttr(None)

    @model_validator(mode="after")
    def _valid_covariance(self):
        try:
            self._noise = Noise(family="gaussian", variance=self.covariance)
        except ValidationError as error:
            _, reason = split_location(error.errors()[0]["msg"].removeprefix("Value error, "))
            raise ValueError(f"@covariance: {reason}") from None
        return self

    def bind(self, dimension):
        _check_length(self.mean, dimension, "mean")
        try:
            self._noise.bind(dimension)
        except ValueError as error:
            raise ValueError(str(error).replace("@variance", "@covariance")) from None
        return self

    def sample(self, random, shape=()):
        draws = self._noise.sample(random, shape)
        return constant_like(np.asarray(self.mean), draws) + draws

    def mean_vector(self):
        return np.asarray(self.mean, dtype=float)

    def covariance_matrix(self):
        return self._noise.covariance()


class UniformLaw(_InitialLaw):
    """Independent uniform components on the box [low, high]."""

    kind: Literal["uniform"] = "uniform"
    low: list[StrictFloat] = Field(description="lower corner of the box")
    high: list[StrictFloat] = Field(description="upper corner of the box")

    @model_validator(mode="after")
    def _ordered(self):
        if len(self.low) == len(self.high) and any(high <= low for low, high in zip(self.low, self.high)):
            raise ValueError("@high: every high must exceed its low")
        return self

    def bind(self, dimension):
        _check_length(self.low, dimension, "low")
        _check_length(self.high, dimension, "high")
        return self

    def sample(self, random, shape=()):
        uniform = random.uniform(tuple(shape) + (len(self.low),))
        low, high = constant_like(np.asarray(self.low), uniform), constant_like(np.asarray(self.high), uniform)
        return low + (high - low) * uniform

    def mean_vector(self):
        return (np.asarray(self.low) + np.asarray(self.high)) / 2.0

    def covariance_matrix(self):
        return np.diag((np.asarray(self.high) - np.asarray(self.low)) ** 2 / 12.0)


InitialLaw = Annotated[Union[PointLaw, GaussianLaw, UniformLaw], Field(discriminator="kind")]
