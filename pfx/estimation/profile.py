r"""The Monte Carlo adjusted profile (MCAP; Ionides, Breto, Park, Smith & King 2017, "Monte Carlo
profile confidence intervals for dynamic systems", J. R. Soc. Interface 14: 20170126), and a
profile run's tables.

A profile run (``estimation.method: profile``, :mod:`pfx.config.profile_settings`) gives, at
each grid value :math:`\psi_i` of the profiled parameter, several estimates :math:`\hat\ell_i`
of the profile log-likelihood (IF2 from several starts, each evaluated by particle filters).
They are noisy: IF2 may stop short of the maximum over the other parameters, and the particle
filter's log-likelihood estimate has its own error. MCAP (pomp's ``mcap``) treats them as
:math:`\hat\ell_i = \ell_p(\psi_i) + \varepsilon_i`:

1. **Smooth** the points by local quadratic regression (loess, degree 2, tricube weights, span
   :math:`\lambda`: each fit uses the :math:`\lfloor\lambda n\rfloor` points nearest the point
   of evaluation), on 1000 evenly spaced values from the grid's first to its last; the
   smoothed profile's highest value gives the estimate :math:`\hat\psi` and its maximum.
2. **Fit a quadratic near the maximum**, :math:`\hat\ell_i \approx c + b\,\psi_i - a\,\psi_i^2`,
   by weighted least squares with tricube weights :math:`(1 - (d_i/d_{max})^3)^3` of the
   distance :math:`d_i = |\psi_i - \hat\psi|`, over the points with :math:`d_i` below the
   :math:`\lfloor\lambda n\rfloor`-th smallest distance (:math:`d_{max}` the largest of these).
   Its covariance :math:`\hat\sigma^2 (X^\top W X)^{-1}` (with :math:`\hat\sigma^2` the weighted
   residual variance on the points of positive weight, as R's ``lm``) gives the Monte Carlo
   standard error of the quadratic's maximiser :math:`b / 2a` by the delta method,

   .. math::

      \mathrm{SE}_{mc}^2 = \frac{1}{4a^2}\Big(V_{bb} - \frac{2b}{a} V_{ab} + \frac{b^2}{a^2} V_{aa}\Big),
      \qquad \mathrm{SE}_{stat}^2 = \frac{1}{2a},

   the second the statistical standard error (the curvature of the log-likelihood).
3. **Adjust the cutoff**: :math:`\delta = \chi^2_1(\text{level})\,(a\,\mathrm{SE}_{mc}^2 + 1/2)`,
   which is :math:`\chi^2_1(0.95)/2 = 1.92` without Monte Carlo error and widens the interval
   so that it covers with its level in spite of that error. The interval is the range of
   values where the smoothed profile is within :math:`\delta` of its maximum.

Where three distinct grid values do not carry positive weight in a local fit (few grid values,
several starts each, a small span), its bandwidth is widened to reach the third nearest
distinct value, so that the quadratic is determined (R's loess would use a pseudo-inverse).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pfx.config.estimation_tables import PROFILE, PROFILE_INTERVAL_COLUMNS, PROFILE_SMOOTHED_COLUMNS

SMOOTHED_POINTS = 1000       # as pomp's mcap: the smoothed profile on 1000 values across the grid
WIDENING = 1.2               # a widened bandwidth reaches a little past the third distinct value


def _tricube(ratio: np.ndarray) -> np.ndarray:
    return np.where(ratio < 1, (1 - np.clip(ratio, 0, 1) ** 3) ** 3, 0.0)


def loess(x: np.ndarray, y: np.ndarray, at: np.ndarray, span: float = 0.75) -> np.ndarray:
    """Local quadratic regression of ``y`` on ``x`` evaluated at ``at`` (module docstring, step 1)."""
    x, y, at = (np.asarray(values, dtype=float) for values in (x, y, at))
    scale = np.ptp(x) or 1.0          # centred and scaled: the normal equations stay well conditioned
    nearest = max(int(np.floor(span * len(x))), 1)
    smoothed = np.empty(len(at))
    for index, point in enumerate(at):
        distance = np.abs(x - point) / scale
        bandwidth = np.sort(distance)[nearest - 1]
        distinct = np.unique(distance)
        if np.count_nonzero(distinct < bandwidth) < 3:
            bandwidth = WIDENING * distinct[min(2, len(distinct) - 1)]
        weight = np.sqrt(_tricube(distance / bandwidth))
        offset = (x - point) / scale
        design = np.stack([np.ones_like(offset), offset, offset ** 2], axis=1)
        coefficients, *_ = np.linalg.lstsq(design * weight[:, None], y * weight, rcond=None)
        smoothed[index] = coefficients[0]
    return smoothed


@dataclass
class AdjustedProfile:
    """MCAP's result: the smoothed profile, its maximum, the cutoff and the interval."""

    values: np.ndarray           # the parameter values of the smoothed profile
    smoothed: np.ndarray         # the smoothed profile log-likelihood there
    maximum: float               # the estimate: where the smoothed profile is highest
    log_likelihood_maximum: float
    cutoff: float                # delta: the interval is where the smoothed profile is within it of its maximum
    lower: float
    upper: float
    se_statistical: float
    se_monte_carlo: float
    flag: str = ""               # why the interval is missing or open at an end, empty if neither


def quadratic_near_maximum(x: np.ndarray, y: np.ndarray, maximum: float, span: float):
    """Step 2: (a, b, their covariance (2, 2)) of y ~ c + b x - a x^2, or None where the fit is
    not determined (fewer than four points of positive weight)."""
    distance = np.abs(x - maximum)
    nearest = max(int(np.floor(span * len(x))), 1)
    included = distance < np.sort(distance)[nearest - 1]
    if np.count_nonzero(included) < 2 or distance[included].max() == 0:     # all at one value: no curvature
        return None
    weight = np.zeros(len(x))
    weight[included] = _tricube(distance[included] / distance[included].max())
    positive = weight > 0
    if np.count_nonzero(positive) <= 3 or len(np.unique(x[positive])) < 3:
        return None
    design = np.stack([np.ones(len(x)), -x ** 2, x], axis=1)[positive]
    w, response = weight[positive], y[positive]
    normal = design.T @ (design * w[:, None])
    coefficients = np.linalg.solve(normal, design.T @ (w * response))
    residual_variance = float(np.sum(w * (response - design @ coefficients) ** 2) / (len(response) - 3))
    covariance = residual_variance * np.linalg.inv(normal)
    return float(coefficients[1]), float(coefficients[2]), covariance[1:, 1:]


def monte_carlo_adjusted_profile(x, y, level: float = 0.95, span: float = 0.75) -> AdjustedProfile:
    """MCAP of the profile estimates ``y`` at parameter values ``x`` (module docstring); the
    points whose log-likelihood is not finite are left out."""
    from scipy import stats

    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    finite = np.isfinite(y)
    x, y = x[finite], y[finite]
    if len(np.unique(x)) < 3:
        nothing = np.array([])
        return AdjustedProfile(nothing, nothing, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan,
                               "fewer than 3 grid values with a finite log-likelihood")
    values = np.linspace(x.min(), x.max(), SMOOTHED_POINTS)
    scale = np.ptp(x)
    smoothed = loess(x, y, values, span)
    best = int(np.argmax(smoothed))
    maximum, top = float(values[best]), float(smoothed[best])
    fit = quadratic_near_maximum(x / scale, y, maximum / scale, span)
    if fit is None or fit[0] <= 0:
        why = "too few points near the maximum for its quadratic" if fit is None else \
              "the profile is not concave near its maximum"
        return AdjustedProfile(values, smoothed, maximum, top, np.nan, np.nan, np.nan, np.nan, np.nan,
                               f"no interval: {why} (widen the grid, or add grid values or starts)")
    a, b, covariance = fit
    se_mc_squared = (covariance[1, 1] - 2 * b / a * covariance[0, 1] + b ** 2 / a ** 2 * covariance[0, 0]) / (4 * a ** 2)
    cutoff = float(stats.chi2.ppf(level, 1) * (a * se_mc_squared + 0.5))
    inside = values[top - smoothed < cutoff]
    lower, upper = float(inside.min()), float(inside.max())
    ends = [name for name, end, edge in (("lower", lower, values[0]), ("upper", upper, values[-1])) if end == edge]
    flag = f"the {' and '.join(ends)} end{'s' if len(ends) > 1 else ''} at the grid's edge: widen the grid" \
        if ends else ""
    # back to the parameter's own scale: the quadratic was fitted in units of the grid's range
    return AdjustedProfile(values, smoothed, maximum, top, cutoff, lower, upper,
                           float(np.sqrt(1 / (2 * a))) * scale, float(np.sqrt(se_mc_squared)) * scale, flag)


PROFILE_INTERVAL_FILE = "profile_interval.csv"


def profile_line(row) -> str:
    """The run's one line for a cell's row of profile_interval.csv: the maximum and the interval,
    or why there is none, and its flag (an end at the grid's edge)."""
    level = f"{100 * row.level:g}%"
    if not np.isfinite(row.lower):
        return f"profile of {row.parameter}: maximum near {row.maximum:.4g}; {row.flag}"
    line = (f"profile of {row.parameter}: maximum {row.maximum:.4g}, {level} interval [{row.lower:.4g}, "
            f"{row.upper:.4g}] (MCAP: cutoff {row.cutoff:.3g} below the smoothed maximum, SE_mc {row.se_monte_carlo:.3g})")
    return line + (f"; {row.flag}" if row.flag else "")


def profile_tables(finals: pd.DataFrame, estimation, labels: list[str]) -> dict[str, pd.DataFrame]:
    """profile.csv, profile_interval.csv and profile_smoothed.csv from maximum_likelihood.csv's
    rows ``finals`` (a row per replicate: replicate ``g * chains + k`` is start k at grid value g,
    :mod:`pfx.config.profile_settings`)."""
    profile, starts = estimation.profile, estimation.chains
    grid, column = np.asarray(profile.values), profile.column
    rows, intervals, curves = [], [], []
    for cell, final in finals.groupby("cell", sort=False):
        final = final.sort_values("replicate")
        replicate = final["replicate"].to_numpy(dtype=int)
        table = final.drop(columns=["replicate", "flag"]).assign(grid_point=replicate // starts, start=replicate % starts)
        table[column] = grid[replicate // starts]        # the grid value itself (the swarm's mean may differ by a rounding)
        rows.append(table[PROFILE.columns(labels, estimation.columns)])
        fit = monte_carlo_adjusted_profile(table[column], table["log_likelihood"], profile.level, profile.span)
        head = {"cell": cell, **{label: final[label].iloc[0] for label in labels}, "parameter": column}
        intervals.append({**head, "level": profile.level, "span": profile.span,
                          "estimates": int(np.isfinite(table["log_likelihood"]).sum()),
                          **{name: getattr(fit, name) for name in PROFILE_INTERVAL_COLUMNS[4:]}})
        curves.append(pd.DataFrame({**head, "value": fit.values, "smoothed_log_likelihood": fit.smoothed}))
    cell_columns = ["cell", *labels]
    return {PROFILE.file: pd.concat(rows, ignore_index=True),
            PROFILE_INTERVAL_FILE: pd.DataFrame(intervals)[[*cell_columns, *PROFILE_INTERVAL_COLUMNS]],
            "profile_smoothed.csv": pd.concat(curves, ignore_index=True)[[*cell_columns, *PROFILE_SMOOTHED_COLUMNS]]}
