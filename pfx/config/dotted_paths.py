"""Dotted key paths into config data (``filter.weighting.form``): splitting, setting and
merging, as ``--set`` and the plan's arms and sweep use them.
"""

from __future__ import annotations

import copy
from typing import Any

from pfx.errors import ConfigError


def split_path(dotted: str) -> list[str]:
    parts = dotted.split(".")
    if not dotted or any(not part for part in parts):
        raise ConfigError(f"invalid key path {dotted!r}")
    return parts


def set_path(config: dict, dotted: str, value: Any) -> None:
    """Set ``config[a][b][c] = value`` for ``dotted = 'a.b.c'``, creating mappings on the way."""
    parts = split_path(dotted)
    node = config
    for index, part in enumerate(parts[:-1]):
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        elif isinstance(child, str) and index + 1 < len(parts):
            # shorthand such as `weighting: gaussian` becomes a mapping when a field is set
            child = node[part] = {"kind": child}
        if not isinstance(child, dict):
            raise ConfigError(f"cannot set {dotted}: {'.'.join(parts[:index + 1])} is not a mapping",
                              key=dotted)
        node = child
    node[parts[-1]] = value


def deep_merge(base: dict, override: dict) -> dict:
    """A copy of ``base`` with ``override`` merged in, mapping by mapping."""
    result = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(result.get(key), dict) and "kind" not in value:
            result[key] = deep_merge(result[key], value)
        else:
            result[key] = copy.deepcopy(value)
    return result
