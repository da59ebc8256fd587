"""How a run records its plugins: the name each is known by (what the hashes and a result
folder's copy use), a result folder's ``plugins:`` list, where the copy of a plugin file's code
lies, and the check that a result folder's copies are still the code its results were computed with.

A result folder made by ``pfx run`` keeps its copies itself, in ``plugins/<name>``: it reruns
on its own, wherever it is moved. The folders of a gallery (``pfx reproduce``'s ``results/``,
``results/benchmarks/``) share one **store**, the gallery's ``plugins/``, where each plugin's code
is kept once, by content, as ``<stem>-<sha12>.py`` (the first 12 hex digits of the sha256 of its
bytes, which the manifest records whole); a folder's ``config.yaml`` names its stored copy by
relative path (``../../plugins/dacca_cholera-7274f21a391a.py``), and nothing else changes: a
plugin is recorded under its own name (``dacca_cholera.py``), so neither hash depends on where
its copy lies (:func:`recorded_names`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Optional

from pfx.config.plugins import PLUGIN_COPIES, LoadedPlugin
from pfx.errors import ConfigError

STORED_DIGITS = 12         # hex digits of the code's sha256 in a stored copy's name


def stored_name(file_name: str, sha256: str) -> str:
    """A plugin file's name in a gallery's store: ``dacca_cholera.py`` with code of sha256
    ``7274f21a391a...`` is ``dacca_cholera-7274f21a391a.py`` (one file per name and content)."""
    path = Path(file_name)
    return f"{path.stem}-{sha256[:STORED_DIGITS]}{path.suffix}"


def original_name(file_name: str, sha256: str) -> str:
    """The plugin file's own name, from the name of a copy of its code: a stored copy's name
    (:func:`stored_name`: it ends in the digits of this very code's sha256) without its digits;
    any other name as it is."""
    path = Path(file_name)
    ending = f"-{sha256[:STORED_DIGITS]}"
    if len(sha256) >= STORED_DIGITS and path.stem.endswith(ending) and path.stem != ending:
        return path.stem.removesuffix(ending) + path.suffix
    return file_name


def recorded_names(plugins: Iterable[LoadedPlugin]) -> list[str]:
    """The name each plugin is recorded under: a file's own name (``coordinated_turn.py``, also
    when the file is a stored copy ``coordinated_turn-<sha12>.py``; a second file of the same
    name gets ``coordinated_turn-2.py``), a module's name. It is what the config and results
    hashes know a plugin by, with its code's sha256, and a file plugin's copy in a result folder
    is ``plugins/<name>``: so a config that names the plugin by another path (the result
    folder's own ``config.yaml`` names the copy) has the same hashes."""
    names: list[str] = []
    for plugin in plugins:
        name = original_name(Path(plugin.path).name, plugin.sha256) if plugin.is_file else plugin.name
        if name in names:
            stem, suffix = Path(name).stem, Path(name).suffix
            name = next(f"{stem}-{number}{suffix}" for number in range(2, len(names) + 2)
                        if f"{stem}-{number}{suffix}" not in names)
        names.append(name)
    return names


def copy_paths(plugins: list[LoadedPlugin]) -> list[Optional[str]]:
    """Where a result folder written by a run keeps each file plugin's copy, relative to the
    folder (``plugins/<name>``; None for a module plugin, which is not copied)."""
    return [f"{PLUGIN_COPIES}/{name}" if plugin.is_file else None
            for plugin, name in zip(plugins, recorded_names(plugins))]


def copied_entries(plugins: list[LoadedPlugin]) -> list[str]:
    """A result folder's ``plugins:`` list: each file plugin as its copy in the folder
    (``plugins/<name>``), each module plugin as it was named."""
    return [copy or plugin.name for plugin, copy in zip(plugins, copy_paths(plugins))]


def is_own_copy(entry: str) -> bool:
    """Whether a result folder's ``plugins:`` entry names a copy the folder keeps itself."""
    parts = Path(entry).parts
    return len(parts) == 2 and parts[0] == PLUGIN_COPIES and entry.endswith(".py")


def manifest_code(manifest: Optional[dict]) -> dict[str, str]:
    """The plugins a folder's manifest records: recorded name -> sha256 of the code (the name
    from the copy, where it lies in the folder or in a store; in older folders, as written)."""
    code = {}
    for entry in (manifest or {}).get("plugins", []):
        if isinstance(entry, dict):
            sha256 = str(entry.get("sha256") or "")
            copy = entry.get("copy")
            code[original_name(Path(copy).name, sha256) if copy else entry.get("name")] = sha256
    return code


def check_copies(plugins: list[LoadedPlugin], config_file: str) -> None:
    """A result folder's ``config.yaml`` runs the copies of its plugins (in its ``plugins/``, or
    in its gallery's store): each must still be the code its results were computed with (the
    manifest's sha256 for the copy it names)."""
    from pfx.result_folder import MANIFEST, read_manifest

    folder = Path(config_file).parent
    files = [plugin for plugin in plugins if plugin.is_file]
    manifest = read_manifest(folder) if files and (folder / MANIFEST).is_file() else None
    if not manifest:
        return
    recorded = {(folder / entry["copy"]).resolve(): entry.get("sha256") for entry in manifest.get("plugins", [])
                if isinstance(entry, dict) and isinstance(entry.get("copy"), str)}
    for plugin in files:
        expected = recorded.get(Path(plugin.path).resolve())
        if expected is not None and expected != plugin.sha256:
            raise ConfigError(f"this copy differs from the code the folder's results were computed with "
                              f"(sha256 {plugin.sha256[:12]} != {str(expected)[:12]} in manifest.json); restore "
                              "it, or run an edited plugin from a config of your own", file=plugin.path)
