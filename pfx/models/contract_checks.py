r"""The checks of a model against the contract (docs/plugins.md), made before anything runs.

The contract is :class:`pfx.models.base.Model`: the members a model must define, their array
shapes and dtypes, the index lists it declares, and that its randomness comes from the trial's
streams. A mistake in a plugin is refused here in one line that names the member, never met later
as ``'int' object is not iterable`` or a broadcasting error deep in the engine. Four checks, from
the cheapest:

* **The class** (at ``pfx.register_model``, :mod:`pfx.config.plugin_registration`):
  :func:`missing_methods` names the required members (:data:`REQUIRED_METHODS`) a class leaves to
  the contract, and :func:`methods_meant_as_properties` the members written as plain methods that
  the contract declares as properties (``def state_names(self)`` without ``@property``). Both are
  given the contract class, which imports this module (it cannot import it back).

* **Shapes** (:func:`check_contract`, :meth:`pfx.models.base.Model.check_contract`): the model's
  methods called once on a tiny batch (2 trials, 3 particles from the initial law), each result a
  floating-point NumPy array of the contract's shape, and names and sizes that agree with each
  other (``state_names``, ``state_units``, ``measurement_names``, the dimensions).

* **Declarations** (:func:`check_component_indices`): ``position_components``,
  ``angular_components`` and ``accumulating_components`` are tuples of state indices,
  ``measurement_angular_components`` a tuple of measurement indices, and the full turns positive
  numbers.

* **Reproducibility** (:func:`reproducibility_fault`): every random draw of a model comes from
  the trial's stream, the ``noise`` argument of ``propagate`` or the ``random`` argument of
  ``simulate_measurement`` and ``transition``. A model that draws from a global generator
  (``np.random.normal``, ``random.random``, a generator of its own) makes two runs of one config
  differ, silently. The probe calls each method twice on the same inputs (the same arrays, and a
  fresh trial stream with the same seeds each time) and compares the results bit for bit: a
  global generator has moved on between the two calls, so they differ. A method that ignores
  the stream it is given but is deterministic passes: its results are the same every run.

The plan (:func:`pfx.config.plan_checks.check_plugin_model`) runs the last three for a plugin's model.
The probes are cheap (2 trials x 3 particles, one step), and the reproducibility verdict is kept
per model class and settings, so that many cells of one model pay it once.
"""

from __future__ import annotations

import inspect
import math
from types import FunctionType
from typing import Callable, Optional

import numpy as np

from pfx.numerics.hashing import SettingsCache
from pfx.numerics.seeding import TrialStreams

# What every model must define itself: the rest of the interface has defaults.
REQUIRED_METHODS = ("state_names", "measurement_dimension", "propagate", "measurement_mean")
# The two noise parameters a model may take as arrays beside its own scalar fields
# (Model.vectorised_parameters, Model.with_parameter_arrays).
NOISE_VARIANCES = ("process_noise.variance", "measurement_noise.variance")
# The private streams of the reproducibility probe (any fixed numbers: the same each call).
PROBE_SEEDS = (20_240_341, 20_240_342)
# The state indices a model declares, checked by check_component_indices.
STATE_INDEX_PROPERTIES = ("position_components", "angular_components", "accumulating_components")

_verdicts = SettingsCache()                   # reproducibility_fault's answers


# -- the class --------------------------------------------------------------------------------------


def missing_methods(model_class: type, contract: type) -> list[str]:
    """The required members (:data:`REQUIRED_METHODS`) that ``model_class`` leaves to
    ``contract`` (:class:`pfx.models.base.Model`), which only declares them."""
    return [name for name in REQUIRED_METHODS if getattr(model_class, name) is getattr(contract, name)]


def methods_meant_as_properties(model_class: type, contract: type) -> list[tuple[str, Optional[int]]]:
    """(name, line of its ``def``) of each member that ``contract`` (:class:`pfx.models.base.Model`)
    declares as a property and ``model_class`` defines as a plain method: ``def state_names(self)``
    without ``@property``, which pfx would read as a bound method, not a tuple."""
    declared = {}                 # the contract's members and its mixins' (the time axis), nearest first
    for klass in contract.__mro__:
        if klass.__module__.startswith("pfx."):
            for name, member in vars(klass).items():
                declared.setdefault(name, member)
    slips = []
    for name, member in declared.items():
        if not isinstance(member, property):
            continue
        defined = inspect.getattr_static(model_class, name)
        if isinstance(defined, FunctionType):
            slips.append((name, defined.__code__.co_firstlineno))
    return slips


# -- shapes and names -------------------------------------------------------------------------------


def check_contract(model, random: TrialStreams) -> None:
    """Call the model's methods once on a tiny batch (2 trials, 3 particles drawn from the
    initial law; a transition of the model's own, ``sample_substep`` or ``sample_transition``,
    too) and raise ``ValueError("<method> returned ...")`` where a result has the
    wrong shape or is not a floating-point array, a name or size disagrees with another
    (:func:`_check_names`), a declared index list is not one (:func:`check_component_indices`),
    or ``vectorised_parameters`` names what is not a number of the model."""
    trials, particles = 2, 3
    _check_names(model)
    d, m = model.state_dimension, model.measurement_dimension
    check_component_indices(model)
    for path in type(model).vectorised_parameters:
        value = getattr(model, path, None) if path not in NOISE_VARIANCES else 0.0
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"vectorised_parameters names {path!r}, which is not a number of the model; "
                             f"expected its scalar fields or {' or '.join(NOISE_VARIANCES)}")
    cloud = np.asarray(model.initial.sample(random, (particles,)), dtype=float).reshape(trials, particles, d)
    truth = cloud[:, 0, :].copy()
    noise = np.zeros((trials, particles, model.process_noise_dimension))
    time = model.within_covariate_table(model.substep_time(1, 0))   # shapes only: the run's span is checked apart
    _check_result("propagate", model.propagate_at(cloud, model.control(1), noise, time), (trials, particles, d))
    _check_result("measurement_mean", model.measurement_mean(cloud), (trials, particles, m))
    measurement = _check_result("simulate_measurement", model.simulate_measurement(truth, random), (trials, m))
    _check_result("log_likelihood", model.log_likelihood(measurement[:, None, :], cloud), (trials, particles))
    drawn_by = model.transition_method()
    if drawn_by in ("sample_transition", "sample_substep"):     # a transition of its own: blamed by its name
        times = [model.within_covariate_table(model.substep_time(1, j)) for j in range(model.propagations_per_step)]
        _check_result(drawn_by, model.sample_transition(cloud.copy(), model.control(1), times, random),
                      (trials, particles, d))


def _check_names(model) -> None:
    """The model agrees with itself: names and sizes (``state_names``, ``state_units``,
    ``measurement_dimension``, ``measurement_names``, ``process_noise_dimension``)."""
    names = model.state_names
    if not (isinstance(names, (tuple, list)) and names and all(isinstance(n, str) and n for n in names)):
        raise ValueError(f"state_names returned {names!r}; expected a tuple of names, one per state "
                         "component, e.g. ('x', 'v')")
    if len(set(names)) != len(names):
        raise ValueError(f"state_names returned {tuple(names)!r}, which repeats a name; each state "
                         "component needs its own (they become column names)")
    for name in ("measurement_dimension", "process_noise_dimension"):
        size = getattr(model, name)
        if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 1:
            raise ValueError(f"{name} returned {size!r}; expected a whole number of at least 1")
    lists = (("measurement_names", model.measurement_dimension, "measurement_dimension"),
             ("state_units", len(names), "state_names"))
    for name, size, source in lists:
        value = getattr(model, name)
        if not (isinstance(value, (tuple, list)) and all(isinstance(item, str) for item in value)):
            raise ValueError(f"{name} returned {value!r}; expected a tuple of {size} strings")
        if len(value) != size:
            raise ValueError(f"{name} returned {len(value)} name(s) {tuple(value)!r}, and {source} says "
                             f"{size}: give one per component")
    measurement_names = tuple(model.measurement_names)
    if len(set(measurement_names)) != len(measurement_names) or "" in measurement_names:
        raise ValueError(f"measurement_names returned {measurement_names!r}; expected distinct, non-empty "
                         "names (they become the column names of a measurements file)")


def _check_result(method: str, value, shape: tuple) -> np.ndarray:
    """A method's result, if it is a floating-point array of ``shape``; else ValueError."""
    if not isinstance(value, np.ndarray):
        raise ValueError(f"{method} returned {type(value).__name__}, not a numpy array of shape {shape}")
    if value.shape != shape:
        raise ValueError(f"{method} returned shape {value.shape} for a batch of 2 trials x 3 particles; "
                         f"expected {shape}")
    if not np.issubdtype(value.dtype, np.floating):
        raise ValueError(f"{method} returned dtype {value.dtype}; expected floating point (float64)")
    return value


# -- declarations -----------------------------------------------------------------------------------


def check_component_indices(model) -> None:
    """Raise ``ValueError("<property> returned ...; expected ...")`` unless every index list
    the model declares is a tuple (or list) of indices in range: the state's for
    :data:`STATE_INDEX_PROPERTIES`, the measurement's for ``measurement_angular_components``;
    and unless ``position_components`` names at least one component and the full turns are
    positive numbers."""
    state_names, measurement_names = tuple(model.state_names), tuple(model.measurement_names)
    for name in STATE_INDEX_PROPERTIES:
        _check_indices(name, getattr(model, name), state_names, "state")
    if not tuple(model.position_components):
        raise ValueError("position_components returned no component; expected at least one index")
    _check_indices("measurement_angular_components", model.measurement_angular_components, measurement_names,
                   "measurement")
    for name in ("full_turn", "measurement_full_turn"):
        turn = getattr(model, name)
        if isinstance(turn, bool) or not isinstance(turn, (int, float)) or not (math.isfinite(turn) and turn > 0):
            raise ValueError(f"{name} returned {turn!r}; expected a positive number (2 * math.pi for radians, "
                             "360.0 for degrees)")


def _check_indices(name: str, value, names: tuple[str, ...], what: str) -> None:
    """ValueError unless ``value`` is a tuple or list of integers indexing ``names``."""
    expected = (f"expected indices of {what} components (integers 0..{len(names) - 1}, e.g. (0,) for "
                f"{names[0]})")
    if not isinstance(value, (tuple, list)):
        raise ValueError(f"{name} returned {value!r}, not a tuple; {expected}")
    if not all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) and 0 <= c < len(names)
               for c in value):
        raise ValueError(f"{name} returned {tuple(value)!r}; {expected}")


# -- reproducibility -------------------------------------------------------------------------------


def reproducibility_fault(model) -> Optional[str]:
    """Why the model is not reproducible: the first method (initial law, prior, ``propagate``,
    ``transition``, ``measurement_mean``, ``simulate_measurement``, ``log_likelihood``) whose two
    calls on the same inputs gave different results, in a sentence that starts with its name;
    None when every one gave the same, bit for bit. Kept per class and settings."""
    return _verdicts.answer(model, lambda: _probe_reproducibility(model))


def defined_by_user_code(model, *names: str) -> bool:
    """Whether the model's class takes any of the methods ``names`` from code outside pfx (a
    plugin's, a notebook's) rather than from pfx's own classes."""
    for name in names:
        owner = next((klass for klass in type(model).__mro__ if name in vars(klass)), None)
        if owner is not None and owner.__module__.split(".")[0] != "pfx":
            return True
    return False


def _user_law(law) -> bool:
    return type(law).__module__.split(".")[0] != "pfx"


def _probe_reproducibility(model) -> Optional[str]:
    """The probe of :func:`reproducibility_fault`: each method the user's code defines (or, for
    the laws, a law class of its own), called twice on the same inputs. pfx's own methods are
    deterministic given their inputs: the default ``transition`` is ``propagate`` with noise from
    the stream, the default ``log_likelihood`` a density of ``measurement_mean``."""
    particles = 3

    def fresh() -> TrialStreams:           # the same streams for both calls
        return TrialStreams.from_seeds(PROBE_SEEDS)

    d = model.state_dimension
    prior = model.default_prior()
    prior.bind(d)                          # a law default_prior() made afresh is not bound yet
    states = np.asarray(model.initial.sample(fresh(), (particles,)), dtype=float)
    noise = np.asarray(model.process_noise.sample(fresh(), (particles,)), dtype=float)
    control, time = model.control(1), model.within_covariate_table(model.substep_time(1, 0))
    # the transition at step 1's substep times, moved into the covariate table as propagate's time
    # is: before the data's times are known, the default axis starts at 0
    times = [model.within_covariate_table(model.substep_time(1, j)) for j in range(model.propagations_per_step)]
    measurement = np.asarray(model.simulate_measurement(states[:, 0].copy(), fresh()), dtype=float)

    draw_hint = "draw from the random argument it is given (the trial's streams)"
    checks: list[tuple[str, bool, Callable[[], np.ndarray], str]] = [
        ("initial", _user_law(model.initial), lambda: model.initial.sample(fresh(), (particles,)),
         "an initial law must draw from the trial's streams it is given"),
        ("default_prior", defined_by_user_code(model, "default_prior") or _user_law(prior),
         lambda: prior.sample(fresh(), (particles,)), "a prior must draw from the trial's streams it is given"),
        ("propagate", True, lambda: model.propagate_at(states.copy(), control, noise.copy(), time),
         "its randomness must come from its noise argument (drawn from the trial's stream)"),
        ("transition", defined_by_user_code(model, "transition", "sample_transition", "sample_substep"),
         lambda: model.sample_transition(states.copy(), control, times, fresh()),
         draw_hint),
        ("measurement_mean", True, lambda: model.measurement_mean(states.copy()), "h(x) must not be random"),
        ("simulate_measurement", defined_by_user_code(model, "simulate_measurement", "measure"),
         lambda: model.simulate_measurement(states[:, 0].copy(), fresh()), draw_hint),
        ("log_likelihood", defined_by_user_code(model, "log_likelihood"),
         lambda: model.log_likelihood(measurement[:, None, :].copy(), states.copy()), "log p(z | x) must not be random"),
    ]
    for name, probed, call, hint in checks:
        if not probed:
            continue
        first, second = np.asarray(call()), np.asarray(call())
        if first.shape != second.shape or not np.array_equal(first, second, equal_nan=True):
            return (f"{name} gave two different results for the same inputs (the same arrays and a fresh trial "
                    "stream with the same seeds): it draws from a global random generator (np.random, random, or "
                    f"a generator of its own), so two runs of one config would differ; {hint} "
                    "(docs/plugins.md, Random draws in a plugin)")
    return None
