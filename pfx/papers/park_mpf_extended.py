r"""park-mpf beyond the paper (experiment ``extended``): 100 paired trials of the PF, MPF-paper,
MPF-innovation, the EKF and the UKF, and the verdicts on the paper's relative claims.

Per state, :func:`compare_with_pf` gives every filter's RMSE and its paired comparison with the
PF (:func:`pfx.analysis.compare.paired_comparison` for the difference,
:func:`pfx.analysis.paired_statistics.relative_change_interval` for the relative change), diverged
trials counted and left out (:mod:`pfx.papers.park_mpf_trials`).

**Verdict on a relative claim** ("MPF's RMSE is 22% lower"), per MPF form, from the extended
comparison's 95% interval [lo, hi] of the relative change of mean RMSE (MPF / PF - 1)
(:func:`claim_verdict`): *reproduced* when hi < 0 and the claimed change lies in [lo, hi];
*partly reproduced* when hi < 0 but the claimed size lies outside (or when the MPF diverged in
some trials but is significantly lower in the others); otherwise *not reproduced* (no detectable
change, an increase, or divergence in every trial). A part of the park-mpf report
(:mod:`pfx.papers.park_mpf`).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from pfx.analysis.compare import paired_comparison
from pfx.analysis.paired_statistics import relative_change_interval
from pfx.analysis.summary import describe
from pfx.analysis.value_ranges import metric_range
from pfx.errors import ConfigError
from pfx.papers.base import Figure, PaperResults, Part, Table, Text, Verdict, interval, markdown_table, percent
from pfx.papers.park_mpf_trials import (
    DIVERGENCE_FACTOR,
    STATES,
    arm_roles,
    baseline_arm,
    diverged_trials,
    mpf_forms,
    rmse_per_trial,
    state_text,
    state_units,
)


def compare_with_pf(trials: pd.DataFrame, label_columns: list[str]) -> pd.DataFrame:
    """One row per (state, arm): RMSE statistics, diverged count, paired comparison with the PF.

    Diverged values (:mod:`pfx.papers.park_mpf_trials`) are set to infinity before pairing, so that
    :func:`pfx.analysis.compare.paired_comparison` leaves them out and counts them in ``excluded_pairs``.
    """
    roles = arm_roles(trials)
    baseline = baseline_arm(roles)
    rows = []
    for state in STATES:
        metric = f"rmse_{state}"
        table = rmse_per_trial(trials, state)
        bad = diverged_trials(table, baseline)
        marked = trials.copy()
        for arm in table.columns:
            flagged = bad.index[bad[arm]]
            marked.loc[(marked["arm"] == arm) & marked["trial"].isin(flagged), metric] = np.inf
        try:
            comparison = paired_comparison(marked, metric, by="arm", baseline=baseline,
                                           label_columns=label_columns).set_index("arm")
        except ConfigError:            # no finite pair at all (every arm diverged): nothing to compare
            comparison = pd.DataFrame()
        for arm in roles:
            values = table[arm].to_numpy(dtype=float)
            kept = values[~bad[arm].to_numpy()]
            # the interval of summary.csv: an RMSE's t-interval cut at 0, none from too few trials
            statistics = describe(kept, metric_range(metric))
            row = {"state": state, "arm": arm, "role": roles[arm], "trials": values.size, "diverged": int(bad[arm].sum()),
                   **{key: statistics[key] for key in ("mean", "ci95_low", "ci95_high")},
                   "median": float(np.median(values)), "std": statistics["std"]}
            if arm != baseline:
                usable = ~(bad[arm].to_numpy() | bad[baseline].to_numpy())
                change, low, high = relative_change_interval(table[baseline].to_numpy(dtype=float)[usable],
                                                             values[usable], value_range=metric_range(metric))
                row.update(relative_change=change, relative_low=low, relative_high=high, pairs=int(usable.sum()))
                if arm in comparison.index:
                    found = comparison.loc[arm]
                    row.update(mean_difference=found["mean_difference"], difference_low=found["ci95_low"],
                               difference_high=found["ci95_high"], p_value=found["p_value"],
                               wins=int(found["wins"]), losses=int(found["losses"]))
            rows.append(row)
    return pd.DataFrame(rows)


def claim_verdict(claimed_change: float, row: pd.Series, form_arm: str, state: str) -> tuple[str, str]:
    """(verdict, evidence) for 'MPF changes the mean RMSE of ``state`` by ``claimed_change``' (module docstring)."""
    n, k = int(row["trials"]), int(row["diverged"])
    change, low, high = row.get("relative_change"), row.get("relative_low"), row.get("relative_high")
    measured = (f"{percent(change)} (95% interval {interval(low, high, number=percent)}, "
                f"{int(row.get('pairs', 0))} pairs)" if np.isfinite(change) else "")
    claimed = percent(claimed_change, decimals=0)
    if k:
        text = (f"{form_arm} diverged in {k} of {n} trials ({state_text(state)} RMSE infinite or above "
                f"{DIVERGENCE_FACTOR:g} x the PF's median), so its mean RMSE is not finite")
        if np.isfinite(change) and high < 0 and k < n:
            return "partly reproduced", text + f"; in the other trials its mean RMSE changed by {measured} against the claimed {claimed}."
        return "not reproduced", text + (f"; in the other trials: {measured}." if measured else ".")
    if not np.isfinite(change):
        return "not reproduced", f"no pair of finite {state_text(state)} RMSEs to compare."
    if high < 0 and low <= claimed_change <= high:
        return "reproduced", f"{form_arm} changed the mean {state_text(state)} RMSE by {measured}, which contains the claimed {claimed}."
    if high < 0:
        return "partly reproduced", (f"{form_arm} changed the mean {state_text(state)} RMSE by {measured}: lower, "
                                     f"but the interval excludes the claimed {claimed}.")
    if low > 0:
        return "not reproduced", f"{form_arm} raised the mean {state_text(state)} RMSE: {measured} (claimed {claimed})."
    return "not reproduced", (f"no detectable change of the mean {state_text(state)} RMSE with {form_arm}: {measured} "
                              f"contains 0" + (f" and excludes the claimed {claimed}." if not low <= claimed_change <= high
                                               else f" (the claimed {claimed} is inside it too)."))

# -- the part -----------------------------------------------------------------------------------


def extended_part(results: PaperResults) -> Part:
    """Beyond the paper: 100 paired trials of five filters, and the verdicts on the relative claims."""
    if not results.has("extended"):
        return Part()
    numbers = results.numbers
    items, verdicts = [], []
    folder = results.folder("extended")
    trials = folder.trials
    comparison = compare_with_pf(trials, folder.label_columns)
    roles = arm_roles(trials)
    baseline = baseline_arm(roles)
    units = state_units(results, "extended")
    n = trials["trial"].nunique()
    for state in STATES:
        rows = []
        for _, row in comparison[comparison["state"] == state].iterrows():
            rows.append({
                "filter": row["arm"], "diverged": f"{row['diverged']}/{row['trials']}",
                "mean RMSE": row["mean"], "95% CI": interval(row["ci95_low"], row["ci95_high"]),
                "median": row["median"],
                f"difference vs {baseline}": row.get("mean_difference"),
                "difference 95% CI": interval(row.get("difference_low", math.nan), row.get("difference_high", math.nan)),
                "relative change": percent(row.get("relative_change", math.nan)),
                "relative 95% CI": interval(row.get("relative_low", math.nan), row.get("relative_high", math.nan),
                                            number=percent),
                "p": row.get("p_value"),
                "wins/losses": (f"{int(row['wins'])}/{int(row['losses'])}" if row.get("pairs", 0) > 0 else ""),
            })
        items.append(Table(
            f"Extended ({n} paired trials): {state_text(state)} RMSE [{units[state]}]",
            markdown_table(pd.DataFrame(rows)),
            f"Mean, CI and differences over the trials that did not diverge (RMSE infinite or above "
            f"{DIVERGENCE_FACTOR:g} x the PF's median; the 'diverged' column counts them); the median is over all "
            f"trials. Differences are paired by trial (same truth and measurements), value - {baseline}, with the "
            f"paired t-interval and p-value (`pfx.analysis.compare`); the relative change is mean / {baseline} mean - 1 "
            f"with its delta-method interval; wins = trials where the filter's RMSE is lower."))
    items.append(Figure("extended", "relative_change_by_state.png",
                        f"Ours, beyond the paper: change of each filter's mean RMSE against the PF over {n} paired "
                        "trials, per state, with 95% intervals; a filter that diverged is marked with its count."))
    items.append(_divergence_note(trials, roles, baseline))
    claims = numbers.get("claims", {})
    for state in STATES:
        claim = claims.get(state, {})
        if "reduction" in claim:
            claimed = -float(claim["reduction"])
            label = f"{state_text(state)} RMSE {100 * claim['reduction']:.0f}% lower with MPF (ten-run means {claim['means']['PF']} vs {claim['means']['MPF']})"
        elif claim.get("means"):
            claimed = claim["means"]["MPF"] / claim["means"]["PF"] - 1
            label = (f"{state_text(state)} RMSE lower with MPF (ten-run means {claim['means']['PF']:g} vs "
                     f"{claim['means']['MPF']:g}: {percent(claimed)})")
        else:
            continue
        for form, arm in mpf_forms(roles).items():
            row = comparison[(comparison["state"] == state) & (comparison["arm"] == arm)].iloc[0]
            verdict, evidence = claim_verdict(claimed, row, arm, state)
            verdicts.append(Verdict(f"{label}: {arm}", verdict, evidence + f" ({n} paired trials.)"))
    return Part(items, verdicts)


def _divergence_note(trials: pd.DataFrame, roles: dict, baseline: str) -> Text:
    """Why MPF-paper diverges: its weights are nearly uniform (measured ESS and lost particles)."""
    by_arm = trials.groupby("arm", sort=False)
    ess = by_arm["ess_mean"].mean()
    lost = by_arm["lost_particles"].mean()
    particles = trials.groupby("arm")["n_particles"].first()
    lines = []
    for form, arm in mpf_forms(roles).items():
        lines.append(f"{arm}: mean ESS {ess[arm]:.0f} of {particles[arm]:.0f} particles per step "
                     f"({baseline}: {ess[baseline]:.0f}), {lost[arm]:.0f} particle states lost (non-finite) per trial "
                     f"({baseline}: {lost[baseline]:.0f})")
    return Text(
        "**Why the printed eq. (6) fails here.** Its weight exp(-½ ν Σ⁻¹ Σ⁻¹ ν) with Σ the spread of the "
        "predicted ranges divides the squared innovation (ft²) by a squared variance (ft⁴): the result depends on "
        "the unit of length, and with a cloud hundreds of feet wide it is nearly the same for every particle, so "
        "the radar is all but ignored. Measured: " + "; ".join(lines) + ". With almost uniform weights the "
        "roughening keeps widening the cloud; particles whose ballistic coefficient turns negative have drag "
        "that grows without bound and their states overflow. The innovation form is a tempered likelihood "
        "(docs/reference-facts.md, Mahalanobis forms): flatter weights than the PF's, but still scaled by the measurement noise. "
        "MPF-paper's ballistic-coefficient errors are small in most trials for a reason that is no merit of "
        "the weighting: nearly uniform weights leave that estimate near the prior mean, which this benchmark "
        "centres on the true value.")
