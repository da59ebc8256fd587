r"""``filtered_over_data``: the filter's estimate of every state component over time, over the data.

The first picture of a filter run on recorded data (R's pomp draws it from a ``pfilter``): at
each step k, the filtering mean :math:`\hat x_{k,j} = E[x_{k,j} \mid z_{1:k}]` of every state
component j (steps.csv's ``estimate_<state>``) with the band
:math:`\hat x_{k,j} \pm 2\,\mathrm{sd}_{k,j}` (``sd_<state>``, the posterior standard
deviation; about the central 95% of a near-Gaussian posterior: steps.csv records no quantiles of
the filtering law), and the measurements as points over the component they measure:

* a measurement component named after the state component (a model whose measurement *is* the
  state, plus noise), or
* for the ``linear_gaussian`` model, a row of its ``measurement_matrix`` (config.yaml) that is a
  unit vector: :math:`z_i = x_j + v_i`.

A measurement that is some other function of the state (reported cases, a range to a beacon)
has no place on a state's axis: ``predictions_over_data`` draws each measurement against the
filter's one-step-ahead prediction of it instead. Where the run knows the truth (simulated
data, or ``data.truth``), the true state is a dashed line.

A row of panels per state component and a column per cell (at most :data:`MOST_CELLS`; the
title names those left out), each cell's first traced trial: with recorded data every trial
filters the same measurements and trials differ only by the filter's own randomness. A cell
whose kind records no posterior sd has its line without a band, and the title says so.
"""

from __future__ import annotations

import numpy as np

from pfx.figures.layout import cell_labels, legend_columns_of, state_text, time_axis, with_unit
from pfx.figures.registry import FIGURES
from pfx.figures.scores import cell_grid, cells_without, traced_steps
from pfx.result_folder import ResultFolder

BAND_SDS = 2.0                 # the band: mean +- this many sd
MOST_CELLS = 4                 # columns of panels; more cells are left out (and named)
MEASUREMENT_POINT_SIZE = 9


def first_traced_trials(steps):
    """steps.csv's rows of each cell's smallest traced trial, in step order within each cell."""
    first = steps[steps["trial"] == steps.groupby("cell")["trial"].transform("min")]
    return first.sort_values(["step"], kind="stable")


def drawn_cells(result: ResultFolder, rows, value_columns: list[str]):
    """The cells (one row each, in the folder's order) with a value in some ``value_columns``,
    at most :data:`MOST_CELLS`, and a note naming the others ("" if none)."""
    has_values = rows[value_columns].notna().any(axis=1)
    cells = rows[rows["cell"].isin(rows.loc[has_values, "cell"])].drop_duplicates("cell")
    kept = cells.head(MOST_CELLS)
    notes = [cells_without(result, rows, cells["cell"])]
    if len(cells) > len(kept):
        labels = cell_labels(cells.iloc[len(kept):], legend_columns_of(result, cells))
        notes.append(f"the first {len(kept)} of {len(cells)} cells (left out: {', '.join(labels)})")
    return kept, "; ".join(note for note in notes if note)


def draw_band(axes, time, mean, sd, colour: str, label: str) -> bool:
    """The mean as a line and mean +- :data:`BAND_SDS` sd shaded; False when ``sd`` has no value."""
    with_sd = bool(np.isfinite(sd).any())
    if with_sd:
        axes.fill_between(time, mean - BAND_SDS * sd, mean + BAND_SDS * sd, color=colour, alpha=0.25,
                          linewidth=0, label=f"± {BAND_SDS:g} sd")
    axes.plot(time, mean, color=colour, linewidth=1.3, label=label)
    return with_sd


def measured_states(result: ResultFolder, states: list[str], components: list[str]) -> dict[str, str]:
    """state -> the measurement component that is that state plus noise (module docstring)."""
    mapping = {component: component for component in components if component in states}
    model = result.config.get("model")
    if isinstance(model, dict) and model.get("kind") == "linear_gaussian":
        rows = model.get("measurement_matrix") or []
        for component, row in zip(components, rows):      # steps.csv holds them in the model's order
            values = np.asarray(row, dtype=float)
            if values.shape == (len(states),) and np.count_nonzero(values) == 1 and values.max() == 1.0:
                mapping.setdefault(states[int(np.argmax(values))], component)
    return mapping


@FIGURES.register("filtered_over_data")
def filtered_over_data(result: ResultFolder):
    """Filtered mean ± 2 posterior sd of every state component over time, with the measurements over the component they measure, a panel per (state, cell).

    From steps.csv's `estimate_<s>` and `sd_<s>` (each cell's first traced trial); measurement points where a component is the state plus noise (named after it, or a unit row of linear_gaussian's measurement matrix); the truth dashed where the run has one.
    """
    steps = traced_steps(result)
    states = [state for state in result.state_names if f"estimate_{state}" in steps]
    if steps.empty or not states:
        return None
    rows = first_traced_trials(steps)
    cells, left_out = drawn_cells(result, rows, [f"estimate_{state}" for state in states])
    if cells.empty:
        return None
    components = [column.removeprefix("measurement_") for column in steps.columns if column.startswith("measurement_")]
    measured = {state: component for state, component in measured_states(result, states, components).items()
                if steps[f"measurement_{component}"].notna().any()}
    x_column, x_label = time_axis(result)
    grid = cell_grid(result, cells, states)
    without_sd = []
    for (state, cell), axes in grid.axes.items():
        trace = rows[rows["cell"] == cell]
        time = trace[x_column].to_numpy(dtype=float)
        if f"truth_{state}" in trace and trace[f"truth_{state}"].notna().any():
            axes.plot(time, trace[f"truth_{state}"], color="black", linestyle="--", linewidth=1, label="true state")
        sd = trace[f"sd_{state}"].to_numpy(dtype=float) if f"sd_{state}" in trace else np.full(len(trace), np.nan)
        if not draw_band(axes, time, trace[f"estimate_{state}"].to_numpy(dtype=float), sd, "C0", "filtered mean"):
            without_sd.append(grid.labels[cell])
        if state in measured:
            axes.scatter(time, trace[f"measurement_{measured[state]}"], s=MEASUREMENT_POINT_SIZE, color="black",
                         zorder=5, label="measurement")
        if len(states) == 1 or axes.get_subplotspec().is_first_row():    # one component: the cells wrap
            axes.set_title(grid.labels[cell], fontsize=9)
    trials = ", ".join(sorted({str(int(trial)) for trial in rows.loc[rows["cell"].isin(cells["cell"]), "trial"]}))
    notes = [f"trial {trials} of each cell" + (" (recorded data: every trial filters the same measurements)"
                                                if result.recorded_data else ""),
             "points: " + ", ".join(f"{component} over {state}" for state, component in measured.items())
             if measured else "no measurement component is a state plus noise: predictions_over_data draws them",
             f"no posterior sd for: {', '.join(dict.fromkeys(without_sd))}" if without_sd else "", left_out]
    title = f"{result.manifest.get('name', '')}: filtered mean ± {BAND_SDS:g} posterior sd of every state\n"
    grid.finish(title + "\n".join(note for note in notes if note), x_label,
                lambda state: with_unit(state_text(state), result.units.get(f"state_{state}", "")))
    return grid.figure
