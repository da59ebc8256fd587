"""Figures of the robot motion models and the binary Bayes filter (Probabilistic Robotics, ch. 4-5).

* ``motion_density_panels`` (Figs. 5.3 / 5.8): one panel per noise setting, the pose density in
  x-y as a grey-scale map (darker = more likely, as in the book), the noise-free path dashed, the
  start and the commanded end pose drawn as robots (a circle and a heading line);
* ``motion_sample_panels`` (Figs. 5.4 / 5.9): the drawn samples, one row per noise family
  (normal, triangular), one column per setting, on common axes;
* ``motion_spread``: the samples' standard deviation along and across the motion per setting and
  noise family, with 95% intervals from the extended count;
* ``binary_bayes_beliefs``: the worked example's belief per cell scan by scan, and the final
  belief against the truth (with the mean over all runs);
* ``binary_bayes_convergence``: over the runs, the visible cells' mean error and share
  misclassified against the scan count.

All read the study tables (:mod:`pfx.studies.robot_motion`, :mod:`pfx.studies.binary_bayes`).
"""

from __future__ import annotations

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

NOISE_STYLE = {"normal": {"color": "tab:blue", "marker": "o"}, "triangular": {"color": "tab:orange", "marker": "^"}}


def _model_name(result: ResultFolder) -> str:
    kind = result.manifest.get("study", "")
    if kind.startswith("velocity"):
        return "Velocity motion model"
    if kind.startswith("odometry"):
        return "Odometry motion model"
    return "Motion model"


def _alphas_text(row) -> str:
    names = sorted(c for c in row.index if c.startswith("alpha"))
    return "α1..α{} = ({})".format(len(names), ", ".join(f"{row[name]:g}" for name in names))


def _draw_robot(axes, x: float, y: float, theta: float, radius: float, color: str, label=None) -> None:
    """A robot as the book draws it: a circle with a line along its heading."""
    from matplotlib.patches import Circle

    axes.add_patch(Circle((x, y), radius, fill=False, edgecolor=color, linewidth=1.5, zorder=4, label=label))
    axes.plot([x, x + 1.6 * radius * np.cos(theta)], [y, y + 1.6 * radius * np.sin(theta)], color=color,
              linewidth=1.5, zorder=4)


def _draw_path(axes, path, radius: float) -> None:
    line = path[path["element"] == "path"]
    axes.plot(line["x"], line["y"], linestyle="--", color="tab:red", linewidth=1.3, zorder=3,
              label="commanded motion (no noise)")
    start = path[path["element"] == "start"].iloc[0]
    end = path[path["element"] == "end"].iloc[0]
    _draw_robot(axes, start["x"], start["y"], start["theta"], radius, "tab:red", label="start pose")
    _draw_robot(axes, end["x"], end["y"], end["theta"], radius, "tab:green", label="commanded end pose")


@FIGURES.register("motion_density_panels")
def motion_density_panels(result: ResultFolder):
    """Figs. 5.3 / 5.8: the pose density in x-y per setting (grey scale), with the commanded motion.

    Studies `velocity_motion_density`, `odometry_motion_density`: start and commanded end pose, noise-free path.
    """
    import matplotlib.pyplot as plt

    density = result.table("density")
    grid = result.optional_table("grid")
    if density.empty or grid.empty:
        return None
    settings = result.table("settings")
    path = result.table("path")
    axes_spec = grid.set_index("axis")
    x_edges, y_edges = (np.linspace(axes_spec.loc[a, "low"], axes_spec.loc[a, "high"], int(axes_spec.loc[a, "cells"]) + 1)
                        for a in ("x", "y"))
    radius = 0.025 * max(x_edges[-1] - x_edges[0], y_edges[-1] - y_edges[0])
    count = len(settings)
    aspect = (y_edges[-1] - y_edges[0]) / (x_edges[-1] - x_edges[0])
    figure, axes = plt.subplots(1, count, figsize=(4.6 * count, 3.7 * aspect + 1.5), layout="constrained",
                                squeeze=False)
    for axis, (_, setting) in zip(axes[0], settings.iterrows()):
        rows = density[density["setting"] == setting["setting"]]
        # cells left out of the table (negligible density) stay 0
        image_values = np.zeros((len(y_edges) - 1, len(x_edges) - 1))
        column = np.floor((rows["x"].to_numpy() - x_edges[0]) / np.diff(x_edges[:2])).astype(int)
        row = np.floor((rows["y"].to_numpy() - y_edges[0]) / np.diff(y_edges[:2])).astype(int)
        image_values[row, column] = rows["density"].to_numpy()
        image = axis.pcolormesh(x_edges, y_edges, image_values, cmap="gray_r", shading="flat", rasterized=True)
        _draw_path(axis, path, radius)
        axis.set_aspect("equal")
        axis.set_xlim(x_edges[0], x_edges[-1])
        axis.set_ylim(y_edges[0], y_edges[-1])
        axis.set_title(f"{setting['label']}\n{_alphas_text(setting)}", fontsize=9.5)
        axis.set_xlabel("x (m)")
        bar = figure.colorbar(image, ax=axis, shrink=0.7, pad=0.02)
        bar.set_label("p(x, y) (1/m²)", fontsize=8)
        bar.ax.tick_params(labelsize=7)
    axes[0][0].set_ylabel("y (m)")
    axes[0][0].legend(loc="upper left", fontsize=7.5, framealpha=0.9)
    figure.suptitle(f"{_model_name(result)}: density of the pose after one motion, projected into x-y\n"
                    "(summed over the heading; darker = more likely)", fontsize=11)
    return figure


@FIGURES.register("motion_sample_panels")
def motion_sample_panels(result: ResultFolder):
    """Figs. 5.4 / 5.9: the sampler's poses per setting (columns) and noise family (rows).

    Studies `velocity_motion_samples`, `odometry_motion_samples`.
    """
    import matplotlib.pyplot as plt

    samples = result.table("samples")
    if samples.empty:
        return None
    settings = result.table("settings")
    path = result.table("path")
    noises = list(dict.fromkeys(samples["noise"]))
    x_all = np.concatenate([samples["x"], path["x"]])
    y_all = np.concatenate([samples["y"], path["y"]])
    margin = 0.05 * max(np.ptp(x_all), np.ptp(y_all))
    limits = ((x_all.min() - margin, x_all.max() + margin), (y_all.min() - margin, y_all.max() + margin))
    radius = 0.025 * max(np.ptp(x_all), np.ptp(y_all))
    count = len(settings)
    aspect = (limits[1][1] - limits[1][0]) / (limits[0][1] - limits[0][0])
    figure, axes = plt.subplots(len(noises), count, figsize=(4.3 * count, (3.5 * aspect + 0.45) * len(noises) + 0.8),
                                layout="constrained", squeeze=False, sharex=True, sharey=True)
    for row, noise in enumerate(noises):
        for column, (_, setting) in enumerate(settings.iterrows()):
            axis = axes[row][column]
            drawn = samples[(samples["setting"] == setting["setting"]) & (samples["noise"] == noise)]
            style = NOISE_STYLE.get(noise, {"color": "black", "marker": "o"})
            axis.scatter(drawn["x"], drawn["y"], s=4, color=style["color"], marker=style["marker"], alpha=0.7,
                         linewidths=0, label=f"{len(drawn)} samples, {noise} errors", zorder=2)
            _draw_path(axis, path, radius)
            axis.set_aspect("equal")
            axis.set_xlim(*limits[0])
            axis.set_ylim(*limits[1])
            axis.grid(alpha=0.25)
            if row == 0:
                axis.set_title(f"{setting['label']}\n{_alphas_text(setting)}", fontsize=9.5)
            if row == len(noises) - 1:
                axis.set_xlabel("x (m)")
            if column == 0:
                axis.set_ylabel(f"{noise} errors\ny (m)")
                axis.legend(loc="lower right", fontsize=7, framealpha=0.9, markerscale=2)
    figure.suptitle(f"{_model_name(result)}: poses drawn by the sampler (Table 5.4 errors), "
                    f"{samples.groupby(['setting', 'noise']).size().iloc[0]} per panel", fontsize=11)
    return figure


@FIGURES.register("motion_spread")
def motion_spread(result: ResultFolder):
    """Standard deviation of the samples along and across the motion, per setting and noise (95% CI).

    Studies `velocity_motion_samples`, `odometry_motion_samples`.
    """
    import matplotlib.pyplot as plt

    spread = result.table("spread")
    if spread.empty:
        return None
    settings = result.table("settings")
    extended = spread[spread["n"] == spread["n"].max()]
    noises = list(dict.fromkeys(extended["noise"]))
    figure, axes = plt.subplots(1, 2, figsize=(11, 4.3), layout="constrained", sharey=True)
    positions = np.arange(len(settings))
    width = 0.8 / len(noises)
    for axis, direction in zip(axes, ("along", "across")):
        for index, noise in enumerate(noises):
            rows = extended[extended["noise"] == noise].set_index("setting").loc[settings["setting"]]
            std = rows[f"std_{direction}"].to_numpy()
            # the standard error of s from that of s^2: se(s) = se(s^2) / (2 s)
            error = 1.96 * rows[f"var_{direction}_se"].to_numpy() / (2 * std)
            axis.bar(positions + (index - (len(noises) - 1) / 2) * width, std, width * 0.9, yerr=error, capsize=3,
                     color=NOISE_STYLE.get(noise, {}).get("color"), label=f"{noise} errors")
        axis.set_xticks(positions, settings["label"], fontsize=8.5)
        axis.set_title(f"{direction} the motion", fontsize=10)
        axis.grid(alpha=0.3, axis="y")
    axes[0].set_ylabel("standard deviation of the final position (m)")
    axes[0].legend(fontsize=8.5)
    n = int(extended["n"].iloc[0])
    figure.suptitle(f"{_model_name(result)}: spread of the sampled positions along and across the direction of "
                    f"motion ({n:,} samples each; bars: 95% CI)", fontsize=11)
    return figure


@FIGURES.register("binary_bayes_beliefs")
def binary_bayes_beliefs(result: ResultFolder):
    """The worked example's belief per cell and scan, and the final belief against the truth.

    Study `binary_bayes`, with the mean over runs.
    """
    import matplotlib.pyplot as plt

    beliefs = result.table("beliefs")
    if beliefs.empty:
        return None
    final = result.optional_table("final")
    positions = np.sort(beliefs["position"].unique())
    size = positions[1] - positions[0] if len(positions) > 1 else 1.0
    edges = np.append(positions - size / 2, positions[-1] + size / 2)
    scans = int(beliefs["scan"].max())
    grid = beliefs.pivot(index="scan", columns="position", values="belief").loc[:, positions].to_numpy()
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(9.5, 7.2), layout="constrained", sharex=True,
                                         height_ratios=[1.15, 1])
    image = top.pcolormesh(edges, np.arange(0.5, scans + 1), grid, cmap="gray_r", vmin=0, vmax=1, shading="flat")
    per_scan = beliefs.drop_duplicates("scan").sort_values("scan")
    top.scatter(per_scan["measured_range"], per_scan["scan"], color="tab:red", marker="|", s=120,
                label="measured range of the scan", zorder=3)
    top.set_ylabel("scan t")
    top.set_yticks(np.arange(1, scans + 1, max(1, scans // 10)))
    top.set_title("Example run: belief bel_t(occupied) per cell after each scan "
                  "(white = free, black = occupied, grey = unknown)", fontsize=10)
    top.legend(loc="upper left", fontsize=8)
    bar = figure.colorbar(image, ax=top, pad=0.01)
    bar.set_label("belief", fontsize=8)
    truth = beliefs[beliefs["scan"] == scans].sort_values("position")
    occupied = truth[truth["occupied"].astype(bool)]
    for index, (_, cell) in enumerate(occupied.iterrows()):
        bottom.axvspan(cell["position"] - size / 2, cell["position"] + size / 2, color="0.85", zorder=0,
                       label="truly occupied cells" if index == 0 else None)
    convergence = result.optional_table("convergence")
    if "prior" in convergence:
        prior = float(convergence["prior"].iloc[0])
        bottom.axhline(prior, color="black", linestyle=":", linewidth=1, label=f"prior {prior:g}")
    bottom.plot(truth["position"], truth["belief"], "o", color="tab:blue", markersize=4,
                label=f"example run after scan {scans}")
    if not final.empty:
        runs_text = "runs"
        if not convergence.empty:
            runs_text = f"{int(convergence['runs'].iloc[0]):,} runs"
        bottom.errorbar(final["position"], final["belief_mean"], yerr=1.96 * final["belief_se"], fmt="-",
                        color="tab:orange", linewidth=1, capsize=2, label=f"mean over {runs_text} (95% CI)")
        hidden = final[~final["visible"].astype(bool)]
        if not hidden.empty:
            bottom.axvline(hidden["position"].min() - size / 2, color="tab:red", linestyle="--", linewidth=1,
                           label="occluded cells (behind the face) to the right")
    bottom.set_ylim(-0.05, 1.05)
    bottom.set_xlabel("distance from the sensor (m)")
    bottom.set_ylabel("final belief bel(occupied)")
    bottom.legend(fontsize=8, loc="center left")
    bottom.grid(alpha=0.3)
    figure.suptitle("Binary Bayes filter in log odds (Table 4.2): a corridor scanned by a range sensor",
                    fontsize=11)
    return figure


@FIGURES.register("binary_bayes_convergence")
def binary_bayes_convergence(result: ResultFolder):
    """Over all runs: the visible cells' mean |belief - truth| and share misclassified, per scan.

    Study `binary_bayes`.
    """
    import matplotlib.pyplot as plt

    convergence = result.table("convergence")
    if convergence.empty:
        return None
    runs = int(convergence["runs"].iloc[0])
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4), layout="constrained")
    for axis, column, label in ((left, "visible_error", "mean |belief − truth|"),
                                (right, "visible_wrong", "share misclassified (wrong side of 1/2)")):
        mean = convergence[f"{column}_mean"]
        error = 1.96 * convergence[f"{column}_se"]
        axis.errorbar(convergence["scan"], mean, yerr=error, marker="o", markersize=4, capsize=3)
        axis.set_yscale("log")
        axis.set_xlabel("scans")
        axis.set_ylabel(label)
        axis.grid(alpha=0.3, which="both")
    left.set_title("error of the visible cells' beliefs", fontsize=10)
    right.set_title("visible cells on the wrong side", fontsize=10)
    figure.suptitle(f"Binary Bayes filter: convergence of the cells the sensor sees, mean over {runs:,} runs "
                    "(bars: 95% CI)", fontsize=11)
    return figure
