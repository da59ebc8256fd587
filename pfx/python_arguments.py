"""The Python door's arguments, checked as a config's keys are.

A config is checked whole before anything runs, and a mistake is one line naming the file and
the key. The functions that run one filter from Python (:mod:`pfx.filtering`: ``pfx.model``,
``pfx.particle_filter``, ``pfx.filter``, ``pfx.load_plugin``) take arguments no config holds:
an array of measurements, seeds, a model or a prior as objects. Their checks live here, in one
place, under the same contract: a bad argument raises :class:`~pfx.errors.ConfigError` whose line
names ``<python>`` and the argument (``<python>: measurements[3]: ...``, ``<python>: seeds[1]:
...``) before anything runs; never an exception from inside numpy, never a silent result.
Whatever a config can also hold (a model's parameters, the filter's settings, an initial law)
is validated by the config's own declarations (:mod:`pfx.config.schema`).

The rules are the config path's:

* **measurements**: real numbers, (T, m) or (trials, T, m), at least one step; a row of NaN is
  a missing measurement (a predict-only step), and a row is either complete or all NaN, as in
  a ``data:`` file (:mod:`pfx.config.data_files`); no infinity, no complex values, no text;
* **trials**, **seed** and **seeds**: integers in the ranges of a config's ``trials`` (1 to
  10,000,000) and ``seed`` (0 to 2**63 - 1), one of ``seeds`` and ``seed``;
* a model is a model object, a prior an initial law (or a dict, read as a config's
  ``filter.initial``); each other kind of value is refused with what to pass instead;
* a model with an input for each step (``controls``, a path) filters at most the steps it
  has inputs for.
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from pfx.config.schema import precision_refusal
from pfx.config.validation import validate
from pfx.errors import ConfigError, split_location
from pfx.models.base import Model, bind_law

CALLER = "<python>"          # what a refusal names as its "file"
MAX_TRIALS = 10_000_000      # a config's `trials` (pfx/config/schema.py)
SEED_LIMIT = 2**63           # a config's `seed`, and every stream's seed, lies below it


def refuse(reason: str, key: str) -> ConfigError:
    """The error for the argument ``key``: ``<python>: key: reason``."""
    return ConfigError(reason, file=CALLER, key=key)


def plain_numbers(value: Any) -> Any:
    """``value`` with NumPy numbers and arrays as Python numbers and lists, so that a model's
    parameters or a filter's settings from a notebook's arrays read as a config's would
    (``particles=np.int64(500)``); mappings and lists are copied, anything else is kept."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {key: plain_numbers(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain_numbers(item) for item in value]
    return value


def _is_integer(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def flag(value: Any, key: str) -> bool:
    """A yes-or-no argument (``genealogy``, ``consistency``, ``traced``): True or False only, as a
    config's booleans (a text "yes" would otherwise count as true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise refuse(f"must be True or False, not {value!r}", key)
    return bool(value)


def validate_settings(schema, kind: Any, settings: dict):
    """The filter's settings (a config's ``filter:`` keys, ``kind`` among them), validated as a
    config's ``filter:`` section is (``schema``: :func:`pfx.config.schema.config_schema`'s)."""
    validated = validate(schema.FilterConfig, {"kind": kind, **plain_numbers(settings)}, file=CALLER, prefix="filter")
    refusal = precision_refusal(validated.backend, validated.precision)      # the rule a config is judged by
    if refusal:
        raise refuse(refusal, "filter.precision")
    if validated.particles == "auto":      # a config's PMMH pilot; from Python, pfx.choose_particles
        raise refuse("auto is a PMMH config's pilot; give a number (pfx.choose_particles chooses one from Python)",
                     "particles")
    return validated


# -- the model and its prior -----------------------------------------------------------------------

def model_kind(kind: Any) -> str:
    """``pfx.model``'s first argument: a model's name."""
    if isinstance(kind, str):
        return kind
    if isinstance(kind, Mapping):
        raise refuse("a dict: for a config's model: section, write pfx.model(**section); else "
                     "pfx.model(kind, **parameters), kind a name such as 'linear_gaussian'", "model.kind")
    raise refuse(f"must be a model's name, such as 'linear_gaussian' (`pfx list models`), not {_shown(kind)}",
                 "model.kind")


def model_argument(model: Any) -> Model:
    """The model a filter is bound to: a model object, never its description."""
    if isinstance(model, Model):
        return model
    build = "build it with pfx.model(kind, **parameters)"
    if isinstance(model, type) and issubclass(model, Model):
        kind = model.model_fields["kind"].default if "kind" in model.model_fields else None
        reason = (f"the class {model.__name__}, not a model: pass an instance, "
                  f"pfx.model({kind!r}, ...) or {model.__name__}(...)")
    elif isinstance(model, Mapping):
        reason = f"a dict, not a model: {build} (pfx.model(**section) for a config's model: section)"
    elif isinstance(model, str):
        reason = f"the text {model!r}, not a model: build it with pfx.model({model!r}, ...) and pass that"
    else:
        reason = f"{_shown(model)}, not a model: {build}, or pass an instance of a pfx.Model class"
    raise refuse(reason, "model")


def prior_argument(prior: Any, initial: Any, validate_initial) -> Any:
    """The filter's prior from ``prior=``: an initial law object (``pfx.GaussianLaw(...)``,
    ``pfx.UniformLaw(...)``, ``pfx.PointLaw(...)``, or any law with ``bind`` and ``sample``), or a
    dict read as a config's ``filter.initial`` (``{"kind": "gaussian", "mean": [...],
    "covariance": ...}``) by ``validate_initial(dict)``; None when none is given. ``initial``: the
    ``initial=`` setting, which says the same thing: not both."""
    if prior is None:
        return None
    if initial is not None:
        raise refuse("give the filter's initial law once: prior= or the setting initial=, not both", "prior")
    if isinstance(prior, Mapping):
        try:
            return validate_initial(plain_numbers(prior))
        except ConfigError as error:
            key = (error.key or "").replace("filter.initial", "prior", 1) or "prior"
            raise refuse(error.reason, key) from None
    if callable(getattr(prior, "sample", None)) and callable(getattr(prior, "bind", None)):
        return prior
    raise refuse(f"{_shown(prior)} is not an initial law: pass pfx.GaussianLaw(mean=..., covariance=...), "
                 "pfx.UniformLaw(low=..., high=...) or pfx.PointLaw(state=...), or the same as a dict "
                 "({'kind': 'gaussian', 'mean': [...], 'covariance': ...}), as a config's filter.initial", "prior")


def bind_prior(law: Any, model: Model, given: bool) -> Any:
    """``law`` bound to the model's state dimension; a mismatch names ``prior`` (given by the
    caller) or ``filter.initial`` (the setting, or the model's own)."""
    try:
        return bind_law(law, model.state_dimension, "prior" if given else "filter.initial")
    except ValueError as error:
        sub, reason = split_location(str(error))
        raise refuse(reason, sub or "prior") from None


# -- a plugin ---------------------------------------------------------------------------------------

def plugin_entry(path: Any) -> str:
    """``pfx.load_plugin``'s argument as a config's ``plugins:`` entry: a ``.py`` file's path
    (a ``Path``, or text ending in ``.py`` or holding a ``/``) or an importable module's name.
    Something at the path that is not a ``.py`` file (a folder, a data file) is refused here;
    a missing file, a module that cannot be found or a plugin that raises, by the loading."""
    if not isinstance(path, (str, os.PathLike)):
        raise refuse(f"must be a plugin file's path (.py) or a module's name, not {_shown(path)}", "path")
    entry = os.fspath(path)
    if not isinstance(entry, str) or not entry.strip():
        raise refuse(f"must be a plugin file's path (.py) or a module's name, not {_shown(path)}", "path")
    found = Path(entry)
    if not entry.endswith(".py") and (isinstance(path, os.PathLike) or found.exists()):
        if found.is_dir():
            raise refuse(f"{entry} is a folder: give the plugin's .py file", "path")
        if found.exists():
            raise refuse(f"{entry} is not a Python file: a plugin file's name ends in .py", "path")
        raise refuse(f"plugin file not found: {entry}", "path")
    return entry


# -- measurements ----------------------------------------------------------------------------------

def measurement_array(measurements: Any, dimension: int) -> np.ndarray:
    """``measurements`` as floats, (trials, T, m), checked: real numbers of the model's
    measurement dimension m, at least one step, finite, each row complete or all NaN."""
    values = _real_numbers(measurements)
    if values.ndim not in (2, 3) or values.shape[-1] != dimension:
        raise refuse(f"shape {values.shape}: expected (T, m) or (trials, T, m) with m = {dimension}, "
                     "the model's measurement dimension", "measurements")
    if values.shape[-2] == 0:
        raise refuse(f"no steps (shape {values.shape}): give at least one row", "measurements")
    if values.ndim == 3 and values.shape[0] == 0:
        raise refuse(f"no trials (shape {values.shape}): give at least one (T, m) block", "measurements")
    infinite = np.argwhere(np.isinf(values))
    if len(infinite):
        index = _index(infinite[0])
        raise refuse(f"{values[tuple(infinite[0])]}: a measurement must be finite (a row of NaN marks a "
                     "missing one)", f"measurements[{index}]")
    missing = np.isnan(values)
    partial = np.argwhere(missing.any(axis=-1) & ~missing.all(axis=-1))
    if len(partial):
        row = tuple(partial[0])
        blank = np.flatnonzero(missing[row])
        raise refuse(f"partly NaN (component {', '.join(map(str, blank))} of {dimension}): a row is either "
                     "complete or all NaN (a missing measurement), as in a data: file; partial rows are not "
                     "supported", f"measurements[{_index(row)}]")
    return values if values.ndim == 3 else values[None]


def _real_numbers(measurements: Any) -> np.ndarray:
    """The array of ``measurements``, as floats, if every entry is a real number."""
    if measurements is None:
        raise refuse("none given: expected an array (T, m) or (trials, T, m) of numbers", "measurements")
    if isinstance(measurements, (str, bytes)):
        raise refuse(f"text ({_shown(measurements)}): expected an array of numbers", "measurements")
    try:
        values = np.asarray(measurements)
    except ValueError:          # rows of different lengths
        raise refuse("rows of different lengths: expected an array (T, m) or (trials, T, m)",
                     "measurements") from None
    if values.dtype.kind in "fiu":
        return values.astype(float, copy=False)
    if values.dtype.kind in "US" and not isinstance(measurements, np.ndarray):
        values = np.asarray(measurements, dtype=object)     # lists with text: find the entry that is not a number
    if values.dtype.kind == "O":
        for position, value in enumerate(values.flat):
            problem = _not_real(value)
            if problem:
                raise refuse(problem, f"measurements[{_index(np.unravel_index(position, values.shape))}]")
        return values.astype(float)
    problem = {"b": "booleans", "c": "complex values (their imaginary parts would be dropped)",
               "U": "text", "S": "text"}.get(values.dtype.kind, f"values of type {values.dtype}")
    first = f" ({_shown(values.flat[0].item())})" if values.size else ""
    raise refuse(f"{problem}{first}: measurements are real numbers", "measurements")


def _not_real(value: Any) -> str:
    """Why one entry of an object array is not a measurement ('' if it is a real number)."""
    if isinstance(value, (bool, np.bool_)):
        return f"{value!r} is a boolean: measurements are real numbers"
    if isinstance(value, numbers.Real):
        return ""
    if isinstance(value, numbers.Complex):
        return f"{value!r} is complex: measurements are real numbers (the imaginary part would be dropped)"
    if value is None:
        return "None: measurements are real numbers (NaN, for the whole row, marks a missing one)"
    return f"{_shown(value)}: measurements are real numbers"


def _index(position) -> str:
    return ", ".join(str(int(i)) for i in position)


def check_horizon(model: Model, steps: int) -> None:
    """Refuse more steps of measurements than the model has inputs for.

    A model's ``steps`` is how many steps it was built for; a model whose inputs are given per
    step (a linear model's ``controls``, a robot's commands or path) has none beyond. Each later
    step's input is asked for before the run: a model without per-step inputs gives one (or
    None) for any step, and filters as many steps as it is given.
    """
    for step in range(model.steps + 1, steps + 1):
        try:
            model.control(step)
        except (LookupError, ValueError) as error:
            where, reason = split_location(str(error))       # a model that says which input: "@controls: ..."
            inputs = f"{where}: {reason}" if where else f"its control(step={step}) raised {type(error).__name__}"
            raise refuse(f"{steps} steps, and model {model.kind} has inputs for steps 1..{model.steps} only "
                         f"({inputs}): give at most {model.steps} rows, or build the model with steps={steps} "
                         "and an input for every step", "measurements") from None


# -- trials and seeds --------------------------------------------------------------------------------

def trial_count(trials: Any) -> Optional[int]:
    """``trials``: None (as many as the measurements or seeds say) or a count, as a config's."""
    if trials is None:
        return None
    if not _is_integer(trials) or not 1 <= trials <= MAX_TRIALS:
        raise refuse(f"must be a whole number from 1 to {MAX_TRIALS:,}, as a config's trials; not {_shown(trials)}",
                     "trials")
    return int(trials)


def seed_value(seed: Any, key: str) -> int:
    """One seed: an integer from 0 to 2**63 - 1, as a config's ``seed``."""
    if not _is_integer(seed) or not 0 <= seed < SEED_LIMIT:
        raise refuse(f"must be a whole number from 0 to 2**63 - 1, as a config's seed; not {_shown(seed)}", key)
    return int(seed)


def seed_list(seeds: Any) -> list[int]:
    """``seeds``: one filter seed per trial, a non-empty sequence of seeds."""
    if isinstance(seeds, (str, bytes, Mapping)) or not isinstance(seeds, (Sequence, np.ndarray, range)):
        raise refuse(f"must be a list of seeds, one per trial; not {_shown(seeds)}", "seeds")
    if isinstance(seeds, np.ndarray) and seeds.ndim != 1:
        raise refuse(f"must be a list of seeds, one per trial; not an array of shape {seeds.shape}", "seeds")
    if len(seeds) == 0:
        raise refuse("empty: give one seed per trial", "seeds")
    return [seed_value(seed, f"seeds[{index}]") for index, seed in enumerate(seeds)]


def trial_plan(data: np.ndarray, seeds: Any, seed: Any, trials: Any) -> tuple[np.ndarray, list[int] | None, int]:
    """The batch a call runs: its measurements (trials, T, m), a single block repeated for
    every trial; the seeds given (or None); the root seed the others are derived from."""
    count = trial_count(trials)
    if seeds is not None:
        if seed is not None:
            raise refuse("give seeds (one per trial) or seed (a root seed they are derived from), not both", "seed")
        seeds = seed_list(seeds)
        if count is not None and count != len(seeds):
            raise refuse(f"{count}, and seeds gives {len(seeds)}: give one of them", "trials")
        count = len(seeds)
    root = 0 if seed is None else seed_value(seed, "seed")
    if count is None:
        count = len(data)
    if len(data) == 1 and count > 1:
        data = np.repeat(data, count, axis=0)
    if len(data) != count:
        given = "seeds" if seeds is not None else "trials"
        raise refuse(f"{len(data)} trials of measurements (shape {data.shape}), and {given} says {count}: give "
                     f"{count} (T, m) blocks, or one (T, m) array for every trial", "measurements")
    return data, seeds, root


def _shown(value: Any) -> str:
    text = repr(value)
    text = text if len(text) <= 60 else text[:57] + "..."
    return f"{text} ({type(value).__name__})" if not isinstance(value, str) else text


def particle_count_settings(target_sd: Any, runs: Any, smallest: Any, largest: Any):
    """:func:`pfx.choose_particles`'s settings, checked as a config's ``estimation.particle_count``
    (:class:`pfx.config.estimation.ParticleCount`), each refusal naming its argument."""
    from pfx.config.estimation import ParticleCount

    values = plain_numbers({"target_sd": target_sd, "runs": runs, "smallest": smallest, "largest": largest})
    if _is_integer(values["target_sd"]):
        values["target_sd"] = float(values["target_sd"])      # 1 means 1.0, as in a config's YAML
    return validate(ParticleCount, values, file=CALLER)
