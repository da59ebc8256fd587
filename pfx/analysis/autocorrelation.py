r"""How much a Markov chain's draws are worth: the integrated autocorrelation time, two ways.

For a stationary chain :math:`\theta_1, \theta_2, \dots` and a function h, the mean of n draws
has variance :math:`\tau\, \mathrm{Var}(h) / n`, with the **integrated autocorrelation time**
(the inefficiency of Pitt, Silva, Giordani & Kohn 2012 and Doucet, Pitt, Deligiannidis & Kohn
2015)

.. math::

    \tau = 1 + 2 \sum_{k \ge 1} \rho_k, \qquad \rho_k = \mathrm{corr}\big(h(\theta_0), h(\theta_k)\big),

so n correlated draws are worth :math:`n / \tau` independent ones (the effective sample size).
Two estimators of :math:`\tau` from C chains of L draws each, shaped (C, L):

* :func:`autocorrelation_time`: :math:`n / \mathrm{ESS}` with ArviZ's effective sample size of
  the mean (the ``arviz-stats`` package, which pfx's posterior.csv uses too): the chains'
  autocorrelations are summed up to the lag where Geyer's initial positive sequence turns
  negative, with the between-chain variance folded in (Vehtari et al. 2021). A sum cut off at a
  lag undercounts :math:`\tau` when the autocorrelations have a long, low tail, as those of a
  pseudo-marginal chain stuck on an overestimated likelihood do;
* :func:`batch_means_time`: each chain's mean is one batch, :math:`\hat\tau = L\,
  \widehat{\mathrm{Var}}(\bar h_c) / \widehat{\mathrm{Var}}(h)`, with no cut-off at all; for
  chains much longer than :math:`\tau` its relative bias is of the order of :math:`-\tau / L`
  (about :math:`-\tau / 2L` for autocorrelations that fall geometrically), and its relative
  standard error about :math:`\sqrt{2 / (C - 1)}`.

Their standard errors come from resampling whole chains (they are independent), from a
generator the caller seeds. :func:`inefficiency_table` applies both to every cell and parameter
of a PMMH chains table: the integrated autocorrelation time :math:`\tau` and the work per
effective draw :math:`\tau \times N` that the N-choice rule of Doucet, Pitt, Deligiannidis &
Kohn (2015) minimises.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

ESTIMATORS = ("ArviZ ESS", "batch means")


def autocorrelation_time(draws: np.ndarray) -> float:
    r""":math:`\hat\tau = C L / \mathrm{ESS}`, ArviZ's effective sample size of the mean of draws (C, L)."""
    from arviz_stats.base import array_stats

    draws = np.asarray(draws, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        ess = float(array_stats.ess(draws, method="mean", chain_axis=0, draw_axis=1))
    return draws.size / ess if ess > 0 else np.nan


def batch_means_time(draws: np.ndarray) -> float:
    r""":math:`\hat\tau = L\, \widehat{\mathrm{Var}}_c(\bar h_c) / \widehat{\mathrm{Var}}(h)`: each of
    the C chains (rows of draws (C, L)) is one batch."""
    draws = np.asarray(draws, dtype=float)
    chains, length = draws.shape
    variance = draws.var(ddof=1)
    if chains < 2 or variance == 0:
        return np.nan
    return float(length * draws.mean(axis=1).var(ddof=1) / variance)


def chain_array(rows: pd.DataFrame, column: str) -> np.ndarray:
    """The draws of ``column`` in a chains table's rows as (chains, draws), in iteration order,
    every chain cut to the shortest."""
    series = [group.sort_values("iteration")[column].to_numpy(dtype=float) for _, group in rows.groupby("chain")]
    length = min(len(values) for values in series)
    return np.stack([values[:length] for values in series])


def inefficiency_table(draws: pd.DataFrame, parameters: list[str], groups: list[str],
                       generator: np.random.Generator, replicates: int = 100) -> tuple[pd.DataFrame, pd.DataFrame]:
    r"""Both estimators for every cell and parameter of ``draws`` (a chains table's rows after the
    warm-up; its cells are the groups of the columns ``groups``, the last of them ``n_particles``).

    Returns ``(table, resampled)``. ``table`` has one row per (cell, parameter, estimator):
    ``tau``, its bootstrap standard error ``tau_se``, the work per effective draw ``cost`` =
    :math:`\tau \times N` and ``cost_se``. ``resampled`` holds every bootstrap replicate's
    ``tau`` (column ``replicate``): within a replicate, one resample of a cell's chains serves all
    its parameters and both estimators, so statistics across them (which N is cheapest) can be
    bootstrapped too.
    """
    import pandas as pd

    estimators = dict(zip(ESTIMATORS, (autocorrelation_time, batch_means_time)))
    rows, resampled = [], []
    for keys, cell in draws.groupby(groups, sort=True):
        keys = keys if isinstance(keys, tuple) else (keys,)
        labels = dict(zip(groups, keys))
        n = int(keys[-1])
        arrays = {parameter: chain_array(cell, parameter) for parameter in parameters}
        chains = next(iter(arrays.values())).shape[0]
        picks = [generator.integers(0, chains, chains) for _ in range(replicates)]
        for parameter, values in arrays.items():
            for name, estimator in estimators.items():
                taus = [estimator(values[pick]) for pick in picks]
                resampled += [{**labels, "parameter": parameter, "estimator": name, "replicate": index, "tau": tau}
                              for index, tau in enumerate(taus)]
                tau = estimator(values)
                se = float(np.nanstd(taus, ddof=1)) if replicates > 1 else np.nan
                rows.append({**labels, "parameter": parameter, "estimator": name, "chains": values.shape[0],
                             "draws": values.shape[1], "tau": tau, "tau_se": se, "cost": tau * n, "cost_se": se * n})
    return pd.DataFrame(rows), pd.DataFrame(resampled)


def mean_over_parameters(table: pd.DataFrame, resampled: pd.DataFrame, groups: list[str]) -> pd.DataFrame:
    r"""The work per effective draw averaged over the parameters, per cell (the columns ``groups``,
    the last ``n_particles``) and estimator: ``tau`` and ``cost`` (:math:`\tau \times N`) of
    :func:`inefficiency_table`'s table, and ``cost_se``, the sd of the same average over the
    bootstrap replicates (one resample of the cell's chains for every parameter)."""
    keys = [*groups, "estimator"]
    mean = table.groupby(keys, sort=True)[["tau", "cost"]].mean()
    replicate = resampled.assign(cost=resampled["tau"] * resampled[groups[-1]])
    spread = replicate.groupby([*keys, "replicate"])["cost"].mean().groupby(keys).std(ddof=1)
    return mean.assign(cost_se=spread).reset_index()
