"""The backend a config's cells run on, in their labels: ``backend`` and ``precision`` columns for
a config that runs any particle filter on jax (docs/backends.md), and the refusals that only the
whole plan can make (a Kalman arm asked for jax; what the jax backend cannot record yet; what
parameter estimation on jax needs).
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
        for cell in on_jax:
            _check_compiled_estimation(experiment.estimation, cell, file)
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


def _check_compiled_estimation(estimation, cell, file: str) -> None:
    """PMMH and IF2 on the jax backend pass the parameters to one compiled program as arrays
    (pfx.estimation.compiled_filter): the model must take each estimated path as an array
    (``vectorised_parameters``), the filter be the bootstrap one, and an initial law that follows
    the parameters be Gaussian or a point, whose mean and covariance the program is given."""
    model, settings = cell.filter_model, cell.filter
    declared = type(model).vectorised_parameters
    for path in estimation.parameters:
        if path[len("model."):] not in declared:
            raise ConfigError(f"estimation on the jax backend passes {path} to the compiled filter as an array, and "
                              f"model {model.kind} does not declare it among its vectorised_parameters "
                              f"({', '.join(declared) or 'none'}; docs/estimation.md); set filter.backend: numpy",
                              file=file, key=f"estimation.parameters.{path}")
    if not settings.bootstrap_stages:
        raise ConfigError("estimation on the jax backend runs the bootstrap particle filter (the transition as "
                          "proposal, the likelihood as weight); set filter.backend: numpy", file=file,
                          key="filter.backend")
    if settings.initial is None and "initial" in model.preset_fields():
        law = model.default_prior()
        if getattr(law, "kind", None) not in ("gaussian", "point"):
            raise ConfigError(f"model {model.kind} derives its initial law ({getattr(law, 'kind', law)}) from its "
                              "parameters, and the jax backend's estimation passes a Gaussian or point law per chain; "
                              "name filter.initial, or set filter.backend: numpy", file=file, key="filter.initial")
