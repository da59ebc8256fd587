"""The model registry: one model per file, registered here under the name configs use.

To add a model: write ``pfx/models/<name>.py`` with a :class:`pfx.models.base.Model` subclass
(its fields are its parameters; ``kind: Literal["<name>"]``), and add one line below.
"""

from pfx.models.base import Model
from pfx.models.falling_body import FallingBody
from pfx.models.growth import GrowthModel
from pfx.models.linear_gaussian import LinearGaussian
from pfx.models.planar_robot import PlanarRobot
from pfx.models.range_beacons import RangeBeacons
from pfx.models.sonar_mcl import SonarMCL
from pfx.registry import Registry

MODELS: Registry[type[Model]] = Registry("model")
MODELS.add("falling_body", FallingBody)
MODELS.add("growth", GrowthModel)
MODELS.add("linear_gaussian", LinearGaussian)
MODELS.add("planar_robot", PlanarRobot)
MODELS.add("range_beacons", RangeBeacons)
MODELS.add("sonar_mcl", SonarMCL)

__all__ = ["MODELS", "Model"]
