r"""Concept figures: one particle-filter step drawn particle by particle (han-lee Fig. 1).

``resampling_concept`` reads the ``predicted``, ``weighted`` and ``resampled`` clouds that
``outputs.particles`` kept (particles.csv) at one step of the first trial of the first cell and
draws them as three rows on the axis of the first state component:

1. **predicted**: :math:`x_k^i \sim p(x_k \mid x_{k-1}^i)`, all with weight :math:`1/N`;
2. **weighted**: :math:`w_k^i \propto w_{k-1}^i\, p(z_k \mid x_k^i)`, a stem of height
   :math:`w_k^i` per particle. The log-weight increment
   :math:`\log w_k^i - \log w_{k-1}^i = \log p(z_k \mid x_k^i) + c` is the log-likelihood up to
   a constant; when it is exactly a quadratic in :math:`x` (a Gaussian likelihood of a linear
   measurement, checked on the particles themselves) the quadratic is drawn through the stems
   as the likelihood curve, scaled to the weights;
3. **resampled**: the offspring :math:`x_k^{j*}`, stacked above their parent by multiplicity
   :math:`N_j`, labelled with the unbiased expectation :math:`N w_k^j` (exact copies share a
   position, which needs ``diffusion: none``; with diffusion every offspring stands alone).

The true state at that step (steps.csv) is marked on every row. Everything comes from the
CSV files: nothing is recomputed from the model.
"""

from __future__ import annotations

import numpy as np

from pfx.figures.registry import FIGURES
from pfx.result_folder import ResultFolder

STAGES = ("predicted", "weighted", "resampled")


def state_columns(particles) -> list[str]:
    """The state columns of particles.csv: those between ``particle`` and ``weight``."""
    columns = list(particles.columns)
    return columns[columns.index("particle") + 1:columns.index("weight")]


def likelihood_quadratic(positions: np.ndarray, increments: np.ndarray, tolerance: float = 1e-6):
    """Coefficients (a, b, c) of log-likelihood increments a x^2 + b x + c, or None if not quadratic.

    Fitted by least squares; accepted only if it reproduces every increment to ``tolerance``
    (relative to their range) and opens downwards (a < 0), i.e. the weights really are a
    Gaussian likelihood of x.
    """
    finite = np.isfinite(increments)
    if finite.sum() < 4 or np.ptp(positions[finite]) == 0:
        return None
    x, y = positions[finite], increments[finite]
    coefficients = np.polyfit(x, y, 2)
    residual = np.max(np.abs(np.polyval(coefficients, x) - y))
    scale = max(np.ptp(y), 1e-12)
    if coefficients[0] >= 0 or residual > tolerance * scale:
        return None
    return coefficients


def offspring_stacks(positions: np.ndarray) -> list[tuple[float, int]]:
    """(position, multiplicity) of each distinct resampled position, sorted by position."""
    values, counts = np.unique(positions, return_counts=True)
    return list(zip(values.tolist(), counts.tolist()))


@FIGURES.register("resampling_concept")
def resampling_concept(result: ResultFolder):
    """One filter step, particle by particle: predicted, weighted (with the likelihood), resampled.

    On the first state axis (han-lee Fig. 1): weights as stems, with the likelihood when the weight increments are exactly Gaussian in x; offspring stacked by multiplicity, labelled N w_j. Needs `outputs.particles` with the three stages at a step, and `diffusion: none` for exact copies.
    """
    import matplotlib.pyplot as plt

    particles = result.particles
    if particles.empty or not set(STAGES) <= set(particles["stage"]):
        return None
    first = particles[(particles["cell"] == particles["cell"].iloc[0])]
    first = first[first["trial"] == first["trial"].min()]
    kept = [s for s in sorted(first["step"].unique())
            if set(STAGES) <= set(first.loc[first["step"] == s, "stage"])]
    if not kept:
        return None
    step, trial = int(kept[0]), int(first["trial"].iloc[0])
    first = first[first["step"] == step]
    name = state_columns(first)[0]
    stage = {s: first[first["stage"] == s].sort_values("particle") for s in STAGES}
    n = len(stage["predicted"])
    unit = result.units.get(f"state_{name}", "")
    truth = None
    steps = result.steps
    if not steps.empty and f"truth_{name}" in steps:
        row = steps[(steps["cell"] == first["cell"].iloc[0]) & (steps["trial"] == trial) & (steps["step"] == step)]
        truth = float(row[f"truth_{name}"].iloc[0]) if not row.empty else None

    figure, (top, middle, bottom) = plt.subplots(3, 1, figsize=(8.5, 7.2), sharex=True, layout="constrained",
                                                 gridspec_kw={"height_ratios": [1, 2.2, 2.2]})
    predicted = stage["predicted"][name].to_numpy()
    top.scatter(predicted, np.zeros(n), s=140, color="tab:blue", edgecolor="black", zorder=3,
                label=f"x_k^i, weight 1/N = {1 / n:.2g}")
    top.set_yticks([])
    top.set_ylim(-1, 1)
    top.set_title(f"(a) predicted: x_k^i ~ p(x_k | x_(k-1)^i), {n} particles of equal weight", fontsize=10,
                  loc="left")

    weighted = stage["weighted"]
    positions, weights = weighted[name].to_numpy(), weighted["weight"].to_numpy()
    middle.vlines(positions, 0, weights, color="tab:orange", linewidth=2.5)
    middle.scatter(positions, weights, s=40 + 400 * weights / weights.max(), color="tab:orange",
                   edgecolor="black", zorder=3, label="w_k^i (marker area ∝ weight)")
    with np.errstate(divide="ignore"):
        increments = np.log(weights) - np.log(stage["predicted"]["weight"].to_numpy())
    quadratic = likelihood_quadratic(positions, increments)
    if quadratic is not None:
        grid = np.linspace(*_span(first[name].to_numpy(), truth), 400)
        log_curve = np.polyval(quadratic, grid)
        # scaled like the weights: the curve passes through the top of every stem
        shift = np.log(np.sum(np.exp(np.polyval(quadratic, positions) - log_curve.max()))) + log_curve.max()
        middle.plot(grid, np.exp(log_curve - shift), color="tab:red", linewidth=1.5,
                    label="likelihood p(z_k | x), scaled to the weights")
    ess = 1.0 / np.sum(weights ** 2)
    middle.set_ylabel("weight w_k^i")
    middle.set_ylim(0, weights.max() * 1.15)
    middle.set_title(f"(b) weighted: w_k^i ∝ w_(k-1)^i p(z_k | x_k^i), normalised; N_eff = 1/Σ w² = {ess:.2f}",
                     fontsize=10, loc="left")

    stacks = offspring_stacks(stage["resampled"][name].to_numpy())
    parent_weight = dict(zip(positions.tolist(), weights.tolist()))
    for position, count in stacks:
        bottom.scatter(np.full(count, position), np.arange(1, count + 1), s=110, color="tab:green",
                       edgecolor="black", zorder=3)
        target = f"\nN w = {n * parent_weight[position]:.2f}" if position in parent_weight else ""
        bottom.annotate(f"×{count}{target}", (position, count), textcoords="offset points", xytext=(0, 9),
                        ha="center", fontsize=8)
    bottom.scatter([], [], s=110, color="tab:green", edgecolor="black", label="x_k^(j*), weight 1/N")
    bottom.set_ylim(0, max(count for _, count in stacks) + 1.8)
    bottom.set_yticks(range(1, max(count for _, count in stacks) + 1))
    bottom.set_ylabel("offspring N_j")
    resampler = str(first["resampler"].iloc[0]) if "resampler" in first else "resampling"
    bottom.set_title(f"(c) resampled ({resampler}): {n} draws; particle j copied N_j times, "
                     f"{len(stacks)} distinct survivors", fontsize=10, loc="left")
    bottom.set_xlabel(f"state {name} [{unit}]" if unit else f"state {name} (dimensionless)")

    for axes in (top, middle, bottom):
        if truth is not None:
            axes.axvline(truth, color="black", linestyle="--", linewidth=1,
                         label="true state x_k" if axes is top else None)
        axes.grid(alpha=0.3, axis="x")
        axes.legend(fontsize=8, loc="upper right")
    figure.suptitle(f"{result.manifest.get('name', '')}: one particle-filter step with {n} particles "
                    f"(step {step}, trial {trial}, our run)", fontsize=12)
    return figure


def _span(values: np.ndarray, truth) -> tuple[float, float]:
    points = np.append(values, truth) if truth is not None else values
    low, high = float(np.min(points)), float(np.max(points))
    pad = 0.12 * (high - low or 1.0)
    return low - pad, high + pad
