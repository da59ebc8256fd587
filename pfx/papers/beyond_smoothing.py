r"""The "beyond the papers" report's smoothing parts: smoothers against the filter, and the
ancestral tree's size against Jacob, Murray & Rubenthaler's bound.

* ``smoothing-<model>`` (the growth model; range beacons with a random walk): every trial's
  filter and its three smoothers (backward sampling, a fixed lag of 5, the genealogy) scored on
  the same truth, so each smoother's position RMSE is paired with the filter's, trial by trial
  (:func:`pfx.analysis.compare.paired_comparison`, the 95% t-interval of the mean difference).
  The claim: a smoother, which uses the later measurements too, estimates the past states better
  than the filter, and backward sampling better than the genealogy, whose paths degenerate.
  *Reproduced* when, on both models, backward sampling's paired difference from the filter and
  from the genealogy smoother lie below zero.
* ``ancestral-tree``: the number of distinct particles, over every step, that are ancestors of
  the last step's particles (``ancestral_tree_size``), for N = 25 to 200 and T = 400 and 800.
  Jacob, Murray & Rubenthaler (2015) bound its expectation by :math:`T + C N \log N`: a single
  path back from the time all lineages have coalesced (T steps), and a bush of
  :math:`O(N \log N)` nodes near the end. *Reproduced* when :math:`(\text{size} - T) / (N \log N)`
  is the same constant to within :data:`CONSTANT_SPREAD` over every N and T, and the bush's size
  does not grow with T: at each N, size - T at T = 800 is within :data:`BUSH_GROWTH` of its value at T = 400.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from pfx.analysis.compare import paired_comparison
from pfx.papers.base import (
    Figure,
    PaperResults,
    Part,
    Table,
    Text,
    Verdict,
    format_number,
    interval,
    markdown_table,
    verdict_from_checks,
)

SMOOTHING_MODELS = (("growth", "the growth model"), ("range-beacons", "range beacons, a random walk"))
ESTIMATORS = (("filter", "rmse_position"), ("ffbs", "rmse_ffbs_position"), ("fixed_lag", "rmse_fixed_lag_position"),
              ("genealogy", "rmse_genealogy_position"))
CONSTANT_SPREAD = 1.5          # max / min of (size - T) / (N log N) over the cells
BUSH_GROWTH = 0.15             # |(size - T) at 2T / (size - T) at T - 1| at most this


def estimator_rows(trials: pd.DataFrame) -> pd.DataFrame:
    """The trials in long form: one row per (trial, estimator) with its position RMSE."""
    frames = [pd.DataFrame({"trial": trials["trial"], "estimator": name, "rmse": trials[column]})
              for name, column in ESTIMATORS if column in trials]
    return pd.concat(frames, ignore_index=True)


def smoothing_numbers(trials: pd.DataFrame) -> pd.DataFrame:
    """Per estimator: mean RMSE, and its paired difference from the filter and from the genealogy smoother."""
    long = estimator_rows(trials)
    against_filter = paired_comparison(long, "rmse", by="estimator", baseline="filter").set_index("estimator")
    against_genealogy = paired_comparison(long, "rmse", by="estimator", baseline="genealogy").set_index("estimator")
    rows = []
    for name, _ in ESTIMATORS:
        values = long.loc[long["estimator"] == name, "rmse"]
        row = {"estimator": name, "mean": values.mean()}
        for prefix, table in (("filter", against_filter), ("genealogy", against_genealogy)):
            if name in table.index:
                found = table.loc[name]
                row.update({f"{prefix}_difference": found["mean_difference"], f"{prefix}_low": found["ci95_low"],
                            f"{prefix}_high": found["ci95_high"]})
        rows.append(row)
    return pd.DataFrame(rows).set_index("estimator")


def _difference(row: pd.Series, prefix: str) -> str:
    if not np.isfinite(row.get(f"{prefix}_difference", np.nan)):
        return ""
    return f"{format_number(row[f'{prefix}_difference'])} {interval(row[f'{prefix}_low'], row[f'{prefix}_high'])}"


def smoothing_part(results: PaperResults) -> Part:
    claims = results.numbers.get("claims", {})
    items: list = [Text(
        "### Smoothers after the filter\n\n"
        "On the record of one bootstrap filter per trial, three smoothers estimate each step's state from every "
        "measurement: backward sampling (FFBS, 100 trajectories drawn back through the weighted clouds), a fixed "
        "lag of 5 steps and the genealogy of the last particles (configs `smoothing-growth.yaml`, "
        "`smoothing-range-beacons.yaml`). Each trial's four estimates are scored on the same truth, so the "
        "differences are paired by trial.")]
    checks, evidence = [], []
    for model, title in SMOOTHING_MODELS:
        experiment = f"smoothing-{model}"
        if not results.has(experiment):
            continue
        trials = results.folder(experiment).trials
        numbers = smoothing_numbers(trials)
        unit = results.folder(experiment).units.get("position", "")
        table = pd.DataFrame([{"estimator": name, f"position RMSE{f' [{unit}]' if unit else ''}": row["mean"],
                               "difference from the filter [95% CI]": _difference(row, "filter"),
                               "difference from the genealogy [95% CI]": _difference(row, "genealogy")}
                              for name, row in numbers.iterrows()])
        items.append(Table(f"Smoothers against the filter: {title} ({len(trials)} trials)", markdown_table(table),
                           "Position RMSE over the steps, mean over the trials; differences paired by trial "
                           "(smoother - baseline), with the 95% t-interval (`pfx compare`'s)."))
        for name, caption in (("smoothing_error_over_time.png", f"{title}: the RMS position error of the filter and "
                                                                "of each smoother, step by step, over every trial"),
                              ("genealogy_tree.png", f"{title}: the genealogy of trial 0, every particle's line to its "
                                                     "parent, the last particles' ancestral lines dark: they coalesce "
                                                     "back in time (path degeneracy)")):
            if name in results.figures(experiment):
                items.append(Figure(experiment, name, caption))
        ffbs = numbers.loc["ffbs"]
        checks += [ffbs["filter_high"] < 0, ffbs["genealogy_high"] < 0]
        evidence.append(f"{title}: FFBS - filter {_difference(ffbs, 'filter')}, FFBS - genealogy "
                        f"{_difference(ffbs, 'genealogy')}")
    if not checks:
        return Part()
    claim = claims.get("smoothing", {})
    verdict = Verdict(f"{claim.get('claim', 'smoothing')} ({claim.get('source', '')})", verdict_from_checks(checks),
                      "; ".join(evidence) + " (each interval must lie below 0).")
    return Part(items, [verdict])


def tree_numbers(trials: pd.DataFrame) -> pd.DataFrame:
    """Per (N, T): the mean ancestral tree size with its 95% interval, and (size - T) / (N log N)."""
    from pfx.analysis.summary import describe

    rows = []
    for (particles, steps), group in trials.groupby(["n_particles", "model_steps"]):
        statistics = describe(group["ancestral_tree_size"].to_numpy(dtype=float))
        bush = statistics["mean"] - steps
        rows.append({"N": int(particles), "T": int(steps), "trials": len(group), "size": statistics["mean"],
                     "low": statistics["ci95_low"], "high": statistics["ci95_high"], "bush": bush,
                     "constant": bush / (particles * math.log(particles))})
    return pd.DataFrame(rows)


def ancestral_tree_part(results: PaperResults) -> Part:
    if not results.has("ancestral-tree"):
        return Part()
    numbers = tree_numbers(results.folder("ancestral-tree").trials)
    table = pd.DataFrame([{"N": row["N"], "T": row["T"], "mean tree size [95% CI]":
                           f"{format_number(row['size'])} {interval(row['low'], row['high'])}",
                           "size - T": row["bush"], "(size - T) / (N ln N)": row["constant"]}
                          for _, row in numbers.iterrows()])
    constants = numbers["constant"]
    spread = constants.max() / constants.min()
    by_particles = numbers.pivot(index="N", columns="T", values="bush")
    short, long = by_particles.columns.min(), by_particles.columns.max()
    growth = (by_particles[long] / by_particles[short] - 1.0).abs()
    checks = [spread <= CONSTANT_SPREAD, bool((growth <= BUSH_GROWTH).all())]
    claim = results.numbers.get("claims", {}).get("ancestral_tree", {})
    verdict = Verdict(
        f"{claim.get('claim', 'ancestral tree')} ({claim.get('source', '')})", verdict_from_checks(checks),
        f"(size - T) / (N ln N) between {format_number(constants.min())} and {format_number(constants.max())} over "
        f"N = {int(numbers['N'].min())}..{int(numbers['N'].max())} and T = {short}, {long} (a spread of "
        f"{spread:.2f}, at most {CONSTANT_SPREAD:g} asked); size - T changes by at most {growth.max():.0%} from "
        f"T = {short} to {long} (at most {BUSH_GROWTH:.0%} asked).")
    items = [Text("### The ancestral tree: path storage\n\n"
                  "How many particles, over all steps, are ancestors of a bootstrap filter's last particles? "
                  "Following the ancestors back, the lineages coalesce into one path; the tree is that path and a "
                  "bush near the end. Config `ancestral-tree.yaml`: multinomial resampling at every step, "
                  "20 trials per cell, the tree's size counted from the recorded genealogy "
                  "(`ancestral_tree_size` in trials.csv)."),
             Table("Size of the ancestral tree against T + C N log N", markdown_table(table),
                   "If the expected size is T + C N log N, the last column is the same constant C in every row "
                   "and size - T does not depend on T.")]
    if "distinct_ancestors.png" in results.figures("ancestral-tree"):
        items.append(Figure("ancestral-tree", "distinct_ancestors.png",
                            "Distinct ancestors of the last particles at each step (one trial per cell): N at the "
                            "end, one long before"))
    return Part(items, [verdict])


SMOOTHING_PARTS = (smoothing_part, ancestral_tree_part)
