r"""Plan-time checks of a model against the contract, beyond shapes: what it declares, and that it
is reproducible.

:meth:`pfx.models.base.Model.check_contract` calls a model's methods once on a tiny batch and
checks the shapes and dtypes of what they return. Two more promises of the contract
(docs/plugins.md) are checked here, before anything runs, for a plugin's model
(:func:`pfx.config.plan.check_plugin_model` calls them):

* **Declarations** (:func:`check_component_indices`): ``position_components``,
  ``angular_components`` and ``accumulating_components`` are tuples of state indices,
  ``measurement_angular_components`` a tuple of measurement indices, and the full turns positive
  numbers. A slip (an ``int`` for a tuple, a name for an index) is refused in one line naming
  the property, never met later as ``'int' object is not iterable`` deep in the engine.

* **Reproducibility** (:func:`reproducibility_fault`): every random draw of a model comes from
  the trial's stream, the ``noise`` argument of ``propagate`` or the ``random`` argument of
  ``simulate_measurement`` and ``transition``. A model that draws from a global generator
  (``np.random.normal``, ``random.random``, a generator of its own) makes two runs of one config
  differ, silently. The probe calls each method twice on the same inputs (the same arrays, and a
  fresh trial stream with the same seeds each time) and compares the results bit for bit: a
  global generator has moved on between the two calls, so they differ. A method that ignores
  the stream it is given but is deterministic passes: its results are the same every run.

The probe is cheap (2 trials x 3 particles, one step) and its verdict is kept per model class
and settings, so that many cells of one model pay it once.
"""

from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np

from pfx.numerics.hashing import SettingsCache
from pfx.numerics.seeding import TrialStreams

# The private streams of the reproducibility probe (any fixed numbers: the same each call).
PROBE_SEEDS = (20_240_341, 20_240_342)
# The state indices a model declares, checked by check_component_indices.
STATE_INDEX_PROPERTIES = ("position_components", "angular_components", "accumulating_components")

_verdicts = SettingsCache()                   # reproducibility_fault's answers


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
    control, time = model.control(1), model.substep_time(1, 0)
    if model._covariate_table is not None:    # a time the covariate table has (its span is checked elsewhere)
        time = float(np.clip(time, model._covariate_table[0][0], model._covariate_table[0][-1]))
    measurement = np.asarray(model.simulate_measurement(states[:, 0].copy(), fresh()), dtype=float)

    draw_hint = "draw from the random argument it is given (the trial's streams)"
    checks: list[tuple[str, bool, Callable[[], np.ndarray], str]] = [
        ("initial", _user_law(model.initial), lambda: model.initial.sample(fresh(), (particles,)),
         "an initial law must draw from the trial's streams it is given"),
        ("default_prior", defined_by_user_code(model, "default_prior") or _user_law(prior),
         lambda: prior.sample(fresh(), (particles,)), "a prior must draw from the trial's streams it is given"),
        ("propagate", True, lambda: model.propagate_at(states.copy(), control, noise.copy(), time),
         "its randomness must come from its noise argument (drawn from the trial's stream)"),
        ("transition", defined_by_user_code(model, "transition"), lambda: model.transition(states.copy(), 1, fresh()),
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
