"""The backend a config's cells run on, in their labels: ``backend`` and ``precision`` columns for
a config that runs any particle filter on jax (docs/backends.md), and the refusals that only the
whole plan can make (a Kalman arm asked for jax; what the jax backend cannot record yet).
:func:`pfx.config.plan.build_plan` calls it once its cells are resolved.
"""

from __future__ import annotations

from pfx.errors import ConfigError


def label_backends(cells: list, experiment, arms: dict, file: str) -> None:
    """A config that runs any particle filter on the jax backend gets ``backend`` and
    ``precision`` columns in its tables, for every cell (empty for the kinds without particles,
    which run on numpy; a config on numpy alone keeps the tables it always had). ``backend`` is
    a particle-filter setting, as ``resampler`` is: an arm of another kind ignores the shared
    section's, but one that asks for jax itself is refused, as is a config whose jax reaches no
    particle filter. What the jax backend cannot record yet is refused by its key."""
    for cell in cells:
        arm = cell.labels["arm"]
        if not cell.filter.uses_particles and ((arms.get(arm) or {}).get("backend") == "jax"):
            raise ConfigError(f"the jax backend runs the particle filters (kind particle or sis); the "
                              f"{cell.filter.kind} filter runs on numpy: drop backend: jax from this arm",
                              file=file, key=f"arms.{arm}.backend")
    on_jax = [cell for cell in cells if cell.filter.uses_particles and cell.filter.backend == "jax"]
    if not on_jax:
        if any(cell.filter.backend == "jax" for cell in cells):
            kinds = sorted({cell.filter.kind for cell in cells})
            raise ConfigError(f"the jax backend runs the particle filters (kind particle or sis); this config runs "
                              f"{', '.join(kinds)} only, on numpy: drop backend: jax", file=file, key="filter.backend")
        return
    if experiment.estimation is not None:
        raise ConfigError("parameter estimation (PMMH, IF2) runs on backend: numpy for now (docs/backends.md); "
                          "set filter.backend: numpy", file=file, key="filter.backend")
    if any(cell.metrics.consistency for cell in on_jax):
        raise ConfigError("the jax backend does not record the posterior covariances and NIS yet; drop "
                          "metrics.consistency or set filter.backend: numpy", file=file, key="metrics.consistency")
    if experiment.outputs.particles is not None and experiment.outputs.particles.steps:
        raise ConfigError("the jax backend does not keep particle clouds (particles.csv) yet; drop "
                          "outputs.particles or set filter.backend: numpy", file=file, key="outputs.particles")
    for cell in cells:
        particles = cell.filter.uses_particles
        cell.labels["backend"] = cell.filter.backend if particles else None
        cell.labels["precision"] = cell.filter.precision if particles else None
