r"""One filter from Python, on arrays: a model, measurements, the filter's settings, results.

The experiment runner (``pfx run``, :func:`pfx.run`) runs many cells and trials and writes
tables; a notebook, a test or an estimation loop often wants one filter on one array, bound
once and called many times. That is this module, on the very engine and settings a config
uses::

    import pfx

    model = pfx.model("linear_gaussian", steps=100, transition_matrix=[[0.9]], measurement_matrix=[[1.0]])
    filter = pfx.particle_filter(model, particles=500, resampler="systematic", ess_threshold=0.5)
    result = filter(measurements, seed=1)          # measurements: (T, m), or (trials, T, m)
    result.estimates, result.ess, result.log_likelihood

* :func:`model` builds a model as a config's ``model:`` section does (its presets filled in,
  its checks run), for a built-in kind or a registered plugin's; a model class can also be
  instantiated directly. :func:`load_plugin` loads a plugin's components for it, as a config's
  ``plugins:`` entry would.
* :func:`particle_filter` binds the filter once: the settings are a config's ``filter:`` keys,
  with the same names, defaults and checks (``proposal="ekf"``, ``move={"kind": "mcmc"}``,
  ``kind="ukf"`` for any other filter kind); ``prior`` is the filter's initial law (default: the
  model's). A refusal is the :class:`~pfx.errors.ConfigError` a config would get.
* Calling it runs a batch of trials. ``seeds`` gives each trial's filter seed (the
  ``filter_seed`` column of trials.csv: the same seeds give the same numbers as the config
  path, to the last bit); ``seed`` derives one per trial from a root seed. It returns a
  :class:`FilterResult`: arrays with the trial axis first, always.
* :func:`filter` binds and calls in one go.
* :func:`simulate` draws a model's truth and measurements as a config's run draws them (trial t
  of ``seed: S`` is trial t of ``simulate(model, trials=..., seed=S)``), so that a notebook
  filters pfx's own simulated data and gets the config's numbers.
* :func:`choose_particles` chooses N for PMMH as a config's ``particles: auto`` does: the sd of
  the log-likelihood estimate near a target, at the model's own parameters.

Every argument is checked before anything runs, as a config's keys are, and a bad one raises
:class:`~pfx.errors.ConfigError` naming it (``<python>: measurements[3]: ...``): the checks of
what no config holds (measurements, trials, seeds, a model or prior object) are
:mod:`pfx.python_arguments`.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np
import pandas as pd

from pfx import python_arguments as arguments
from pfx.config.plan_checks import check_plugin_model
from pfx.config.plugin_faults import locate
from pfx.config.plugins import LoadedPlugin, loaded_plugins, python_origins
from pfx.config.plugins import load_plugin as load_plugin_entry
from pfx.config.schema import config_schema
from pfx.config.scores import compiled_draws_refusal, default_draws_refusal
from pfx.config.validation import validate
from pfx.errors import ConfigError, ModelNumericalError, located_value_error
from pfx.estimation.likelihood_spread import Spread
from pfx.estimation.particle_count import choose_particle_count
from pfx.filters import FILTERS
from pfx.filters.trace import FilterTrace, Predictive
from pfx.models import MODELS
from pfx.models.base import Model
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, filter_seed, spread_seed, truth_seed
from pfx.python_arguments import CALLER


@dataclass
class FilterResult:
    """A filter's run on a batch of trials: arrays with the trial axis first.

    ``estimates`` (trials, T, d) the posterior mean at each step (before resampling); ``ess``
    (trials, T) the effective sample size (NaN for Kalman kinds); ``log_likelihood`` (trials,) the
    estimate of log p(z_1:T); ``ancestors`` (trials, T, N) the genealogy when asked for, else
    None; ``smoothed``: each smoother's result by kind (``settings`` ``smoothers=[...]``), with
    ``means`` and ``standard_deviations`` (trials, T, d); ``seeds`` the filter seed of each trial;
    ``trace`` everything the filter recorded (:class:`~pfx.filters.trace.FilterTrace`).
    """

    estimates: np.ndarray
    ess: np.ndarray
    log_likelihood: np.ndarray
    ancestors: Optional[np.ndarray]
    seeds: list[int]
    trace: FilterTrace
    smoothed: dict
    predictive: Optional[Predictive] = None


def model(kind: str, **parameters: Any) -> Model:
    """The model ``kind`` with ``parameters``, validated as a config's ``model:`` section (NumPy
    numbers and arrays read as plain numbers and lists)."""
    kind = arguments.model_kind(kind)
    if kind not in MODELS:
        raise ConfigError(MODELS.unknown_message(kind), file=CALLER, key="model.kind")
    return validate(MODELS[kind], {"kind": kind, **arguments.plain_numbers(parameters)}, file=CALLER,
                    prefix="model")


def load_plugin(path: Union[str, "os.PathLike[str]"]) -> LoadedPlugin:
    """Load a plugin from Python, as a config's ``plugins:`` entry is loaded: a ``.py`` file
    (relative to the working directory) or an importable module's name. Its components are then
    known to :func:`model` and :func:`particle_filter`, and a config naming the same file later
    runs the same loaded code. Returns what was loaded (``.registered``: ``("model cv_radar",)``)."""
    return load_plugin_entry(arguments.plugin_entry(path), Path("."), config_file=CALLER, key="path")


class Filter:
    """A filter bound once to a model and its settings (:func:`particle_filter`); call it on
    measurements to run it."""

    def __init__(self, model: Model, kind: str, settings, prior, planned):
        self.model, self.kind, self.settings, self.prior, self.planned = model, kind, settings, prior, planned

    def __call__(self, measurements, *, seeds: Optional[Sequence[int]] = None, seed: Optional[int] = None,
                 trials: Optional[int] = None, genealogy: bool = False, consistency: bool = False,
                 traced: bool = False, scores: bool = False) -> FilterResult:
        """Run on ``measurements``, (T, m) for one trial (or ``trials`` of them on the same data)
        or (trials, T, m); a row of NaN is a missing measurement. ``seeds``: one filter seed per
        trial; else trial t's is derived from ``seed`` (default 0). ``genealogy``: record the
        ancestor indices (particle kinds). ``consistency``: the posterior covariances and NIS (on
        either backend). ``traced``:
        the spread and posterior standard deviations of every trial (steps.csv's traced-trial
        columns). ``scores``: the one-step-ahead predictive law of the measurement and its proper
        scores (``metrics.scores``: docs/scores.md), in the result's ``predictive``.
        Every argument is checked first (:mod:`pfx.python_arguments`)."""
        data = arguments.measurement_array(measurements, self.model.measurement_dimension)
        data, seeds, root = arguments.trial_plan(data, seeds, seed, trials)
        genealogy = arguments.flag(genealogy, "genealogy")
        consistency = arguments.flag(consistency, "consistency")
        traced = arguments.flag(traced, "traced")
        scores = arguments.flag(scores, "scores")
        arguments.check_horizon(self.model, data.shape[1])
        count = len(data)
        seeds = seeds if seeds is not None else [filter_seed(root, 0, t) for t in range(count)]
        options = {"consistency": consistency}
        if traced and self.planned.takes_trace_rows:
            options["trace_rows"] = np.arange(count)
        if genealogy:
            if not FILTERS[self.kind].carries_particles:
                raise ConfigError(f"the {self.kind} filter has no particles, so no genealogy", file=CALLER,
                                  key="genealogy")
            options["genealogy"] = True
        if scores:
            if not self.planned.computes_scores:
                raise ConfigError(f"the {self.kind} filter does not compute the predictive scores (the particle "
                                  "filters and kf, ekf, ukf do)", file=CALLER, key="scores")
            self._check_measurement_draws()
            options["scores"] = True
        trace = self.planned.run(self.model, data, TrialStreams.from_seeds(seeds), settings=self.settings,
                                 prior=self.prior, **options)
        return FilterResult(estimates=trace.estimates, ess=trace.ess, log_likelihood=trace.log_likelihood,
                            ancestors=trace.ancestors, seeds=seeds, trace=trace, smoothed=trace.smoothed,
                            predictive=trace.predictive)


    def _check_measurement_draws(self) -> None:
        """The scores of a particle filter come from the model's measurement draws: refused, as a
        config's ``metrics.scores`` is (:mod:`pfx.config.scores`), where they are not the law the
        filter weighs by, or cannot run in the jax backend's compiled filter."""
        if not FILTERS[self.kind].carries_particles:
            return
        reason = default_draws_refusal(self.model, "the scores' CRPS and PIT")
        if reason is None and self.settings.backend == "jax":
            reason = compiled_draws_refusal(self.model, self.settings.precision)
            reason = reason and f"{reason}, or set backend='numpy'"
        if reason is not None:
            raise ConfigError(reason, file=CALLER, key="scores")


def particle_filter(model: Model, *, kind: str = "particle", prior=None, **settings: Any) -> Filter:
    """Bind a filter to ``model`` once: ``settings`` are a config's ``filter:`` keys (module
    docstring); ``prior`` the filter's initial law, an initial law object or a dict read as a
    config's ``filter.initial`` (default: the ``initial`` setting, else the model's
    ``default_prior()``). A plugin's model is checked as a config's is (its contract, no global
    random generator)."""
    model = arguments.model_argument(model)
    check_plugin_model(model, loaded_plugins())
    schema = config_schema(python_origins())          # the loaded plugins' components too
    filter_settings = arguments.validate_settings(schema, kind, settings)
    if filter_settings.backend == "jax" and not filter_settings.uses_particles:
        raise ConfigError(f"the jax backend runs the particle filters (kind particle or sis); the {kind} filter runs "
                          "on numpy: drop backend (backend: numpy)", file=CALLER, key="filter.backend")
    given = arguments.prior_argument(
        prior, settings.get("initial"),
        lambda initial: arguments.validate_settings(schema, kind, {"initial": initial}).initial)
    chosen = given if given is not None else filter_settings.initial or model.default_prior()
    arguments.bind_prior(chosen, model, given is not None)
    try:
        planned = FILTERS[filter_settings.kind].plan(model, filter_settings, chosen)
    except Exception as error:
        fault = locate(error)           # raised in a plugin's code, while the kind probed its model
        if fault is not None:
            raise fault.as_config_error() from error
        if isinstance(error, ValueError):
            raise located_value_error(error, prefix="filter", file=CALLER) from None
        raise
    return Filter(model, filter_settings.kind, filter_settings, chosen, planned)


def filter(model: Model, measurements, *, seeds: Optional[Sequence[int]] = None, seed: Optional[int] = None,
           trials: Optional[int] = None, genealogy: bool = False, consistency: bool = False,
           traced: bool = False, scores: bool = False, kind: str = "particle", prior=None,
           **settings: Any) -> FilterResult:
    """:func:`particle_filter` and its call in one go."""
    return particle_filter(model, kind=kind, prior=prior, **settings)(
        measurements, seeds=seeds, seed=seed, trials=trials, genealogy=genealogy, consistency=consistency,
        traced=traced, scores=scores)


@dataclass
class Simulation:
    """:func:`simulate`'s answer, trial axis first: ``states`` x_0..x_T (trials, T + 1, d),
    ``measurements`` z_1..z_T (trials, T, m), and ``seeds``, each trial's truth seed (trials.csv's
    ``truth_seed``)."""

    states: np.ndarray
    measurements: np.ndarray
    seeds: list[int]


def simulate(model: Model, *, trials: Optional[int] = None, seed: Optional[int] = None,
             seeds: Optional[Sequence[int]] = None, datasets: Optional[int] = None) -> Simulation:
    """The model's true states and measurements, drawn as a config's run draws them: trial t of a
    config with ``seed: S`` (and ``datasets``) has the truth ``simulate(model, trials=..., seed=S)``
    gives as its trial t (the seeds ``truth_seed(S, t, datasets)``), so a notebook can filter pfx's
    own simulated data and get the config's numbers. ``seeds`` gives each trial's truth seed
    instead. Default: one trial of seed 0."""
    model = arguments.model_argument(model)
    check_plugin_model(model, loaded_plugins())
    count = arguments.trial_count(trials)
    if seeds is not None:
        if seed is not None or datasets is not None:
            raise ConfigError("give seeds (one truth seed per trial) or seed and datasets, not both", file=CALLER,
                              key="seeds")
        truth_seeds = arguments.seed_list(seeds)
        if count is not None and count != len(truth_seeds):
            raise ConfigError(f"{count}, and seeds gives {len(truth_seeds)}: give one of them", file=CALLER,
                              key="trials")
    else:
        root = 0 if seed is None else arguments.seed_value(seed, "seed")
        if datasets is not None:
            datasets = arguments.trial_count(datasets)
        truth_seeds = [truth_seed(root, trial, datasets) for trial in range(count or 1)]
    states, measurements = simulate_truth(model, TrialStreams.from_seeds(truth_seeds))
    return Simulation(states=states, measurements=measurements, seeds=truth_seeds)


@dataclass
class ParticleCountResult:
    """:func:`choose_particles`'s answer: ``particles``, the N chosen; ``table``, every particle
    count measured (particle_count.csv's columns without the cell's: particles, runs, finite, mean,
    sd, sd_standard_error, run_time_s, chosen)."""

    particles: int
    table: pd.DataFrame


def choose_particles(model: Model, measurements, *, target_sd: float = 1.2, runs: int = 40, smallest: int = 16,
                     largest: int = 100_000, seed: int = 0, kind: str = "particle", prior=None,
                     **settings: Any) -> ParticleCountResult:
    """The particle count PMMH would use on ``measurements`` (one dataset, (T, m)) at the model's
    own parameters: the rule of a config's ``particles: auto``
    (:func:`pfx.estimation.particle_count.choose_particle_count`), each particle count N measured by
    ``runs`` runs of the filter (``kind``, ``prior``, ``settings`` as :func:`particle_filter` takes
    them) with seeds ``spread_seed(seed, 0, N, run)``. Every argument is checked first; a cap whose
    sd is still above the target is refused in one line naming ``largest``."""
    if "particles" in settings:
        raise arguments.refuse("choose_particles chooses the particle count; drop particles", "particles")
    pilot = arguments.particle_count_settings(target_sd, runs, smallest, largest)
    root = arguments.seed_value(seed, "seed")
    first = particle_filter(model, kind=kind, prior=prior, particles=pilot.smallest, **settings)
    if not FILTERS[first.kind].carries_particles:
        raise arguments.refuse(f"the {first.kind} filter has no particles to choose a count of", "kind")
    data = arguments.measurement_array(measurements, first.model.measurement_dimension)
    if len(data) != 1:
        raise arguments.refuse(f"shape {data.shape}: give one dataset, (T, m)", "measurements")
    arguments.check_horizon(first.model, data.shape[1])
    repeated = np.repeat(data, pilot.runs, axis=0)

    def spread_at(particles: int) -> Spread:
        started = time.perf_counter()
        bound = particle_filter(first.model, kind=kind, prior=prior, particles=particles, **settings)
        seeds = [spread_seed(root, 0, particles, run) for run in range(pilot.runs)]
        try:
            estimates = bound(repeated, seeds=seeds).log_likelihood
        except ModelNumericalError:     # some run lost its particles to NaN: find which, run by run (the same numbers)
            estimates = np.array([_log_likelihood_or_zero(bound, data, seed) for seed in seeds])
        return Spread.of(particles, estimates, time.perf_counter() - started)

    choice = choose_particle_count(spread_at, pilot, key="largest", point_text="the model's parameters", file=CALLER,
                                   largest_name="largest", nearer="a model at parameters nearer it")
    return ParticleCountResult(choice.particles, choice.table())


def _log_likelihood_or_zero(bound: Filter, data: np.ndarray, seed: int) -> float:
    """One run's log-likelihood estimate; -inf where every particle became NaN (as a parameter
    estimation's target counts it: :meth:`pfx.estimation.target.EstimationTarget.log_likelihoods`)."""
    try:
        return float(bound(data, seeds=[seed]).log_likelihood[0])
    except ModelNumericalError:
        return -np.inf
