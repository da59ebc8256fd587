"""The ``estimation:`` section: which model parameters to estimate from the data, and how.

A config with this section is a parameter-estimation experiment (docs/estimation.md): each
cell (arm x sweep combination) runs the method on one dataset (the recorded data, or the
simulated dataset of trial 0) with the cell's filter inside. The keys of ``parameters`` are
dotted paths into the model, the same paths ``--set`` takes (``model.mu``,
``model.process_noise.variance``); each names a number of the filter's model.
"""

from __future__ import annotations

import math
from typing import Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, model_validator

from pfx.config.estimation_tables import reserved_names, tables_with
from pfx.config.profile_settings import ProfileSettings, check_profile
from pfx.errors import ConfigError
from pfx.laws.priors import Prior, TransformName, make_transform
from pfx.registry import with_article

# The figures an estimation config draws unless its outputs name others (a filter run's defaults
# draw trials, which it has none of).
ESTIMATION_FIGURES = {"pmmh": ("chain_traces", "posterior_marginals", "posterior_pairs"), "if2": ("if2_convergence",),
                      "profile": ("profile_likelihood",)}


# The settings one method reads and the other does not, each with what the other method does
# instead: a PMMH setting in an IF2 config (or the reverse) is refused rather than ignored, so
# that a user who knows another package's names does not think it set the walk it runs.
METHOD_ONLY_KEYS = {
    "warm_up": ("pmmh", "IF2 has no warm-up (every pass moves the swarm, and its random walk shrinks by "
                        "cooling_fraction_50)"),
    "adapt": ("pmmh", "IF2's random walk does not adapt, it cools by cooling_fraction_50"),
    "adapt_after": ("pmmh", "IF2's random walk does not adapt, it cools by cooling_fraction_50"),
    "particle_count": ("pmmh", "IF2 takes a number of particles, filter.particles"),
    "cooling_fraction_50": ("if2", "PMMH's random walk does not cool, it adapts during the warm-up (warm_up, "
                                   "adapt)"),
    "evaluations": ("if2", "PMMH's chains carry each draw's log-likelihood (chains.csv)"),
}
METHOD_ONLY_PARAMETER_KEYS = {
    "proposal_sd": ("pmmh", "IF2's random walk is set by random_walk_sd"),
    "random_walk_sd": ("if2", "PMMH's proposal is set by proposal_sd"),
}
METHOD_NAMES = {"pmmh": "PMMH", "if2": "IF2"}


def _other_methods_keys(settings: BaseModel, method: str, table: dict, prefix: str = "") -> None:
    """ValueError naming the first key of ``settings`` that only the other method reads. A key
    at its default value is let through: the record a run writes (config.yaml) holds every key
    with its default, and must run again as it is."""
    for key, (owner, instead) in table.items():
        if owner != method and key in settings.model_fields_set:
            default = type(settings).model_fields[key].default
            if getattr(settings, key) != default:
                raise ValueError(f"@{prefix}{key}: {with_article(METHOD_NAMES[owner])} setting, which "
                                 f"{METHOD_NAMES[method]} does not read: {instead}; drop it")


class EstimatedParameter(BaseModel):
    """One estimated parameter: its prior, the scale it moves on, where chains start."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    prior: Prior = Field(description="prior law (`law`: uniform, normal, lognormal, gamma, inverse_gamma, beta, "
                                     "flat) and its parameters; IF2 reads only its support")
    transform: Optional[TransformName] = Field(
        None, description="scale the random walks move on: none, log (variances), logit (probabilities, or any "
                          "bounded interval); default from the prior's support")
    start: Union[StrictFloat, list[StrictFloat], Literal["prior"]] = Field(
        "prior", description="starting value: one number for every chain, one per chain, or `prior` (each chain "
                             "draws its own from the prior, from its own stream)")
    proposal_sd: StrictFloat = Field(0.1, gt=0, description="PMMH: the random walk's initial standard deviation on the "
                                                            "transformed scale (adapted during warm-up if `adapt`)")
    random_walk_sd: StrictFloat = Field(0.02, gt=0, description="IF2: the perturbation's standard deviation on the "
                                                                "transformed scale at the first iteration")
    name: Optional[str] = Field(None, pattern=r"^[A-Za-z_][A-Za-z0-9_.]*$",
                                description="column name in the tables (default: the path without `model.`)")

    @model_validator(mode="after")
    def _check(self):
        transform = make_transform(self.transform, self.prior.support)      # ValueError('@transform: ...')
        if self.start == "prior" and self.prior.law == "flat":
            raise ValueError("@start: a flat prior cannot be drawn from (start: prior, the default); give the "
                             "chains a start: one number, or one per chain")
        starts = [self.start] if isinstance(self.start, float) else self.start if isinstance(self.start, list) else []
        for value in starts:
            if not math.isfinite(float(self.prior.log_density(value))):
                raise ValueError(f"@start: {value:g} lies outside the prior's support {self.prior.support}")
            if not math.isfinite(float(transform.to_unconstrained(value))):
                raise ValueError(f"@start: {value:g} is on the boundary of the {transform.name} transform's range")
        return self


class ParticleCount(BaseModel):
    """How ``particles: auto`` chooses a PMMH cell's particle count (docs/estimation.md, "Choosing N",
    and :mod:`pfx.estimation.particle_count`, the rule)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    target_sd: StrictFloat = Field(1.2, gt=0, description="the sd of the log-likelihood estimate to aim at, at the "
                                                          "point `at` (Doucet, Pitt, Deligiannidis & Kohn 2015: about "
                                                          "1.2 at the posterior's centre)")
    runs: StrictInt = Field(40, ge=10, le=100_000, description="filter runs per particle count measured; the sd's "
                                                              "relative standard error is about 1/sqrt(2 (runs - 1))")
    smallest: StrictInt = Field(16, ge=2, le=100_000_000, description="the first particle count measured; the "
                                                                     "ladder doubles it")
    largest: StrictInt = Field(100_000, ge=2, le=100_000_000, description="the most particles the choice may take "
                                                                         "(the ladder's cap)")
    at: Union[Literal["start"], dict[str, StrictFloat]] = Field(
        "start", description="where the sd is measured: `start` (the chains' common start, or the per-parameter "
                             "median of their starts) or a mapping dotted path -> value for every estimated parameter")

    after_warm_up: StrictBool = Field(
        True, description="measure again at the end of the warm-up, at the median of the chains' positions over its "
                          "second half, and run the iterations after it with that count (each chain's current "
                          "estimate computed again with it); no effect without a warm-up")

    @model_validator(mode="after")
    def _check(self):
        if self.largest < self.smallest:
            raise ValueError(f"@largest: {self.largest} is below smallest ({self.smallest})")
        return self


class EstimationConfig(BaseModel):
    """Parameter estimation from the data: PMMH (a posterior sample) or IF2 (maximum likelihood)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    method: Literal["pmmh", "if2", "profile"] = Field(
        description="pmmh: particle marginal Metropolis-Hastings (Andrieu, Doucet & Holenstein 2010); if2: "
                    "iterated filtering (Ionides et al. 2015); profile: a likelihood profile over one parameter by IF2 "
                    "at each grid value, with the Monte Carlo adjusted profile's interval (Ionides et al. 2017)")
    parameters: dict[str, EstimatedParameter] = Field(
        min_length=1, description="dotted path into the model (as `--set` takes it, e.g. model.mu) -> prior, "
                                  "transform, start")
    chains: StrictInt = Field(4, ge=1, le=100_000, description="PMMH chains, or IF2 replicates, run as rows of "
                                                               "one batch")
    iterations: StrictInt = Field(ge=1, le=10_000_000,
                                  description="PMMH iterations per chain, or IF2 passes through the data; a "
                                              "finished folder is extended by asking for more")
    warm_up: StrictInt = Field(0, ge=0, description="PMMH: the first iterations, where the proposal adapts; left out "
                                                   "of posterior.csv")
    adapt: StrictBool = Field(True, description="PMMH: adapt the random walk's covariance during warm-up "
                                               "(Haario et al. 2001: 2.38^2 / d times the chain's covariance so far)")
    adapt_after: StrictInt = Field(100, ge=2, description="PMMH: iterations before the first adaptation")
    cooling_fraction_50: StrictFloat = Field(
        0.5, gt=0, le=1, description="IF2: the perturbations' sd after 50 iterations, as a fraction of the first "
                                     "(geometric cooling, as pomp's mif2)")
    evaluations: StrictInt = Field(10, ge=1, le=10_000, description="IF2: filter runs at each replicate's final "
                                                                   "estimate, for its log-likelihood and standard "
                                                                   "error (maximum_likelihood.csv)")
    profile: Optional[ProfileSettings] = Field(
        None, description="method: profile: the profiled parameter (a dotted path) and its grid (grid, or lower, "
                          "upper and points); chains are the IF2 starts per grid value")
    particle_count: Optional[ParticleCount] = Field(
        None, description="PMMH with `particles: auto`: how the pilot chooses each cell's particle count "
                          "(target_sd, runs, smallest, largest, at); default: those defaults")

    @model_validator(mode="before")
    @classmethod
    def _model_paths(cls, data):
        # before the parameters' own settings are read: `--set estimation.parameters.model.misspelt.x=1`
        # makes a key `model` whose settings are all missing, and the path is what is wrong
        parameters = data.get("parameters") if isinstance(data, dict) else None
        for path in parameters if isinstance(parameters, dict) else ():
            if not isinstance(path, str) or not path.startswith("model.") or path == "model.":
                raise ValueError(f"@parameters.{path}: give a dotted path into the model, e.g. model.mu (with "
                                 "--set, a path that names none of the estimated parameters makes a new key)")
        return data

    @model_validator(mode="after")
    def _check(self):
        method = "if2" if self.method == "profile" else self.method     # a profile runs IF2 (its settings)
        _other_methods_keys(self, method, METHOD_ONLY_KEYS)
        check_profile(self, reserved_names())
        for path, parameter in self.parameters.items():
            _other_methods_keys(parameter, method, METHOD_ONLY_PARAMETER_KEYS, prefix=f"parameters.{path}.")
            if isinstance(parameter.start, list) and len(parameter.start) != self.chains:
                raise ValueError(f"@parameters.{path}.start: {len(parameter.start)} values for {self.chains} chains")
        names = [self.column(path) for path in self.parameters]
        if len(set(names)) != len(names):
            raise ValueError("@parameters: two parameters have the same column name; give one a `name`")
        reserved = reserved_names()
        for path in self.parameters:
            name = self.column(path)
            if name in reserved:
                raise ValueError(f"@{self.name_key(path)}: {name!r} is a column of {', '.join(tables_with(name))}, "
                                 "which the parameter's own column would overwrite; give it another `name`")
        if self.particle_count is not None and isinstance(self.particle_count.at, dict):
            self._check_pilot_point(self.particle_count.at)
        if self.method == "pmmh" and self.warm_up >= self.iterations:
            raise ValueError(f"@warm_up: {self.warm_up} warm-up iterations leave none of the {self.iterations} for "
                             "the posterior")
        return self

    def _check_pilot_point(self, point: dict[str, float]) -> None:
        """``particle_count.at`` names every estimated parameter, each inside its prior's support."""
        for path in point:
            if path not in self.parameters:
                raise ValueError(f"@particle_count.at.{path}: not an estimated parameter (they are "
                                 f"{', '.join(self.parameters)})")
        for path, parameter in self.parameters.items():
            if path not in point:
                raise ValueError(f"@particle_count.at: gives no value for {path}; give one for every estimated "
                                 "parameter, or at: start")
            if not math.isfinite(float(parameter.prior.log_density(point[path]))):
                raise ValueError(f"@particle_count.at.{path}: {point[path]:g} lies outside the prior's support "
                                 f"{parameter.prior.support}")

    def column(self, path: str) -> str:
        """The column name of the parameter at ``path``."""
        return self.parameters[path].name or path[len("model."):]

    def name_key(self, path: str) -> str:
        """The key (below ``estimation``) that gives the parameter at ``path`` its column name:
        its ``name``, or the path itself."""
        return f"parameters.{path}.name" if self.parameters[path].name else f"parameters.{path}"

    @property
    def pilot(self) -> ParticleCount:
        """The settings of ``particles: auto`` (``particle_count``, or its defaults)."""
        return self.particle_count or ParticleCount()

    @property
    def columns(self) -> list[str]:
        """The parameters' columns in the tables; a profile's profiled parameter first."""
        profiled = [self.profile.column] if self.profile is not None and self.method == "profile" else []
        return profiled + [self.column(path) for path in self.parameters]


def check_figures_apply(figures: list[str], estimation: Optional[EstimationConfig], file: str,
                        asked: frozenset = frozenset()) -> None:
    """ConfigError for a figure the config names (``outputs.figures``) that the folder it makes
    cannot draw: a filter run's figure in an estimation config, an estimation figure in a filter
    run's, a figure of a key the config does not ask for (``asked``: ``outputs.forecasts``,
    ``metrics.scores``; :func:`pfx.figures.registry.refusal_in_config`)."""
    from pfx.figures.registry import refusal_in_config

    for index, name in enumerate(figures):
        reason = refusal_in_config(name, estimation.method if estimation is not None else None, asked)
        if reason:
            raise ConfigError(f"{reason}; `pfx list figures` says what each figure draws", file=file,
                              key=f"outputs.figures[{index}]")


def check_column_names(estimation: EstimationConfig, labels: list[str], file: str, cell_text: str = "") -> None:
    """ConfigError if a parameter's column name is one of the cell's columns (``arm``, ``n_particles``,
    a swept key's column), which the tables put beside the parameters (:mod:`pfx.config.estimation_tables`)."""
    for path in estimation.parameters:
        name = estimation.column(path)
        if name in labels:
            raise ConfigError(f"{name!r} is one of the cell's label columns{cell_text}, which every estimation table "
                              "has and the parameter's own column would overwrite; give it another `name`", file=file,
                              key=f"estimation.{estimation.name_key(path)}")


def check_estimated_paths(estimation: EstimationConfig, model, file: str, cell_text: str = "") -> None:
    """ConfigError unless every estimated path names a number of ``model`` (a cell's filter model)."""
    for path in estimation.parameters:
        value = model
        for part in path.split(".")[1:]:
            value = getattr(value, part, None) if not isinstance(value, dict) else value.get(part)
            if value is None:
                break
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            found = "nothing" if value is None else with_article(type(value).__name__)
            raise ConfigError(f"{path} names {found} in model {model.kind}{cell_text}; an estimated parameter is "
                              "a number of the model (a scalar variance, a coefficient)", file=file,
                              key=f"estimation.parameters.{path}")


AUTO = "auto"


def auto_particle_keys(experiment) -> list[str]:
    """The keys that set ``particles: auto``: ``filter.particles`` and each arm's own
    ``arms.<name>.particles`` (an arm without the key takes the ``filter:`` section's)."""
    keys = ["filter.particles"] if experiment.filter.particles == AUTO else []
    return keys + [f"arms.{name}.particles" for name, arm in experiment.arms.items()
                   if "particles" in arm.model_fields_set and arm.particles == AUTO]


def check_auto_particles(experiment, file: str) -> None:
    """ConfigError where ``particles: auto`` cannot be honoured: it is PMMH's pilot (a particle
    count chosen so that the log-likelihood estimate's sd is near a target, docs/estimation.md),
    so a filter run, IF2 and a sweep list (whose values are the counts being compared) take a
    number; and ``estimation.particle_count`` without ``auto`` anywhere would do nothing."""
    estimation = experiment.estimation
    purpose = ("`auto` lets a PMMH run choose the particle count by a pilot (the sd of the log-likelihood estimate "
               "near estimation.particle_count.target_sd)")
    for index, value in enumerate(experiment.sweep.get("filter.particles", [])):
        if value == AUTO:
            raise ConfigError(f"{purpose}; a sweep compares the counts it lists, so give a number", file=file,
                              key=f"sweep.filter.particles[{index}]")
    keys = auto_particle_keys(experiment)
    if keys and (estimation is None or estimation.method != "pmmh"):
        run = "a filter run" if estimation is None else "IF2"
        raise ConfigError(f"{purpose}, with estimation: {{method: pmmh}}; {run} needs a number of particles, give "
                          "one", file=file, key=keys[0])
    if estimation is not None and estimation.particle_count is not None and not keys:
        raise ConfigError("sets how `particles: auto` chooses a PMMH cell's particle count, and neither filter."
                          "particles nor an arm's particles is auto here, so it would do nothing: drop it, or set "
                          "particles: auto", file=file, key="estimation.particle_count")
