"""Figures, drawn from the CSV files of a result folder only (never by rerunning).

Each figure is a function ``figure(result: ResultFolder) -> matplotlib Figure | None``
registered under the name configs use in ``outputs.figures``. To add one, write the function
in a module here and register it; ``pfx figures RESULT_DIR`` re-renders every figure the
folder's config asks for.

Every command imports these modules (a config's ``outputs.figures`` is checked against the
registry's names), so they import matplotlib only inside the functions that draw: a command that
draws no figure never imports it (about half a second; ``tests/test_import_cost.py``).
:func:`~pfx.figures.registry.render_figures` selects matplotlib's file backend (Agg) before the
first figure is drawn.
"""

# One import per figure module (each registers its figures).
from pfx.figures import (
    arena,  # noqa: F401
    closeups,  # noqa: F401
    concept,  # noqa: F401
    degeneracy,  # noqa: F401
    estimation_chains,  # noqa: F401
    estimation_pairs,  # noqa: F401
    estimator_spread,  # noqa: F401
    filtered_over_data,  # noqa: F401
    forecasts,  # noqa: F401
    if2,  # noqa: F401
    log_likelihood,  # noqa: F401
    mahalanobis,  # noqa: F401
    maps,  # noqa: F401
    motion,  # noqa: F401
    particle_count,  # noqa: F401
    pmmh_efficiency,  # noqa: F401
    predictions_over_data,  # noqa: F401
    profile,  # noqa: F401
    resampling,  # noqa: F401
    sampling,  # noqa: F401
    scores,  # noqa: F401
    simulations_over_data,  # noqa: F401
    smoothing,  # noqa: F401
    state_errors,  # noqa: F401
    sweeps,  # noqa: F401
    textbook,  # noqa: F401
    traces,  # noqa: F401
)
from pfx.figures.registry import FIGURES, render_figures

__all__ = ["FIGURES", "render_figures"]
