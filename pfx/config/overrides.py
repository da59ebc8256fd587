"""``--set key.path=value``: change one setting of a config from the command line.

An override always wins. A config can set the same key in three places (the ``filter:``
section, an arm, a sweep axis), and the most specific one decides a cell's value; an override
of ``filter.particles`` that only changed the ``filter:`` section would be silently lost
whenever an arm or the sweep also sets it. So ``--set filter.KEY=VALUE``:

* sets ``filter.KEY`` and, in every arm that sets ``KEY`` itself, the arm's value too (an arm
  that chose another component, e.g. ``weighting: gaussian`` against ``--set
  filter.weighting.form=...``, keeps its own);
* replaces a sweep axis at ``filter.KEY`` (or below it) by that one value.

``--set sweep.KEY=[v1, v2]`` adds a sweep axis, or replaces one (the rest of the path is the
axis name, dots and all); ``--set sweep.KEY=null`` removes one. An override below a swept value
(``--set filter.weighting.form=paper`` while the sweep lists whole weightings) is refused with
one line: it would apply to some cells and not others. Every arm or sweep axis an override
replaces is reported, so nothing is changed unseen.

A config that an override made invalid is the override's fault, not the file's: a typo in
``--set filter.particels=10`` is reported as ``exp.yaml: --set filter.particels=10: unknown key
filter.particels (did you mean filter.particles?)`` (:func:`blame_override`), the override in
place of the key path, never as a key of the config file, which holds no such key.
"""

from __future__ import annotations

import copy
import re
from typing import Any

from pfx.config.dotted_paths import set_path, split_path
from pfx.errors import ConfigError
from pfx.safe_yaml import parse_yaml

SWEEP = "sweep"


def apply_overrides(config: dict, assignments: list[str], file: str) -> tuple[dict, list[str]]:
    """Apply ``--set key.path=value`` assignments (values parsed as YAML); return the new config
    and one note per arm value or sweep axis an assignment replaced."""
    result = copy.deepcopy(config)
    notes: list[str] = []
    for assignment in assignments:
        if "=" not in assignment:
            raise ConfigError(f"--set {assignment!r}: expected key.path=value", file=file)
        dotted, _, raw_value = assignment.partition("=")
        dotted = dotted.strip()
        value = parse_yaml(raw_value, f"--set {dotted}") if raw_value.strip() else None
        try:
            if dotted.startswith(SWEEP + "."):
                _set_sweep_axis(result, dotted.removeprefix(SWEEP + "."), value)
            else:
                notes += _set_everywhere(result, dotted, value)
        except ConfigError as error:
            raise ConfigError(f"--set: {error.reason}", file=file, key=dotted) from None
    return result, notes


def _set_sweep_axis(config: dict, axis: str, value: Any) -> None:
    split_path(axis)                       # refuses empty parts
    sweep = config.get(SWEEP)
    if not isinstance(sweep, dict):
        sweep = config[SWEEP] = {}
    if value is None:
        if axis not in sweep:
            raise ConfigError(f"the sweep has no axis {axis!r} to remove")
        del sweep[axis]
    elif not isinstance(value, list) or not value:
        raise ConfigError("a sweep axis takes a list of values, e.g. [100, 200]")
    else:
        sweep[axis] = value


def _set_everywhere(config: dict, dotted: str, value: Any) -> list[str]:
    notes = []
    sweep = config.get(SWEEP) if isinstance(config.get(SWEEP), dict) else {}
    for axis in list(sweep):
        if dotted.startswith(axis + "."):
            raise ConfigError(f"the sweep sets {axis}; override the whole value (--set {axis}=...) "
                              f"or the sweep axis (--set {SWEEP}.{axis}=[...])")
    if dotted.startswith("arms."):
        _, arm, *rest = split_path(dotted)
        axis = ".".join(["filter", *rest])
        if rest and axis in sweep:
            raise ConfigError(f"the sweep sets {axis} for every arm, which would override this; "
                              f"remove the axis first (--set {SWEEP}.{axis}=null)")
    set_path(config, dotted, copy.deepcopy(value))
    for axis in list(sweep):
        if axis == dotted or axis.startswith(dotted + "."):
            notes.append(f"--set {dotted} replaces the sweep axis {axis} ({_values(sweep[axis])})")
            del sweep[axis]
    if dotted.startswith("filter."):
        key = dotted.removeprefix("filter.")
        arms = config.get("arms") if isinstance(config.get("arms"), dict) else {}
        touched = [name for name, arm in arms.items() if _sets(arm, split_path(key))]
        for name in touched:
            set_path(arms[name], key, copy.deepcopy(value))
        if touched:
            notes.append(f"--set {dotted} also replaces the value of arm{'s' if len(touched) > 1 else ''} "
                         f"{', '.join(touched)}")
    return notes


def _sets(arm: Any, parts: list[str]) -> bool:
    """Whether an arm's own settings hold a value at this path (through mappings only)."""
    node = arm
    for part in parts:
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def _values(values: Any) -> str:
    text = ", ".join(map(str, values)) if isinstance(values, list) else str(values)
    return f"[{text}]" if len(text) <= 60 else f"{len(values)} values"


# validation's words for an unknown key (pfx.config.validation), to restate with whole key paths
_UNKNOWN_KEY = re.compile(r"unknown key '([^']*)'(?: \(did you mean '([^']*)'\?\))?(.*)", re.S)


def blame_override(error: ConfigError, config: dict, assignments: list[str], file: str,
                   label: str = "--set") -> ConfigError:
    """``error`` (found validating ``file``'s config, ``config`` as read, after ``assignments``)
    told as the override's where an override put the value it is about: one at the error's key
    or above it (the value came from the command line), or below it when the key itself was
    made by the override (``--set filtr.particles=10`` creates ``filtr``). Any other error,
    and an error in another file (a data file, a plugin), is returned as it is. ``label`` is
    how the user wrote the overrides (``--set``; ``overrides`` for :func:`pfx.run`)."""
    if error.file != file or not error.key:
        return error
    for assignment in reversed(assignments):         # the last override of a key is the one that counts
        dotted, _, value = assignment.partition("=")
        dotted = dotted.strip()
        if _from_override(error.key, dotted, config):
            value = " ".join(value.split()).removesuffix(" ...")    # a YAML document's end marker (pfx.run)
            return ConfigError(_restated(error, dotted), file=file, key=f"{label} {dotted}={value}")
    return error


def _from_override(key: str, dotted: str, config: dict) -> bool:
    """Whether the value at ``key`` (an error's key path) came from ``--set dotted=...``."""
    arm = re.match(r"arms\.[^.\[]+\.(.*)", key)
    if arm and dotted.startswith("filter."):        # --set filter.KEY also sets the arms that set KEY
        key = f"filter.{arm.group(1)}"
    if key == dotted or key.startswith((dotted + ".", dotted + "[")):
        return True
    return dotted.startswith(key + ".") and not _holds(config, key.split("."))


def _holds(config: Any, parts: list[str]) -> bool:
    """Whether the config data has a value at this key path (through mappings)."""
    for part in parts:
        if not isinstance(config, dict) or part not in config:
            return False
        config = config[part]
    return True


def _restated(error: ConfigError, dotted: str) -> str:
    """The reason for a line that the override leads: with the error's key path where it is not
    the override's own, and an unknown key by its whole path ("unknown key filter.particels (did
    you mean filter.particles?)"), as the user typed it."""
    match = _UNKNOWN_KEY.fullmatch(error.reason)
    parent, _, last = error.key.rpartition(".")
    if match and last == match.group(1):
        name, hint, rest = match.groups()
        prefix = f"{parent}." if parent else ""
        suggestion = f" (did you mean {prefix}{hint}?)" if hint else ""
        return f"unknown key {prefix}{name}{suggestion}{rest}"
    return error.reason if error.key == dotted else f"{error.key}: {error.reason}"
