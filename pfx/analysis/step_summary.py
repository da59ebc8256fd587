r"""Per-step summaries over every trial of a cell: ``steps_summary.csv``.

``steps.csv`` keeps the full traces of a few trials; figures of a quantity over time need all
of them. For every cell and step, over the cell's :math:`n` trials, this table holds

* ``trials`` (:math:`n`), and for each of ``error_distance``, ``ess``, ``nees`` and ``nis``:
  ``<q>_mean`` :math:`\bar q_k = \tfrac1n \sum_r q_{k,r}`, ``<q>_std`` (sample standard deviation)
  and the 95% t-interval of the mean ``<q>_ci95_low``/``_high``
  (:math:`\bar q_k \pm t_{0.975,n-1}\, s_k/\sqrt n`);
* ``rms_error_<state>`` for every state component:
  :math:`\sqrt{\tfrac1n \sum_r (\hat x_{k,r} - x_{k,r})^2}` (angles wrapped).

Every statistic is one a run extended with more trials can update without the old trials'
traces: means and squared deviations merge exactly in exact arithmetic (Chan, Golub and LeVeque's
pairwise update), so a summary extended from n to n' trials equals a fresh run's to rounding
(about 1e-15 relative); a fresh run computes it from every trial's values at once, the same
whatever the batching. A diverged trial makes its cell's mean infinite at that step: it is not
hidden. ``nees`` and ``nis`` are empty where the filter records no covariance.
"""

from __future__ import annotations

import numpy as np

QUANTITIES = ("error_distance", "ess", "nees", "nis")
STATISTICS = ("mean", "std", "ci95_low", "ci95_high")


def step_values(truth, trace, model) -> dict[str, np.ndarray]:
    """The per-trial, per-step values this table summarises: name -> (trials, T) array.

    ``squared_error_<state>`` holds the squared error of each state component. Without the
    truth (recorded data that has none: ``truth`` None) the errors and NEES are NaN.
    """
    from pfx.analysis.metrics import error_distance, normalised_squares, state_error

    trials, steps = trace.estimates.shape[:2]
    missing = np.full((trials, steps), np.nan)
    if truth is None:
        truth = np.full(trace.estimates.shape, np.nan)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        errors = state_error(truth, trace.estimates, model)
        values = {"error_distance": error_distance(truth, trace.estimates, model),
                  "ess": np.asarray(trace.ess, dtype=float),
                  "nees": (normalised_squares(errors, trace.covariances)
                           if trace.covariances is not None else missing),
                  "nis": np.asarray(trace.nis, dtype=float) if trace.nis is not None else missing}
        for j, name in enumerate(model.state_names):
            values[f"squared_error_{name}"] = errors[..., j] ** 2
    return values


def _t_quantile(trials: int) -> float:
    from scipy import stats

    return float(stats.t.ppf(0.975, trials - 1)) if trials >= 2 else np.nan


def summarize_steps(values: dict[str, np.ndarray], state_names, labels: dict, times: np.ndarray):
    """The summary rows of one cell from every trial's values (``step_values``, trials stacked)."""
    import pandas as pd

    trials, steps = values["error_distance"].shape
    columns: dict = {**labels, "step": np.arange(1, steps + 1), "time": times, "trials": trials}
    with np.errstate(over="ignore", invalid="ignore"):
        for quantity in QUANTITIES:
            data = values[quantity]
            mean = data.mean(axis=0)
            std = data.std(axis=0, ddof=1) if trials >= 2 else np.full(steps, np.nan)
            columns.update(_interval(quantity, mean, std, trials))
        for name in state_names:
            columns[f"rms_error_{name}"] = np.sqrt(values[f"squared_error_{name}"].mean(axis=0))
    return pd.DataFrame(columns)


def _interval(quantity: str, mean: np.ndarray, std: np.ndarray, trials: int) -> dict[str, np.ndarray]:
    half = _t_quantile(trials) * std / np.sqrt(trials)
    return {f"{quantity}_mean": mean, f"{quantity}_std": std,
            f"{quantity}_ci95_low": mean - half, f"{quantity}_ci95_high": mean + half}


def merge_step_summaries(first, second):
    """One cell's summary over the trials of both (rows matched by step), as if computed at once.

    Means combine weighted by trial counts; squared deviations by the pairwise update
    M2 = M2_a + M2_b + delta^2 n_a n_b / n, with M2 = std^2 (n - 1).
    """
    first = first.reset_index(drop=True)
    second = second.reset_index(drop=True)
    merged = first.copy()
    n_a, n_b = int(first["trials"].iloc[0]), int(second["trials"].iloc[0])
    n = n_a + n_b
    merged["trials"] = n
    with np.errstate(over="ignore", invalid="ignore"):
        for quantity in QUANTITIES:
            mean_a = first[f"{quantity}_mean"].to_numpy(dtype=float)
            mean_b = second[f"{quantity}_mean"].to_numpy(dtype=float)
            delta = mean_b - mean_a
            mean = mean_a + delta * n_b / n
            squares = (_squared_deviations(first[f"{quantity}_std"], n_a)
                       + _squared_deviations(second[f"{quantity}_std"], n_b) + delta ** 2 * n_a * n_b / n)
            for name, column in _interval(quantity, mean, np.sqrt(squares / (n - 1)), n).items():
                merged[name] = column
        for column in [c for c in first.columns if c.startswith("rms_error_")]:
            squares = (n_a * first[column].to_numpy(dtype=float) ** 2
                       + n_b * second[column].to_numpy(dtype=float) ** 2)
            merged[column] = np.sqrt(squares / n)
    return merged


def _squared_deviations(std, trials: int) -> np.ndarray:
    """M2 = std^2 (n - 1): zero for a single trial (whose std is empty)."""
    if trials < 2:
        return np.zeros(len(std))
    return std.to_numpy(dtype=float) ** 2 * (trials - 1)
