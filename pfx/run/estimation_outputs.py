"""What a PMMH folder makes from its chains alone: forecasts.csv, and a finished folder's record
brought up to a config whose chains it already holds.

After PMMH, ``outputs.forecasts`` forecasts from posterior draws of the chains
(:mod:`pfx.estimation.posterior_forecasts`): each draw's filter has its own stream, from the
seed, the cell and the draw's number, so the forecasts of a finished folder's chains are the
same whether they are made with the chains or afterwards. They are therefore not part of the
folder's results hash (:attr:`pfx.config.plan.Plan.results_hash`), as the iterations are not: a
finished folder asked for forecasts keeps its chains and gains forecasts.csv.

:func:`update_outputs` does that for a finished folder whose every chain already holds the
iterations asked (what else may differ from the config that made it: the name, the
description, the figures, their formats, the forecasts): it makes forecasts.csv where the
forecasts asked differ from those the folder made (or it has none), removes it where none are
asked, writes the record (config.yaml, the manifest's name, description, config hash and
figures) and draws the figures that are new, or that read forecasts made again (every figure,
where the formats changed). The chains' tables (chains.csv, posterior.csv, priors.csv,
likelihood_spread.csv) and their times in the manifest are left as they were, byte for byte.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import pandas as pd
import yaml

from pfx.config.plan import Plan
from pfx.estimation.posterior_forecasts import posterior_forecasts
from pfx.result_folder import write_csv, write_manifest
from pfx.run.folder_record import drop_stale_figures, plugins_record

FORECASTS = "forecasts.csv"
FORECASTS_KEY = "outputs.forecasts"      # the key whose table forecast figures read (pfx.figures.registry.asks_for)


def posterior_forecast_table(plan: Plan, work: list, forecasts, out: Path,
                             report: Callable[[str], None]) -> pd.DataFrame:
    """forecasts.csv after PMMH: every particle-filter cell's forecasts from its posterior draws
    (``work``: each cell's :class:`~pfx.run.estimation.CellWork`, its rows and its target), the
    cell's labels first; a draw whose filter failed is left out, and the run says so in one line
    per cell."""
    frames = []
    for item in work:
        if not item.cell.filter.uses_particles:
            continue
        rows = item.rows[item.rows["iteration"] <= plan.experiment.estimation.iterations]
        table, draws, left_out = posterior_forecasts(item.target, rows, forecasts, plan.experiment.seed,
                                                     item.cell.stream_key)
        if left_out:
            report(f"{out}: cell {item.cell.key}: forecasts from {draws - len(left_out)} of {draws} posterior "
                   f"draws; {len(left_out)} left out, the filter failing at their parameters ({left_out[0]})")
        if not table.empty:
            frames.append(pd.concat([pd.DataFrame({"cell": item.cell.key, **item.cell.labels}, index=table.index),
                                     table], axis=1))
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def update_outputs(plan: Plan, out: Path, work: list, manifest: dict, report: Callable[[str], None],
                   write_config: Callable) -> None:
    """A finished PMMH folder whose chains hold the iterations asked, brought up to ``plan``
    without running them again (module docstring). ``manifest``: the folder's; ``work``: each
    cell's rows read back from the folder (:func:`pfx.run.estimation._prepare`)."""
    from pfx.figures import FIGURES, render_figures

    outputs = plan.experiment.outputs
    forecasts = outputs.forecasts
    remade = forecasts.requested and (_recorded_forecasts(out) != plan.resolved["outputs"].get("forecasts")
                                      or not (out / FORECASTS).is_file())
    started = time.perf_counter()
    if remade:          # the table made in full before anything is written: a stopped run leaves the record
        write_csv(posterior_forecast_table(plan, work, forecasts, out, report), out / FORECASTS)
    elif not forecasts.requested:
        (out / FORECASTS).unlink(missing_ok=True)
    seconds = time.perf_counter() - started
    figures, formats, old_figures, old_formats, removed = drop_stale_figures(out, manifest, outputs)
    write_config(plan, out)
    manifest.update(name=plan.experiment.name, description=plan.experiment.description, config_file=plan.file,
                    config_hash=plan.config_hash, figures=figures, formats=formats, **plugins_record(plan))
    write_manifest(manifest, out)
    drawn = [name for name in figures if formats != old_formats or name not in old_figures
             or (remade and getattr(FIGURES[name], "asks_for", None) == FORECASTS_KEY)]
    render_figures(out, drawn, tuple(formats))
    iterations = plan.experiment.estimation.iterations
    report(f"{out}: chains up to date ({iterations} iterations, same results hash {plan.results_hash}); record "
           "updated" + (f", {FORECASTS} made from the kept chains in {seconds:.1f} s" if remade else "")
           + (f", figures rendered: {', '.join(drawn)}" if drawn else "")
           + (f", figures removed: {', '.join(removed)}" if removed else ""))


def _recorded_forecasts(out: Path):
    """``outputs.forecasts`` of the config that made the folder (its config.yaml), None if none."""
    try:
        recorded = yaml.safe_load((out / "config.yaml").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    outputs = recorded.get("outputs") if isinstance(recorded, dict) else None
    return outputs.get("forecasts") if isinstance(outputs, dict) else None
