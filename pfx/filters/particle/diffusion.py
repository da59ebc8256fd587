r"""Post-resampling diffusion ("roughening", "jitter") against sample impoverishment.

After a trial resamples, duplicated particles are moved apart by independent noise:

* ``none``: nothing.
* ``gaussian``: :math:`x \leftarrow x + \sigma \epsilon`, fixed standard deviation ``std``
  (a number or one per state component): han-lee's "diffusion rate".
* ``roughening``: Gordon, Salmond & Smith (1993): :math:`\sigma_j = K E_j N^{-1/d}`, with
  :math:`E_j` the range (max - min) of component :math:`j` over the trial's particles, ``factor``
  :math:`K` (Simon uses K = 0.2), :math:`d` the state dimension.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat

from pfx.filters.backends import BOTH, Backends
from pfx.numerics.seeding import TrialStreams
from pfx.registry import Registry


class _Diffusion(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    #: where it runs (pfx.filters.backends): the built-in ones draw through the array namespace
    backends: ClassVar[Backends] = Backends(BOTH)

    def apply(self, particles: np.ndarray, random: TrialStreams) -> np.ndarray:
        raise NotImplementedError

    def check(self, dimension: int) -> None:
        """Raise ValueError('@key: reason') if the parameters do not fit the state dimension."""


DIFFUSIONS: Registry[type["_Diffusion"]] = Registry("diffusion")


@DIFFUSIONS.register_kind
class NoDiffusion(_Diffusion):
    """No post-resampling noise."""

    kind: Literal["none"] = "none"

    def apply(self, particles, random):
        return particles


@DIFFUSIONS.register_kind
class GaussianDiffusion(_Diffusion):
    """Add N(0, std^2) to every component after resampling."""

    kind: Literal["gaussian"] = "gaussian"
    std: Union[Annotated[StrictFloat, Field(ge=0)], list[Annotated[StrictFloat, Field(ge=0)]]] = Field(
        description="standard deviation (one, or one per component)")

    def check(self, dimension):
        if isinstance(self.std, list) and len(self.std) != dimension:
            raise ValueError(f"@std: give one value or one per state component ({dimension}), got {len(self.std)}")

    def apply(self, particles, random):
        std = np.asarray(self.std, dtype=float)
        return particles + std * random.standard_normal(particles.shape[1:])


@DIFFUSIONS.register_kind
class Roughening(_Diffusion):
    """Roughening: std_j = factor * range_j * N^(-1/d) (Gordon et al. 1993)."""

    kind: Literal["roughening"] = "roughening"
    factor: StrictFloat = Field(0.2, gt=0, description="K in K * E_j * N^(-1/d)")

    def apply(self, particles, random):
        n, d = particles.shape[-2], particles.shape[-1]
        spread = particles.max(axis=-2, keepdims=True) - particles.min(axis=-2, keepdims=True)
        std = self.factor * spread * n ** (-1.0 / d)
        return particles + std * random.standard_normal(particles.shape[1:])


Diffusion = DIFFUSIONS.kind_union()
