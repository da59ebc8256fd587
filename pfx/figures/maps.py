"""Map figures for planar models: the world (scene.csv), paths (steps.csv), particles (particles.csv).

* ``trajectory_map``: the true and the estimated path of one trial over the model's scene
  (beacons, walls, designed path), one panel per cell, and the same trial in every panel: the
  smallest trial number that steps.csv traced in every drawn cell. A trial's truth comes from
  its own stream, the same in every cell of one model, so the panels show the filters on one
  true path (a trial picked per panel would compare different paths, and could pick the
  luckiest for one filter and the worst for another). The figure's title names the trial, each
  panel's its position RMSE. Panels of the same world (one model) share their axes, so their
  paths compare at a glance. Recorded data without ``data.truth`` have no true path: the map
  draws the estimated path alone (it still shows where the filter put the target), with no
  legend entry, start or RMSE of a truth that does not exist, and its title says so.
* ``particle_snapshots``: the particle cloud at the kept steps of the first cell's first trial
  (marker area proportional to weight), with the true and estimated positions.
* ``particle_animation``: the same, step by step, as an animated GIF.

They need a model with at least two position components; models draw their world through
:meth:`pfx.models.base.Model.scene`.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

MAX_PANELS = 6
MAX_FRAMES = 60


def draw_scene(axes, scene) -> None:
    """Beacons as triangles, walls as thick lines, the designed path dashed, the region boxed."""
    if scene.empty:
        return
    from matplotlib.patches import Rectangle

    for _, row in scene[scene["element"] == "region"].iterrows():
        axes.add_patch(Rectangle((row["x"], row["y"]), row["x_end"] - row["x"], row["y_end"] - row["y"],
                                 fill=False, linestyle=":", edgecolor="gray", linewidth=1, label="region"))
    walls = scene[scene["element"] == "wall"]
    for index, (_, row) in enumerate(walls.iterrows()):
        axes.plot([row["x"], row["x_end"]], [row["y"], row["y_end"]], color="black", linewidth=2.2,
                  solid_capstyle="round", label="walls" if index == 0 else None)
    path = scene[scene["element"] == "path"]
    if not path.empty:
        axes.plot(path["x"], path["y"], linestyle="--", color="gray", linewidth=1, label="designed path")
    beacons = scene[scene["element"] == "beacon"]
    if not beacons.empty:
        axes.scatter(beacons["x"], beacons["y"], marker="^", s=90, color="crimson", edgecolor="black",
                     zorder=5, label="beacons / tags")
        if "label" in beacons:
            for _, row in beacons.iterrows():
                if isinstance(row.get("label"), str):
                    axes.annotate(row["label"], (row["x"], row["y"]), textcoords="offset points",
                                  xytext=(5, 5), fontsize=8)


def _axes_labels(axes, result: ResultFolder, x_name: str, y_name: str) -> None:
    unit = result.units.get("position", "")
    suffix = f" [{unit}]" if unit else ""
    axes.set_xlabel(f"{x_name}{suffix}")
    axes.set_ylabel(f"{y_name}{suffix}")
    axes.set_aspect("equal", adjustable="box")
    axes.grid(alpha=0.25)


def _planar(result: ResultFolder):
    names = result.position_states
    return names[:2] if len(names) >= 2 else None


def _grid(count: int, share: bool = False):
    """A figure with ``count`` map panels and no empty slot: up to three a row (four as two
    by two), a shorter last row centred. ``share``: every panel shares the first one's axes."""
    import matplotlib.pyplot as plt

    columns = 2 if count == 4 else min(count, 3)
    rows = -(-count // columns)
    figure = plt.figure(figsize=(4.6 * columns, 4.3 * rows), layout="constrained")
    # Each panel spans two half-columns, so a last row of fewer panels can sit in the middle.
    grid = figure.add_gridspec(rows, 2 * columns)
    axes_list = []
    for index in range(count):
        row, column = divmod(index, columns)
        in_row = min(columns, count - row * columns)
        start = (columns - in_row) + 2 * column
        shared = axes_list[0] if share and axes_list else None
        axes_list.append(figure.add_subplot(grid[row, start:start + 2], sharex=shared, sharey=shared))
    return figure, axes_list


def shared_trial(frame, cells: list[str]) -> Optional[int]:
    """The smallest trial number that ``frame`` (steps.csv with each row's cell label in
    ``_cell``) traced in every one of ``cells``; None if no trial is traced in all of them."""
    common = None
    for cell in cells:
        traced = {int(trial) for trial in frame.loc[frame["_cell"] == cell, "trial"]}
        common = traced if common is None else common & traced
    return min(common) if common else None


def _trial_rmse(result: ResultFolder, cell_key: str, trial: int) -> float:
    """The position RMSE of one trial of one cell (trials.csv's ``rmse_position``); NaN without it."""
    trials = result.optional_table("trials")
    if "rmse_position" not in trials:
        return float("nan")
    rows = trials[(trials["cell"] == cell_key) & (trials["trial"] == trial)]
    return float(rows["rmse_position"].iloc[0]) if not rows.empty else float("nan")


def _same_world(frame, cells: list[str]) -> bool:
    """Whether the drawn cells' truth models agree (one model kind, no model setting swept
    apart), so that their panels show one world and can share axes."""
    drawn = frame[frame["_cell"].isin(cells)]
    columns = [c for c in drawn.columns if c == "model" or c.startswith("model_")]
    return all(drawn[c].nunique(dropna=False) <= 1 for c in columns)


@FIGURES.register("trajectory_map")
def trajectory_map(result: ResultFolder):
    """True and estimated path of one trial over the model's world, a panel per cell, the same trial in every panel (the smallest trial number traced in every cell).

    Planar models: the world from scene.csv; panels of one world share their axes; the title names the trial, each panel its position RMSE. Recorded data without data.truth: the estimated path alone.
    """
    planar = _planar(result)
    steps = result.steps
    if planar is None or steps.empty:
        return None
    x_name, y_name = planar
    frame = steps.assign(_cell=result.cell_names(steps))
    names = list(dict.fromkeys(frame["_cell"]))
    cells = names[:MAX_PANELS]
    common = shared_trial(frame, cells)
    figure, axes_list = _grid(len(cells), share=_same_world(frame, cells))
    unit = result.units.get("position", "")
    truthless = False
    for axes, cell in zip(axes_list, cells):
        rows = frame[frame["_cell"] == cell]
        # No trial traced in every cell (a folder written by hand): each panel its own first.
        trial = common if common is not None else int(rows["trial"].min())
        rows = rows[rows["trial"] == trial].sort_values("step")
        draw_scene(axes, result.scene)
        # recorded data without data.truth: no true path, and the start is the estimate's
        start = "truth" if rows[[f"truth_{x_name}", f"truth_{y_name}"]].notna().to_numpy().any() else "estimate"
        truthless = truthless or start == "estimate"
        if start == "truth":
            axes.plot(rows[f"truth_{x_name}"], rows[f"truth_{y_name}"], color="black", linewidth=1.6,
                      label="true path")
        axes.plot(rows[f"estimate_{x_name}"], rows[f"estimate_{y_name}"], color="tab:blue", linewidth=1.3,
                  marker=".", markersize=4, label="estimated path")
        axes.scatter(rows[f"{start}_{x_name}"].iloc[:1], rows[f"{start}_{y_name}"].iloc[:1], marker="o",
                     color="black", zorder=6, label="start")
        rmse = _trial_rmse(result, rows["cell"].iloc[0], trial)
        which = f"trial {trial}" + (f": RMSE {rmse:.3g} {unit}".rstrip() if np.isfinite(rmse) else "")
        axes.set_title(f"{cell}\n({which})", fontsize=10)
        _axes_labels(axes, result, x_name, y_name)
    handles, labels = axes_list[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncol=4, fontsize=8)
    shown = f" (the first {len(cells)} of {len(names)} cells)" if len(names) > len(cells) else ""
    if common is None:
        which = "no trial traced in every cell: each panel its first traced trial"
    elif len(cells) > 1:
        which = f"trial {common} in every panel (the first trial traced in every cell)"
    else:
        which = f"trial {common}"
    paths = "estimated paths (recorded data: no true path)" if truthless else "true and estimated paths"
    figure.suptitle(f"{result.manifest.get('name', '')}: {paths}{shown}\n{which}", fontsize=12)
    return figure


def _first_cloud_series(result: ResultFolder):
    """Particles, truth and estimates of the first cell's first kept trial, by step."""
    particles = result.particles
    if particles.empty or _planar(result) is None:
        return None
    first_cell = particles["cell"].iloc[0]
    particles = particles[particles["cell"] == first_cell]
    trial = particles["trial"].min()
    particles = particles[particles["trial"] == trial]
    stages = list(dict.fromkeys(particles["stage"]))
    stage = "weighted" if "weighted" in stages else stages[-1]
    chosen = particles[(particles["stage"] == stage) | (particles["step"] == 0)]
    steps = result.steps
    track = steps[(steps["cell"] == first_cell) & (steps["trial"] == trial)].sort_values("step") \
        if not steps.empty else steps
    label = result.cell_names(particles.head(1)).iloc[0]
    return chosen, track, label, stage, trial


def _draw_cloud(axes, result, cloud, track, step: int, x_name: str, y_name: str, size_scale: float) -> None:
    draw_scene(axes, result.scene)
    weights = cloud["weight"].to_numpy()
    sizes = size_scale * weights / weights.max() if weights.max() > 0 else np.full(len(cloud), size_scale)
    axes.scatter(cloud[x_name], cloud[y_name], s=np.maximum(sizes, 1.5), color="tab:orange", alpha=0.55,
                 edgecolor="none", label="particles (area ∝ weight)")
    if not track.empty and step > 0:
        upto = track[track["step"] <= step]
        axes.plot(upto[f"truth_{x_name}"], upto[f"truth_{y_name}"], color="black", linewidth=1.2, label="true path")
        axes.plot(upto[f"estimate_{x_name}"], upto[f"estimate_{y_name}"], color="tab:blue", linewidth=1,
                  label="estimate")
        now = upto.iloc[-1]
        axes.scatter([now[f"truth_{x_name}"]], [now[f"truth_{y_name}"]], marker="*", s=160, color="black",
                     zorder=6, label="true position")
        axes.scatter([now[f"estimate_{x_name}"]], [now[f"estimate_{y_name}"]], marker="X", s=80,
                     color="tab:blue", edgecolor="white", zorder=6, label="estimate (weighted mean)")


def _kept_steps(clouds, most: int) -> list:
    """The kept steps, thinned evenly to at most ``most``."""
    kept = sorted(clouds["step"].unique())
    if len(kept) > most:
        kept = [kept[i] for i in np.linspace(0, len(kept) - 1, most).round().astype(int)]
    return kept


def _limits(result, cloud_frame, track, x_name, y_name):
    xs = [cloud_frame[x_name]]
    ys = [cloud_frame[y_name]]
    scene = result.scene
    if not scene.empty:
        xs += [scene["x"], scene.get("x_end", scene["x"])]
        ys += [scene["y"], scene.get("y_end", scene["y"])]
    if not track.empty:
        xs.append(track[f"truth_{x_name}"])
        ys.append(track[f"truth_{y_name}"])
    x = np.concatenate([np.asarray(v, dtype=float) for v in xs])
    y = np.concatenate([np.asarray(v, dtype=float) for v in ys])
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    pad_x, pad_y = 0.05 * (x.max() - x.min() or 1), 0.05 * (y.max() - y.min() or 1)
    return (x.min() - pad_x, x.max() + pad_x), (y.min() - pad_y, y.max() + pad_y)


@FIGURES.register("particle_snapshots")
def particle_snapshots(result: ResultFolder):
    """The particle cloud at up to six kept steps of one trial, over the model's world.

    Planar models; marker area proportional to weight; needs `outputs.particles`.
    """
    series = _first_cloud_series(result)
    if series is None:
        return None
    clouds, track, label, stage, trial = series
    x_name, y_name = _planar(result)
    kept = _kept_steps(clouds, MAX_PANELS)
    figure, axes_list = _grid(len(kept))
    x_limits, y_limits = _limits(result, clouds, track, x_name, y_name)
    for axes, step in zip(axes_list, kept):
        cloud = clouds[clouds["step"] == step]
        _draw_cloud(axes, result, cloud, track, int(step), x_name, y_name, size_scale=40)
        axes.set_title("prior (step 0)" if step == 0 else f"step {int(step)}", fontsize=10)
        _axes_labels(axes, result, x_name, y_name)
        axes.set_xlim(x_limits)
        axes.set_ylim(y_limits)
    handles, labels = axes_list[-1 if len(kept) > 1 else 0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncol=4, fontsize=8)
    n = int(clouds[clouds["step"] == kept[-1]]["particle"].nunique())
    figure.suptitle(f"{result.manifest.get('name', '')}: {n} particles ({stage}) of {label}, trial {int(trial)}",
                    fontsize=12)
    return figure


@FIGURES.register("particle_animation")
def particle_animation(result: ResultFolder):
    """Animated GIF of one trial: the particle cloud step by step, with the true and estimated paths.

    The particle snapshots as an animated GIF, one frame per kept step; needs `outputs.particles`.
    """
    series = _first_cloud_series(result)
    if series is None:
        return None
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    clouds, track, label, stage, trial = series
    x_name, y_name = _planar(result)
    kept = _kept_steps(clouds, MAX_FRAMES)
    figure, axes = plt.subplots(figsize=(5.6, 6.2), layout="constrained")
    x_limits, y_limits = _limits(result, clouds, track, x_name, y_name)
    by_step = {step: clouds[clouds["step"] == step] for step in kept}
    # The scene and the artists are made once; each frame only moves their data (redrawing
    # whole axes per frame cost most of the GIF's time).
    draw_scene(axes, result.scene)
    cloud = axes.scatter(np.empty(0), np.empty(0), s=20, color="tab:orange", alpha=0.55,
                         edgecolor="none", label="particles (area ∝ weight)")
    true_path, = axes.plot([], [], color="black", linewidth=1.2, label="true path")
    estimate_path, = axes.plot([], [], color="tab:blue", linewidth=1, label="estimate")
    true_now = axes.scatter(np.empty(0), np.empty(0), marker="*", s=160, color="black", zorder=6,
                            label="true position")
    estimate_now = axes.scatter(np.empty(0), np.empty(0), marker="X", s=80, color="tab:blue", edgecolor="white",
                                zorder=6, label="estimate (weighted mean)")
    _axes_labels(axes, result, x_name, y_name)
    axes.set_xlim(x_limits)
    axes.set_ylim(y_limits)
    handles, labels = axes.get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=7)   # off the map, every frame
    title = axes.set_title("", fontsize=10)
    nowhere = np.empty((0, 2))

    def draw(frame_index: int):
        step = kept[frame_index]
        points = by_step[step]
        weights = points["weight"].to_numpy()
        sizes = 30 * weights / weights.max() if weights.max() > 0 else np.full(len(points), 30.0)
        cloud.set_offsets(np.column_stack([points[x_name], points[y_name]]))
        cloud.set_sizes(np.maximum(sizes, 1.5))
        upto = track[track["step"] <= step] if not track.empty and step > 0 else None
        if upto is None or upto.empty:
            for line in (true_path, estimate_path):
                line.set_data([], [])
            true_now.set_offsets(nowhere)
            estimate_now.set_offsets(nowhere)
        else:
            true_path.set_data(upto[f"truth_{x_name}"], upto[f"truth_{y_name}"])
            estimate_path.set_data(upto[f"estimate_{x_name}"], upto[f"estimate_{y_name}"])
            now = upto.iloc[-1]
            true_now.set_offsets([[now[f"truth_{x_name}"], now[f"truth_{y_name}"]]])
            estimate_now.set_offsets([[now[f"estimate_{x_name}"], now[f"estimate_{y_name}"]]])
        title.set_text(f"{result.manifest.get('name', '')}: {label}, trial {int(trial)}\n"
                       + ("prior (step 0)" if step == 0 else f"step {int(step)} ({stage})"))
        return []

    # Lay the figure out once, then freeze it: every frame has the same axes.
    draw(0)
    figure.canvas.draw()
    figure.set_layout_engine("none")
    animation = FuncAnimation(figure, draw, frames=len(kept), blit=False)
    animation.frames_per_second = 4
    return animation
