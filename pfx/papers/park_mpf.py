r"""The park-mpf report: Park, Lim & Yang (2021), a particle filter weighted by Mahalanobis distance
(docs/papers/park-mpf.md; the falling-body variants and the two readings of its eq. (6):
docs/reference-facts.md). It reads ``results/park-mpf/`` and the document's numbers (``paper.yaml``),
one experiment group per module, in the order of :data:`PARTS`:

* ``table1`` (study ``mahalanobis_distances``): Table 1 and Fig. 1, the paper's printed distances
  against their sampling distribution (:mod:`pfx.papers.park_mpf_distances`).
* ``one-run`` (Table 2, Figs. 4-6), ``ten-runs`` (Table 3): the paper's numbers beside ours, and
  why its absolute RMSEs cannot be compared with ours (:mod:`pfx.papers.park_mpf_runs`).
* ``extended`` (100 paired trials, PF, MPF-paper, MPF-innovation, EKF, UKF): per state, every
  filter's RMSE and its paired comparison with the PF, and the verdicts on the paper's relative
  claims (:mod:`pfx.papers.park_mpf_extended`).

What the filter experiments share (which arm is which filter, each state's RMSE per trial, when a
trial counts as diverged) is :mod:`pfx.papers.park_mpf_trials`.
"""

from __future__ import annotations

from pfx.papers.base import REPORTS, PaperResults, Section, assemble
from pfx.papers.park_mpf_distances import table1_part
from pfx.papers.park_mpf_extended import extended_part
from pfx.papers.park_mpf_runs import absolute_values_part, table2_part, table3_part

PAPER = "park-mpf"
PARTS = (table1_part, table2_part, table3_part, extended_part, absolute_values_part)


@REPORTS.register(PAPER)
def park_mpf_report(results: PaperResults) -> Section:
    numbers = results.numbers
    summary = (
        f"{numbers.get('citation', 'Park, Lim & Yang (2021)')} The paper proposes weighting particles by a "
        "Mahalanobis distance (eq. 6) instead of the Gaussian likelihood (eq. 5) and compares the two on the "
        "falling-body benchmark. Its printed constants mix units (docs/reference-facts.md, falling-body variants), "
        "so we run the source its equation copies, Simon's example 14.2 in feet; the prior, Q, time step and "
        "particle count it leaves open are chosen, with reasons, in `configs/papers/park-mpf/`. Eq. (6) is "
        "ambiguous, so both readings run: **MPF-paper** (eq. 6 as printed, Σ the spread of the predicted "
        "ranges) and **MPF-innovation** (ν'S⁻¹ν with S = R + that spread). EKF and UKF rows go beyond the paper. "
        "The paper's RMSEs have no unit and cannot be compared in size with ours; its relative claims can.")
    items, verdicts = assemble(results, PARTS)
    return Section(PAPER, "park-mpf: particle filter with Mahalanobis weighting (Park, Lim & Yang 2021)",
                   summary, items, verdicts)
