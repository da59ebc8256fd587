"""The figure registry, the read-only view of a result folder, and rendering.

A figure function returns a matplotlib Figure (saved in the config's formats), a
``matplotlib.animation.Animation`` (saved as an animated GIF with matplotlib's Pillow writer;
an attribute ``frames_per_second`` on it sets the frame rate), or None when the folder has
nothing for it to draw.
"""

from __future__ import annotations

import json
import os
import tempfile
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Optional

from pfx.registry import Registry
from pfx.tables import FILE_MODE

if TYPE_CHECKING:          # pandas and numpy are imported where a figure is drawn, not before
    import numpy as np
    import pandas as pd

FIGURES: Registry[Callable] = Registry("figure")


class ResultFolder:
    """A result folder as figures see it: its CSV tables and its manifest, nothing else."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def table(self, name: str) -> pd.DataFrame:
        import pandas as pd

        try:
            # A cell key is 12 hex digits: read as text, or "120e45678901" would become a number.
            return pd.read_csv(self.path / f"{name}.csv", dtype={"cell": str})
        except pd.errors.EmptyDataError:
            return pd.DataFrame()

    @cached_property
    def trials(self) -> pd.DataFrame:
        return self.table("trials")

    @cached_property
    def steps(self) -> pd.DataFrame:
        return self.table("steps")

    @cached_property
    def steps_summary(self) -> pd.DataFrame:
        """steps_summary.csv: one row per (cell, step) over every trial of the cell.

        A folder written before that table existed gets the same columns computed from the
        traced trials of steps.csv instead (:attr:`steps_summary_covers_every_trial` is then
        False, and a figure should say "traced trials"), so figures have one drawing path.
        """
        if (self.path / "steps_summary.csv").exists():
            return self.table("steps_summary")
        return self._steps_summary_from_traces()

    @property
    def steps_summary_covers_every_trial(self) -> bool:
        """True when :attr:`steps_summary` is the run's own table, False when derived from steps.csv."""
        return (self.path / "steps_summary.csv").exists()

    @property
    def state_names(self) -> list[str]:
        """The model's state components in order (from the manifest's units, else steps.csv)."""
        names = [key.removeprefix("state_") for key in self.units if key.startswith("state_")]
        return names or [c.removeprefix("truth_") for c in self.steps.columns if c.startswith("truth_")]

    def state_error(self, frame: pd.DataFrame, state: str) -> np.ndarray:
        """estimate - truth of one state component in rows of steps.csv; an angle's (the
        manifest's ``angular_states``) wrapped into half a turn either side, as
        :func:`pfx.metrics.state_error` does."""
        import numpy as np

        from pfx.angles import wrap_difference

        with np.errstate(over="ignore", invalid="ignore"):
            error = (frame[f"estimate_{state}"] - frame[f"truth_{state}"]).to_numpy(dtype=float)
        if state in self.manifest.get("angular_states", []):
            return wrap_difference(error, self.manifest["full_turn"])
        return error

    def _steps_summary_from_traces(self) -> pd.DataFrame:
        """steps_summary.csv's table computed from the traced trials in steps.csv (older folders).

        Each cell's traces become (trials, steps) arrays of the per-step values, summarised by
        the very function the run uses (:func:`pfx.step_summary.summarize_steps`).
        """
        import numpy as np
        import pandas as pd

        from pfx.step_summary import QUANTITIES, summarize_steps

        steps = self.steps
        if steps.empty:
            return pd.DataFrame()
        # steps.csv starts with the cell columns (cell, labels, swept keys), then "trial".
        cell_columns = list(steps.columns[:steps.columns.get_loc("trial")])
        states = [c.removeprefix("truth_") for c in steps.columns if c.startswith("truth_")]
        summaries = []
        for _, rows in steps.groupby("cell", sort=False):
            values = {quantity: self._by_trial(rows, rows.get(quantity, np.nan))
                      for quantity in QUANTITIES}
            for state in states:
                values[f"squared_error_{state}"] = self._by_trial(rows, self.state_error(rows, state) ** 2)
            first = rows.iloc[0]
            times = rows.groupby("step")["time"].first().to_numpy(dtype=float)
            summaries.append(summarize_steps(values, states, {c: first[c] for c in cell_columns}, times))
        return pd.concat(summaries, ignore_index=True)

    @staticmethod
    def _by_trial(rows: pd.DataFrame, values) -> np.ndarray:
        """Per-step values of one cell's rows of steps.csv as an array: one row per trial, one column per step."""
        table = rows.assign(_value=values).pivot(index="trial", columns="step", values="_value")
        return table.to_numpy(dtype=float)

    @cached_property
    def summary(self) -> pd.DataFrame:
        return self.table("summary")

    @cached_property
    def particles(self) -> pd.DataFrame:
        """particles.csv: the kept particle clouds (empty if the config kept none)."""
        return self.optional_table("particles")

    @cached_property
    def scene(self) -> pd.DataFrame:
        """scene.csv: the model's fixed world (beacons, walls, path; empty if it has none)."""
        return self.optional_table("scene")

    def optional_table(self, name: str) -> pd.DataFrame:
        import pandas as pd

        return self.table(name) if (self.path / f"{name}.csv").exists() else pd.DataFrame()

    @property
    def position_states(self) -> list[str]:
        """The state columns that form the position (the first two are drawn on maps)."""
        return self.manifest.get("position_states", [])

    @cached_property
    def manifest(self) -> dict:
        return json.loads((self.path / "manifest.json").read_text())

    @property
    def units(self) -> dict:
        return self.manifest.get("units", {})

    @property
    def label_columns(self) -> list[str]:
        return self.manifest.get("label_columns", ["arm"])

    def cell_names(self, frame: pd.DataFrame) -> pd.Series:
        """A legend label per row: the arm (if several) and the swept values, joined."""
        columns = [c for c in self.manifest.get("legend_columns", []) if c in frame]
        if not columns:
            columns = ["arm"]
        if columns == ["arm"]:
            return frame["arm"].astype(str)
        parts = [(c + "=") + frame[c].astype(str) if c != "arm" else frame[c].astype(str) for c in columns]
        label = parts[0]
        for part in parts[1:]:
            label = label + ", " + part
        return label


def _save(figure, target: Path) -> None:
    """Write a figure (or an animation, as GIF) atomically: a temporary file, then rename."""
    descriptor, temporary = tempfile.mkstemp(dir=target.parent, prefix=".tmp-", suffix=target.suffix)
    os.close(descriptor)
    try:
        if _is_animation(figure):
            canvas = getattr(getattr(figure, "_fig", None), "canvas", None)
            if canvas is not None:
                # The writer draws every frame for the file; the animation's own screen refresh
                # after each frame (there is no screen) would draw it a second time for nothing.
                canvas.draw_idle = lambda *args, **kwargs: None
            figure.save(temporary, writer=_gif_writer(getattr(figure, "frames_per_second", 5)), dpi=90)
        else:
            figure.savefig(temporary, dpi=150, bbox_inches="tight")
        os.chmod(temporary, FILE_MODE)
        os.replace(temporary, target)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def _gif_writer(frames_per_second: float):
    """matplotlib's Pillow writer, reducing each frame to 256 colours by Pillow's fast octree.

    Pillow's default for GIF (median cut) took longer than drawing the frames; a plot's few
    flat colours come out the same either way.
    """
    from matplotlib.animation import PillowWriter
    from PIL import Image

    class FastGifWriter(PillowWriter):
        def grab_frame(self, **savefig_kwargs):
            super().grab_frame(**savefig_kwargs)
            self._frames[-1] = self._frames[-1].quantize(256, method=Image.Quantize.FASTOCTREE)

    return FastGifWriter(fps=frames_per_second)


def render_figures(result_dir: str | Path, names: Optional[list[str]] = None,
                   formats: tuple[str, ...] = ("png",)) -> list[Path]:
    """Render the named figures (default: those in the folder's manifest) from CSV; return paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    result = ResultFolder(result_dir)
    names = names if names is not None else result.manifest.get("figures", [])
    out = result.path / "figures"
    out.mkdir(exist_ok=True)
    written: list[Path] = []
    for name in names:
        figure = FIGURES[name](result)
        if figure is None:
            continue
        for extension in ("gif",) if _is_animation(figure) else formats:
            target = out / f"{name}.{extension}"
            _save(figure, target)
            written.append(target)
        plt.close("all")       # an animation's figure too
    return written


def _is_animation(figure) -> bool:
    from matplotlib.animation import Animation

    return isinstance(figure, Animation)
