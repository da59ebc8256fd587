"""Studies: experiments that are computations, not filter runs over trials.

Some tables and figures of the source documents are not a particle filter tracking a system:
the Mahalanobis distances of four points (park-mpf, Table 1), an empirical CDF beside the true
one (bayes-blog), a resampler's expected and observed offspring counts (han-lee, Algorithm IV),
a motion model's density on a grid (Probabilistic Robotics, Fig. 5.3). A **study** is such a
computation, declared in a config like any experiment::

    name: mahalanobis-table
    seed: 3
    study:
      kind: mahalanobis_distances      # `pfx list studies`
      samples: 1000                    # the study's own parameters
    outputs:
      figures: [mahalanobis_scatter]

A study is a pydantic model (its fields are its parameters, typed and described, so the config
schema and the error messages come from them) with one method, :meth:`Study.tables`, which draws
from the one generator it is given (derived from the config's ``seed``) and returns named
tables. ``pfx run`` writes each table as ``<name>.csv`` in the result folder, with the resolved
``config.yaml`` and ``manifest.json``, and renders the figures the config names, from those CSV
files only, exactly as for a filter experiment.

To add a study: write ``pfx/studies/<name>.py`` with a :class:`Study` subclass whose ``kind``
is a ``Literal`` of its name, and register it in :data:`STUDIES` at the bottom of this file.
"""

from __future__ import annotations

from pfx.studies.base import STUDIES, Study

__all__ = ["STUDIES", "Study"]

# Registered studies (import and add; one line each).
from pfx.studies.offspring_counts import OffspringCounts  # noqa: E402

STUDIES.add("offspring_counts", OffspringCounts)
from pfx.studies.importance_sampling import ImportanceSampling  # noqa: E402
from pfx.studies.kalman_1d_steps import KalmanSteps  # noqa: E402
from pfx.studies.nonlinear_transform import NonlinearTransform  # noqa: E402

STUDIES.add("kalman_1d_steps", KalmanSteps)
STUDIES.add("importance_sampling", ImportanceSampling)
STUDIES.add("nonlinear_transform", NonlinearTransform)
from pfx.studies.mahalanobis_distances import MahalanobisDistances  # noqa: E402

STUDIES.add("mahalanobis_distances", MahalanobisDistances)
from pfx.studies.empirical_cdf import EmpiricalCdf  # noqa: E402
from pfx.studies.importance_sampling_cdf import ImportanceSamplingCdf  # noqa: E402

STUDIES.add("empirical_cdf", EmpiricalCdf)
STUDIES.add("importance_sampling_cdf", ImportanceSamplingCdf)
from pfx.studies.odometry_motion import OdometryMotionDensity, OdometryMotionSamples  # noqa: E402
from pfx.studies.velocity_motion import VelocityMotionDensity, VelocityMotionSamples  # noqa: E402

STUDIES.add("velocity_motion_density", VelocityMotionDensity)
STUDIES.add("velocity_motion_samples", VelocityMotionSamples)
STUDIES.add("odometry_motion_density", OdometryMotionDensity)
STUDIES.add("odometry_motion_samples", OdometryMotionSamples)
from pfx.studies.binary_bayes import BinaryBayesCorridor  # noqa: E402

STUDIES.add("binary_bayes", BinaryBayesCorridor)
