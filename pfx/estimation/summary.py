"""The posterior's summary from PMMH chains, and the prior densities the figures draw beside it.

posterior.csv has one row per (cell, parameter), from the draws after the warm-up, pooled over
the chains: mean, sd, quantiles, and ArviZ's convergence diagnostics (the ``arviz-stats``
package, the computations of ArviZ on plain arrays): the rank-normalised split R-hat (Vehtari
et al. 2021; below 1.01 when the chains agree), the bulk and tail effective sample sizes and the
Monte Carlo standard error of the mean. ``acceptance_rate`` is the share of accepted proposals
after the warm-up. ``flag`` names the checks of Vehtari et al. (2021) a row fails (R-hat above
1.01, a bulk or tail ESS under 100 per chain: :mod:`pfx.analysis.estimation_flags`, where the
thresholds are), empty when it passes.

For a flagged cell whose filter has particles, :func:`spread_at_posterior_mean` measures the sd
of the log-likelihood estimate at the posterior mean (likelihood_spread.csv): above 2, the
particles are the first thing to change. It runs only for such a cell, on streams of its own,
so an unflagged run costs nothing more and no chain's numbers depend on it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from arviz_stats.base import array_stats

from pfx.analysis.estimation_flags import SPREAD_RUNS, posterior_flag, too_few_draws
from pfx.config.estimation_tables import (
    DIAGNOSTICS,
    LIKELIHOOD_SPREAD,
    POSTERIOR_COLUMNS,
    POSTERIOR_EXTRA_ROWS,
    PRIORS_COLUMNS,
    QUANTILES,
)
from pfx.estimation.likelihood_spread import log_likelihood_spread
from pfx.estimation.target import EstimationTarget

GRID_POINTS = 200


def posterior_summary(rows: pd.DataFrame, columns: list[str], warm_up: int) -> pd.DataFrame:
    """One row per parameter (and the log-likelihood) from a cell's chains table ``rows``; the
    columns of :data:`pfx.config.estimation_tables.POSTERIOR_COLUMNS`."""
    draws = rows[rows["iteration"] > warm_up].sort_values(["chain", "iteration"])
    chains = draws["chain"].nunique()
    length = draws.groupby("chain").size().min()
    summary = []
    for name in [*columns, *POSTERIOR_EXTRA_ROWS]:
        values = np.stack([group[name].to_numpy(dtype=float)[:length] for _, group in draws.groupby("chain")])
        pooled = values.ravel()
        row = {"parameter": name, "n": pooled.size, "mean": pooled.mean(), "sd": pooled.std(ddof=1) if pooled.size > 1
               else np.nan, **{key: np.quantile(pooled, q) for key, q in QUANTILES.items()}}
        row.update(_diagnostics(values))
        row["acceptance_rate"] = float(draws["accepted"].astype(bool).mean())
        row["chains"] = chains
        row["flag"] = posterior_flag(row["r_hat"], row["ess_bulk"], row["ess_tail"], chains, length)
        summary.append(row)
    return pd.DataFrame(summary)[list(POSTERIOR_COLUMNS)]


def _diagnostics(values: np.ndarray) -> dict:
    """R-hat, bulk and tail ESS, MCSE of the mean for draws (chains, draws); NaN where too few."""
    if too_few_draws(values.shape[1]):
        return dict.fromkeys(DIAGNOSTICS, np.nan)
    options = {"chain_axis": 0, "draw_axis": 1}
    with np.errstate(invalid="ignore", divide="ignore"):
        return {"r_hat": float(array_stats.rhat(values, **options)),
                "ess_bulk": float(array_stats.ess(values, method="bulk", **options)),
                # the tail ESS: the smaller of the 5% and 95% quantiles' (Vehtari et al. 2021),
                # spelled out, since arviz-stats' "tail" method changed its arguments across versions
                "ess_tail": float(min(array_stats.ess(values, method="quantile", prob=prob, **options)
                                      for prob in (0.05, 0.95))),
                "mcse_mean": float(array_stats.mcse(values, method="mean", **options))}


def spread_at_posterior_mean(target: EstimationTarget, summary: pd.DataFrame, root_seed: int) -> pd.DataFrame | None:
    """likelihood_spread.csv's row (the cell's columns aside) for a cell whose posterior.csv rows
    ``summary`` are flagged on draws enough to judge, and whose filter has particles: the sd of
    the log-likelihood estimate over SPREAD_RUNS runs at the posterior mean, N the cell's own
    (:func:`pfx.estimation.likelihood_spread.log_likelihood_spread`). None for any other cell."""
    flagged = summary["flag"].astype(str) != ""
    draws_per_chain = int(summary["n"].iloc[0]) // int(summary["chains"].iloc[0])
    if not flagged.any() or too_few_draws(draws_per_chain) or not target.cell.filter.uses_particles:
        return None
    means = summary.set_index("parameter")["mean"]
    point = np.array([means[name] for name in target.columns], dtype=float)
    spread = log_likelihood_spread(target, point, target.cell.filter.particles, SPREAD_RUNS, root_seed)
    row = {**dict(zip(target.columns, point)), **spread.columns()}
    return pd.DataFrame([row])[LIKELIHOOD_SPREAD.progress_columns(list(target.columns))]


def prior_grid(estimation, draws: pd.DataFrame) -> pd.DataFrame:
    """priors.csv: each parameter's prior density (``estimation``: the config's section) on
    GRID_POINTS points spanning its draws (widened by a quarter of their range each side, clipped
    to the prior's support)."""
    frames = []
    for name, parameter in zip(estimation.columns, estimation.parameters.values()):
        prior = parameter.prior
        values = draws[name].to_numpy(dtype=float) if name in draws else np.array([])
        if values.size == 0:
            continue
        low, high = values.min(), values.max()
        margin = 0.25 * (high - low) if high > low else 0.1 * abs(low) + 1e-9
        lower, upper = prior.support
        grid = np.linspace(max(low - margin, lower), min(high + margin, upper), GRID_POINTS)
        frames.append(pd.DataFrame({"parameter": name, "value": grid, "density": np.exp(prior.log_density(grid))}))
    return pd.concat(frames, ignore_index=True)[list(PRIORS_COLUMNS)] if frames else pd.DataFrame(columns=list(PRIORS_COLUMNS))
