"""The refusals a plan makes: what no single section's schema can see, checked once the config is
validated (:func:`check_experiment`) and once its cells are resolved (:func:`check_cells`).

A section's own schema (:mod:`pfx.config.schema`) refuses a wrong type or an out-of-range value
by its key. What is left needs more than one section, or the resolved cells:

* before the cells: an estimation config that also asks for trials, ``particles: auto`` where no
  pilot runs, a sweep key outside ``model.``/``filter.``/``metrics.``, recorded data with
  ``datasets``;
* per cell, while it is resolved: a plugin's model, called once on a tiny batch
  (:func:`check_plugin_model`);
* over the cells: a burn-in that leaves no step, two cells with the same settings, what the jax
  backend cannot run or record, scores no cell computes or that would come from another law than
  the filter's (:mod:`pfx.config.scores`), forecasts that cannot be made
  (:mod:`pfx.config.forecasts`), figures the folder cannot draw or that draw what the config does
  not ask for, estimated parameters the cells' filter cannot vary.

Each is one :class:`~pfx.errors.ConfigError` naming the file and the key (docs/configuration.md).
:func:`pfx.config.plan.build_plan` calls them; nothing runs before they pass. What can be made
in part is made, and :func:`plan_notes` says in one line each what the run leaves out (the
runner prints them).
"""

from __future__ import annotations

import inspect
from typing import Iterable

from pfx.config.covariate_files import check_covariate_spans
from pfx.config.estimation import (
    check_auto_particles,
    check_column_names,
    check_estimated_paths,
    check_figures_apply,
)
from pfx.config.forecasts import check_forecasts, forecast_notes
from pfx.config.plugin_faults import locate as locate_plugin_fault
from pfx.config.plugins import LoadedPlugin
from pfx.config.profile_settings import profile_as_if2
from pfx.config.scores import check_measurement_draws, check_scores, scores_notes
from pfx.errors import ConfigError
from pfx.models import MODELS
from pfx.models.base import Model
from pfx.models.contract_checks import reproducibility_fault

SWEEP_HEADS = ("model", "filter", "metrics")     # the sections a sweep key may vary


def check_experiment(experiment, raw: dict, file: str, *, recorded_data: bool) -> None:
    """The refusals that need the whole validated config but no cell."""
    if experiment.estimation is not None:
        for key in ("trials", "datasets"):
            if key in raw:
                raise ConfigError(f"an estimation config runs chains on one dataset, not trials; drop {key} (how many "
                                  "chains: estimation.chains)", file=file, key=key)
    check_auto_particles(experiment, file)
    for dotted in experiment.sweep:
        if dotted.split(".")[0] not in SWEEP_HEADS:
            raise ConfigError("sweep keys must start with model., filter. or metrics.", file=file,
                              key=f"sweep.{dotted}")
    if recorded_data and experiment.datasets is not None:
        raise ConfigError("recorded data is one dataset: every trial filters it already; drop datasets",
                          file=file, key="datasets")


def check_cells(cells: list, experiment, arms: dict, raw: dict, file: str) -> None:
    """The refusals over the resolved cells (with their recorded data attached, if any), in the
    order a reader meets the sections."""
    sweep = experiment.sweep
    check_covariate_spans(cells, raw, file)
    for cell in cells:                           # with the recorded data's times, if any
        _check_burn_in(cell, file, swept="metrics.burn_in" in sweep)
    seen: dict[str, int] = {}
    for index, cell in enumerate(cells):
        if cell.key in seen:
            raise ConfigError(f"cells {seen[cell.key] + 1} and {index + 1} have identical settings; "
                              "remove the repeated sweep value", file=file, key="sweep")
        seen[cell.key] = index
    check_backends(cells, experiment, arms, file)


def check_outputs_and_estimation(cells: list, experiment, file: str) -> None:
    """The refusals of ``outputs`` and ``estimation`` over the cells: scores no cell computes or
    that would come from another law (:mod:`pfx.config.scores`), forecasts that cannot be made,
    figures the folder cannot draw (or that draw what the config does not ask for), estimated
    parameters the cells cannot vary."""
    check_scores(cells, experiment, file)
    check_forecasts(experiment, cells, file)
    if experiment.outputs.forecasts.requested:       # its quantiles and scores come from the model's draws
        check_measurement_draws([cell for cell in cells if cell.filter.uses_particles], file, "outputs.forecasts",
                                "the forecasts' measurement quantiles, CRPS and PIT")
    if "figures" in experiment.outputs.model_fields_set:
        check_figures_apply(experiment.outputs.figures, experiment.estimation, file, asked_outputs(cells, experiment))
    if experiment.estimation is not None:
        for cell in cells:
            check_estimation(experiment.estimation, cell, file, len(cells) > 1)


def asked_outputs(cells: list, experiment) -> frozenset:
    """The keys that write what some figures draw (:func:`pfx.figures.registry.asks_for`) which
    this config asks for; and ``NO_TRUTH`` for recorded data without ``data.truth``, which the
    figures of the true states cannot draw (:func:`pfx.figures.registry.draws_truth`)."""
    from pfx.figures.registry import NO_TRUTH

    asked = {"outputs.forecasts"} if experiment.outputs.forecasts.requested else set()
    if any(cell.metrics.scores for cell in cells):
        asked.add("metrics.scores")
    if any(cell.data is not None and cell.data.truth is None for cell in cells):
        asked.add(NO_TRUTH)
    return frozenset(asked)


def plan_notes(plan) -> list[str]:
    """What the plan's run will leave out of what its config asks, where leaving it out is the
    honest answer (part of it can be made), and what reading the config did in its place (a
    data file's dates read as days: ``plan.notes``), one line each: the runner prints them,
    ``--quiet`` silences them. A config that asks for what cannot be made at all is refused instead."""
    return plan.notes + forecast_notes(plan.experiment, plan.cells) + scores_notes(plan.cells)


def check_backends(cells: list, experiment, arms: dict, file: str) -> None:
    """``backend`` is a particle-filter setting, as ``resampler`` is: an arm of another kind
    ignores the shared section's, but one that asks for jax itself is refused, as is a config
    whose jax reaches no particle filter. Estimation the compiled filter cannot run is refused
    by its key (docs/backends.md)."""
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


def check_estimation(estimation, cell, file: str, several: bool) -> None:
    """The estimated paths name numbers of the cell's filter model, and their columns are not the
    cell's label columns (:mod:`pfx.config.estimation_tables`); IF2 perturbs every particle's
    parameters, so it needs a bootstrap particle filter and a model that takes each of them as an
    array (``vectorised_parameters``)."""
    where = f" (cell {cell.labels})" if several else ""
    if estimation.method == "profile":      # the IF2 run it is: its profiled parameter is checked as an estimated one
        profiled = estimation.profile.parameter
        try:
            check_estimation(profile_as_if2(estimation), cell, file, several)
        except ConfigError as error:
            key = ("estimation.profile.parameter" if (error.key or "").startswith(f"estimation.parameters.{profiled}")
                   else error.key)
            raise ConfigError(error.reason, file=file, key=key) from None
        return
    check_estimated_paths(estimation, cell.filter_model, file, where)
    check_column_names(estimation, list(cell.labels), file, where)
    if estimation.method != "if2":
        return
    settings = cell.filter
    if settings.kind != "particle" or not settings.bootstrap_stages:
        raise ConfigError(f"IF2 runs the bootstrap particle filter (kind particle, the transition as proposal, the "
                          f"likelihood as weight, no auxiliary stage, move, adaptive count or injection){where}",
                          file=file, key="estimation.method")
    declared = type(cell.filter_model).vectorised_parameters
    for path in estimation.parameters:
        if path[len("model."):] not in declared:
            raise ConfigError(f"IF2 gives every particle its own {path}, and model {cell.filter_model.kind} does not "
                              f"declare it among its vectorised_parameters ({', '.join(declared) or 'none'}; "
                              "docs/estimation.md)", file=file, key=f"estimation.parameters.{path}")


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


def _check_burn_in(cell, file: str, swept: bool) -> None:
    """A burn-in (``metrics.burn_in``) must leave at least one step to score: a step at a time
    after it (:mod:`pfx.analysis.metrics`)."""
    burn_in = cell.metrics.burn_in
    times = cell.truth_model.times()
    if burn_in > 0 and not (times > burn_in).any():
        raise ConfigError(f"{burn_in:g} leaves no step to score: the steps at times <= burn_in are not scored, "
                          f"and the last step is at time {times[-1]:g}",
                          file=file, key="sweep.metrics.burn_in" if swept else "metrics.burn_in")


def check_plugin_model(model: Model, plugins: Iterable[LoadedPlugin]) -> None:
    """A plugin's model, checked before anything runs: called once on a tiny batch (its shapes,
    dtypes and declared index lists: :meth:`Model.check_contract`), then probed for a global
    random generator (the same inputs twice must give the same outputs:
    :func:`~pfx.models.contract_checks.reproducibility_fault`). Its mistakes are one
    :class:`ConfigError` line naming the plugin file (and the line, where known). A model whose
    class none of ``plugins`` registered or defines (pfx's own) passes unchecked."""
    model_class = type(model)
    registered = model.kind in MODELS and MODELS[model.kind] is model_class
    origin = MODELS.origin(model.kind) if registered else None     # the plugin that registered it, if one did
    plugin = next((plugin for plugin in plugins
                   if (origin is not None and plugin.origin == origin) or plugin.module == model_class.__module__),
                  None)
    if plugin is None:
        return
    from pfx.numerics.seeding import TrialStreams

    try:
        model.check_contract(TrialStreams.from_seeds([0, 1]))
        fault = reproducibility_fault(model)
        if fault is not None:
            raise ValueError(fault)
    except Exception as error:          # the plugin's own code: any exception is its mistake
        located = locate_plugin_fault(error, [plugin])
        if located is not None:         # raised in the plugin's code: its line
            raise located.as_config_error() from error
        # A result pfx's check refused: the line of the member's definition, where it has one.
        reason = " ".join(str(error).split())
        member = inspect.getattr_static(model_class, reason.split(" ", 1)[0], None)
        function = member.fget if isinstance(member, property) else member
        code = getattr(function, "__code__", None)
        line = code.co_firstlineno if code is not None and code.co_filename in (plugin.path, plugin.code_file) \
            else None
        raise ConfigError(f"model {model.kind}: {reason}", file=plugin.path, line=line) from error
