"""The arena and the commanded route of a walled-map model (kim-mcl's Figs. 3 and 5).

``arena_map`` draws, from scene.csv, the walls, the start pose (an arrow along the start
heading) and the commanded route executed exactly (the ``path`` rows, one per action), with the
action numbers: a move is numbered at its end point, and the actions that leave the robot in
one place (turns: a scan) share one label such as ``1-4``. From steps.csv it adds the true path
of the first traced trial, so the map shows how far the real robot (biased, noisy actions)
falls behind the route it was given.
"""

from __future__ import annotations

import numpy as np

from pfx.figures.maps import _axes_labels, draw_scene
from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

ARROW_LENGTH = 18.0          # cm: the start-heading arrow, about a robot's length


def action_groups(path) -> list[tuple[float, float, str]]:
    """(x, y, label) per stop of the route: consecutive actions ending at one place share a label.

    ``path`` holds one row per action end (row 0: the start, label ``0``); a run of actions that
    leaves the position unchanged (turns) is labelled ``first-last``. The start is not labelled.
    """
    groups: list[tuple[float, float, list[int]]] = []
    previous = None
    for _, row in path.iterrows():
        number = int(row["label"])
        point = (float(row["x"]), float(row["y"]))
        if previous is not None and np.hypot(point[0] - previous[0], point[1] - previous[1]) < 1e-6:
            groups[-1][2].append(number)
        else:
            groups.append((point[0], point[1], [number]))
        previous = point
    labels = []
    for x, y, numbers in groups:
        numbers = [n for n in numbers if n > 0]
        if numbers:
            text = str(numbers[0]) if len(numbers) == 1 else f"{numbers[0]}-{numbers[-1]}"
            labels.append((x, y, text))
    return labels


@FIGURES.register("arena_map")
def arena_map(result: ResultFolder):
    """Walls, start pose, the commanded route with its action numbers, and one true path.

    Walled-map models (kim-mcl Figs. 3 and 5): the start heading, the route executed exactly (scene.csv `path` rows).
    """
    import matplotlib.pyplot as plt

    scene = result.scene
    if scene.empty or "wall" not in set(scene["element"]):
        return None
    path = scene[scene["element"] == "path"]
    figure, axes = plt.subplots(figsize=(8.2, 7.0), layout="constrained")
    draw_scene(axes, scene[scene["element"] != "path"])
    if not path.empty:
        axes.plot(path["x"], path["y"], color="tab:blue", linewidth=1.6, marker="o", markersize=3.5,
                  label="commanded route (actions executed exactly)")
        for x, y, text in action_groups(path):
            axes.annotate(text, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8, color="tab:blue")
        start = path.iloc[0]
        if "heading" in path and np.isfinite(start["heading"]):
            radians = np.deg2rad(start["heading"])
            axes.annotate("", xy=(start["x"] + ARROW_LENGTH * np.cos(radians), start["y"] + ARROW_LENGTH * np.sin(radians)),
                          xytext=(start["x"], start["y"]),
                          arrowprops=dict(arrowstyle="-|>", color="black", linewidth=1.6))
        axes.scatter([start["x"]], [start["y"]], s=80, color="black", zorder=6, label="start pose (arrow: heading)")
    steps = result.steps
    planar = result.position_states[:2]
    if not steps.empty and len(planar) == 2:
        trial = steps[(steps["cell"] == steps["cell"].iloc[0]) & (steps["trial"] == steps["trial"].min())]
        trial = trial.sort_values("step")
        axes.plot(trial[f"truth_{planar[0]}"], trial[f"truth_{planar[1]}"], color="crimson", linewidth=1.1,
                  linestyle="--", label=f"true path of the real robot (trial {int(trial['trial'].iloc[0])})")
    _axes_labels(axes, result, *(planar if len(planar) == 2 else ("x", "y")))
    actions = max(len(path) - 1, 0)
    axes.set_title(f"{result.manifest.get('name', '')}: the arena and the route ({actions} actions; "
                   "numbers: action index)", fontsize=11)
    axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8)
    return figure
