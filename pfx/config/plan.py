"""Expand a validated config into the plan: every (arm x sweep combination) cell, resolved.

A cell is fully resolved before anything runs: its true model, the model its filter assumes
(the true model's parameters with ``filter.model`` merged over them), the prior, the filter
settings and the metric parameters. Any invalid combination stops the whole plan with an
error naming the arm or sweep entry responsible.

The plugins a config names (``plugins:``, :mod:`pfx.config.plugins`) are imported first, and
the config is validated against the classes :func:`pfx.config.schema.config_schema` builds for
pfx's own components plus theirs. Their code's hashes join the config and results hashes.
"""

from __future__ import annotations

import copy
import itertools
import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Optional

from pfx.analysis.metrics import MetricsConfig
from pfx.config.data import CellData, attach_recorded_data, prepare_recorded_data
from pfx.config.dotted_paths import deep_merge, set_path
from pfx.config.estimation import ESTIMATION_FIGURES
from pfx.config.plan_checks import check_cells, check_experiment, check_outputs_and_estimation, check_plugin_model
from pfx.config.plugin_faults import locate as locate_plugin_fault
from pfx.config.plugin_faults import plan_time_fault
from pfx.config.plugin_record import check_copies
from pfx.config.plugins import LoadedPlugin, load_config_plugins, unknown_name_hint
from pfx.config.record_hash import identity_dump, with_data_content, with_plugin_code
from pfx.config.schema import ConfigSchema, config_schema
from pfx.config.validation import validate
from pfx.errors import ConfigError, located_value_error
from pfx.filters import FILTERS, FilterKind
from pfx.models import MODELS
from pfx.models.base import Model, bind_law
from pfx.numerics.hashing import canonical_hash

if TYPE_CHECKING:       # the classes of the built-in components; a plan's own come from config_schema
    from pfx.config.schema import Experiment, FilterConfig, StudyExperiment

DEFAULT_ARM = "default"
# sweep keys that already have a column of their own in the tables
_KNOWN_COLUMNS = {"filter.particles": "n_particles", "filter.resampler": "resampler",
                  "filter.ess_threshold": "ess_threshold", "filter.weighting": "weighting",
                  "filter.kind": "filter", "filter.diffusion": "diffusion", "model.kind": "model",
                  "filter.proposal": "proposal", "filter.auxiliary": "auxiliary"}


@dataclass
class Cell:
    """One combination of settings, run for every trial."""

    key: str                       # hex hash of everything that defines the cell
    filter_key: str                # hex hash of what the filter run depends on: names its stream
    labels: dict[str, Any]         # the columns that identify the cell in every CSV
    truth_model: Model
    filter_model: Model
    filter: FilterConfig
    prior: Any
    metrics: MetricsConfig
    planned_filter: FilterKind     # the filter kind planned for this cell (pfx.filters.base)
    data: Optional[CellData] = None  # recorded data to filter instead of simulating (pfx.config.data)

    @property
    def stream_key(self) -> int:
        """Cells that differ only in metric parameters share the filter stream (paired)."""
        return int(self.filter_key, 16)


@dataclass
class Plan:
    file: str
    experiment: Experiment
    resolved: dict                 # the resolved config (written as config.yaml)
    cells: list[Cell] = field(default_factory=list)
    plugins: list[LoadedPlugin] = field(default_factory=list)   # what ``plugins:`` loaded
    notes: list[str] = field(default_factory=list)      # what reading the config did that the run says

    @property
    def config_hash(self) -> str:
        """Hash of the whole resolved config: the record of what was asked (with the code of
        its plugins and the contents of its data files, if any, not the paths that reach them)."""
        return canonical_hash(with_plugin_code(with_data_content(self.resolved), self.plugins))

    @property
    def results_hash(self) -> str:
        """Hash of what the numbers depend on: every cell (its settings and labels), the seed,
        and which trials keep traces and particle clouds. Not the name, the description, the
        figures or the trial count: changing those keeps a result folder's results (more trials
        extend them, each trial having its own random streams); nor, after PMMH, the forecasts,
        made from the kept chains (:mod:`pfx.run.estimation_outputs`)."""
        outputs = self.experiment.outputs
        numbers_depend_on = {"seed": self.experiment.seed,
                             "cells": [[cell.key, cell.labels] for cell in self.cells],
                             "trace_trials": outputs.trace_trials,
                             "particles": outputs.particles.model_dump(mode="json")}
        if self.experiment.datasets is not None:     # absent, the hash of earlier results is unchanged
            numbers_depend_on["datasets"] = self.experiment.datasets
        if outputs.genealogy:                        # likewise: genealogy.csv is a table of the results
            numbers_depend_on["genealogy"] = outputs.genealogy
        if outputs.forecasts.requested and self.experiment.estimation is None:   # and a filter run's forecasts.csv
            numbers_depend_on["forecasts"] = outputs.forecasts.model_dump(mode="json")   # (PMMH's reads the chains)
        if self.experiment.estimation is not None:   # every setting but the iterations (more extend a run)
            estimation = self.experiment.estimation.model_dump(mode="json", exclude={"iterations"})
            for optional in ("particle_count", "profile"):     # absent, the hash of earlier results is unchanged
                if getattr(self.experiment.estimation, optional) is None:
                    estimation.pop(optional, None)
            numbers_depend_on["estimation"] = estimation
        return canonical_hash(with_plugin_code(numbers_depend_on, self.plugins))

    @property
    def size_text(self) -> str:
        estimation = self.experiment.estimation
        if estimation is not None:
            chains, passes = ("chain(s)", "iteration(s)") if estimation.method == "pmmh" else ("replicate(s)", "pass(es)")
            return f"{len(self.cells)} cell(s) x {estimation.chains} {chains} x {estimation.iterations} {passes}"
        return f"{len(self.cells)} cell(s) x {self.experiment.trials} trial(s)"

    @property
    def label_columns(self) -> list[str]:
        return list(self.cells[0].labels) if self.cells else []

    @property
    def legend_columns(self) -> list[str]:
        """The columns that tell cells apart in a legend: the arm (if several), the sweep keys."""
        arms = ["arm"] if len(self.experiment.arms) > 1 else []
        return arms + [sweep_column(key) for key in self.experiment.sweep]


@dataclass
class StudyPlan:
    """A study config, validated: one computation, no cells (see :mod:`pfx.studies`)."""

    file: str
    experiment: StudyExperiment
    resolved: dict
    cells: list = field(default_factory=list)
    plugins: list[LoadedPlugin] = field(default_factory=list)

    @property
    def config_hash(self) -> str:
        return canonical_hash(with_plugin_code(self.resolved, self.plugins))

    @property
    def results_hash(self) -> str:
        """Hash of what the tables depend on: the study and the seed (not its figures)."""
        return canonical_hash(with_plugin_code({"seed": self.experiment.seed, "study": self.resolved["study"]},
                                               self.plugins))

    @property
    def size_text(self) -> str:
        return f"study {self.experiment.study.kind}"


def sweep_column(key: str) -> str:
    return _KNOWN_COLUMNS.get(key, key.replace(".", "_"))


def _filter_model(truth: Model, raw_model: dict, overrides: dict, file: str, prefix: str) -> Model:
    """The model the filter assumes: the true model's settings with ``filter.model`` merged over.

    Settings the true model took from its presets (or that equal them, as in a resolved
    config, which writes every preset out) are derived again for the filter's model, so that
    an override they depend on (``motion.noise`` for ``planar_robot``'s process noise, the
    ``variant`` of ``falling_body``) carries through to them.
    """
    if overrides:
        derived = truth.preset_fields()
        raw_model = {key: value for key, value in raw_model.items() if key not in derived}
    merged = deep_merge(raw_model, overrides)
    if merged.get("kind") != raw_model.get("kind"):
        raise ConfigError("the filter's model must be of the same kind as the true model",
                          file=file, key=f"{prefix}.kind")
    return validate(MODELS[merged["kind"]], merged, file=file, prefix=prefix)


def _resolve_cell(raw: dict, arm: str, arm_raw: Optional[dict], combination: dict, file: str,
                  prefix: str = "", schema: Optional[ConfigSchema] = None,
                  plugins: tuple[LoadedPlugin, ...] = ()) -> Cell:
    """Resolve one cell; errors are located under ``prefix`` (an arm or sweep entry) if given."""
    cell_raw = {key: copy.deepcopy(value) for key, value in raw.items() if key not in ("arms", "sweep")}
    if arm_raw:
        cell_raw["filter"] = deep_merge(cell_raw.get("filter") or {}, arm_raw)
    for dotted, value in combination.items():
        try:
            set_path(cell_raw, dotted, copy.deepcopy(value))
        except ConfigError as error:
            raise ConfigError(error.reason, file=file, key=prefix or f"sweep.{dotted}") from None

    def locate(error: ConfigError) -> ConfigError:
        if not prefix or (error.file is not None and error.file != file):
            return error         # located in another file (a plugin, a data file): its own words
        return ConfigError(f"{error.key}: {error.reason}" if error.key else error.reason,
                           file=file, key=prefix)

    try:
        experiment = validate((schema or config_schema()).Experiment, cell_raw, file=file)
        settings = experiment.filter
        truth = experiment.model
        check_plugin_model(truth, plugins)
        filter_model = _filter_model(truth, cell_raw["model"], settings.model, file, "filter.model")
        check_plugin_model(filter_model, plugins)
        if (filter_model.state_dimension, filter_model.measurement_dimension) != \
                (truth.state_dimension, truth.measurement_dimension):
            raise ConfigError("the filter's model must have the true model's state and measurement sizes",
                              file=file, key="filter.model")
        try:
            settings.diffusion.check(filter_model.state_dimension)
        except ValueError as error:
            raise located_value_error(error, prefix="filter.diffusion", file=file) from None
        prior = settings.initial or filter_model.default_prior()
        try:
            bind_law(prior, filter_model.state_dimension, "initial")
        except ValueError as error:
            raise located_value_error(error, prefix="filter", file=file) from None
        try:        # the kind's checks, and what it fixes for the cell (the histogram grid)
            planned_filter = FILTERS[settings.kind].plan(filter_model, settings, prior)
        except ValueError as error:
            fault = locate_plugin_fault(error, plugins)      # a plugin's own ValueError, met while a check probed it
            if fault is not None:
                raise fault.as_config_error() from error
            raise located_value_error(error, prefix="filter", file=file) from None
        except ConfigError as error:
            raise error.located(file=file) from None
    except ConfigError as error:
        raise locate(error) from None

    settings_dump = identity_dump(settings)
    settings_dump.pop("model", None)
    settings_dump.pop("initial", None)
    identity = {"arm": arm, "truth": identity_dump(truth), "filter": settings_dump,
                "filter_model": identity_dump(filter_model), "prior": identity_dump(prior)}
    particles = settings.uses_particles      # other kinds leave the particle columns empty
    labels: dict[str, Any] = {
        "arm": arm,
        "model": truth.kind,
        "filter": settings.kind,
        "n_particles": settings.particles if particles else None,
        "resampler": settings.resampler if particles else None,
        "ess_threshold": settings.effective_threshold() if particles else None,
        "weighting": settings.weighting.label() if particles else None,
        "diffusion": settings.diffusion.kind if particles else None,
        "move": settings.move.kind if particles else None,
    }
    for dotted, value in combination.items():
        column = sweep_column(dotted)
        if column not in labels:
            labels[column] = value if isinstance(value, (int, float, str, bool)) else json.dumps(value)
    metrics = experiment.metrics.identity()
    return Cell(key=canonical_hash({**identity, "metrics": metrics}, 12),
                filter_key=canonical_hash(identity, 12), labels=labels, truth_model=truth,
                filter_model=filter_model, filter=settings, prior=prior, metrics=experiment.metrics,
                planned_filter=planned_filter)


def build_plan(raw: dict, file: str, *, trials: Optional[int] = None) -> Plan | StudyPlan:
    """Validate the whole config and expand it into cells; raise ConfigError on any problem.

    A config with a ``study`` section is a study (:mod:`pfx.studies`): it has no cells. The
    plugins the config names are imported first (and only they: docs/plugins.md).
    """
    plugins = load_config_plugins(raw, file)
    if plugins:
        check_copies(plugins, file)
    schema = config_schema([plugin.origin for plugin in plugins])
    try:
        plan = _expand(raw, file, trials, schema, tuple(plugins))
    except ConfigError as error:
        # a name none of the config's plugins registered: what they did register, and what
        # code imported by hand registered, which the config does not name
        hint = unknown_name_hint(plugins, error.reason) if error.reason.startswith("unknown ") else ""
        if hint:
            raise ConfigError(error.reason + hint, file=error.file, key=error.key,
                              line=error.line, column=error.column) from None
        raise
    except Exception as error:          # raised by a plugin's code (presets(), a property, ...)
        fault = plan_time_fault(error, plugins)
        if fault is None:
            raise
        raise fault from error
    plan.plugins = list(plugins)
    if not plugins:
        plan.resolved.pop("plugins", None)     # the record of a config without plugins is unchanged
    return plan


def _expand(raw: dict, file: str, trials: Optional[int], schema: ConfigSchema,
            plugins: tuple[LoadedPlugin, ...]) -> Plan | StudyPlan:
    """:func:`build_plan` once the plugins are loaded: validation against ``schema``, the cells."""
    raw = copy.deepcopy(raw)
    if isinstance(raw, dict) and "study" in raw:
        if trials is not None:
            raise ConfigError("a study has no trials; drop --trials", file=file, key="study")
        study = validate(schema.StudyExperiment, raw, file=file)
        return StudyPlan(file=file, experiment=study, resolved=study.model_dump(mode="json"))
    if trials is not None:
        raw["trials"] = trials
    data = prepare_recorded_data(raw, file)      # reads data: files; fills model.steps (dt, controls) from them
    experiment = validate(schema.Experiment, raw, file=file)
    check_experiment(experiment, raw, file, recorded_data=data is not None)
    raw_arms = raw.get("arms") or {}
    arms: dict[str, Optional[dict]] = {name: raw_arms[name] for name in experiment.arms} or {DEFAULT_ARM: None}
    sweep = experiment.sweep

    # Check each arm and each sweep value on its own first, so errors name their source.
    for name, arm_raw in arms.items():
        if arm_raw is not None:
            _resolve_cell(raw, name, arm_raw, {}, file, prefix=f"arms.{name}", schema=schema, plugins=plugins)
    for dotted, values in sweep.items():
        for index, value in enumerate(values):
            _resolve_cell(raw, DEFAULT_ARM, None, {dotted: value}, file, prefix=f"sweep.{dotted}[{index}]",
                          schema=schema, plugins=plugins)

    cells: list[Cell] = []
    keys = list(sweep)
    for name, arm_raw in arms.items():
        for values in itertools.product(*(sweep[key] for key in keys)):
            combination = dict(zip(keys, values))
            where = f"arms.{name}" if arm_raw is not None else "sweep"
            cells.append(_resolve_cell(raw, name, arm_raw, combination, file,
                                       prefix=where if (arm_raw is not None or keys) else "",
                                       schema=schema, plugins=plugins))
    attach_recorded_data(cells, data, file)
    check_cells(cells, experiment, arms, raw, file)
    _label_backends(cells)

    if "figures" not in experiment.outputs.model_fields_set and experiment.estimation is not None:
        experiment.outputs.figures = list(ESTIMATION_FIGURES[experiment.estimation.method])
    elif "figures" not in experiment.outputs.model_fields_set and _sweeps_particle_count(sweep):
        experiment.outputs.figures = ["rmse_vs_particles", *experiment.outputs.figures]
    resolved = resolved_config(experiment, raw, arms, cells, file, schema)
    files = {key: value for key, value in (resolved.get("data") or {}).items() if value is not None}
    for key in ("controls", "covariates"):      # a table a data file filled is recorded by the file's
        if key in files:                        # path (rerunning reads it again), not copied into the model
            resolved["model"].pop(key, None)
    if data is None and not files:
        resolved.pop("data", None)     # the record of a config without data is unchanged
    elif data is None:
        resolved["data"] = files       # covariates only: the measurements are simulated
    if experiment.datasets is None:
        resolved.pop("datasets", None)     # nor is that of a config without datasets
    if experiment.time_unit is None:
        resolved.pop("time_unit", None)    # nor that of a config without a time unit
    if not experiment.outputs.genealogy:
        resolved["outputs"].pop("genealogy", None)     # nor that of a config without genealogy.csv
    if not experiment.metrics.scores and "metrics" in resolved:
        resolved["metrics"].pop("scores", None)        # nor that of a config without scores
    if not experiment.outputs.forecasts.requested:
        resolved["outputs"].pop("forecasts", None)     # nor that of a config without forecasts.csv
    check_outputs_and_estimation(cells, experiment, file)
    if experiment.estimation is None:
        resolved.pop("estimation", None)     # nor that of a config without estimation
    else:
        resolved.pop("trials", None)         # it has none
        for optional in ("particle_count", "profile"):     # the record of a config without them is unchanged
            if getattr(experiment.estimation, optional) is None:
                resolved["estimation"].pop(optional, None)
    return Plan(file=file, experiment=experiment, resolved=resolved, cells=cells,
                notes=[data.measurements.note] if data is not None and data.measurements.note else [])


def _label_backends(cells: list[Cell]) -> None:
    """A config that runs any particle filter on the jax backend gets ``backend`` and
    ``precision`` columns in its tables, for every cell (empty for the kinds without particles,
    which run on numpy); a config on numpy alone keeps the tables it always had (docs/backends.md)."""
    if not any(cell.filter.uses_particles and cell.filter.backend == "jax" for cell in cells):
        return
    for cell in cells:
        particles = cell.filter.uses_particles
        cell.labels["backend"] = cell.filter.backend if particles else None
        cell.labels["precision"] = cell.filter.precision if particles else None


def _sweeps_particle_count(sweep: dict) -> bool:
    return len(sweep.get("filter.particles", [])) >= 2


def resolved_config(experiment: Experiment, raw: dict, arms: dict[str, Optional[dict]], cells: list[Cell],
                    file: str, schema: Optional[ConfigSchema] = None) -> dict:
    """The config as it runs, every default filled in: what ``config.yaml`` records and ``pfx
    validate`` prints. Running it gives the same cells, hence the same numbers.

    Each arm is written as what it changes against the resolved ``filter:`` section (the arm's
    own keys merged over that section, then compared with it), so that the record reads like
    the config. Filter settings that apply to none of the cells' filter kinds (``grid`` for a
    particle filter) are left out where they hold their default.
    """
    resolved = experiment.model_dump(mode="json")
    kinds_by_arm: dict[str, set[str]] = {}
    for cell in cells:
        kinds_by_arm.setdefault(cell.labels["arm"], set()).add(cell.filter.kind)
    all_kinds = set().union(*kinds_by_arm.values()) if kinds_by_arm else {experiment.filter.kind}
    section = experiment.filter.model_dump(mode="json")
    resolved["filter"] = experiment.filter.applicable_dump(all_kinds)
    if all(cell.filter.backend == "numpy" for cell in cells):
        for key in ("backend", "precision"):      # the record of a config on numpy alone is unchanged
            resolved["filter"].pop(key, None)
    if all(cell.filter.count_draws == "exact" for cell in cells):
        resolved["filter"].pop("count_draws", None)   # likewise the record of a config with exact draws
    if experiment.arms:
        resolved["arms"] = {}
        for name, arm_raw in arms.items():
            merged = validate((schema or config_schema()).FilterConfig, deep_merge(raw.get("filter") or {}, arm_raw or {}),
                              file=file, prefix=f"arms.{name}")
            resolved["arms"][name] = {key: value for key, value in merged.model_dump(mode="json").items()
                                      if section.get(key) != value}
    return resolved
