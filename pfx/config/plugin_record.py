"""How a run records its plugins: the name each is known by (what the hashes and a result
folder's copy ``plugins/<name>`` use), a result folder's ``plugins:`` list, and the check that a
result folder's copies are still the code its results were computed with.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

from pfx.config.plugins import PLUGIN_COPIES, LoadedPlugin
from pfx.errors import ConfigError


def recorded_names(plugins: Iterable[LoadedPlugin]) -> list[str]:
    """The name each plugin is recorded under: a file's name (``coordinated_turn.py``; a second
    file of the same name gets ``coordinated_turn-2.py``), a module's name. It is what the config
    and results hashes know a plugin by, with its code's sha256, and a file plugin's copy in a
    result folder is ``plugins/<name>``: so a config that names the plugin by another path (the
    result folder's own ``config.yaml`` names the copy) has the same hashes."""
    names: list[str] = []
    for plugin in plugins:
        name = Path(plugin.path).name if plugin.is_file else plugin.name
        if name in names:
            stem, suffix = Path(name).stem, Path(name).suffix
            name = next(f"{stem}-{number}{suffix}" for number in range(2, len(names) + 2)
                        if f"{stem}-{number}{suffix}" not in names)
        names.append(name)
    return names


def copied_entries(plugins: list[LoadedPlugin]) -> list[str]:
    """A result folder's ``plugins:`` list: each file plugin as its copy in the folder
    (``plugins/<name>``), each module plugin as it was named."""
    return [f"{PLUGIN_COPIES}/{name}" if plugin.is_file else plugin.name
            for plugin, name in zip(plugins, recorded_names(plugins))]


def check_copies(plugins: list[LoadedPlugin], config_file: str) -> None:
    """A result folder's ``config.yaml`` runs the copies of its plugins in ``plugins/``: each must
    still be the code its results were computed with (the manifest's sha256)."""
    from pfx.result_folder import read_manifest

    folder = Path(config_file).parent
    manifest = read_manifest(folder) if (folder / PLUGIN_COPIES).is_dir() else None
    if not manifest:
        return
    recorded = {entry.get("copy"): entry.get("sha256") for entry in manifest.get("plugins", [])
                if isinstance(entry, dict)}
    for plugin in plugins:
        path = Path(plugin.path)
        if not plugin.is_file or path.parent.resolve() != (folder / PLUGIN_COPIES).resolve():
            continue
        expected = recorded.get(f"{PLUGIN_COPIES}/{path.name}")
        if expected is not None and expected != plugin.sha256:
            raise ConfigError(f"this copy differs from the code the folder's results were computed with "
                              f"(sha256 {plugin.sha256[:12]} != {str(expected)[:12]} in manifest.json); restore "
                              "it, or run an edited plugin from a config of your own", file=plugin.path)
