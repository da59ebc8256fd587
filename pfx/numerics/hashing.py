"""The canonical hash of settings: the same settings give the same hex digest, whatever the
order of their keys. It names cells (and so their random streams, :mod:`pfx.numerics.seeding`)
and records configs in a result folder's manifest.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any


def canonical_hash(data: Any, length: int = 16) -> str:
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]
