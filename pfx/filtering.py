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
  instantiated directly.
* :func:`particle_filter` binds the filter once: the settings are a config's ``filter:`` keys,
  with the same names, defaults and checks (``proposal="ekf"``, ``move={"kind": "mcmc"}``,
  ``kind="ukf"`` for any other filter kind); ``prior`` is the filter's initial law (default: the
  model's). A refusal is the :class:`~pfx.errors.ConfigError` a config would get.
* Calling it runs a batch of trials. ``seeds`` gives each trial's filter seed (the
  ``filter_seed`` column of trials.csv: the same seeds give the same numbers as the config
  path, to the last bit); ``seed`` derives one per trial from a root seed. It returns a
  :class:`FilterResult`: arrays with the trial axis first, always.
* :func:`filter` binds and calls in one go.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from pfx.config.plan import check_plugin_model
from pfx.config.plugin_faults import locate
from pfx.config.plugins import loaded_plugins
from pfx.config.schema import config_schema
from pfx.config.validation import validate
from pfx.errors import ConfigError, located_value_error
from pfx.filters import FILTERS
from pfx.filters.trace import FilterTrace
from pfx.models import MODELS
from pfx.models.base import Model, bind_law
from pfx.numerics.seeding import TrialStreams, filter_seed

CALLER = "<python>"          # what a refusal names as its "file"


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


def model(kind: str, **parameters: Any) -> Model:
    """The model ``kind`` with ``parameters``, validated as a config's ``model:`` section."""
    if kind not in MODELS:
        raise ConfigError(MODELS.unknown_message(kind), file=CALLER, key="model.kind")
    return validate(MODELS[kind], {"kind": kind, **parameters}, file=CALLER, prefix="model")


class Filter:
    """A filter bound once to a model and its settings (:func:`particle_filter`); call it on
    measurements to run it."""

    def __init__(self, model: Model, kind: str, settings, prior, planned):
        self.model, self.kind, self.settings, self.prior, self.planned = model, kind, settings, prior, planned

    def __call__(self, measurements, *, seeds: Optional[Sequence[int]] = None, seed: int = 0,
                 trials: Optional[int] = None, genealogy: bool = False, consistency: bool = False,
                 traced: bool = False) -> FilterResult:
        """Run on ``measurements``, (T, m) for one trial (or ``trials`` of them on the same data)
        or (trials, T, m); NaN rows are missing measurements. ``seeds``: one filter seed per
        trial; else trial t's is derived from ``seed``. ``genealogy``: record the ancestor indices
        (particle kinds). ``consistency``: the posterior covariances and NIS. ``traced``: the spread
        and posterior standard deviations of every trial (steps.csv's traced-trial columns)."""
        data = np.asarray(measurements, dtype=float)
        if data.ndim == 2:
            data = data[None]
        if data.ndim != 3 or data.shape[-1] != self.model.measurement_dimension:
            raise ConfigError(f"measurements of shape {np.shape(measurements)}: expected (T, m) or (trials, T, m) "
                              f"with m = {self.model.measurement_dimension}", file=CALLER, key="measurements")
        count = len(seeds) if seeds is not None else trials or len(data)
        if len(data) == 1 and count > 1:
            data = np.repeat(data, count, axis=0)
        if len(data) != count:
            raise ConfigError(f"{len(data)} rows of measurements for {count} trials", file=CALLER, key="measurements")
        seeds = [int(s) for s in seeds] if seeds is not None else [filter_seed(seed, 0, t) for t in range(count)]
        options = {"consistency": consistency}
        if traced and self.planned.takes_trace_rows:
            options["trace_rows"] = np.arange(count)
        if genealogy:
            if not FILTERS[self.kind].carries_particles:
                raise ConfigError(f"the {self.kind} filter has no particles, so no genealogy", file=CALLER,
                                  key="genealogy")
            options["genealogy"] = True
        trace = self.planned.run(self.model, data, TrialStreams.from_seeds(seeds), settings=self.settings,
                                 prior=self.prior, **options)
        return FilterResult(estimates=trace.estimates, ess=trace.ess, log_likelihood=trace.log_likelihood,
                            ancestors=trace.ancestors, seeds=seeds, trace=trace, smoothed=trace.smoothed)


def particle_filter(model: Model, *, kind: str = "particle", prior=None, **settings: Any) -> Filter:
    """Bind a filter to ``model`` once: ``settings`` are a config's ``filter:`` keys (module
    docstring); ``prior`` the filter's initial law (default: the model's ``default_prior()``)."""
    if isinstance(model, Model):        # a plugin's model: checked as a config's is
        check_plugin_model(model, loaded_plugins())
    schema = config_schema([plugin.origin for plugin in loaded_plugins()])     # plugins' components too
    filter_settings = validate(schema.FilterConfig, {"kind": kind, **settings}, file=CALLER, prefix="filter")
    chosen = prior if prior is not None else filter_settings.initial or model.default_prior()
    try:
        bind_law(chosen, model.state_dimension, "initial")
        planned = FILTERS[kind].plan(model, filter_settings, chosen)
    except Exception as error:
        fault = locate(error)           # raised in a plugin's code, while the kind probed its model
        if fault is not None:
            raise fault.as_config_error() from error
        if isinstance(error, ValueError):
            raise located_value_error(error, prefix="filter", file=CALLER) from None
        raise
    return Filter(model, kind, filter_settings, chosen, planned)


def filter(model: Model, measurements, *, seeds: Optional[Sequence[int]] = None, seed: int = 0,
           trials: Optional[int] = None, genealogy: bool = False, consistency: bool = False,
           traced: bool = False, kind: str = "particle", prior=None, **settings: Any) -> FilterResult:
    """:func:`particle_filter` and its call in one go."""
    return particle_filter(model, kind=kind, prior=prior, **settings)(
        measurements, seeds=seeds, seed=seed, trials=trials, genealogy=genealogy, consistency=consistency,
        traced=traced)
