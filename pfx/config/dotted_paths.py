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
    """Set ``config[a][b][c] = value`` for ``dotted = 'a.b.c'``, creating mappings on the way.

    A mapping whose keys hold dots themselves (``estimation.parameters``, keyed by model paths
    such as ``model.mu``) is entered at its longest key the path continues with, so
    ``estimation.parameters.model.mu.proposal_sd`` reaches the ``proposal_sd`` of ``model.mu``."""
    parts = split_path(dotted)
    node = config
    index = 0
    while True:
        key, index = _next_key(node, parts, index)
        if index == len(parts):
            node[key] = value
            return
        child = node.get(key)
        if child is None:
            child = node[key] = {}
        elif isinstance(child, str):
            # shorthand such as `weighting: gaussian` becomes a mapping when a field is set
            child = node[key] = {"kind": child}
        if not isinstance(child, dict):
            raise ConfigError(f"cannot set {dotted}: {'.'.join(parts[:index])} is not a mapping",
                              key=dotted)
        node = child


def _next_key(node: dict, parts: list[str], index: int) -> tuple[str, int]:
    """The key of ``node`` that ``parts[index:]`` begins with (the longest existing dotted key,
    else the next part) and the index of the part after it."""
    for end in range(len(parts), index + 1, -1):
        joined = ".".join(parts[index:end])
        if joined in node:
            return joined, end
    return parts[index], index + 1


def deep_merge(base: dict, override: dict) -> dict:
    """A copy of ``base`` with ``override`` merged in, mapping by mapping."""
    result = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(result.get(key), dict) and "kind" not in value:
            result[key] = deep_merge(result[key], value)
        else:
            result[key] = copy.deepcopy(value)
    return result
