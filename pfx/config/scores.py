"""``metrics.scores`` at plan time: which cells compute the predictive scores, and what their
model must offer for them (docs/scores.md).

A filter kind says whether it computes the scores (``computes_scores``, :mod:`pfx.filters.base`):
the particle kinds and the Gaussian filters do, the grid and most plugin kinds do not, and their
score columns stay empty. So:

* a config that asks for scores where no cell computes them (a histogram-only config, or an
  estimation config, which writes no per-step table) is refused, naming the kinds that do
  (:func:`check_scores`); one where some cells do runs, and the run says in one line which
  cells leave the columns empty (:func:`scores_notes`);
* a particle filter scores a weighted sample of measurement draws, one per particle, from the
  model's ``simulate_measurement``, and weighs by its ``log_likelihood``. A model whose class
  writes its own ``log_likelihood`` (Poisson counts, say) but keeps pfx's default draws
  (h(x) plus the measurement noise) would be scored by a law other than the one the filter
  weighs by: it is refused, naming the method to add (:func:`check_measurement_draws`, for the
  forecasts too, whose quantiles and scores come from the same draws);
* on the jax backend the draws are made inside the compiled filter: a ``simulate_measurement``
  written for NumPy only is refused at plan time, naming the method
  (:func:`pfx.filters.particle.jax_support.measurement_draw_fault`), not met as JAX's error
  mid-run.

Each refusal is one :class:`~pfx.errors.ConfigError` naming the file and the key.
"""

from __future__ import annotations

from pfx.errors import ConfigError
from pfx.filters import FILTERS
from pfx.models.contract_checks import defined_by_user_code


def scores_key(experiment) -> str:
    """The key that asks for the scores: ``metrics.scores``, or its sweep's."""
    return "sweep.metrics.scores" if "metrics.scores" in experiment.sweep else "metrics.scores"


def scoring_kinds() -> list[str]:
    """The filter kinds that compute the predictive scores."""
    return [name for name in FILTERS if FILTERS[name].computes_scores]


def check_scores(cells: list, experiment, file: str) -> None:
    """Refuse scores that would not be computed, or would be computed from another law than the
    filter's (module docstring)."""
    asking = [cell for cell in cells if cell.metrics.scores]
    if not asking:
        return
    key = scores_key(experiment)
    if experiment.estimation is not None:
        raise ConfigError("an estimation run writes no per-step tables, so no scores; score a filter run at the "
                          "estimates, or, after PMMH, forecast from the posterior (outputs.forecasts with horizon 1 "
                          "gives the one-step scores; docs/forecasts.md)", file=file, key=key)
    if not any(cell.planned_filter.computes_scores for cell in asking):
        kinds = sorted({cell.filter.kind for cell in asking})
        raise ConfigError(f"no cell's filter computes the predictive scores (this config runs {', '.join(kinds)}); "
                          f"the kinds that do: {', '.join(scoring_kinds())}; drop metrics.scores or add an arm of one "
                          "of them", file=file, key=key)
    drawn = [cell for cell in asking if cell.filter.uses_particles and cell.planned_filter.computes_scores]
    check_measurement_draws(drawn, file, key, "the scores' CRPS and PIT")
    traced: set = set()
    for cell in drawn:
        if cell.filter.backend != "jax" or (type(cell.filter_model), cell.filter.precision) in traced:
            continue
        traced.add((type(cell.filter_model), cell.filter.precision))
        reason = compiled_draws_refusal(cell.filter_model, cell.filter.precision)
        if reason is not None:
            raise ConfigError(f"{reason}, or set filter.backend: numpy", file=file, key=key)


def compiled_draws_refusal(model, precision: str):
    """Why the jax backend's compiled filter cannot draw ``model``'s measurements for the scores
    (its ``simulate_measurement`` written for NumPy only), as the start of a sentence; None where
    it can."""
    from pfx.filters.particle.jax_support import measurement_draw_fault

    reason = measurement_draw_fault(model, precision)
    if reason is None:
        return None
    return (f"model {model.kind}'s simulate_measurement does not run on the jax backend ({reason}), and the scores "
            "draw from it inside the compiled filter; write it against the array namespace, xp = "
            "pfx.namespace(state), drawing from the random argument (docs/plugins.md, 'Writing a model for both "
            "backends')")


def check_measurement_draws(cells: list, file: str, key: str, what: str) -> None:
    """Refuse a cell whose filter model weighs by a ``log_likelihood`` of the user's code while
    its measurements are drawn by pfx's default ``simulate_measurement``: ``what`` (the draws'
    use, in words) would come from another law than the one the filter weighs by."""
    for cell in cells:
        reason = default_draws_refusal(cell.filter_model, what)
        if reason is not None:
            raise ConfigError(reason, file=file, key=key)


def default_draws_refusal(model, what: str):
    """Why ``model``'s measurement draws cannot serve ``what``: its class writes its own
    ``log_likelihood`` and keeps pfx's default ``simulate_measurement``; None where they can."""
    if not defined_by_user_code(model, "log_likelihood") or defined_by_user_code(model, "simulate_measurement", "measure"):
        return None
    code = getattr(type(model).log_likelihood, "__code__", None)
    where = f" (plugin {code.co_filename})" if code is not None else ""
    return (f"model {model.kind}{where} defines its own log_likelihood but not simulate_measurement: its measurements "
            "are drawn by pfx's (by default h(x) plus the measurement noise), another law than the one the filter "
            f"weighs by, so {what} would be wrong; add simulate_measurement(self, state, random) to the model, drawing "
            "z from the law log_likelihood evaluates (docs/plugins.md)")


def scores_notes(cells: list) -> list[str]:
    """What a run with scores leaves empty, in one line: the cells whose filter kind computes none."""
    silent = sorted({cell.filter.kind for cell in cells
                     if cell.metrics.scores and not cell.planned_filter.computes_scores})
    if not silent:
        return []
    return [f"metrics.scores: the {', '.join(silent)} filter computes no predictive scores, so its cells' score "
            f"columns stay empty (the kinds that compute them: {', '.join(scoring_kinds())})"]
