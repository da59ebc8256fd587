"""What ``pfx run`` prints when a run ends: a short table of its main metrics per cell, and the
command a user would want next.

Read from the finished folder's summary.csv (the same numbers a notebook would load): per
cell, the columns that tell cells apart, the trial count, and for each main metric the mean
with its 95% confidence interval (:mod:`pfx.analysis.summary`: inside the metric's range, the
Wilson interval for the share of converged trials), or ``[no CI]`` where the cell has too few
values for one. Headings carry the unit the manifest records for the position; a share is in
percent, its interval too. On a terminal the table is drawn by rich (as plain text: a unit in
square brackets is not markup); elsewhere (CI, a pipe, a log file) it is plain aligned text.

**A metric only where it means something.** The errors (position RMSE, final error) need the
true states: a run on recorded data without a truth file has none, and its table leaves them
out (trials.csv keeps their empty columns: docs/output-files.md). So does the share converged
there, unless the config chose the convergence radius: the default radius of 1 position unit
is a robot's criterion (1 m), which on a series of counts or flows means nothing. Where every
trial of a cell filtered the same measurements (recorded data, ``datasets: 1``) the table adds,
beside the mean log-likelihood, the log of the mean likelihood with its jackknife standard
error (summary.csv's ``log_mean_likelihood``, pomp's ``logmeanexp(ll, se = TRUE)``): how the
field reports a particle filter's likelihood. Over independent datasets that average means
nothing, and the table leaves it out.

Two things a reader could not see from the means alone are said in the table and in a line:

* **The convergence radius.** The share converged depends wholly on ``metrics.convergence.radius``
  (1.0 unless the config sets it, in the model's position units): 1 m, 1 ft and 1 cm are
  different criteria. The heading says the radius, and whether it is the default (read from the
  folder's ``config.yaml``); when no cell converged with the default radius, a line suggests
  setting the radius in the model's units.
* **Degenerate steps.** A step at which every particle weight was zero (underflowed) is reset
  to uniform weights and counted (trials.csv ``degenerate_steps``, docs/filters-and-models.md):
  the estimates there follow the model alone, and the log-likelihood of such a trial is -inf,
  which summary.csv's statistics, over finite values only, leave out. A cell with such steps
  gets a ``degenerate steps`` column, its log-likelihood shown as ``-inf``, and one line saying
  what happened and what to try (read from trials.csv).
"""

from __future__ import annotations

import math
import shlex
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import yaml

from pfx.analysis.estimation_flags import flag_texts, if2_advice, pmmh_advice
from pfx.analysis.metrics import ConvergenceCriterion
from pfx.analysis.summary import LOG_MEAN_LIKELIHOOD, MINIMUM_VALUES

# (summary.csv metric, heading, scale, unit): the metrics a reader looks at first. The unit is
# the manifest's unit of the position (None: none, a log-likelihood), or a fixed suffix.
POSITION = "position"
MAIN_METRICS = (("rmse_position", "position RMSE", 1.0, POSITION),
                ("error_distance_final", "final error", 1.0, POSITION),
                ("converged", "converged", 100.0, "%"),
                ("log_likelihood", "log-likelihood", 1.0, None))
TRUTH_METRICS = ("rmse_position", "error_distance_final")    # errors against the true state
LOG_MEAN_HEADING = "log mean likelihood (se)"
NO_INTERVAL = "no CI"
DEFAULT_RADIUS = ConvergenceCriterion.model_fields["radius"].default


def _number(value: float) -> str:
    if value is None or not math.isfinite(value):
        return "inf" if value is not None and value == math.inf else "-"
    return f"{value:.4g}"


def _cell_value(row: pd.Series, metric: str, scale: float, suffix: str) -> str:
    """"mean [low, high]" with the suffix on every number ("%"), or "mean [no CI]" where the
    cell has too few values for an interval (pfx.analysis.summary.MINIMUM_VALUES)."""
    mean = row.get(f"{metric}_mean")
    if mean is None or pd.isna(mean):
        return "-"
    low, high = row.get(f"{metric}_ci95_low"), row.get(f"{metric}_ci95_high")
    text = f"{_number(scale * mean)}{suffix}"
    if low is not None and not pd.isna(low):
        return text + f" [{_number(scale * low)}{suffix}, {_number(scale * high)}{suffix}]"
    count = row.get(f"{metric}_n")
    if count is not None and not pd.isna(count) and count < MINIMUM_VALUES:
        return text + f" [{NO_INTERVAL}]"
    return text


def _folder_config(folder: Path) -> dict:
    """The folder's config.yaml ({} where it is missing or unreadable)."""
    try:
        config = yaml.safe_load((folder / "config.yaml").read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):
        return {}
    return config if isinstance(config, dict) else {}


def _log_mean_value(row: pd.Series) -> str:
    """"-3804.96 (0.12)": the log of the mean likelihood with its jackknife standard error (the
    estimate alone where there is none: one trial, or every likelihood zero)."""
    estimate, error = row.get(LOG_MEAN_LIKELIHOOD), row.get(f"{LOG_MEAN_LIKELIHOOD}_se")
    if estimate is None or pd.isna(estimate):
        return "-"
    return f"{estimate:.6g}" + (f" ({error:.2g})" if error is not None and not pd.isna(error) else "")


def convergence_radius(folder: Path) -> tuple[float, bool] | None:
    """(the convergence radius, whether it is pfx's default) from the folder's config.yaml;
    None where it cannot be said in one heading (no config.yaml, or a sweep of the convergence
    settings: each cell's value is then in its own label column)."""
    config = _folder_config(folder)
    try:
        radius = float(config["metrics"]["convergence"]["radius"])
    except (KeyError, TypeError, ValueError):
        return None
    if any(str(key).startswith("metrics.convergence") for key in (config.get("sweep") or {})):
        return None
    return radius, radius == DEFAULT_RADIUS


def has_truth(folder: Path) -> bool:
    """Whether the run knew the true states: False for recorded measurements without a truth
    file (config.yaml's ``data``), whose errors and truth-based convergence mean nothing."""
    data = _folder_config(folder).get("data")
    return not (isinstance(data, dict) and data.get("measurements") and not data.get("truth"))


def radius_chosen(folder: Path) -> bool:
    """Whether the config set the convergence radius (or swept it) rather than leaving pfx's default."""
    radius = convergence_radius(folder)
    return radius is None or not radius[1]


def shares_data(folder: Path, manifest: dict) -> bool:
    """Whether every trial of a cell filtered the same measurements (recorded data, or
    ``datasets: 1``): only then is the log of their mean likelihood an estimate of one likelihood
    (:mod:`pfx.analysis.summary`)."""
    return bool(manifest.get("recorded_data")) or _folder_config(folder).get("datasets") == 1


@dataclass
class Degeneracy:
    """A cell's trials whose weights all underflowed at some step, or whose log-likelihood is -inf."""

    trials: int                    # the cell's trials
    affected: int                  # of them, with at least one degenerate step
    fewest: int                    # degenerate steps in an affected trial: the fewest and the most
    most: int
    steps: int                     # steps per trial (T)
    impossible: int                # trials whose log-likelihood is -inf


def degenerate_cells(folder: Path) -> dict[str, Degeneracy]:
    """Per cell key, its :class:`Degeneracy`, for the cells with degenerate steps or a -inf
    log-likelihood (read from trials.csv; none where it is missing)."""
    wanted = ("cell", "steps", "degenerate_steps", "log_likelihood")
    try:
        trials = pd.read_csv(folder / "trials.csv", usecols=lambda column: column in wanted, dtype={"cell": str})
    except (OSError, ValueError, pd.errors.EmptyDataError):
        return {}
    if "cell" not in trials:
        return {}
    def column(name: str, otherwise) -> pd.Series:
        return trials[name] if name in trials else pd.Series(otherwise, index=trials.index)

    degenerate = column("degenerate_steps", 0).fillna(0).astype(int)
    impossible = column("log_likelihood", math.nan) == -math.inf
    steps = column("steps", 0).fillna(0)
    cells = {}
    for cell, rows in trials.groupby("cell", sort=False).groups.items():
        counts = degenerate[rows]
        hit = counts[counts > 0]
        if hit.empty and not impossible[rows].any():
            continue
        cells[cell] = Degeneracy(trials=len(rows), affected=len(hit), fewest=int(hit.min()) if len(hit) else 0,
                                 most=int(hit.max()) if len(hit) else 0, steps=int(steps[rows].max()),
                                 impossible=int(impossible[rows].sum()))
    return cells


def summary_rows(folder: Path, manifest: dict) -> tuple[list[str], list[list[str]]]:
    """The table: a header and one row of text per cell. A heading names its unit as the
    manifest records it (``position RMSE [m]``), a share its percent sign in the values; the
    share converged its radius; cells with degenerate steps add a column (module docstring)."""
    summary = pd.read_csv(folder / "summary.csv", dtype={"cell": str})
    label_columns = [c for c in manifest.get("legend_columns", []) if c in summary] or ["arm"]
    position_unit = manifest.get("units", {}).get("position", "")
    degenerate = degenerate_cells(folder)
    impossible = {cell for cell, found in degenerate.items() if found.impossible}
    radius = convergence_radius(folder)
    truth = has_truth(folder)
    metrics = []
    for metric, heading, scale, unit in MAIN_METRICS:
        shown = f"{metric}_mean" in summary and summary[f"{metric}_mean"].notna().any()
        if not shown and not (metric == "log_likelihood" and impossible):
            continue
        if not truth and (metric in TRUTH_METRICS or (metric == "converged" and not radius_chosen(folder))):
            continue       # recorded data without the truth: no error, and no criterion the user chose
        if unit == POSITION:
            metrics.append((metric, heading + (f" [{position_unit}]" if position_unit else ""), scale, ""))
        elif metric == "converged" and radius is not None:
            value, default = radius
            within = f"r = {value:g}" + (f" {position_unit}" if position_unit else "")
            metrics.append((metric, f"{heading} ({within}{', default' if default else ''})", scale, unit or ""))
        else:
            metrics.append((metric, heading, scale, unit or ""))
        if metric == "log_likelihood" and LOG_MEAN_LIKELIHOOD in summary and shares_data(folder, manifest):
            metrics.append((LOG_MEAN_LIKELIHOOD, LOG_MEAN_HEADING, 1.0, ""))
    if any(found.affected for found in degenerate.values()):
        metrics.append(("degenerate_steps", "degenerate steps", 1.0, ""))
    header = [*label_columns, "trials", *(heading for _, heading, _, _ in metrics)]
    rows = []
    for _, row in summary.iterrows():
        values = [_log_mean_value(row) if metric == LOG_MEAN_LIKELIHOOD else _cell_value(row, metric, scale, suffix)
                  for metric, _, scale, suffix in metrics]
        if row.get("cell") in impossible:      # the mean of values with a -inf among them is -inf
            values[[metric for metric, _, _, _ in metrics].index("log_likelihood")] = "-inf"
        rows.append([str(row[c]) for c in label_columns] + [str(int(row["trials"]))] + values)
    return header, rows


def summary_notes(folder: Path, manifest: dict) -> list[str]:
    """The lines below the table: one per cell with degenerate steps or a -inf log-likelihood
    (what happened and what to try), and one when no cell converged with the default convergence
    radius (in metres or feet it is often too small to mean anything)."""
    summary = pd.read_csv(folder / "summary.csv", dtype={"cell": str})
    label_columns = [c for c in manifest.get("legend_columns", []) if c in summary] or ["arm"]
    notes = []
    for cell, found in degenerate_cells(folder).items():
        rows = summary[summary["cell"] == cell] if "cell" in summary else summary.iloc[:0]
        name = (", ".join(f"{c}={rows.iloc[0][c]}" for c in label_columns) if len(rows) else cell)
        notes.append(f"cell {name}: {_degeneracy_text(found)}")
    radius = convergence_radius(folder)
    if radius is not None and radius[1] and "converged_mean" in summary and has_truth(folder):
        shares = summary["converged_mean"].dropna()
        if len(shares) and shares.eq(0).all():
            unit = manifest.get("units", {}).get("position", "")
            notes.append(f"converged: every cell 0% with the default radius r = "
                         f"{radius[0]:g}{' ' + unit if unit else ''}, which may not suit this model's scale: set "
                         "metrics.convergence.radius in its position units (docs/configuration.md)")
    return notes


def _degeneracy_text(found: Degeneracy) -> str:
    """What happened in a cell (:class:`Degeneracy`) and what to try, in one line."""
    which = "in every trial" if found.affected == found.trials else f"in {found.affected} of {found.trials} trials"
    impossible = ("its log-likelihood is -inf" if found.impossible == found.trials
                  else f"the log-likelihood is -inf in {found.impossible} of {found.trials} trials")
    if not found.affected:
        return (f"{impossible}: the measurements had zero likelihood under the filter's model; check the "
                "measurement noise the filter assumes (filter.model.measurement_noise) and the measurements' units")
    steps = f"{found.most}" if found.fewest == found.most else f"{found.fewest} to {found.most}"
    return (f"every particle weight was zero at {steps} of {found.steps} steps {which} (reset to uniform, counted "
            "in degenerate_steps): the estimates there follow the model, not the measurements"
            + (f", and {impossible}" if found.impossible else "")
            + "; try more particles, a wider or heavier-tailed assumed measurement noise "
            "(filter.model.measurement_noise), or check the measurements' units")


def next_command(folder: Path, manifest: dict) -> str | None:
    """``pfx compare`` by the column that varies most naturally (the arm, else the first swept
    column), or None when the run has a single cell. The metric is the position RMSE, or where
    there is no RMSE (recorded data without the truth) the first CRPS when the run scored its
    predictions (``metrics.scores``), else the log-likelihood."""
    columns = manifest.get("legend_columns", [])
    if len(manifest.get("cells", [])) < 2 or not columns:
        return None
    summary = pd.read_csv(folder / "summary.csv")
    has_rmse = "rmse_position_mean" in summary and summary["rmse_position_mean"].notna().any()
    crps = [column.removesuffix("_mean") for column in summary.columns
            if column.startswith("crps_") and column.endswith("_mean") and summary[column].notna().any()]
    metric = "rmse_position" if has_rmse else crps[0] if crps else "log_likelihood --higher-is-better"
    return f"pfx compare {shlex.quote(str(folder))} --metric {metric} --by {columns[0]}"


def print_run_summary(folder: Path, manifest: dict, echo, rich_console: bool, console=None) -> None:
    """Print the table and the next command (``echo`` for plain text, rich on a terminal:
    ``console``, a rich Console, or a new one on stdout)."""
    header, rows = summary_rows(folder, manifest)
    title = f"{manifest.get('name', '')}: mean [95% CI] over trials, per cell"
    if rich_console:
        from rich.console import Console
        from rich.table import Table
        from rich.text import Text

        # Text, not markup: rich would read "[m]" (a unit) or "[no CI]" as a style and drop it.
        table = Table(title=Text(title), title_justify="left")
        labels = header.index("trials")              # the label columns come first
        for index, heading in enumerate(header):
            table.add_column(Text(heading), justify="left" if index < labels else "right")
        for row in rows:
            table.add_row(*(Text(text) for text in row))
        (console or Console()).print(table)
    else:
        widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
        echo(title)
        for line in [header, *rows]:
            echo("  " + "  ".join(text.ljust(width) for text, width in zip(line, widths)).rstrip())
    if any(f"[{NO_INTERVAL}]" in text for row in rows for text in row):
        echo(f"{NO_INTERVAL}: fewer than {MINIMUM_VALUES} values, too few for a 95% interval "
             "(docs/output-files.md, summary.csv)")
    for note in summary_notes(folder, manifest):
        echo(note)
    command = next_command(folder, manifest)
    if command:
        columns = manifest.get("legend_columns", [])
        echo(f"next: {command}   (paired differences, trial by trial, with 95% intervals"
             + (f"; --by any of: {', '.join(columns)})" if len(columns) > 1 else ")"))


def _r_hat(value: float) -> str:
    """R-hat to the third decimal (the 1.01 rule), a huge one (chains that never met) as a number."""
    return f"{value:.3f}" if math.isfinite(value) and value < 1000 else _number(value)


def print_estimation_summary(folder: Path, manifest: dict, echo) -> None:
    """What an estimation run prints at its end: per cell and parameter, the posterior mean and
    sd with R-hat, bulk and tail ESS and the row's flag (PMMH, posterior.csv), or the best
    replicate's estimate and its log-likelihood, with how many replicates are flagged (IF2,
    maximum_likelihood.csv); then, per flagged cell, the line that says what to try
    (:mod:`pfx.analysis.estimation_flags`), read from the folder's files alone."""
    method = manifest.get("estimation", {}).get("method")
    labels = [column for column in manifest.get("legend_columns", [])] or []
    notes = []
    if method == "pmmh" and (folder / "posterior.csv").is_file():
        table = _with_flags(pd.read_csv(folder / "posterior.csv", dtype={"cell": str}))
        header = [*labels, "parameter", "mean", "sd", "R-hat", "bulk ESS", "tail ESS", "flag"]
        rows = [[*(str(row[c]) for c in labels), str(row["parameter"]), _number(row["mean"]), _number(row["sd"]),
                 _r_hat(row["r_hat"]), _number(row["ess_bulk"]), _number(row["ess_tail"]), row["flag"]]
                for _, row in table.iterrows()]
        title = f"{manifest.get('name', '')}: posterior after the warm-up, chains pooled, per cell"
        spreads = _likelihood_spreads(folder)
        iterations = int(manifest.get("estimation", {}).get("iterations") or 0)
        chains = _chains(folder)
        estimation = _folder_config(folder).get("estimation") or {}
        proposal = {key: estimation[key] for key in ("adapt", "adapt_after") if key in estimation}
        for cell, cell_rows in table.groupby("cell", sort=False):
            advice = pmmh_advice(cell_rows, iterations, spreads.get(cell),
                                 chosen_by_pilot=cell in (manifest.get("particle_count") or {}),
                                 chains=chains.get(cell), **proposal)
            if advice:
                notes.append(f"cell {_cell_name(cell_rows, labels, cell)}: {advice}")
    elif method == "if2" and (folder / "maximum_likelihood.csv").is_file():
        table = _with_flags(pd.read_csv(folder / "maximum_likelihood.csv", dtype={"cell": str}))
        parameters = [c for c in table.columns
                      if c not in ("cell", "replicate", "log_likelihood", "log_likelihood_se", "flag")
                      and c not in manifest.get("label_columns", [])]
        # A cell whose every likelihood is zero (-inf) still has a row: its first replicate's, shown as -inf.
        best = table.loc[table["log_likelihood"].fillna(-math.inf).groupby(table["cell"], sort=False).idxmax()]
        flagged = (table["flag"] != "").groupby(table["cell"], sort=False).agg(["sum", "size"])
        header = [*labels, "replicate", *parameters, "log-likelihood", "se", "flagged"]
        rows = [[*(str(row[c]) for c in labels), str(int(row["replicate"])), *(_number(row[p]) for p in parameters),
                 f"{row['log_likelihood']:.3f}", _number(row["log_likelihood_se"]),
                 f"{flagged.loc[row['cell'], 'sum']} of {flagged.loc[row['cell'], 'size']}"]
                for _, row in best.iterrows()]
        title = f"{manifest.get('name', '')}: IF2, the replicate of highest log-likelihood, per cell"
        for cell, cell_rows in table.groupby("cell", sort=False):
            advice = if2_advice(list(cell_rows["flag"]), len(parameters))
            if advice:
                notes.append(f"cell {_cell_name(cell_rows, labels, cell)}: {advice}")
    else:
        return
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    echo(title)
    for line in [header, *rows]:
        echo("  " + "  ".join(text.ljust(width) for text, width in zip(line, widths)).rstrip())
    for note in notes:
        echo(note)


def _with_flags(table: pd.DataFrame) -> pd.DataFrame:
    """The table with its ``flag`` column as text ("" where a row passes: pandas reads NaN), and
    an empty one for a folder written before there were flags."""
    table = table.copy()
    table["flag"] = flag_texts(table["flag"]) if "flag" in table else ""
    return table


def _chains(folder: Path) -> dict[str, pd.DataFrame]:
    """chains.csv's rows per cell key, whose draws name a correlated pair in the advice (none
    where the folder has no readable chains.csv)."""
    try:
        chains = pd.read_csv(folder / "chains.csv", dtype={"cell": str})
    except (OSError, pd.errors.EmptyDataError):
        return {}
    return {cell: rows for cell, rows in chains.groupby("cell", sort=False)}


def _likelihood_spreads(folder: Path) -> dict[str, pd.Series]:
    """likelihood_spread.csv's row per cell key (none where the run measured none)."""
    try:
        spreads = pd.read_csv(folder / "likelihood_spread.csv", dtype={"cell": str})
    except (OSError, pd.errors.EmptyDataError):
        return {}
    return {row["cell"]: row for _, row in spreads.iterrows()}


def _cell_name(rows: pd.DataFrame, labels: list[str], cell: str) -> str:
    """"arm=KF, n_particles=200" from a cell's rows, or its key where it has no label columns."""
    shown = [column for column in labels if column in rows]
    return ", ".join(f"{column}={rows.iloc[0][column]}" for column in shown) if shown else cell
