r"""``pfx simulate CONFIG --out FOLDER``: paths simulated from a config's model, over its recorded data.

Before trusting a filter's answer on recorded data, ask whether the model, at the config's
parameters, makes data like the data (R's pomp: ``simulate`` over the data). This draws
``paths`` independent paths of the config's model (``model:``, with the steps, times, controls
and covariates its ``data:`` fix) and writes, into FOLDER:

* ``simulations.csv``, tidy: a row per (path, step) with ``path``, ``truth_seed`` (the path's
  seed), ``step``, ``time``, ``state_<s>`` for every state component, ``measurement_<m>`` for
  every measurement component, and, where the config has recorded measurements,
  ``observed_<m>``: the recorded measurement of that step (empty where it is missing);
* ``figures/simulations_over_data.png`` (and the config's other ``outputs.formats``), drawn
  from that table alone (:mod:`pfx.figures.simulations_over_data`), so ``pfx figures FOLDER``
  draws it again;
* ``manifest.json``: the config, the seed, the paths, and what the figures need.

**Reproducible.** Path p is drawn from its own stream, the truth stream of trial p of the
config's ``seed`` (:func:`pfx.numerics.seeding.truth_seed`; without ``datasets``): the same
seed gives the same table, path by path whatever ``paths`` is, and a config without ``data:``
simulates in path p the very truth its ``pfx run`` filters in trial p (:func:`pfx.simulate`
draws the same).

**Bad input** is one :class:`~pfx.errors.ConfigError` line, before anything is written: a count
of paths out of 1..:data:`MOST_PATHS`, a study config (no model), a config whose cells simulate
from different models (a sweep of a ``model.`` key: fix it with ``--set``), a folder holding
anything but an earlier ``pfx simulate``'s output.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pfx.config.plan import Plan
from pfx.config.record_hash import identity_dump
from pfx.errors import ConfigError
from pfx.models.simulation import simulate_truth
from pfx.numerics.hashing import canonical_hash
from pfx.numerics.seeding import TrialStreams, truth_seed
from pfx.result_folder import MANIFEST, check_writable, read_manifest, write_csv, write_manifest

MOST_PATHS = 10_000
TABLE = "simulations.csv"
FIGURE = "simulations_over_data"


def simulate_over_data(plan: Plan, out: Path, paths: int) -> list[Path]:
    """Draw ``paths`` paths of the plan's model into ``out`` (module docstring); return the
    files written: the table, then the figures."""
    from pfx.figures.registry import render_figures

    out = Path(out)
    if not 1 <= paths <= MOST_PATHS:
        raise ConfigError(f"{paths} paths: give 1 to {MOST_PATHS}", file=plan.file, key="--paths")
    model = the_model(plan)
    check_writable(out)
    check_folder(out)
    seeds = [truth_seed(plan.experiment.seed, path) for path in range(paths)]
    states, measurements = simulate_truth(model, TrialStreams.from_seeds(seeds))
    recorded = plan.cells[0].data.measurements if plan.cells[0].data is not None else None
    table = simulation_table(model, states, measurements, seeds, recorded)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(table, out / TABLE)
    formats = list(plan.experiment.outputs.formats)
    manifest = {
        "name": plan.experiment.name, "description": plan.experiment.description, "config_file": plan.file,
        "simulations": {"paths": paths, "seed": plan.experiment.seed}, "seed": plan.experiment.seed,
        "units": {"time": model.time_unit, "position": model.position_unit,
                  **{f"state_{name}": unit for name, unit in zip(model.state_names, model.state_units)}},
        **({"recorded_data": True} if recorded is not None else {}),
        "figures": [FIGURE], "formats": formats, "complete": False,
    }
    write_manifest(manifest, out)      # the figure reads it (names, units); complete once drawn
    figures = render_figures(out, [FIGURE], tuple(formats))
    write_manifest({**manifest, "complete": True}, out)
    return [out / TABLE, *figures]


def the_model(plan: Plan):
    """The one model the plan's cells simulate from; a ConfigError for a study or a model sweep."""
    if not plan.cells:
        raise ConfigError("a study config has no model to simulate; pfx simulate takes a config with model:",
                          file=plan.file)
    models = {canonical_hash(identity_dump(cell.truth_model)): cell.truth_model for cell in plan.cells}
    if len(models) > 1:
        swept = [key for key in plan.experiment.sweep if key.startswith("model.")] or ["model"]
        raise ConfigError(f"the cells simulate from {len(models)} different models (sweep of {', '.join(swept)}); "
                          "pfx simulate draws from one: fix the value with --set", file=plan.file, key="sweep")
    return next(iter(models.values()))


def check_folder(out: Path) -> None:
    """Refuse a folder holding anything but an earlier ``pfx simulate``'s output (a run's
    results would be mixed with simulations, or its manifest overwritten)."""
    if not out.exists() or not any(out.iterdir()):
        return
    manifest = read_manifest(out) if (out / MANIFEST).is_file() else None
    if manifest is None or "simulations" not in manifest:
        raise ConfigError("folder exists and holds other files than pfx simulate's; choose another --out",
                          file=str(out))


def simulation_table(model, states: np.ndarray, measurements: np.ndarray, seeds: list[int],
                     recorded) -> pd.DataFrame:
    """simulations.csv's rows: one per (path, step) (module docstring); ``states`` (paths,
    T + 1, d) from x_0, ``measurements`` (paths, T, m), ``recorded`` (T, m) or None."""
    paths, steps = measurements.shape[:2]
    columns = {"path": np.repeat(np.arange(paths), steps),
               "truth_seed": np.repeat(np.asarray(seeds, dtype=np.int64), steps),
               "step": np.tile(np.arange(1, steps + 1), paths), "time": np.tile(model.times(), paths)}
    for j, name in enumerate(model.state_names):
        columns[f"state_{name}"] = states[:, 1:, j].reshape(-1)
    for j, name in enumerate(model.measurement_names):
        columns[f"measurement_{name}"] = measurements[:, :, j].reshape(-1)
    if recorded is not None:
        for j, name in enumerate(model.measurement_names):
            columns[f"observed_{name}"] = np.tile(recorded[:, j], paths)
    return pd.DataFrame(columns)
