"""Figures, drawn from the CSV files of a result folder only (never by rerunning).

Each figure is a function ``figure(result: ResultFolder) -> matplotlib Figure | None``
registered under the name configs use in ``outputs.figures``. To add one, write the function
in a module here and register it; ``pfx figures RESULT_DIR`` re-renders every figure the
folder's config asks for.
"""

from pfx.figures.registry import FIGURES, render_figures
from pfx.figures import maps, motion, resampling, sweeps, traces  # noqa: F401  (registers the figures)

__all__ = ["FIGURES", "render_figures"]
