"""Figures, drawn from the CSV files of a result folder only (never by rerunning).

Each figure is a function ``figure(result: ResultFolder) -> matplotlib Figure | None``
registered under the name configs use in ``outputs.figures``. To add one, write the function
in a module here and register it; ``pfx figures RESULT_DIR`` re-renders every figure the
folder's config asks for.
"""

from pfx.figures.registry import FIGURES, render_figures
# One import per figure module (each registers its figures).
from pfx.figures import arena  # noqa: F401
from pfx.figures import closeups  # noqa: F401
from pfx.figures import concept  # noqa: F401
from pfx.figures import degeneracy  # noqa: F401
from pfx.figures import mahalanobis  # noqa: F401
from pfx.figures import maps  # noqa: F401
from pfx.figures import motion  # noqa: F401
from pfx.figures import resampling  # noqa: F401
from pfx.figures import sampling  # noqa: F401
from pfx.figures import state_errors  # noqa: F401
from pfx.figures import sweeps  # noqa: F401
from pfx.figures import textbook  # noqa: F401
from pfx.figures import traces  # noqa: F401

__all__ = ["FIGURES", "render_figures"]
