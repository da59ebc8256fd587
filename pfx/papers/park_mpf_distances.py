r"""park-mpf's Table 1 and Fig. 1 (experiment ``table1``, study ``mahalanobis_distances``): the
squared Euclidean and Mahalanobis distances of four test points from a sample of 1000 draws,
the paper's printed values beside ours (one seeded draw) and the exact ones.

The verdict compares the paper's eight printed values, and our seeded ones, with the sampling
distribution of each squared distance for 1000 samples (mean and standard deviation over the
study's replications): consistent when every :math:`|z| = |v - \text{mean}| / \text{sd}` is below
the Bonferroni bound :math:`z_{1 - 0.05 / (2K)}` for K values (a 5% family-wise level,
:data:`FAMILY_LEVEL`). A part of the park-mpf report (:mod:`pfx.papers.park_mpf`).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from pfx.papers.base import Figure, PaperResults, Part, Table, Verdict, format_number, markdown_table

FAMILY_LEVEL = 0.05               # family-wise level of the Table 1 consistency check


def table1_part(results: PaperResults) -> Part:
    """Table 1 and Fig. 1: the squared distances of four test points, paper beside ours."""
    if not results.has("table1"):
        return Part()
    numbers = results.numbers
    items, verdicts = [], []
    distances = results.folder("table1").table("distances")
    printed = {p["point"]: p for p in numbers.get("table1", {}).get("points", [])}
    rows, paper_z, our_z = [], [], []
    for _, row in distances.iterrows():
        paper = printed.get(row["point"], {})
        line = {"point": row["point"], "colour (paper)": paper.get("colour", "")}
        for kind, label in (("euclidean", "d_E²"), ("mahalanobis", "d_M²")):
            centre, spread = row[f"{kind}_sampling_mean"], row[f"{kind}_sampling_sd"]
            value = paper.get(kind)
            z_paper = (value - centre) / spread if value is not None else math.nan
            z_ours = (row[f"{kind}_sample"] - centre) / spread
            paper_z.append(z_paper)
            our_z.append(z_ours)
            line.update({f"{label} paper": value, f"{label} ours (seeded)": row[f"{kind}_sample"],
                         f"{label} exact": row[f"{kind}_exact"], f"{label} sampling sd": spread,
                         f"{label} z paper": z_paper})
        rows.append(line)
    frame = pd.DataFrame(rows)
    values = len(paper_z)
    bound = float(stats.norm.ppf(1 - FAMILY_LEVEL / (2 * values)))
    samples = int(distances["samples"].iloc[0])
    replications = int(distances["replications"].iloc[0])
    items.append(Table(
        "Table 1: squared distances of the test points from the sample (paper, ours from one seeded draw, exact)",
        markdown_table(frame, formats={c: (lambda v: f"{v:+.2f}") for c in frame.columns if " z " in c}),
        f"All distances are squared and dimensionless: d_E² = (p - m)'(p - m) and d_M² = (p - m)' C⁻¹ (p - m) "
        f"with the sample mean m and sample covariance C (divisor n - 1) of {samples} draws, as MATLAB's "
        f"`mahal`; 'exact' uses the true mean and covariance. 'sampling sd' is the standard deviation of "
        f"each distance over {replications} repeated draws of {samples} samples, and 'z paper' = (paper - "
        f"sampling mean) / sampling sd. The plain (unsquared) exact distances would be "
        f"{math.sqrt(distances['euclidean_exact'].iloc[0]):.2f} (Euclidean) and "
        + " / ".join(f"{math.sqrt(v):.2f}" for v in sorted(set(distances["mahalanobis_exact"].round(9))))
        + " (Mahalanobis): the paper prints squares, as its text says (\"sqrt(2)^2 = 2.0\")."))
    items.append(Figure("table1", "mahalanobis_scatter.png",
                        f"Fig. 1 (ours): {samples} samples of N(0, [[1, .9], [.9, 1]]) with the four test points "
                        "coloured by squared Mahalanobis distance from the sample (colour bar), the 1-, 2- and "
                        "3-sigma ellipses of the sample covariance and the Euclidean circle through the points."))
    worst_paper = float(np.nanmax(np.abs(paper_z)))
    worst_ours = float(np.max(np.abs(our_z)))
    consistent = worst_paper < bound and worst_ours < bound
    exact = (format_number(distances["euclidean_exact"].iloc[0]) + " and "
             + " / ".join(format_number(v) for v in sorted(set(distances["mahalanobis_exact"].round(9)))))
    if consistent:
        evidence = (f"every printed value lies within sampling error of a {samples}-sample draw (largest |z| "
                    f"{worst_paper:.2f}, ours {worst_ours:.2f}; bound {bound:.2f} for {values} values at a 5% "
                    f"family-wise level), around the exact squared values {exact}.")
    else:
        evidence = (f"largest |z| of the printed values {worst_paper:.2f} (ours {worst_ours:.2f}) exceeds the bound "
                    f"{bound:.2f} for {values} values at a 5% family-wise level (exact squared values {exact}).")
    verdicts.append(Verdict(
        "Table 1: squared Euclidean distances 2.09 / 2.04 / 1.96 / 1.91 (true 2.0) and squared Mahalanobis "
        "distances 1.11 / 20.36 / 19.59 / 1.01 from 1000 samples",
        "reproduced" if consistent else "not reproduced", evidence))
    return Part(items, verdicts)
