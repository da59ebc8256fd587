"""Turn a pydantic ValidationError into one clear ConfigError line.

The key path is the dotted location of the offending value (``filter.resampler``,
``arms.MPF.weighting.form``, ``model.beacons[2]``). Unknown keys and unknown names get the
closest valid name as a hint. Validators inside pfx locate cross-field errors below their
model by starting the message with ``@sub.key:``.
"""

from __future__ import annotations

import re
import types
import typing
from typing import Any, Union

from pydantic import BaseModel, ValidationError

from pfx.errors import ConfigError, split_location
from pfx.registry import ComponentName, closest_name


def format_path(parts) -> str:
    text = ""
    for part in parts:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text


def _unwrap(annotation):
    """Strip Annotated/Optional layers; return the remaining annotation."""
    while True:
        origin = typing.get_origin(annotation)
        if origin is typing.Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin in (Union, types.UnionType):
            members = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(members) == 1:
                annotation = members[0]
            else:
                return annotation
        else:
            return annotation


def _union_members(annotation):
    return [_unwrap(a) for a in typing.get_args(annotation) if a is not type(None)]


# the keys whose value chooses a member of a discriminated union: a component's ``kind``, a
# prior's ``law`` (pfx.laws.priors)
TAG_KEYS = ("kind", "law")


def _kind_of(model_class) -> Any:
    """The tag that chooses ``model_class`` in its union: its ``kind`` (or ``law``)."""
    for key in TAG_KEYS:
        field = model_class.model_fields.get(key)
        if field is not None:
            return field.default
    return None


def _walk(root: type[BaseModel], location: tuple) -> tuple[tuple, Any]:
    """Follow ``location`` through the model tree.

    Returns the location without discriminator tags (pydantic inserts the tag of a
    discriminated union, e.g. ``model.falling_body.variant``) and the annotation reached
    (None where the tree could not be followed).
    """
    annotation: Any = root
    clean: list = []
    for part in location:
        if annotation is None:
            clean.append(part)
            continue
        annotation = _unwrap(annotation)
        origin = typing.get_origin(annotation)
        if origin in (Union, types.UnionType):
            members = [m for m in _union_members(annotation) if isinstance(m, type) and issubclass(m, BaseModel)]
            chosen = [m for m in members if _kind_of(m) == part]
            if chosen:
                annotation = chosen[0]
                continue
            if isinstance(part, str) and _TYPE_TAG.match(part):
                continue        # pydantic names the member of a plain union ('float', 'list[float]')
            annotation = members[0] if members else None
            if annotation is None:
                clean.append(part)
                continue
        if isinstance(annotation, type) and issubclass(annotation, BaseModel) and part == _kind_of(annotation) \
                and part not in annotation.model_fields:
            continue            # the tag of a one-member discriminated union
        clean.append(part)
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            fields = {f.alias or name: f for name, f in annotation.model_fields.items()}
            annotation = fields[part].annotation if part in fields else None
        elif origin in (dict, list, tuple):
            arguments = typing.get_args(annotation)
            annotation = arguments[-1] if arguments else None
        else:
            annotation = None
    return tuple(clean), annotation


def _allowed_keys(annotation) -> list[str]:
    """Field names of the model(s) an annotation stands for."""
    annotation = _unwrap(annotation)
    members = _union_members(annotation) if typing.get_origin(annotation) in (Union, types.UnionType) else [annotation]
    names: list[str] = []
    for member in members:
        if isinstance(member, type) and issubclass(member, BaseModel):
            names += [f.alias or n for n, f in member.model_fields.items() if (f.alias or n) not in names]
    return names


def _component_name(root: type[BaseModel], location: tuple) -> str:
    """What the union at ``location`` chooses: the name its registry gives it (``smoother`` for
    an entry of ``filter.smoothers``), else the key that holds it (``move``), never a list index."""
    annotation = _walk(root, location)[1]
    if typing.get_origin(annotation) is typing.Annotated:
        for metadata in typing.get_args(annotation)[1:]:
            if isinstance(metadata, ComponentName):
                return metadata.what
    keys = [str(part) for part in location if not isinstance(part, int)]
    return keys[-1] if keys else "component"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _describe(error: dict, root: type[BaseModel]) -> tuple[tuple, str]:
    location = tuple(error["loc"])
    kind = error["type"]
    context = error.get("ctx") or {}
    message = error["msg"]
    if kind == "extra_forbidden" and location:
        allowed = _allowed_keys(_walk(root, location[:-1])[1])
        hint = closest_name(location[-1], allowed)
        suggestion = f" (did you mean {hint!r}?)" if hint else (
            f" (valid keys: {', '.join(allowed)})" if allowed else "")
        return location, f"unknown key {location[-1]!r}{suggestion}"
    if kind == "missing":
        return location, "required key is missing"
    if kind == "union_tag_invalid":
        tag_key = context.get("discriminator", "kind").strip("'")
        expected = re.findall(r"'([^']*)'", str(context.get("expected_tags", "")))
        hint = closest_name(context.get("tag"), expected)
        suggestion = f" (did you mean {hint!r}?)" if hint else f" (known: {', '.join(expected)})"
        return location + (tag_key,), \
            f"unknown {_component_name(root, location)} {tag_key} {context.get('tag')!r}{suggestion}"
    if kind == "union_tag_not_found":
        tag_key = context.get("discriminator", "kind").strip("'")
        annotation = _unwrap(_walk(root, location)[1])
        kinds = [_kind_of(m) for m in _union_members(annotation)
                 if isinstance(m, type) and issubclass(m, BaseModel)] if annotation is not None else []
        given = error.get("input")
        other = [key for key in TAG_KEYS if key != tag_key and isinstance(given, dict) and key in given]
        instead = f"; write {tag_key}: instead of {other[0]}:" if other else ""
        return location + (tag_key,), f"required key is missing (one of: {', '.join(map(str, kinds))}){instead}"
    if kind == "literal_error":
        expected = re.findall(r"'([^']*)'", str(context.get("expected", "")))
        hint = closest_name(error.get("input"), expected)
        suggestion = f" (did you mean {hint!r}?)" if hint else f" (expected one of: {', '.join(expected)})"
        return location, f"unknown value {_short(error.get('input'))}{suggestion}"
    if kind == "value_error":
        sub, reason = split_location(message.removeprefix("Value error, "))
        extra = tuple(int(p) if p.isdigit() else p for p in re.split(r"\.|\[|\]", sub) if p)
        return location + extra, reason
    if kind.endswith("_type") or kind.endswith("_parsing") or kind in ("model_type", "dict_type", "list_type"):
        return location, f"{message[0].lower()}{message[1:]} (got {_short(error.get('input'))})"
    return location, f"{message[0].lower()}{message[1:]} (got {_short(error.get('input'))})"


def validate(model_class: type[BaseModel], data: Any, *, file: str | None = None, prefix: str = ""):
    """Validate ``data`` as ``model_class``; raise ConfigError located at the first problem.

    Validators find the config file's name in the validation context (``config_file``), to
    read files the config names relative to its folder.
    """
    try:
        return model_class.model_validate(data, context={"config_file": file})
    except ValidationError as error:
        raise to_config_error(error, model_class, file=file, prefix=prefix) from None


def to_config_error(error: ValidationError, root: type[BaseModel], *, file=None, prefix="") -> ConfigError:
    details = error.errors(include_url=False)
    details[0]["loc"] = tuple(part for part in details[0]["loc"] if not _is_internal(part))
    # A discriminated union reports the tag in the location; errors about other union members
    # are noise when one member matched the tag. Report the first, most specific error.
    location, reason = _describe(details[0], root)
    location = tuple(part for part in location if not _is_internal(part))
    location, _ = _walk(root, location)
    key = format_path(location)
    if prefix:
        key = f"{prefix}.{key}" if key else prefix
    return ConfigError(reason, file=file, key=key or None)


_TYPE_TAG = re.compile(r"^(float|int|str|bool|none|constrained-\w+|(list|dict|tuple|set|literal)\[.*\])$",
                       re.IGNORECASE)


def _is_internal(part) -> bool:
    # pydantic adds markers: 'function-before[...]' for wrapped validators, '[key]' for dict keys,
    # and the member type ('float', 'list[float]') of a plain union
    return isinstance(part, str) and (part == "[key]" or "[" in part and "(" in part
                                      or part.startswith("function-"))
