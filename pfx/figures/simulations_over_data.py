r"""``simulations_over_data``: measurement paths simulated from the config's model, over the recorded measurements.

Does the model, at the config's parameters, make data like the data? ``pfx simulate CONFIG``
(:mod:`pfx.run.simulations`) draws paths of the model's states and measurements, each from its
own seeded stream, into simulations.csv: a row per (path, step) with ``measurement_<m>``, and
``observed_<m>``, the recorded measurement of that step, where the config has ``data:``. This
figure draws, a panel per measurement component, the simulated paths as thin lines (at most
:data:`MOST_PATHS`; the title says how many of how many), the band holding the central 90% of
every path at each step when there are :data:`PATHS_FOR_A_BAND` paths or more, and the
recorded measurements as points. Data that leave the band, or wander where no path goes, are
what the model does not explain. It draws only a ``pfx simulate`` folder's table, and declares
it (:func:`~pfx.figures.registry.draws_from`).
"""

from __future__ import annotations

import numpy as np

from pfx.figures.filtered_over_data import MEASUREMENT_POINT_SIZE
from pfx.figures.layout import legend_outside, time_axis
from pfx.figures.registry import FIGURES, draws_from
from pfx.result_folder import ResultFolder

MOST_PATHS = 10                # drawn one by one; more would hide each other and the data
PATHS_FOR_A_BAND = 20          # the fewest paths whose 5% and 95% quantiles mean something
BAND_QUANTILES = (0.05, 0.95)


@FIGURES.register("simulations_over_data")
@draws_from("simulations")
def simulations_over_data(result: ResultFolder):
    """Measurement paths simulated from the config's model (`pfx simulate`), over the recorded measurements, a panel per measurement component.

    From simulations.csv: a thin line per path (at most 10), the central 90% of the paths at each step shaded (20 paths or more), the recorded measurements (`observed_<m>`) as points.
    """
    import matplotlib.pyplot as plt

    table = result.table("simulations")
    components = [column.removeprefix("measurement_") for column in table.columns if column.startswith("measurement_")]
    if table.empty or not components:
        return None
    x_column, x_label = time_axis(result)
    paths = list(dict.fromkeys(table["path"]))
    drawn = paths[:MOST_PATHS]
    figure, grid = plt.subplots(len(components), 1, figsize=(8.5, 2.9 * len(components) + 1.2), sharex=True,
                                squeeze=False, layout="constrained")
    for axes, component in zip(grid[:, 0], components):
        by_path = table.pivot(index="step", columns="path", values=f"measurement_{component}")
        time = table.groupby("step", sort=True)[x_column].first().to_numpy(dtype=float)
        if len(paths) >= PATHS_FOR_A_BAND:
            low, high = np.nanquantile(by_path.to_numpy(dtype=float), BAND_QUANTILES, axis=1)
            axes.fill_between(time, low, high, color="C0", alpha=0.2, linewidth=0,
                              label=f"central {BAND_QUANTILES[1] - BAND_QUANTILES[0]:.0%} of the {len(paths)} paths")
        for index, path in enumerate(drawn):
            axes.plot(time, by_path[path].to_numpy(dtype=float), color="C0", linewidth=0.8, alpha=0.6,
                      label="simulated paths" if index == 0 else None)
        observed = f"observed_{component}"
        if observed in table and table[observed].notna().any():
            data = table[table["path"] == paths[0]].sort_values("step")
            axes.scatter(data[x_column], data[observed], s=MEASUREMENT_POINT_SIZE, color="black", zorder=5,
                         label="recorded measurements")
        axes.set_ylabel(f"measurement {component}")
        axes.grid(alpha=0.3)
    grid[-1, 0].set_xlabel(x_label)
    legend_outside(figure)
    has_data = any(f"observed_{component}" in table for component in components)
    shown = f"{len(drawn)} of {len(paths)}" if len(drawn) < len(paths) else f"{len(paths)}"
    figure.suptitle(f"{result.manifest.get('name', '')}: {shown} measurement paths simulated from the config's model"
                    + (", over the recorded measurements" if has_data else " (the config has no recorded data)"),
                    fontsize=11)
    return figure
