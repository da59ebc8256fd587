"""What a plan's hashes are computed over: the settings that define a cell (its key, hence its
random streams) and the whole resolved config (the record of what was asked), each in the form
that names what a run depends on and nothing else: plugins by their code, data files by their
bytes, settings at their declared default left out. :class:`pfx.config.plan.Plan` hashes these.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from pfx.config.plugin_record import recorded_names
from pfx.config.plugins import LoadedPlugin


def with_plugin_code(record: dict, plugins: list[LoadedPlugin]) -> dict:
    """``record`` with the sha256 of each plugin's code, for hashing: changed plugin code changes
    the hashes, so a result folder is not resumed or kept with it. A plugin counts by its code
    and its recorded name (:func:`~pfx.config.plugin_record.recorded_names`), not by the path a config
    reaches it by: the result folder's ``config.yaml``, which names the folder's copy of the
    plugin, has the hashes of the config it was made from. Without plugins, ``record`` itself:
    the hashes of configs without plugins are what they always were."""
    if not plugins:
        return record
    record = {key: value for key, value in record.items() if key != "plugins"}
    return {**record, "plugin_code": dict(zip(recorded_names(plugins), (plugin.sha256 for plugin in plugins)))}


def with_data_content(record: dict) -> dict:
    """``record`` with each data file (``data:``) named by the sha256 of its bytes, for hashing,
    as :func:`with_plugin_code` names a plugin by its code: the same data reached by another path
    (a clone of the repository in another folder; the result folder's ``config.yaml``, which names
    it relative to the folder) is the same record. Without data, ``record`` itself."""
    files = record.get("data")
    if not files:
        return record
    def content(path):
        return None if path is None else "sha256:" + hashlib.sha256(Path(path).read_bytes()).hexdigest()

    return {**record, "data": {key: content(path) for key, path in files.items()}}


def identity_dump(value: Any) -> Any:
    """The settings that define a cell, for its key: fields at their declared default are left
    out (but every ``kind`` is kept), so an option added to pfx later with a default changes
    neither the cell keys nor the random streams, hence the results, of existing configs."""
    if isinstance(value, BaseModel):
        out = {}
        for name, field in type(value).model_fields.items():
            item = getattr(value, name)
            if name != "kind":
                if field.default is not PydanticUndefined and item == field.default:
                    continue
                if field.default_factory is not None and item == field.default_factory():
                    continue
            out[field.alias or name] = identity_dump(item)
        return out
    if isinstance(value, (list, tuple)):
        return [identity_dump(item) for item in value]
    if isinstance(value, dict):
        return {key: identity_dump(item) for key, item in value.items()}
    return value
