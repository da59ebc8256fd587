"""The canonical hash of settings: the same settings give the same hex digest, whatever the
order of their keys. It names cells (and so their random streams, :mod:`pfx.numerics.seeding`)
and records configs in a result folder's manifest. :class:`SettingsCache` keeps answers per
settings likewise.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, Callable


def canonical_hash(data: Any, length: int = 16) -> str:
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


class SettingsCache:
    """Answers about a component (a model, say) kept per class and settings, for plan-time
    probes that every cell, and every PMMH parameter value, would otherwise repeat.

    The key is the component's class and its settings as canonical JSON (pydantic's dump), so
    two components of one class with equal settings share the answer. A component whose
    settings are not plain data (a model copy holding parameter arrays) is never cached. The
    oldest answers are dropped beyond ``size``.
    """

    def __init__(self, size: int = 256):
        self.size = size
        self._answers: dict[tuple, Any] = {}

    def answer(self, component, compute: Callable[[], Any]) -> Any:
        """The kept answer for ``component``'s class and settings, or ``compute()`` (kept)."""
        try:
            key = (type(component), json.dumps(component.model_dump(mode="json"), sort_keys=True))
        except (TypeError, ValueError):
            return compute()
        if key not in self._answers:
            value = compute()
            if len(self._answers) >= self.size:
                self._answers.pop(next(iter(self._answers)))
            self._answers[key] = value
        return self._answers[key]
