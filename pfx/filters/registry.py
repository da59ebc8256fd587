"""The filter-kind registry (see :mod:`pfx.filters`)."""

from typing import Callable

from pfx.registry import Registry

FILTERS: Registry[Callable] = Registry("filter")
