r"""Close-ups of a planar particle cloud: each kept step framed on the cloud, not on the world.

Once a filter has locked on, its cloud is a fraction of a metre wide in a world tens of metres
across, and a map of the whole world (``particle_snapshots``) shows it as a dot under the
markers. ``particle_closeups`` frames each kept step of the first cell's first trial on the
particles themselves: the window is centred on the weighted mean and spans the particles that
hold 99% of the weight, together with the true position, with a margin. Marker area is
proportional to weight; the true position and the estimate are drawn hollow so that the
particles under them stay visible. Each panel's title gives N_eff = 1 / sum w^2 and the
window's width, so the scale is never hidden. Reads particles.csv (``weighted`` stage, or the
last kept stage) and steps.csv only.
"""

from __future__ import annotations

import numpy as np

from pfx.figures.maps import MAX_PANELS, _first_cloud_series, _grid, _planar, draw_scene
from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

HELD_WEIGHT = 0.99                 # the window holds the particles carrying this much weight


def closeup_window(x: np.ndarray, y: np.ndarray, weights: np.ndarray, truth=None,
                   minimum_half_width: float = 0.05) -> tuple[tuple[float, float], tuple[float, float]]:
    """A square window around the heaviest particles (``HELD_WEIGHT`` of the weight) and the truth."""
    centre = np.array([np.sum(weights * x), np.sum(weights * y)]) / np.sum(weights)
    distance = np.hypot(x - centre[0], y - centre[1])
    order = np.argsort(distance)
    held = np.searchsorted(np.cumsum(weights[order]) / np.sum(weights), HELD_WEIGHT)
    radius = distance[order][min(held, len(order) - 1)]
    if truth is not None:
        radius = max(radius, float(np.hypot(truth[0] - centre[0], truth[1] - centre[1])))
    half = max(1.2 * radius, minimum_half_width)
    return (centre[0] - half, centre[0] + half), (centre[1] - half, centre[1] + half)


@FIGURES.register("particle_closeups")
def particle_closeups(result: ResultFolder):
    """The particle cloud at up to six kept steps of one trial, each framed on the cloud (area ∝ weight).

    From particles.csv: each panel framed on the particles holding 99% of the weight and the truth, with N_eff and the window's width.
    """
    series = _first_cloud_series(result)
    if series is None:
        return None
    clouds, track, label, stage, trial = series
    x_name, y_name = _planar(result)
    kept = [int(s) for s in sorted(clouds["step"].unique())]
    if len(kept) > MAX_PANELS:
        kept = [kept[i] for i in np.linspace(0, len(kept) - 1, MAX_PANELS).round().astype(int)]
    unit = result.units.get("position", "")
    suffix = f" [{unit}]" if unit else ""
    figure, axes_list = _grid(len(kept))
    for axes, step in zip(axes_list, kept):
        cloud = clouds[clouds["step"] == step]
        x, y, weights = (cloud[x_name].to_numpy(), cloud[y_name].to_numpy(), cloud["weight"].to_numpy())
        now = track[track["step"] == step] if step > 0 and not track.empty else track.iloc[:0]
        truth = (float(now[f"truth_{x_name}"].iloc[0]), float(now[f"truth_{y_name}"].iloc[0])) if len(now) else None
        x_limits, y_limits = closeup_window(x, y, weights, truth)
        draw_scene(axes, result.scene)
        sizes = 60 * weights / weights.max()
        axes.scatter(x, y, s=np.maximum(sizes, 1.0), color="tab:orange", alpha=0.6, edgecolor="none",
                     label="particles (area ∝ weight)")
        if len(now):
            upto = track[track["step"] <= step]
            axes.plot(upto[f"truth_{x_name}"], upto[f"truth_{y_name}"], color="black", linewidth=1, label="true path")
            axes.plot(upto[f"estimate_{x_name}"], upto[f"estimate_{y_name}"], color="tab:blue", linewidth=1,
                      label="estimated path")
            axes.scatter([truth[0]], [truth[1]], marker="*", s=220, facecolor="none", edgecolor="black",
                         linewidth=1.3, zorder=6, label="true position")
            axes.scatter(now[f"estimate_{x_name}"], now[f"estimate_{y_name}"], marker="o", s=90,
                         facecolor="none", edgecolor="tab:blue", linewidth=1.6, zorder=6,
                         label="estimate (weighted mean)")
        ess = 1.0 / np.sum((weights / weights.sum()) ** 2)
        width = x_limits[1] - x_limits[0]
        axes.set_title(("prior (step 0)" if step == 0 else f"step {step}")
                       + f": N_eff = {ess:.3g} of {len(cloud)}\nwindow {width:.3g} {unit} wide", fontsize=10)
        axes.set_xlim(x_limits)
        axes.set_ylim(y_limits)
        axes.set_aspect("equal", adjustable="box")
        axes.set_xlabel(f"{x_name}{suffix}")
        axes.set_ylabel(f"{y_name}{suffix}")
        axes.grid(alpha=0.25)
    handles = {}
    for axes in axes_list[:len(kept)]:
        for handle, text in zip(*axes.get_legend_handles_labels()):
            handles.setdefault(text, handle)
    figure.legend(list(handles.values()), list(handles.keys()), loc="outside lower center", ncol=4, fontsize=8)
    figure.suptitle(f"{result.manifest.get('name', '')}: the {stage} particle cloud of {label}, trial {trial}, "
                    "framed on the cloud at each step", fontsize=12)
    return figure
