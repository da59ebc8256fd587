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
is a ``Literal`` of its name, decorated with ``@STUDIES.register_kind``, and import the module
below.
"""

from __future__ import annotations

from pfx.studies import (  # noqa: F401  (each module registers its studies)
    binary_bayes,
    empirical_cdf,
    importance_sampling,
    importance_sampling_cdf,
    kalman_1d_steps,
    mahalanobis_distances,
    nonlinear_transform,
    odometry_motion,
    offspring_counts,
    velocity_motion,
)
from pfx.studies.base import STUDIES, Study

__all__ = ["STUDIES", "Study"]
