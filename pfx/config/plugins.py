"""Loading plugins: the code that brings components (models, resamplers, weightings, proposals,
filter kinds) from outside pfx into a run.

A plugin is Python code that registers components with the decorators of the public API
(``pfx.register_model`` and friends: :mod:`pfx.config.plugin_registration`, which also knows
who owns each registration; docs/plugins.md). It reaches pfx in one of three ways:

* a config's ``plugins:`` list names it: a Python file (its name ends in ``.py`` or holds a
  ``/``; relative to the config's folder), or an importable module, or the name of an entry
  point of an installed package (below). :func:`load_config_plugins` imports exactly these,
  before the config is validated, and nothing else: **a config naming a plugin runs its code**,
  and a config without ``plugins:`` runs none;
* ``pfx list --plugin FILE`` and ``pfx schema --plugin FILE`` load the files given, and
  ``pfx.load_plugin(path)`` from Python (:mod:`pfx.filtering`) loads one as a config would;
* installed packages offer plugins through the entry-point group ``pfx.plugins`` (in their
  ``pyproject.toml``: ``[project.entry-points."pfx.plugins"] name = "package.module"``).
  These are loaded only by ``pfx list``, which shows what is installed, and when a config names
  one in ``plugins:``. Never at startup, never behind a config's back: a run depends on a
  plugin's code, whose hash goes into the run's record, so every run names what it uses.

A loaded plugin is a :class:`LoadedPlugin`: its name as written, the file its code came from,
the sha256 of that code (recorded in ``manifest.json`` and mixed into the config and results
hashes, so a result folder is never resumed with changed plugin code), and what it registered.
The registries remember which plugin registered what (:mod:`pfx.registry`), and a config sees
only the built-in components and those of its own plugins.

A file plugin is executed from the very bytes that were hashed, as the module
``pfx_plugin_<stem>_<hash>``; worker processes (local or Dask) receive the bytes with each task
and execute them the same way (:func:`ensure_loaded`), so no shared file system is needed.
Module plugins must be installed on the workers, like pfx itself. Loading the file of code that
was imported by hand replaces the hand-imported registrations with the plugin's.

Every failure is one :class:`~pfx.errors.ConfigError` line naming the plugin: a missing file or
module, an exception while importing it (located at its last line in the plugin's own file,
``plugin.py:12: NameError: ...``), a name that clashes with a built-in component, a model class
that does not define a required method.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import re
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional

from pfx.config.plugin_registration import IMPORTED_BY_HAND, LOADED, PluginError, forget, registries
from pfx.errors import ConfigError, ExecutorError, UsageError
from pfx.numerics.compiled import keep_cache_apart
from pfx.registry import RegistrationClash, registering_for
from pfx.user_files import UnreadableFile, read_user_file

ENTRY_POINT_GROUP = "pfx.plugins"
# the folder of a result folder that holds its plugin files' code; in a gallery, the store of them all
PLUGIN_COPIES = "plugins"
MAX_PLUGIN_BYTES = 10 * 1024 * 1024


@dataclass(frozen=True)
class LoadedPlugin:
    """A plugin imported into this process (see the module docstring)."""

    name: str                        # as the config (or --plugin) wrote it
    origin: str                      # its owner name in the registries: the file's absolute path, or the module
    path: str                        # its source file, as shown in messages
    sha256: str                      # of the source file's bytes
    module: str                      # its module name in sys.modules
    source: Optional[bytes] = field(default=None, repr=False)   # a file plugin's code, for the workers
    registered: tuple[str, ...] = ()  # "model damped_walk", ...
    code_file: str = ""               # the file name its code was compiled with: what tracebacks show

    def __post_init__(self):
        if not self.code_file:
            object.__setattr__(self, "code_file", self.path)

    @property
    def is_file(self) -> bool:
        """A plugin file (its code travels with it and is copied into result folders), not a module."""
        return self.source is not None

    def record(self, copy: Optional[str]) -> dict:
        """What manifest.json says of it; ``copy``: a file plugin's copy, as the result folder's
        config.yaml names it (:func:`pfx.config.plugin_record.copy_paths`)."""
        entry = {"name": self.name, "file": self.path, "sha256": self.sha256}
        if self.is_file:
            entry["copy"] = copy
        return entry

    def summary(self) -> str:
        return f"{self.name} ({', '.join(self.registered) or 'registered nothing'})"


MODULE_PREFIX = "pfx_plugin_"                # a file plugin runs as the module pfx_plugin_<stem>_<hash>


def load_config_plugins(raw: Any, config_file: str) -> list[LoadedPlugin]:
    """Import the plugins a config names (``plugins:``; files relative to its folder).

    Only the list's shape is checked here; everything else in the config is validated after,
    with the plugins' components known (and a result folder's copies checked against its
    manifest: :func:`pfx.config.plugin_record.check_copies`, which the plan calls).
    """
    entries = raw.get("plugins") if isinstance(raw, dict) else None
    if entries is None or entries == []:
        return []
    if not isinstance(entries, list) or not all(isinstance(entry, str) and entry.strip() for entry in entries):
        raise ConfigError("must be a list of plugin file names (.py) or module names", file=config_file,
                          key="plugins")
    folder = Path(config_file).parent
    plugins = [load_plugin(entry, folder, config_file=config_file, key=f"plugins[{index}]")
               for index, entry in enumerate(entries)]
    return plugins


def load_plugin(entry: str, folder: Path = Path("."), *, config_file: Optional[str] = None,
                key: Optional[str] = None) -> LoadedPlugin:
    """Import one plugin: a file (relative to ``folder``), an entry point's name or a module name.

    ``config_file`` and ``key`` locate the errors about the entry itself (a missing file);
    without a config file they are command-line errors (``--plugin``).
    """
    refuse = ConfigError if config_file else UsageError
    if entry.endswith(".py") or "/" in entry or "\\" in entry:
        path = folder / entry
        try:         # only a regular file, read at once: a pipe or device is refused, never read
            source = read_user_file(path, MAX_PLUGIN_BYTES)
        except UnreadableFile as error:
            reason = f"plugin file not found: {path}" if error.missing else f"plugin file {path} {error.reason}"
            raise refuse(reason, file=config_file, key=key) from None
        return _load_file(entry, path, source)
    entry_point = installed_entry_points().get(entry)
    module = entry_point.module if entry_point is not None else entry
    if not re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*", module) or _find_spec(module) is None:
        raise refuse(f"no plugin module or installed plugin named {entry!r} (a plugin file's name "
                     "ends in .py)", file=config_file, key=key)
    return _load_module(entry, module)


def load_plugins(entries: Iterable[str], folder: Path = Path("."), *, what: str = "--plugin") -> list[LoadedPlugin]:
    """Load plugins given on the command line (``--plugin``), files relative to ``folder``."""
    return [load_plugin(entry, folder, key=what) for entry in entries]


def installed_entry_points() -> dict:
    """The installed packages' plugins: entry point name -> entry point (group ``pfx.plugins``)."""
    from importlib.metadata import entry_points

    return {entry_point.name: entry_point for entry_point in entry_points(group=ENTRY_POINT_GROUP)}


def load_installed_plugins(entry_points: Optional[Iterable] = None) -> list[LoadedPlugin]:
    """Import every installed plugin (``pfx list`` shows them); ``entry_points`` for tests."""
    chosen = list(installed_entry_points().values()) if entry_points is None else list(entry_points)
    return [_load_module(entry_point.name, entry_point.module) for entry_point in chosen]


def _find_spec(module: str):
    try:
        return importlib.util.find_spec(module)
    except (ImportError, ValueError):      # a parent package that is missing or broken
        return None


def _load_file(name: str, path: Path, source: bytes) -> LoadedPlugin:
    digest = hashlib.sha256(source).hexdigest()
    origin = str(path.resolve())
    earlier = LOADED.get(origin)
    if earlier is None or earlier.sha256 != digest:
        # The same code from another file (a result folder's copy of a plugin loaded already):
        # the same plugin, whose components are registered already.
        earlier = next((plugin for plugin in LOADED.values() if plugin.is_file and plugin.sha256 == digest), None)
    if earlier is not None and earlier.sha256 == digest:
        return _renamed(earlier, name, str(path))
    for module, file in list(IMPORTED_BY_HAND.items()):     # this file imported by hand: pfx's load replaces it
        if file == origin:
            forget(module)
            del IMPORTED_BY_HAND[module]
    module = f"{MODULE_PREFIX}{re.sub(r'[^0-9A-Za-z_]', '_', path.stem)}_{digest[:12]}"
    plugin = LoadedPlugin(name=name, origin=origin, path=str(path), sha256=digest, module=module, source=source)
    return _remember(_execute(plugin))


def _load_module(name: str, module: str) -> LoadedPlugin:
    earlier = LOADED.get(module)
    if earlier is not None:
        return _renamed(earlier, name, earlier.path)
    spec = _find_spec(module)
    source_file = spec.origin if spec is not None and spec.origin and Path(spec.origin).is_file() else None
    digest = hashlib.sha256(Path(source_file).read_bytes()).hexdigest() if source_file else ""
    plugin = LoadedPlugin(name=name, origin=module, path=source_file or module, sha256=digest, module=module)
    _prepare_registries()
    with registering_for(plugin.origin):
        try:
            importlib.import_module(module)      # imported by hand already: its registrations are the module's
        except Exception as error:
            forget(plugin.origin)
            raise import_failure(error, plugin) from None
    IMPORTED_BY_HAND.pop(module, None)
    return _remember(plugin)


def _execute(plugin: LoadedPlugin) -> LoadedPlugin:
    """Run a file plugin's code (the hashed bytes) as its module, its registrations owned by it."""
    _prepare_registries()
    forget(plugin.origin)                   # an earlier version of the same file, in this process
    if b"numba" in plugin.source:            # numba's cache, apart from the file imported by hand
        keep_cache_apart(MODULE_PREFIX)
    module = types.ModuleType(plugin.module)
    module.__file__ = plugin.code_file
    sys.modules[plugin.module] = module      # classes pickle by module name: workers find it too
    with registering_for(plugin.origin):
        try:
            exec(compile(plugin.source, plugin.code_file, "exec"), module.__dict__)
        except (Exception, SystemExit) as error:
            del sys.modules[plugin.module]
            forget(plugin.origin)
            raise import_failure(error, plugin) from None
    return plugin


def _remember(plugin: LoadedPlugin) -> LoadedPlugin:
    registered = tuple(f"{registry.what} {name}" for registry in registries() for name in registry
                       if registry.origin(name) == plugin.origin)
    plugin = LoadedPlugin(**{**plugin.__dict__, "registered": registered})
    LOADED[plugin.origin] = plugin
    return plugin


def _renamed(plugin: LoadedPlugin, name: str, path: str) -> LoadedPlugin:
    return LoadedPlugin(**{**plugin.__dict__, "name": name, "path": path})


def import_failure(error: BaseException, plugin: LoadedPlugin) -> ConfigError:
    """The one line for an exception raised while importing a plugin: the plugin's file and its
    last line in the traceback, the exception's type and message."""
    line = None
    if isinstance(error, SyntaxError) and error.filename == plugin.code_file:
        line = error.lineno
    traceback = error.__traceback__
    while traceback is not None:
        if traceback.tb_frame.f_code.co_filename == plugin.code_file:
            line = traceback.tb_lineno
        traceback = traceback.tb_next
    if isinstance(error, PluginError) and error.line is not None:
        line = error.line
    message = " ".join(str(error.msg if isinstance(error, SyntaxError) else error).split())
    reason = message if isinstance(error, (PluginError, RegistrationClash)) else \
        f"{type(error).__name__}: {message}" if message else type(error).__name__
    return ConfigError(reason, file=plugin.path, line=line)


def loaded_plugins() -> list[LoadedPlugin]:
    """Every plugin loaded in this process (its latest version)."""
    return list(LOADED.values())


def python_origins() -> list[str]:
    """The owners of the components the Python door sees (:mod:`pfx.filtering`): every plugin
    loaded in this process, and the code imported by hand that registered components."""
    return [plugin.origin for plugin in LOADED.values()] + list(IMPORTED_BY_HAND)


def unload_plugin(plugin: LoadedPlugin) -> None:
    """Undo loading ``plugin`` in this process: its registrations, its module, the record of it.

    The test suite runs the command line in its own process and unloads what each command
    loaded, so that every command starts with the registries of a fresh process.
    """
    forget(plugin.origin)
    LOADED.pop(plugin.origin, None)
    sys.modules.pop(plugin.module, None)


def _prepare_registries() -> None:
    """Import pfx's own components before a plugin runs, so that none is taken for the plugin's
    (importing ``pfx.models.base`` from a plugin would otherwise register the built-in models
    while the plugin's name is the registries' current owner)."""
    registries()


def ensure_loaded(plugins: Iterable[LoadedPlugin]) -> None:
    """In a worker process: make the plugins of a task importable (their classes unpickle),
    executing a file plugin's shipped code once per process."""
    for plugin in plugins:
        if plugin.module in sys.modules:
            continue
        if plugin.source is not None:
            try:
                _execute(plugin)
            except ConfigError as error:
                raise ExecutorError(f"plugin {plugin.name} failed on a worker: {error}") from None
            continue
        try:
            with registering_for(plugin.origin):
                importlib.import_module(plugin.module)
        except Exception as error:
            raise ExecutorError(f"plugin module {plugin.module!r} cannot be imported on a worker "
                                f"({type(error).__name__}: {error}); install it there, as pfx itself") from None


def unknown_name_hint(plugins: list[LoadedPlugin], reason: str = "") -> str:
    """For an unknown component name (``reason``: the message that names it, quoted): which
    plugins were loaded and what they registered, and which code imported by hand registered
    that very name, which a config sees only by naming it."""
    hint = "; plugins loaded: " + ", ".join(plugin.summary() for plugin in plugins) if plugins else ""
    by_hand = []
    for module, file in IMPORTED_BY_HAND.items():
        names = [f"{registry.what} {name}" for registry in registries() for name in registry
                 if registry.origin(name) == module and repr(name) in reason]
        if names:
            remedy = f"name {Path(file).name} in plugins:" if file else "move it to a .py file named in plugins:"
            by_hand.append(f"{', '.join(names)} (module {module}, imported outside pfx: {remedy})")
    if by_hand:
        hint += "; a config sees only the plugins it names, not " + "; ".join(by_hand)
    return hint
