"""The models: one state-space model per file, registered at its definition.

To add a model: write ``pfx/models/<name>.py`` with a :class:`pfx.models.base.Model` subclass
(its fields are its parameters; ``kind: Literal["<name>"] = "<name>"``) decorated with
``@MODELS.register_kind``, and import the module below.
"""

from pfx.models import (  # noqa: F401  (each module registers its model)
    falling_body,
    growth,
    linear_gaussian,
    planar_robot,
    range_beacons,
    sonar_mcl,
)
from pfx.models.base import MODELS, Model

__all__ = ["MODELS", "Model"]
