"""The unit of a run's times: what its figures' time axes and its record (manifest.json's
``units.time``) say, and what a model's ``dt`` and a data file's ``time`` column are counted in.

A model declares the unit its parameters assume (``time_unit``, a class attribute: ``s`` unless
it says otherwise; ``step`` or ``action`` for a model that counts steps, whose figures then put
the step on the axis). A config may say it instead, with the top-level key ``time_unit``
(``time_unit: day`` for daily counts filtered with a model that declares none): a label, which
changes no number. :func:`time_unit` is the one place that decides between the two; whatever
converts times into the run's unit (a data file's dates, say) asks it too. A config's unit is a
short name (:data:`UnitName`: at most :data:`LONGEST_UNIT_NAME` characters, none of them a square
bracket, which the axis label puts around it).
"""

from __future__ import annotations

from typing import Annotated, Any, Mapping, Optional

from pydantic import AfterValidator

from pfx.models import MODELS

DEFAULT_TIME_UNIT = "s"
LONGEST_UNIT_NAME = 20


def _unit_name(unit: str) -> str:
    """A time unit as a config gives it: a short name, which an axis label puts in square
    brackets (``time [day]``)."""
    if not unit.strip() or len(unit) > LONGEST_UNIT_NAME or any(character in unit for character in "[]\n"):
        raise ValueError(f"a unit's name of 1 to {LONGEST_UNIT_NAME} characters without square brackets or line "
                         f"breaks, e.g. day (got {unit!r})")
    return unit


UnitName = Annotated[str, AfterValidator(_unit_name)]     # the config's ``time_unit``


def time_unit(config: Mapping[str, Any], model: Optional[Any] = None) -> str:
    """The config's ``time_unit`` where it sets one, else the model's own ``time_unit``: of
    ``model`` (a model or its class) when given, else of the class ``config["model"]["kind"]``
    names; ``s`` for a kind not (yet) registered. ``config`` is the config as read or resolved
    (a mapping; before validation too)."""
    configured = config.get("time_unit") if isinstance(config, Mapping) else None
    if isinstance(configured, str) and configured:
        return configured
    if model is None:
        section = config.get("model") if isinstance(config, Mapping) else None
        kind = section.get("kind") if isinstance(section, Mapping) else None
        model = MODELS[kind] if isinstance(kind, str) and kind in MODELS else None
    return getattr(model, "time_unit", DEFAULT_TIME_UNIT)
