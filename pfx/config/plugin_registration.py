"""Registering a plugin's components: the public decorators, and who owns what they register.

A plugin is Python code that registers components with the decorators of the public API
(``pfx.register_model``, ``pfx.register_resampler``, ``pfx.register_weighting``,
``pfx.register_proposal``, ``pfx.register_filter_kind``; docs/plugins.md). Each decorator
checks the contract where it can before anything runs (a model class defines the methods
every model must, a weighting its ``log_weights`` ...) and refuses a broken one with a
:class:`PluginError`, one line without a type name.

Every registration has an *owner*, its origin in the registries (:mod:`pfx.registry`), so that
a config sees only the built-in components and those of the plugins it names:

* while pfx loads a plugin (:mod:`pfx.config.plugins`: a config's ``plugins:``,
  ``pfx.load_plugin``, ``--plugin``), that plugin owns what its code registers;
* code may also register components without pfx loading it: a plugin module imported by hand
  (``import cv_radar`` in a notebook), a class defined in a notebook cell. What it registers
  belongs to its module (:func:`_owner`), never passes for pfx's own: ``pfx.model`` and the
  filters on arrays see it (:func:`pfx.config.plugins.python_origins`), a config does only by
  naming its file or module, and loading that file replaces the hand-imported registrations
  with the plugin's.

This module remembers both kinds of owner (:data:`LOADED`, :data:`IMPORTED_BY_HAND`), because
a registration by hand may have to take the place of a loaded plugin's; the loader
(:mod:`pfx.config.plugins`) fills and empties them.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Optional

from pfx.registry import registering_for, registering_origin

# origin -> the plugin as pfx last loaded it in this process (a pfx.config.plugins.LoadedPlugin)
LOADED: dict[str, Any] = {}
# module -> its source file (resolved; None for a notebook's __main__): code imported by hand that
# registered components (_owner)
IMPORTED_BY_HAND: dict[str, Optional[str]] = {}


class PluginError(ValueError):
    """A plugin breaks the contract of a decorator (reported as one line, without a type name);
    ``line``: the line of the plugin the mistake is on, where the decorator knows it better than
    the traceback (a method's ``def``, not the decorator above the class)."""

    def __init__(self, message: str, line: Optional[int] = None):
        super().__init__(message)
        self.line = line


# -- the public decorators ------------------------------------------------------------------------


def register_model(model_class):
    """Class decorator: register a :class:`pfx.Model` subclass under its ``kind``.

    Checks the contract where it can before anything runs: the class is a Model, has a
    ``kind: Literal["<name>"] = "<name>"`` field, and defines ``state_names``,
    ``measurement_dimension``, ``propagate`` and ``measurement_mean``. (The shapes and dtypes
    its methods return are checked at plan time, on a tiny batch: :meth:`pfx.models.base.Model.check_contract`.)
    """
    from pfx.models.base import MODELS, Model
    from pfx.models.contract_checks import methods_meant_as_properties, missing_methods

    if not (isinstance(model_class, type) and issubclass(model_class, Model)):
        raise PluginError(f"register_model: {getattr(model_class, '__name__', model_class)!r} "
                          "is not a subclass of pfx.Model")
    kind = _declared_kind(model_class, "register_model")
    missing = missing_methods(model_class, Model)
    if missing:
        raise PluginError(f"model {kind} (class {model_class.__name__}) does not define "
                          f"{', '.join(missing)}, which every model must (docs/plugins.md)")
    for name, line in methods_meant_as_properties(model_class, Model):     # the most common slip
        raise PluginError(f"model {kind} (class {model_class.__name__}): {name} is a method, and pfx reads it "
                          f"as a property: write @property on the line above `def {name}`", line=line)
    with _owner(MODELS, kind, model_class):
        return MODELS.register_kind(model_class)


def register_weighting(weighting_class):
    """Class decorator: register a weighting (a pydantic class with a ``kind`` literal and
    ``log_weights(model, measurement, particles, weights) -> (trials, N)``; docs/extending.md)."""
    from pfx.filters.particle.weighting import WEIGHTINGS

    kind = _declared_kind(weighting_class, "register_weighting")
    if not callable(getattr(weighting_class, "log_weights", None)):
        raise PluginError(f"weighting class {weighting_class.__name__} does not define log_weights")
    if not callable(getattr(weighting_class, "label", None)):      # the tables' name for it
        weighting_class.label = lambda self: self.kind
    with _owner(WEIGHTINGS, kind, weighting_class):
        return WEIGHTINGS.register_kind(weighting_class)


def register_resampler(name: str, *, unbiased: bool, description: Optional[str] = None) -> Callable:
    """Function decorator: register ``(weights (R, N), random) -> indices (R, N)`` as resampler
    ``name``; ``unbiased`` says whether E[N_j] = N w_j (the tables flag biased ones)."""
    from pfx.filters.particle.resampling import RESAMPLERS, Resampler

    def decorate(function):
        with _owner(RESAMPLERS, name, function):
            RESAMPLERS.add(name, Resampler(function, unbiased=unbiased), description)
        return function

    return decorate


def register_proposal(proposal_class):
    """Class decorator: register a proposal (``filter.proposal: <kind>``): a subclass of
    ``pfx.Proposal`` with a ``kind`` literal, its settings as fields, and
    ``propose(model, previous, step, measurement, observed, random) -> (particles (R, N, d),
    log p(x_k | x_k-1) - log q(x_k | x_k-1, z_k) (R, N))``; ``check(model)`` may refuse a model
    (docs/plugins.md)."""
    from pfx.filters.particle.proposals import PROPOSALS, ProposalBase

    if not (isinstance(proposal_class, type) and issubclass(proposal_class, ProposalBase)):
        raise PluginError(f"register_proposal: {getattr(proposal_class, '__name__', proposal_class)!r} "
                          "is not a subclass of pfx.Proposal")
    kind = _declared_kind(proposal_class, "register_proposal")
    if proposal_class.propose is ProposalBase.propose and proposal_class.bind is ProposalBase.bind:
        raise PluginError(f"proposal {kind} (class {proposal_class.__name__}) does not define propose(model, "
                          "previous, step, measurement, observed, random)")
    with _owner(PROPOSALS, kind, proposal_class):
        return PROPOSALS.register_kind(proposal_class)


def register_filter_kind(kind_class):
    """Class decorator: register a :class:`pfx.filters.base.FilterKind` subclass under its ``kind``."""
    from pfx.filters.base import FILTERS, FilterKind

    if not (isinstance(kind_class, type) and issubclass(kind_class, FilterKind)):
        raise PluginError(f"register_filter_kind: {getattr(kind_class, '__name__', kind_class)!r} "
                          "is not a subclass of pfx.filters.base.FilterKind")
    if not isinstance(getattr(kind_class, "kind", None), str):
        raise PluginError(f"filter kind class {kind_class.__name__} needs a class attribute kind = '<name>'")
    with _owner(FILTERS, kind_class.kind, kind_class):
        return FILTERS.register_kind(kind_class)


# -- who owns a registration ----------------------------------------------------------------------


@contextmanager
def _owner(registry, name: str, definition):
    """Who owns a registration by the decorators above (the registries' *origin*).

    While pfx loads a plugin (a config's ``plugins:``, :func:`pfx.load_plugin`, ``--plugin``),
    that plugin does. Otherwise the code was imported by hand (``import cv_radar`` in a
    notebook, a class defined in a notebook cell): its module owns what it registers, so that
    nothing of it passes for a built-in component, and a config sees it only by naming it.
    Importing by hand the code pfx loaded already (the same file, or the same module) takes its
    place; importing a module again (``importlib.reload``, a cell run twice) replaces its
    earlier definitions rather than clashing with them.
    """
    if registering_origin() is not None:
        yield
        return
    module = getattr(definition, "__module__", None) or "__main__"
    source = _source_file(module)
    IMPORTED_BY_HAND[module] = source
    for loaded in {source, module} & LOADED.keys():
        forget(loaded)
        del LOADED[loaded]
    if name in registry and registry.origin(name) == module and \
            _definition(registry[name]) == _definition(definition):
        forget(module)
    with registering_for(module):
        yield


def _source_file(module: str) -> Optional[str]:
    """The resolved path of a module's source file (None: none, a notebook's ``__main__``)."""
    file = getattr(sys.modules.get(module), "__file__", None)
    return str(Path(file).resolve()) if file else None


def _definition(component) -> tuple:
    """Where a component was defined: its module and qualified name (a resampler by its function)."""
    component = getattr(component, "function", component)
    return getattr(component, "__module__", None), getattr(component, "__qualname__", None)


def _declared_kind(component_class, decorator: str) -> str:
    fields = getattr(component_class, "model_fields", {})
    kind = fields["kind"].default if "kind" in fields else None
    if not isinstance(kind, str):
        raise PluginError(f"{decorator}: class {getattr(component_class, '__name__', component_class)} needs "
                          f'a field kind: Literal["<name>"] = "<name>"')
    return kind


def registries() -> list:
    """Every registry a plugin may add to (:mod:`pfx.config.components`, the one list)."""
    from pfx.config.components import all_registries

    return list(all_registries().values())


def forget(origin: str) -> None:
    """Remove from every registry what ``origin`` (a plugin, or a module imported by hand) registered."""
    for registry in registries():
        registry.forget(origin)
