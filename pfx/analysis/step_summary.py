r"""Per-step summaries over every trial of a cell: ``steps_summary.csv``.

``steps.csv`` keeps the full traces of a few trials; figures of a quantity over time need all
of them. For every cell and step, over the cell's :math:`n` trials, this table holds

* ``trials`` (:math:`n`), and for each of ``error_distance``, ``ess``, ``nees`` and ``nis``:
  ``<q>_mean`` :math:`\bar q_k = \tfrac1n \sum_r q_{k,r}`, ``<q>_std`` (sample standard deviation)
  and the 95% t-interval of the mean ``<q>_ci95_low``/``_high``
  (:math:`\bar q_k \pm t_{0.975,n-1}\, s_k/\sqrt n`), cut at zero, since all four are
  nonnegative, and empty from fewer than 6 values (as in summary.csv: :mod:`pfx.analysis.summary`);
* for ``nees`` and ``nis`` also ``<q>_n``: the trials that have a value at that step, over which
  their mean, standard deviation and interval are taken. A NEES needs a covariance that can be
  inverted reliably (:mod:`pfx.numerics.quadratic_forms`: a particle cloud collapsed onto a
  few particles has none) and the truth; a NIS needs a measurement. ``trials - nees_n`` is the
  number of trials left out at that step;
* ``rms_error_<state>`` for every state component:
  :math:`\sqrt{\tfrac1n \sum_r (\hat x_{k,r} - x_{k,r})^2}` (angles wrapped); and
  ``rms_error_<smoother>_<state>``, the same of each smoother's mean (``filter.smoothers``);
* last, for the log-likelihood increment :math:`L_k = \log \hat p(z_k \mid z_{1:k-1})`
  (:mod:`pfx.filters.trace`), ``log_likelihood_increment_mean``, ``_std``, ``_ci95_low`` and
  ``_ci95_high`` as above, not cut (an increment takes any sign); empty for a filter kind that
  does not record it.

Every statistic is one a run extended with more trials can update without the old trials'
traces: counts add, and means and squared deviations merge exactly in exact arithmetic (Chan,
Golub and LeVeque's pairwise update), so a summary extended from n to n' trials equals a fresh
run's to rounding (about 1e-15 relative); a fresh run computes it from every trial's values at
once, the same whatever the batching. A diverged trial makes its cell's mean infinite at that
step: it is not hidden. ``nees`` and ``nis`` are empty where the filter records no covariance.
"""

from __future__ import annotations

import numpy as np

from pfx.analysis.summary import MINIMUM_VALUES, cut_to_range, t_quantile
from pfx.analysis.value_ranges import ANY_VALUE, NONNEGATIVE, ValueRange

QUANTITIES = ("error_distance", "ess", "nees", "nis")
# quantities of any sign, summarised like the others but after the rms_error_* columns (a
# column added later goes last) and with intervals that are not cut at zero
SIGNED_QUANTITIES = ("log_likelihood_increment",)
# the quantities a trial may have no value of at a step: counted in <q>_n (module docstring)
COUNTED = ("nees", "nis")
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
                  "nis": np.asarray(trace.nis, dtype=float) if trace.nis is not None else missing,
                  "log_likelihood_increment": (np.asarray(trace.log_likelihood_increments, dtype=float)
                                               if trace.log_likelihood_increments is not None else missing)}
        for j, name in enumerate(model.state_names):
            values[f"squared_error_{name}"] = errors[..., j] ** 2
        for label, smoothed in trace.smoothed.items():          # each smoother's errors too
            smoothed_errors = state_error(truth, smoothed.means, model)
            for j, name in enumerate(model.state_names):
                values[f"squared_error_{label}_{name}"] = smoothed_errors[..., j] ** 2
    return values


def summarize_steps(values: dict[str, np.ndarray], state_names, labels: dict, times: np.ndarray):
    """The summary rows of one cell from every trial's values (``step_values``, trials stacked)."""
    import pandas as pd

    trials, steps = values["error_distance"].shape
    columns: dict = {**labels, "step": np.arange(1, steps + 1), "time": times, "trials": trials}
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for quantity in QUANTITIES:
            data = values[quantity]
            if quantity in COUNTED:
                # the trials with a value at each step; all of them: the same operations as below
                present = ~np.isnan(data)
                n = present.sum(axis=0)
                mean = np.where(present, data, 0.0).sum(axis=0) / n
                deviations = np.where(present, data - mean, 0.0)
                std = np.where(n >= 2, np.sqrt((deviations * deviations).sum(axis=0) / (n - 1)), np.nan)
            else:
                n = trials
                mean = data.mean(axis=0)
                std = data.std(axis=0, ddof=1) if trials >= 2 else np.full(steps, np.nan)
            columns.update(_interval(quantity, mean, std, n))
            if quantity in COUNTED:
                columns[f"{quantity}_n"] = n
        for name in state_names:
            columns[f"rms_error_{name}"] = np.sqrt(values[f"squared_error_{name}"].mean(axis=0))
        smoothed = [key.removeprefix("squared_error_") for key in values
                    if key.startswith("squared_error_") and key.removeprefix("squared_error_") not in state_names]
        for name in smoothed:                     # <smoother>_<state>, in the order the run made them
            columns[f"rms_error_{name}"] = np.sqrt(values[f"squared_error_{name}"].mean(axis=0))
        for quantity in SIGNED_QUANTITIES:
            data = values.get(quantity, np.full((trials, steps), np.nan))   # a table from older traces
            std = data.std(axis=0, ddof=1) if trials >= 2 else np.full(steps, np.nan)
            columns.update(_interval(quantity, data.mean(axis=0), std, trials, ANY_VALUE))
    return pd.DataFrame(columns)


def _interval(quantity: str, mean: np.ndarray, std: np.ndarray, trials,
              value_range: ValueRange = NONNEGATIVE) -> dict[str, np.ndarray]:
    """mean, std and the 95% t-interval of the mean (cut to ``value_range``, by default at zero;
    empty below MINIMUM_VALUES)."""
    enough = np.asarray(trials) >= MINIMUM_VALUES
    quantile = np.where(enough, t_quantile(0.975, np.maximum(trials, 2) - 1), np.nan)
    half = quantile * std / np.sqrt(trials)
    low, high = cut_to_range(mean - half, mean + half, value_range)
    return {f"{quantity}_mean": mean, f"{quantity}_std": std,
            f"{quantity}_ci95_low": low, f"{quantity}_ci95_high": high}


def merge_step_summaries(first, second):
    """One cell's summary over the trials of both (rows matched by step), as if computed at once.

    Counts add; means combine weighted by the counts of values (``trials``, or ``<q>_n`` for
    the counted quantities); squared deviations by the pairwise update
    M2 = M2_a + M2_b + delta^2 n_a n_b / n, with M2 = std^2 (n - 1).
    """
    first = first.reset_index(drop=True)
    second = second.reset_index(drop=True)
    for quantity in SIGNED_QUANTITIES:       # a table written before the quantity existed: unknown there
        for table in (first, second):
            for statistic in STATISTICS:
                if f"{quantity}_{statistic}" not in table:
                    table[f"{quantity}_{statistic}"] = np.nan
    merged = first.copy()
    n_a, n_b = int(first["trials"].iloc[0]), int(second["trials"].iloc[0])
    n = n_a + n_b
    merged["trials"] = n
    with np.errstate(over="ignore", invalid="ignore"):
        for quantity in (*QUANTITIES, *SIGNED_QUANTITIES):
            mean_a = first[f"{quantity}_mean"].to_numpy(dtype=float)
            mean_b = second[f"{quantity}_mean"].to_numpy(dtype=float)
            if quantity in COUNTED:
                count_a, count_b = _values_counted(first, quantity), _values_counted(second, quantity)
            else:
                count_a, count_b = np.full(len(first), n_a), np.full(len(second), n_b)
            count = count_a + count_b
            delta = mean_b - mean_a
            both = (count_a > 0) & (count_b > 0)
            mean = np.where(count_a == 0, mean_b, np.where(count_b == 0, mean_a, mean_a + delta * count_b / count))
            squares = (_squared_deviations(first[f"{quantity}_std"], count_a)
                       + _squared_deviations(second[f"{quantity}_std"], count_b)
                       + np.where(both, delta ** 2 * count_a * count_b / count, 0.0))
            std = np.where(count >= 2, np.sqrt(squares / (count - 1)), np.nan)
            value_range = ANY_VALUE if quantity in SIGNED_QUANTITIES else NONNEGATIVE
            for name, column in _interval(quantity, mean, std, count if quantity in COUNTED else n,
                                          value_range).items():
                merged[name] = column
            if quantity in COUNTED:
                merged[f"{quantity}_n"] = count
        for column in [c for c in first.columns if c.startswith("rms_error_")]:
            squares = (n_a * first[column].to_numpy(dtype=float) ** 2
                       + n_b * second[column].to_numpy(dtype=float) ** 2)
            merged[column] = np.sqrt(squares / n)
    return merged[_column_order(merged)]


def _values_counted(summary, quantity: str) -> np.ndarray:
    """``<q>_n`` per step; a table written before that column existed counted every trial
    wherever the mean has a value."""
    if f"{quantity}_n" in summary:
        return summary[f"{quantity}_n"].to_numpy(dtype=int)
    trials = int(summary["trials"].iloc[0])
    return np.where(summary[f"{quantity}_mean"].notna().to_numpy(), trials, 0)


def _column_order(summary) -> list[str]:
    """``<q>_n`` after ``<q>_ci95_high``, as :func:`summarize_steps` writes it (a table written
    before that column existed gets it there)."""
    signed = [f"{quantity}_{statistic}" for quantity in SIGNED_QUANTITIES for statistic in STATISTICS]
    columns = [c for c in summary.columns if not (c.endswith("_n") and c[:-2] in COUNTED) and c not in signed]
    for quantity in COUNTED:
        columns.insert(columns.index(f"{quantity}_ci95_high") + 1, f"{quantity}_n")
    return columns + signed


def _squared_deviations(std, counts: np.ndarray) -> np.ndarray:
    """M2 = std^2 (n - 1) per step: zero where fewer than two values (whose std is empty)."""
    return np.where(counts >= 2, std.to_numpy(dtype=float) ** 2 * (counts - 1), 0.0)
