"""Figures of the Mahalanobis distance itself (park-mpf, Fig. 1)."""

from __future__ import annotations

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

SIGMA_LEVELS = (1, 2, 3)          # ellipses at Mahalanobis distance 1, 2, 3 (not squared)


def _ellipse(centre: np.ndarray, covariance: np.ndarray, radius: float, points: int = 200) -> np.ndarray:
    r"""The curve :math:`\{x : (x - m)^\top C^{-1} (x - m) = r^2\}` as (points, 2): :math:`m + r L u(\theta)`."""
    angle = np.linspace(0.0, 2.0 * np.pi, points)
    circle = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    return centre + radius * circle @ np.linalg.cholesky(covariance).T


@FIGURES.register("mahalanobis_scatter")
def mahalanobis_scatter(result: ResultFolder):
    """The sample, the test points coloured by squared Mahalanobis distance, 1-3 sigma ellipses (park-mpf Fig. 1).

    Study `mahalanobis_distances`.
    """
    import matplotlib.pyplot as plt

    samples, distances = result.table("samples"), result.table("distances")
    if samples.empty or distances.empty or not {"x", "y"} <= set(samples.columns):
        return None
    draw = samples[["x", "y"]].to_numpy()
    centre = draw.mean(axis=0)
    covariance = np.cov(draw, rowvar=False)          # divisor n - 1, as the study's distances
    figure, axes = plt.subplots(figsize=(7.6, 6.4), layout="constrained")
    axes.scatter(draw[:, 0], draw[:, 1], s=6, color="tab:red", alpha=0.45, linewidths=0,
                 label=f"samples (n = {len(draw)})")
    for level in SIGMA_LEVELS:
        curve = _ellipse(centre, covariance, level)
        axes.plot(curve[:, 0], curve[:, 1], color="0.25", linewidth=1.0,
                  linestyle=("-", "--", ":")[level - 1], label=f"Mahalanobis distance {level} ({level}σ ellipse)")
    offsets = distances[["x", "y"]].to_numpy() - centre
    radius = float(np.sqrt(np.mean(np.sum(offsets * offsets, axis=1))))
    circle = centre + radius * np.stack([np.cos(np.linspace(0, 2 * np.pi, 200)),
                                         np.sin(np.linspace(0, 2 * np.pi, 200))], axis=-1)
    axes.plot(circle[:, 0], circle[:, 1], color="tab:blue", linewidth=1.0, alpha=0.6,
              label=f"Euclidean circle, radius {radius:.2f}")
    marks = axes.scatter(distances["x"], distances["y"], c=distances["mahalanobis_sample"], cmap="viridis",
                         s=180, edgecolors="black", linewidths=1.2, zorder=4,
                         vmin=0, vmax=float(distances["mahalanobis_sample"].max()))
    for _, row in distances.iterrows():
        axes.annotate(f"{row['point']}\n$d_E^2$ = {row['euclidean_sample']:.2f}\n$d_M^2$ = {row['mahalanobis_sample']:.2f}",
                      (row["x"], row["y"]), xytext=(14 * np.sign(row["x"]), 14 * np.sign(row["y"])),
                      textcoords="offset points", fontsize=8.5, ha="left" if row["x"] > 0 else "right",
                      va="bottom" if row["y"] > 0 else "top",
                      bbox=dict(boxstyle="round,pad=0.25", facecolor="white", alpha=0.85, linewidth=0.5))
    colour_bar = figure.colorbar(marks, ax=axes, shrink=0.85)
    colour_bar.set_label("squared Mahalanobis distance $d_M^2$ (sample mean, sample covariance)")
    limit = max(3.6, float(np.abs(draw).max()) * 1.05)
    axes.set_xlim(-limit, limit)
    axes.set_ylim(-limit, limit)
    axes.set_aspect("equal")
    axes.set_xlabel("x (dimensionless)")
    axes.set_ylabel("y (dimensionless)")
    axes.set_title("Euclidean vs Mahalanobis distance (park-mpf Fig. 1)\n"
                   "four points at the same Euclidean distance, far apart in Mahalanobis distance", fontsize=11)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=8, loc="lower right", framealpha=0.9)
    return figure
