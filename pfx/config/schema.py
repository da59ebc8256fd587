"""The config format, declared once.

Every section is a pydantic model whose fields carry types, defaults, bounds and
descriptions. From these declarations come validation (:func:`pfx.config.plan.build_plan`),
the JSON Schema printed by ``pfx schema``, and the config reference in docs/configuration.md
(``pfx schema --format markdown``). Model parameters are declared by the models themselves
(:mod:`pfx.models`), weightings by :mod:`pfx.filters.particle.weighting`, and so on.

The sections that name registered components (``model.kind``, ``filter.kind``, the resampler,
weighting, diffusion, figures, studies) are built from the registries' contents, and plugins
(docs/plugins.md) add to the registries after this module is imported. So those classes are
not built once, at import: :func:`config_schema` builds them for the built-in components plus
a config's plugins, and builds them again whenever a registry has changed since (a cache keyed
by :func:`pfx.registry.changes`). Every reader asks :func:`config_schema` for the classes when
it needs them. ``schema.Experiment`` (and the other class names) still work, as the classes
of the built-in components alone.
"""

from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Collection, Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, create_model, model_validator

from pfx.analysis.metrics import MetricsConfig
from pfx.config.data import DataConfig
from pfx.config.estimation import EstimationConfig
from pfx.config.forecasts import ForecastOutputs
from pfx.config.time_units import LONGEST_UNIT_NAME, UnitName
from pfx.figures import FIGURES
from pfx.filters import FILTERS
from pfx.filters.particle.adaptive import KLDSampling
from pfx.filters.particle.diffusion import DIFFUSIONS, NoDiffusion
from pfx.filters.particle.injection import AugmentedMCL
from pfx.filters.particle.moves import MOVES, NoMove
from pfx.filters.particle.proposals import PROPOSALS, BootstrapProposal
from pfx.filters.particle.resampling import RESAMPLERS
from pfx.filters.particle.weighting import WEIGHTINGS, GaussianWeighting
from pfx.filters.smoothers import SMOOTHERS
from pfx.laws.initial import InitialLaw
from pfx.models import MODELS
from pfx.registry import changes
from pfx.studies import STUDIES

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._+-]*$"


class ParticleSnapshots(BaseModel):
    """Particle clouds to keep (particles.csv), for figures of the particles themselves."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    steps: Union[Literal["all"], list[Annotated[StrictInt, Field(ge=0)]]] = Field(
        default_factory=list, description="steps whose particles are kept (0 = the prior), or `all`")
    trials: StrictInt = Field(1, ge=1, le=1000, description="how many trials per cell (the first ones)")
    stages: list[Literal["predicted", "weighted", "resampled"]] = Field(
        default_factory=lambda: ["weighted"], min_length=1,
        description="predicted (after the transition), weighted (after the weight update, before "
                    "resampling), resampled (after resampling and diffusion)")


class ExperimentHeader(BaseModel):
    """What every config starts with: its name, description and root seed."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = Field(pattern=NAME_PATTERN, max_length=100,
                      description="experiment name (the default result folder is runs/<name>)")
    description: str = Field("", description="free text, copied to the manifest")
    seed: StrictInt = Field(0, ge=0, lt=2**63, description="root seed of every random stream")
    plugins: list[Annotated[str, Field(min_length=1)]] = Field(
        default_factory=list,
        description="Python files (relative to this config's folder) or module names whose "
                    "components (models, ...) the config uses; pfx imports them, so naming a plugin "
                    "runs its code (docs/plugins.md)")


@dataclass(frozen=True)
class ConfigSchema:
    """The config's classes for one set of components (see the module docstring)."""

    SharedFilterSettings: type
    FilterConfig: type
    FigureOutputs: type
    OutputsConfig: type
    Experiment: type
    StudyExperiment: type


_CACHE: dict[frozenset, tuple[int, ConfigSchema]] = {}


def config_schema(plugins: Collection[str] = ()) -> ConfigSchema:
    """The config's classes for pfx's own components plus those of ``plugins`` (the names
    :mod:`pfx.config.plugins` gives loaded plugins); rebuilt when a registry has changed."""
    key = frozenset(plugins)
    version = changes()
    cached = _CACHE.get(key)
    if cached is None or cached[0] != version:
        cached = _CACHE[key] = (version, _build(key))
    return cached[1]


def __getattr__(name: str):
    """``schema.Experiment`` and the other classes of :class:`ConfigSchema`: the built-in ones."""
    if name in ConfigSchema.__dataclass_fields__:
        return getattr(config_schema(), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _build(plugins: frozenset) -> ConfigSchema:
    """Declare the sections that name registered components, from the registries' contents
    (the built-in components and those of ``plugins``)."""
    filters = FILTERS.visible(plugins)
    ResamplerName = Literal[tuple(RESAMPLERS.visible(plugins))]  # type: ignore[valid-type]
    FilterKind = Literal[tuple(filters)]  # type: ignore[valid-type]
    FigureName = Literal[tuple(FIGURES.visible(plugins))]  # type: ignore[valid-type]
    ModelConfig = Annotated[Union[tuple(MODELS.visible(plugins).values())], Field(discriminator="kind")]
    StudyConfig = Annotated[Union[tuple(STUDIES.visible(plugins).values())], Field(discriminator="kind")]
    Weighting = WEIGHTINGS.kind_union(plugins)
    Diffusion = DIFFUSIONS.kind_union(plugins)
    Move = MOVES.kind_union(plugins)
    Proposal = PROPOSALS.kind_union(plugins)
    Smoother = SMOOTHERS.kind_union(plugins)

    class SharedFilterSettings(BaseModel):
        """The filter run on every cell (arms override any of these keys)."""

        model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

        kind: FilterKind = Field(  # type: ignore[valid-type]
            "particle", description="filter kind (`pfx list filters`): particle (SIR with the ESS rule), "
                                    "sis (never resample), ...")
        particles: Union[Annotated[StrictInt, Field(ge=1, le=100_000_000)], Literal["auto"]] = Field(
            1000, description="number of particles N; `auto` (PMMH only): chosen by a pilot run, so that the "
                              "log-likelihood estimate's sd is near estimation.particle_count.target_sd")
        resampler: ResamplerName = Field(  # type: ignore[valid-type]
            "systematic", description="resampling scheme (`pfx list resamplers`)")
        ess_threshold: StrictFloat = Field(
            1.0, ge=0.0, le=1.0,
            description="resample when ESS < ess_threshold * N; 1 = every step, 0 = never")
        weighting: Weighting = Field(  # type: ignore[valid-type]
            default_factory=GaussianWeighting,
            description="weight update (`pfx list weightings`): a name or {kind: ..., ...}")
        diffusion: Diffusion = Field(  # type: ignore[valid-type]
            default_factory=NoDiffusion,
            description="post-resampling noise: none, {kind: gaussian, std}, {kind: roughening, factor}")
        move: Move = Field(  # type: ignore[valid-type]
            default_factory=NoMove,
            description="move after resampling, given the step's context (`pfx list moves`): none, "
                        "{kind: regularise, kernel, bandwidth, bandwidth_scale, jitter}, {kind: mcmc, steps, scale}")
        initial: Optional[InitialLaw] = Field(None, description="the filter's prior (default: the model's)")
        adaptive: Optional[KLDSampling] = Field(
            None, description="adaptive particle count: {kind: kld, epsilon, delta, bin_size, min_particles} "
                              "(KLD-sampling, Fox 2003; `particles` is the maximum); default none: N fixed")
        injection: Optional[AugmentedMCL] = Field(
            None, description="particle injection at resampling: {kind: augmented, alpha_slow, alpha_fast} "
                              "(augmented MCL: prior draws when the likelihood drops); default none")
        # guided proposals and the auxiliary particle filter (pfx/filters/particle/proposals.py, auxiliary.py)
        proposal: Proposal = Field(  # type: ignore[valid-type]
            default_factory=BootstrapProposal,
            description="how particles are drawn (`pfx list proposals`): bootstrap (the transition), "
                        "locally_optimal, ekf, {kind: ukf, alpha, beta, kappa}")
        auxiliary: StrictBool = Field(
            False, description="the auxiliary particle filter (Pitt & Shephard 1999): resample by the "
                               "look-ahead weights w p(z | f(x)) before proposing")
        backend: Literal["numpy", "jax"] = Field(
            "numpy", description="where the particle filter runs (docs/backends.md): numpy (NumPy and numba, the "
                                 "CPU default) or jax (compiled with JAX, on a CPU or a GPU; pip install 'pfx[jax]')")
        precision: Literal["float64", "float32"] = Field(
            "float64", description="the jax backend's floating point: float64 (default) or float32 (faster on a "
                                   "GPU; the resamplers' sums stay float64); the numpy backend is float64")
        count_draws: Literal["exact", "inverse_cdf"] = Field(
            "exact", description="how the filter draws binomial, Poisson and gamma variates (count models): exact "
                                 "(NumPy's or JAX's exact samplers, the default) or inverse_cdf (the branch-free "
                                 "quantile of one uniform: fast on both backends, accurate to about float32 "
                                 "rounding; docs/plugins.md)")
        smoothers: list[Smoother] = Field(  # type: ignore[valid-type]
            default_factory=list,
            description="smoothers run after the filter on the whole record (`pfx list smoothers`): "
                        "{kind: ffbs, trajectories}, {kind: ffbs_rejection, trajectories, rounds}, "
                        "{kind: fixed_lag, lag}, genealogy; rts after kf, ekf, ukf; default none")

        # which kinds read each setting: the shared settings a kind declares in ``reads``, and each
        # kind's own settings blocks (every other setting applies to every kind)
        KIND_SPECIFIC: ClassVar[dict[str, frozenset[str]]] = {
            key: frozenset(name for name, kind in filters.items() if key in kind.reads or key in kind.settings)
            for kind in filters.values() for key in (*kind.reads, *kind.settings)}

        # the plugins these classes were built for (see __reduce__)
        PLUGINS: ClassVar[tuple[str, ...]] = tuple(sorted(plugins))

        def __reduce__(self):
            # Pickled (to worker processes) as "the FilterConfig of these plugins" and its
            # state, not by class identity: each process builds its own classes (config_schema).
            return (_filter_settings, (self.PLUGINS, self.__getstate__()))

        @model_validator(mode="after")
        def _particle_stages(self):
            # adaptive counts and injection are stages of resampling: only kinds that read them
            for key in ("adaptive", "injection"):
                if getattr(self, key) is not None and self.kind not in self.KIND_SPECIFIC.get(key, ()):
                    raise ValueError(f"@{key}: the {self.kind} filter has no resampling stage to apply it to "
                                     f"(use kind particle)")
            # smoothers run only after the kinds that run them: never silently left out
            if self.smoothers and self.kind not in self.KIND_SPECIFIC.get("smoothers", ()):
                raise ValueError(f"@smoothers: no smoother runs after the {self.kind} filter (particle and sis "
                                 "run the particle smoothers, kf, ekf and ukf the rts smoother)")
            return self

        @property
        def uses_particles(self) -> bool:
            return FILTERS[self.kind].carries_particles

        @property
        def bootstrap_stages(self) -> bool:
            """Whether a particle filter of these settings reads of the model only its transition
            and its likelihood: the transition as proposal, the likelihood as weight, no auxiliary
            stage, move, adaptive count or injection (parameter estimation batches such a filter
            over per-row parameters)."""
            return (not self.proposal.guided and not self.auxiliary and self.weighting.is_likelihood
                    and self.move.kind == "none" and self.adaptive is None and self.injection is None)

        def applicable_dump(self, kinds) -> dict:
            """The settings as config data, without those that none of ``kinds`` reads and that
            hold their default (a setting given explicitly is always kept)."""
            defaults = type(self)().model_dump(mode="json")
            return {key: value for key, value in self.model_dump(mode="json").items()
                    if key not in self.KIND_SPECIFIC or self.KIND_SPECIFIC[key] & set(kinds)
                    or value != defaults[key]}

        def effective_threshold(self) -> float:
            """The ESS threshold the particle kind applies (``sis``: 0, it never resamples)."""
            return FILTERS[self.kind].ess_threshold(self) if self.uses_particles else self.ess_threshold

    # ``filter:`` is the shared settings, each filter kind's own settings blocks (declared by the
    # kind: ``grid`` for histogram, ``unscented`` for ukf), and the filter's model.
    FilterConfig = create_model(
        "FilterConfig", __base__=SharedFilterSettings, __doc__=SharedFilterSettings.__doc__,
        **{key: (block, Field(default_factory=block, description=description))
           for kind in filters.values() for key, (block, description) in kind.settings.items()},
        model=(dict[str, Any], Field(
            default_factory=dict,
            description="model parameters the filter assumes where they differ from the truth "
                        "(e.g. {process_noise: {variance: 0.5}}); same keys as `model`")))

    class FigureOutputs(BaseModel):
        """Which figures to render, in which formats."""

        model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
        figures: list[FigureName] = Field(  # type: ignore[valid-type]
            default_factory=list, description="figures to render (`pfx list figures`)")
        formats: list[Literal["png", "svg", "pdf"]] = Field(
            default_factory=lambda: ["png"], description="figure file formats (animations are always GIF)")

    class OutputsConfig(FigureOutputs):
        """Which traces, particle clouds and figures to write."""

        figures: list[FigureName] = Field(  # type: ignore[valid-type]
            default_factory=lambda: ["error_over_time", "ess_over_time"],
            description="figures to render (`pfx list figures`)")
        trace_trials: StrictInt = Field(3, ge=0, le=10_000, description="trials per cell whose per-step traces go to steps.csv")
        particles: ParticleSnapshots = Field(default_factory=ParticleSnapshots,
                                             description="particle clouds to keep in particles.csv")
        forecasts: ForecastOutputs = Field(
            default_factory=ForecastOutputs,
            description="forecasts from the filter's cloud, k steps ahead, to forecasts.csv: {horizons, origins, trials, "
                        "quantiles} (docs/forecasts.md); default none")
        genealogy: StrictInt = Field(
            0, ge=0, le=100, description="trials per cell (the first ones) whose genealogy goes to genealogy.csv: "
                                         "each particle's ancestor, weight and state at every step (particle "
                                         "filters; memory T N (d + 2) numbers per trial); default 0: none")

    class Experiment(ExperimentHeader):
        """One experiment: a model, a filter, its arms and sweep, trials and seed."""

        trials: StrictInt = Field(1, ge=1, le=10_000_000, description="independent trials per cell")
        datasets: Optional[StrictInt] = Field(
            None, ge=1, le=10_000_000,
            description="how many simulated datasets (true trajectories with their measurements) the "
                        "trials share: trial t filters dataset t mod datasets, so the trials of one "
                        "dataset are repeated runs of the filter on the same measurements (the spread "
                        "of an estimator, e.g. of the log-likelihood, for fixed data); default: one "
                        "dataset per trial")
        model: ModelConfig = Field(description="the true system (`pfx list models`)")  # type: ignore[valid-type]
        filter: FilterConfig = Field(default_factory=FilterConfig, description="filter defaults")  # type: ignore[valid-type]
        arms: dict[Annotated[str, Field(pattern=NAME_PATTERN)], FilterConfig] = Field(  # type: ignore[valid-type]
            default_factory=dict,
            description="named filter variants; each overrides the filter defaults it names")
        sweep: dict[str, Annotated[list[Any], Field(min_length=1)]] = Field(
            default_factory=dict,
            description="dotted key -> list of values; the Cartesian product forms the cells "
                        "(e.g. filter.particles: [200, 400])")
        metrics: MetricsConfig = Field(default_factory=MetricsConfig, description="metric parameters")
        outputs: OutputsConfig = Field(default_factory=OutputsConfig, description="tables and figures")
        data: Optional[DataConfig] = Field(
            None, description="recorded data to filter instead of simulating the model (docs/recorded-data.md); "
                              "default none: simulate")
        time_unit: Optional[UnitName] = Field(
            None, json_schema_extra={"minLength": 1, "maxLength": LONGEST_UNIT_NAME},
            description="the unit of the times (the model's dt, a data file's `time` column), for the figures' time "
                        "axes and the record (manifest units.time), e.g. `day`; a label, which changes no number "
                        "(`step` puts the step on the axes); default: the model's own (`s` for most models)")
        estimation: Optional[EstimationConfig] = Field(
            None, description="estimate model parameters from the data (PMMH or IF2, docs/estimation.md) instead "
                              "of running trials; default none")

        @model_validator(mode="after")
        def _precisions(self):
            # An arm inherits the filter: section's keys, so its precision is judged with the
            # backend it runs on (its own, else the section's), never on its own keys alone.
            shared = self.filter
            if precision_refusal(shared.backend, shared.precision):
                raise ValueError(f"@filter.precision: {precision_refusal(shared.backend, shared.precision)}")
            for name, arm in self.arms.items():
                own = arm.model_fields_set
                backend = arm.backend if "backend" in own else shared.backend
                if "precision" in own and precision_refusal(backend, arm.precision):
                    raise ValueError(f"@arms.{name}.precision: {precision_refusal(backend, arm.precision)}")
                if "precision" not in own and precision_refusal(backend, shared.precision):
                    raise ValueError(f"@arms.{name}.backend: {precision_refusal(backend, shared.precision)} (this "
                                     f"arm inherits precision: {shared.precision} from filter:; set precision: float64 "
                                     "in it)")
            return self

    class StudyExperiment(ExperimentHeader):
        """A study: a computation that writes tables (not a filter run; see `pfx list studies`)."""

        study: StudyConfig = Field(  # type: ignore[valid-type]
            description="the computation and its parameters (`pfx list studies`)")
        outputs: FigureOutputs = Field(default_factory=FigureOutputs, description="figures")

    return ConfigSchema(SharedFilterSettings, FilterConfig, FigureOutputs, OutputsConfig, Experiment,
                        StudyExperiment)


def precision_refusal(backend: str, precision: str) -> str:
    """Why ``precision`` cannot run on ``backend`` ('' when it can): the numpy backend computes in
    float64, float32 is the jax backend's. A config's filter: section, each arm (with the keys it
    inherits) and the Python door's settings are judged by it."""
    if backend == "numpy" and precision != "float64":
        return f"the numpy backend computes in float64; {precision} is for backend: jax"
    return ""


def _filter_settings(plugins: tuple[str, ...], state: dict):
    """Unpickle ``filter:`` settings (see ``SharedFilterSettings.__reduce__``)."""
    settings_class = config_schema(plugins).FilterConfig
    settings = settings_class.__new__(settings_class)
    settings.__setstate__(state)
    return settings


def config_json_schema(plugins: Collection[str] = ()) -> dict:
    """The JSON Schema of a config file: an experiment or a study (``pfx schema``), for pfx's
    own components plus those of ``plugins``.

    It describes what pfx accepts, shorthands included (``weighting: gaussian``, a route's
    ``turn 90``, ``alphas: [...]``); cross-field checks (a covariance that is not positive
    definite, a sweep key that names no setting) are pfx's own and only ``pfx validate`` makes them.
    """
    from pydantic import TypeAdapter

    classes = config_schema(plugins)
    schema = TypeAdapter(Union[classes.Experiment, classes.StudyExperiment]).json_schema()
    schema["title"] = "pfx config"
    schema["description"] = "A pfx experiment (model, filter, arms, sweep, ...) or a study (study: {kind: ...})."
    return schema
