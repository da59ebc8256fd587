"""Every registry of components a config can name, in one list.

Each kind of component (models, resamplers, proposals, figures, ...) has its registry beside its
base class (:class:`pfx.registry.Registry`; a component registers at its definition). This
module is the one list of them, in the order ``pfx list`` shows them, and every place that needs
"all the registries" reads it: ``pfx list`` (:mod:`pfx.cli`), the plugins' bookkeeping of what
they registered and the loading of plugins (:mod:`pfx.config.plugins`), and the config
reference (:mod:`pfx.config.reference`).

The registries' modules are imported only when asked for (:func:`registry`,
:func:`all_registries`): importing them all takes a second or more, which ``pfx --help`` and
``pfx list figures`` need not pay.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Optional

from pfx.registry import Registry


@dataclass(frozen=True)
class RegistrySource:
    """Where a registry lives, and where a config names its components."""

    name: str                       # plural, as `pfx list NAME` takes it
    module: str
    attribute: str
    config_key: Optional[str] = None    # the config key whose value is a component of it


REGISTRIES = (
    RegistrySource("models", "pfx.models", "MODELS", "model.kind"),
    RegistrySource("studies", "pfx.studies", "STUDIES", "study.kind"),
    RegistrySource("filters", "pfx.filters", "FILTERS", "filter.kind"),
    RegistrySource("resamplers", "pfx.filters.particle.resampling", "RESAMPLERS", "filter.resampler"),
    RegistrySource("weightings", "pfx.filters.particle.weighting", "WEIGHTINGS", "filter.weighting"),
    RegistrySource("noises", "pfx.laws.noise", "NOISE_FAMILIES", "family"),
    RegistrySource("diffusions", "pfx.filters.particle.diffusion", "DIFFUSIONS", "filter.diffusion"),
    RegistrySource("moves", "pfx.filters.particle.moves", "MOVES", "filter.move"),
    RegistrySource("proposals", "pfx.filters.particle.proposals", "PROPOSALS", "filter.proposal"),
    RegistrySource("smoothers", "pfx.filters.smoothers", "SMOOTHERS", "filter.smoothers"),
    RegistrySource("metrics", "pfx.analysis.metrics", "METRICS"),
    RegistrySource("figures", "pfx.figures", "FIGURES", "outputs.figures"),
)
NAMES = tuple(source.name for source in REGISTRIES)


def registry(name: str) -> Registry:
    """The registry ``pfx list NAME`` shows (imports its module)."""
    source = next(source for source in REGISTRIES if source.name == name)
    return getattr(importlib.import_module(source.module), source.attribute)


def all_registries() -> dict[str, Registry]:
    """Every registry by name, in :data:`REGISTRIES`' order (imports their modules)."""
    return {source.name: registry(source.name) for source in REGISTRIES}
