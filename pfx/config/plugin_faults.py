"""Exceptions that come out of plugin code, located in one line.

pfx calls a plugin's code at many moments: at import (the decorators), while validating a config
(``presets()``, ``check()``, ``setup()``, properties such as ``state_names``), while planning
(:meth:`pfx.models.base.Model.check_contract` on a tiny batch) and while running (``propagate``
and ``log_likelihood`` on every batch, in worker processes too). Whatever a plugin raises, its
user sees one line that says where, in their own file:

    walk.py:41: model hidden_walk: propagate raised RuntimeError: particle store full (step 3 of the filter)

* the file and line are those of the **innermost** frame of the exception's traceback that runs
  plugin code: the plugin's own line that raised, or that called the library that raised;
* the component and function are those of the **outermost** plugin frame, the function pfx
  called (``propagate``), and the registered component it belongs to (``model hidden_walk``),
  found by its ``self`` or by the registered function's code;
* the context in parentheses is what the engine adds as a note on its way out (``(step 3 of
  the filter)``, ``(step 2 of the truth)``: :data:`STEP_NOTE_PREFIX`).

Before any trial ran, the line becomes a :class:`~pfx.errors.ConfigError` (exit status 2,
nothing written); during a run, a :class:`~pfx.errors.PluginFault` (exit status 1, the finished
cells kept). An exception that passes through no plugin frame but happened in a run of a
plugin's component (pfx's code choking on what a plugin returned) is reported against that
plugin by :func:`run_time_fault`. ``pfx --traceback`` (or ``PFX_TRACEBACK=1``) shows the full
traceback as well (docs/plugins.md).
"""

from __future__ import annotations

import traceback as traceback_module
from dataclasses import dataclass
from types import TracebackType
from typing import Iterable, Optional

from pfx.config.plugin_registration import registries
from pfx.config.plugins import LoadedPlugin, loaded_plugins
from pfx.errors import STEP_NOTE_PREFIX, ConfigError, ModelContractError, PluginFault


@dataclass(frozen=True)
class Fault:
    """Where a plugin's exception came from, in words."""

    file: str                 # the plugin file, as messages show it
    line: Optional[int]       # the line in it (None: not known)
    text: str                 # "model hidden_walk: propagate raised RuntimeError: ... (step 3 of the filter)"

    def one_line(self) -> str:
        where = f"{self.file}:{self.line}" if self.line is not None else self.file
        return " ".join(f"{where}: {self.text}".split())

    def as_config_error(self) -> ConfigError:
        return ConfigError(" ".join(self.text.split()), file=self.file, line=self.line)


def locate(error: BaseException, plugins: Optional[Iterable[LoadedPlugin]] = None) -> Optional[Fault]:
    """The :class:`Fault` of an exception whose traceback runs through a plugin's code
    (``plugins``: those to look for; default every plugin loaded in this process); None if it
    never entered plugin code."""
    files = {plugin.code_file: plugin for plugin in (loaded_plugins() if plugins is None else plugins)}
    frames = [(frame, line) for frame, line in _frames(error.__traceback__)
              if frame.f_code.co_filename in files]
    if not frames:
        return None
    outer, _ = frames[0]
    inner, line = frames[-1]
    plugin = files[outer.f_code.co_filename]
    function = outer.f_code.co_name
    component = _component(outer, plugin)
    subject = f"{component}: {function}" if component else function
    return Fault(file=inner.f_code.co_filename, line=line,
                 text=f"{subject} raised {_exception_text(error)}{_context(error)}")


def _frames(traceback: Optional[TracebackType]):
    while traceback is not None:
        yield traceback.tb_frame, traceback.tb_lineno
        traceback = traceback.tb_next


def _component(frame, plugin: LoadedPlugin) -> Optional[str]:
    """``model hidden_walk``: the registered component a frame's function belongs to (a method
    of a registered class, or a registered function), or None."""
    owner = frame.f_locals.get("self")
    owner_class = owner if isinstance(owner, type) else type(owner) if owner is not None else None
    for registry in registries():
        for name in registry:
            if registry.origin(name) != plugin.origin:
                continue
            item = registry[name]
            if owner_class is not None and isinstance(item, type) and issubclass(owner_class, item):
                return f"{registry.what} {name}"
            function = getattr(item, "function", item)
            if getattr(function, "__code__", None) is frame.f_code:
                return f"{registry.what} {name}"
    if owner_class is not None:
        kind = getattr(owner, "kind", None)
        return f"{owner_class.__name__} {kind}" if isinstance(kind, str) else f"class {owner_class.__name__}"
    return None


def _exception_text(error: BaseException) -> str:
    message = " ".join(str(error).split())
    return f"{type(error).__name__}: {message}" if message else type(error).__name__


def _context(error: BaseException) -> str:
    """`` (step 3 of the filter)``: the innermost step note the engine added, if any."""
    notes = [note for note in getattr(error, "__notes__", []) if note.startswith(STEP_NOTE_PREFIX)]
    return f" ({notes[0].removeprefix(STEP_NOTE_PREFIX)})" if notes else ""


def plan_time_fault(error: Exception, plugins: list[LoadedPlugin]) -> Optional[ConfigError]:
    """While a config is validated or planned: the ConfigError (exit status 2) for an exception
    raised by, or because of, its plugins' code; None when no plugin is involved (a bug of pfx,
    which keeps its traceback)."""
    if not plugins:
        return None
    fault = locate(error, plugins)
    if fault is not None:
        return fault.as_config_error()
    # No plugin frame: pfx's own code choked on something a plugin gave it (a property of
    # the wrong type, say). The plugins are the only code that differs from a tested run.
    names = ", ".join(plugin.path for plugin in plugins)
    return ConfigError(f"checking the components of plugin(s) {names} failed with {_exception_text(error)}"
                       f"{_context(error)}; check their properties and return values against the contract "
                       "in docs/plugins.md (pfx --traceback shows where)", file=plugins[0].path)


def run_time_fault(error: Exception, plugins: tuple[LoadedPlugin, ...], model) -> Optional[PluginFault]:
    """While a batch runs: the :class:`PluginFault` (exit status 1) for an exception raised by a
    plugin's code, or by pfx's code in a run whose model comes from a plugin; None otherwise."""
    details = "".join(traceback_module.format_exception(error))
    fault = locate(error, plugins)
    if fault is not None:
        return PluginFault(fault.one_line(), details)
    owner = next((plugin for plugin in plugins if plugin.module == type(model).__module__), None)
    if owner is None:
        return None
    if isinstance(error, ModelContractError):     # the engine's own check names the method already
        return PluginFault(f"{owner.path}: {' '.join(str(error).split())}", details)
    return PluginFault(f"{owner.path}: model {model.kind}: the run failed with {_exception_text(error)}"
                       f"{_context(error)}; check the shapes and values its methods return for this batch "
                       "against the contract in docs/plugins.md (pfx --traceback shows where)", details)
