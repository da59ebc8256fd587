"""The figure registry and rendering (a figure reads a :class:`~pfx.result_folder.ResultFolder`).

A figure function returns a matplotlib Figure (saved in the config's formats), a
``matplotlib.animation.Animation`` (saved as an animated GIF with matplotlib's Pillow writer;
an attribute ``frames_per_second`` on it sets the frame rate), or None when the folder has
nothing for it to draw.

A figure drawn from tables that a kind of folder does not write does not apply to it: a filter
run's ``ess_over_time`` (steps_summary.csv) to an estimation folder (chains.csv), or
``chain_traces`` to a filter run's folder. Such a figure is refused in one line naming it and
why (:func:`applicability`), before anything is drawn: asked of a folder (``pfx figures``,
:func:`render_figures`) or named in a config (:func:`refusal_in_config`). The estimation
figures declare their tables (:func:`draws_from`); pfx's other figures draw a filter run's or a
study's tables, never an estimation folder's. A figure that reads a table its folder lacks
(:class:`~pfx.result_folder.MissingTable`, a plugin's figure say) is refused the same way when
drawn.

A figure that draws what only one config key writes declares that key (:func:`asks_for`:
``forecast_fan`` draws forecasts.csv, which ``outputs.forecasts`` writes; the score figures,
``metrics.scores``'s columns). A config that names the figure without the key would get no
figure and no word: it is refused by :func:`refusal_in_config` instead. A filter run's figure
that an estimation folder can draw too declares the tables it reads there
(:func:`draws_on_estimation_from`: ``forecast_fan``, the posterior predictive forecasts of
forecasts.csv after PMMH).

A figure drawn from the true states (estimate - truth) declares so (:func:`draws_truth`).
Recorded data without ``data.truth`` have no true states: such a figure is refused in one
line, in a config (the plan passes :data:`NO_TRUTH` among ``asked``) and asked of a folder
(:func:`truth_refusal`). A figure that has something to show without the truth draws that
instead (``trajectory_map`` draws the estimated path alone) and does not declare it.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, Collection, Optional

from pfx.errors import ConfigError
from pfx.registry import Registry
from pfx.result_folder import ESTIMATION_TABLES, FILE_MODE, MissingTable, ResultFolder, estimation_kind

FIGURES: Registry[Callable] = Registry("figure")
# A member of refusal_in_config's ``asked``: the config's recorded data come without data.truth.
NO_TRUTH = "no data.truth"


def draws_from(*tables: str) -> Callable[[Callable], Callable]:
    """Decorator: the tables (names without ``.csv``) a figure cannot be drawn without."""
    def declare(figure: Callable) -> Callable:
        figure.tables = tables
        return figure
    return declare


def asks_for(key: str) -> Callable[[Callable], Callable]:
    """Decorator: the config key (``outputs.forecasts``, ``metrics.scores``) without which the
    figure has nothing to draw."""
    def declare(figure: Callable) -> Callable:
        figure.asks_for = key
        return figure
    return declare


def draws_on_estimation_from(*tables: str) -> Callable[[Callable], Callable]:
    """Decorator: a filter run's figure that an estimation folder holding ``tables`` (names
    without ``.csv``) can draw too."""
    def declare(figure: Callable) -> Callable:
        figure.estimation_tables = tables
        return figure
    return declare


def draws_truth(figure: Callable) -> Callable:
    """Decorator: the figure draws the true states, so recorded data without ``data.truth`` have
    nothing for it (module docstring)."""
    figure.draws_truth = True
    return figure


def _without_truth(name: str) -> str:
    return (f"figure {name} draws the true states (estimate - truth), and recorded data without data.truth have "
            "none: add data.truth, or drop the figure (filtered_over_data draws the estimates over the data)")


def truth_refusal(name: str, result: ResultFolder) -> Optional[str]:
    """Why figure ``name`` cannot be drawn from ``result``: it draws the true states, and the
    folder's recorded data had none (no finite ``rms_error_<state>`` in steps_summary.csv);
    None if it may."""
    if not getattr(FIGURES[name], "draws_truth", False) or not result.recorded_data:
        return None
    if not {"steps_summary", "steps"} & result.tables:
        return None                    # drawing it says which table is missing
    summary = result.steps_summary
    errors = [column for column in summary.columns if column.startswith("rms_error_")]
    return None if summary[errors].notna().to_numpy().any() else _without_truth(name)


def applicability(name: str, tables: set[str], kind: str, estimation: bool) -> Optional[str]:
    """Why figure ``name`` does not apply to a folder holding ``tables``, ``kind`` in words
    (:attr:`ResultFolder.kind`), an estimation folder or not; None if it may (module docstring)."""
    figure = FIGURES[name]
    needed = getattr(figure, "tables", None)
    if needed is not None:
        missing = [table for table in needed if table not in tables]
        if missing:
            return (f"figure {name} draws {', '.join(table + '.csv' for table in missing)}, which {kind} does not "
                    f"have: it is {_kind_of_tables(needed)}'s figure")
    elif estimation and hasattr(figure, "estimation_tables"):
        missing = [table for table in figure.estimation_tables if table not in tables]
        if missing:
            key = getattr(figure, "asks_for", None)
            return (f"figure {name} draws {', '.join(table + '.csv' for table in missing)}, which {kind} does not "
                    f"have" + (f" ({key} writes it)" if key else ""))
    elif estimation and FIGURES.origin(name) is None:
        return (f"figure {name} draws a filter run's (or a study's) tables, and {kind} has "
                f"{', '.join(sorted(table + '.csv' for table in tables))} instead")
    return None


def _kind_of_tables(tables) -> str:
    for method, written in ESTIMATION_TABLES.items():
        if set(tables) <= set(written):
            return estimation_kind(method)
    if set(tables) <= {"simulations"}:
        return "a `pfx simulate` folder"
    return "another kind of folder"


def refusal_in_config(name: str, estimation_method: Optional[str], asked: Collection[str] = ()) -> Optional[str]:
    """Why a config's figure ``name`` would not apply to the folder the config makes (an
    estimation method's, or a filter run's), or would draw nothing: it asks for a key
    (:func:`asks_for`) that is not among the config's ``asked``, or it draws the true states
    (:func:`draws_truth`) and ``asked`` holds :data:`NO_TRUTH`; None if it may."""
    if estimation_method is None:
        reason = applicability(name, set(), "a filter run's folder", estimation=False)
    else:
        # with the tables the figure reads there, which its key (asks_for, below) writes
        written = set(getattr(FIGURES[name], "estimation_tables", ()))
        reason = applicability(name, set(ESTIMATION_TABLES[estimation_method]) | written,
                               estimation_kind(estimation_method), estimation=True)
    key = getattr(FIGURES[name], "asks_for", None)
    if reason is None and key is not None and key not in asked:
        reason = f"figure {name} draws what {key} writes, and this config does not ask for it: add {key}, or drop the figure"
    if reason is None and getattr(FIGURES[name], "draws_truth", False) and NO_TRUTH in asked:
        reason = _without_truth(name)
    return reason


def figure_table() -> str:
    """The figure table of ``docs/figures.md``, from the registry: one row per figure, its
    docstring's summary line and, if it has one, its second paragraph (the details a reader
    needs: which study or output it draws, what it needs). A test keeps the page current."""
    import inspect

    rows = ["| figure | shows |", "| --- | --- |"]
    for name in FIGURES:
        paragraphs = inspect.cleandoc(FIGURES[name].__doc__ or "").split("\n\n")
        text = " ".join(" ".join(paragraph.split()) for paragraph in paragraphs[:2])
        rows.append(f"| `{name}` | " + text.replace("|", "\\|") + " |")
    return "\n".join(rows)


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
    result = ResultFolder(result_dir)
    names = names if names is not None else result.manifest.get("figures", [])
    tables = result.tables
    for name in names:                     # every refusal before anything is drawn
        reason = applicability(name, tables, result.kind, result.is_estimation) or truth_refusal(name, result)
        if reason:
            raise ConfigError(f"{reason}; `pfx list figures` says what each figure draws", file=str(result.path))
    out = result.path / "figures"
    out.mkdir(exist_ok=True)
    written: list[Path] = []
    for name in names:
        pyplot = _file_pyplot()
        try:
            figure = FIGURES[name](result)
        except MissingTable as missing:
            raise ConfigError(f"figure {name} draws {missing.name}.csv, which {result.kind} does not have; "
                              "`pfx list figures` says what each figure draws", file=str(result.path)) from None
        if figure is None:
            continue
        for extension in ("gif",) if _is_animation(figure) else formats:
            target = out / f"{name}.{extension}"
            _save(figure, target)
            written.append(target)
        pyplot.close("all")    # an animation's figure too
    return written


def _file_pyplot():
    """matplotlib.pyplot drawing into files (the Agg backend, no window), imported only when a
    figure is drawn: importing matplotlib costs every command that draws none, ``pfx run`` of a
    config without figures included, about half a second."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot

    return matplotlib.pyplot


def _is_animation(figure) -> bool:
    from matplotlib.animation import Animation

    return isinstance(figure, Animation)
