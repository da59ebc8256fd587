r"""What the motion-model studies share: Probabilistic Robotics Figs. 5.3/5.4 and 5.8/5.9.

A robot at the pose :math:`x_{t-1} = (x, y, \theta)` executes one motion command :math:`u_t`;
its new pose :math:`x_t` is uncertain, with the law :math:`p(x_t \mid u_t, x_{t-1})`. The book
draws this law twice for three **noise settings** (the motion error parameters alpha): as a
density projected into the x-y plane (Fig. 5.3 for the velocity model, 5.8 for odometry) and as
500 samples of the sampler (Figs. 5.4 and 5.9). A concrete motion (velocity or odometry,
:mod:`pfx.studies.velocity_motion`, :mod:`pfx.studies.odometry_motion`) says how to sample a
pose, how to evaluate its density, what the noise-free path is, and how wide the heading is
spread once the position is fixed; this module turns that into the two studies.

**The density study** (:class:`MotionDensity`) evaluates, on the centres of an x-y grid, the
x-y marginal of the pose density by a sum over a grid of headings (the midpoint rule):

.. math::

    p(x, y) = \int p(x, y, \theta)\, d\theta \approx \sum_{k=1}^{K} p(x, y, \theta_k)\, \Delta\theta,
    \qquad \theta_k = \theta_{end} - h + (k - \tfrac12)\Delta\theta, \quad \Delta\theta = 2h / K,

a window of half-width :math:`h` about the commanded final heading :math:`\theta_{end}`. Given
the position, the heading is spread only by the last rotation error (the velocity model's
:math:`\hat\gamma\Delta t`, the odometry model's :math:`\hat\delta_{rot2}`), a smooth density of
standard deviation :math:`\sigma_\theta`; the midpoint rule is then exact to many digits once
:math:`\Delta\theta \le \sigma_\theta / 2`, which the study requires. ``grid_mass``
:math:`= \sum p(x, y)\,\Delta x\,\Delta y` (table ``agreement``) shows that both grids hold the
whole distribution (it is 1 when they do).

Two densities are written: ``density``, the density of the pose itself (the book's terms
divided by the Jacobian of the map from noise to pose, ``pfx.motion.pose_density_*``), and
``table_5_1``, the book's own value (Table 5.1 or 5.5: the density of the noise at the pose's
preimage) summed the same way and normalised over the grid. They differ by the Jacobian,
which varies across the distribution.

**Agreement with the sampler.** The study also draws ``check_samples`` poses with the sampler
(Table 5.3 or 5.6) and bins them into blocks of ``check_block`` x ``check_block`` grid cells,
plus one bin for everything outside the grid. Table ``agreement`` has, per setting and per
density (``pose`` or ``table_5_1``), with the bins' size ``bin_x``, ``bin_y`` (m): the Pearson chi-square statistic of the counts against the
density's block probabilities (blocks expecting fewer than 5 samples pooled into one), its
degrees of freedom and p-value, and the total variation distance
:math:`\tfrac12\sum_b |n_b / n - p_b|` beside the distance that sampling alone gives when the
density is exact (mean and 99th percentile over 200 multinomial draws of the same size).

**The samples study** (:class:`MotionSamples`) draws ``extended_samples`` poses per setting and
noise family (normal and triangular, Table 5.4); table ``samples`` keeps the first ``samples``
(500, the book's count: the figure) and table ``spread`` has, for both counts, the sample mean
and the variances **along** the motion (the direction from the start to the noise-free end,
``along_angle``) and **across** it, each with its standard error
:math:`\sqrt{(m_4 - s^4 (n-3)/(n-1)) / n}` (:math:`m_4` the fourth central moment), and their
correlation.

Table ``density`` has one row per setting and grid cell (``x``, ``y`` its centre) with ``density``
and ``table_5_1`` (1/m^2, five significant digits); cells where both are below 1e-4 of the peak
are left out (the figure draws them white). Table ``grid`` gives the grid: per axis ``low``,
``high`` and ``cells``.

Both studies write ``settings`` (name, label, the alphas) and ``path`` (the noise-free motion:
rows ``path`` from the start to the end, then ``start`` and ``end`` with their headings).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, model_validator

from pfx.motion.distributions import MotionNoise
from pfx.studies.base import Study

Pose = tuple[StrictFloat, StrictFloat, StrictFloat]
Interval = tuple[StrictFloat, StrictFloat]

#: multinomial replicates for the total variation that sampling alone produces
NULL_REPLICATES = 200
#: chi-square bins expecting fewer samples than this are pooled (the usual validity rule)
MINIMUM_EXPECTED = 5.0
#: grid cells whose density is below this fraction of the peak are left out of density.csv (an
#: invisible shade on a linear grey scale; the figure draws them white, the check uses them all)
SHOWN_FRACTION = 1e-4


class NamedSetting(BaseModel):
    """A named noise setting; subclasses add the model's typed ``alphas``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$", max_length=40,
                      description="short name, the value of the `setting` column (e.g. a)")
    label: str = Field("", max_length=80, description="caption of the setting's panel (e.g. '(a) default')")


class RobotMotion(Study):
    """A robot's pose before one motion command and the named noise settings to compare."""

    start: Pose = Field((0.0, 0.0, 0.0), description="the pose x_{t-1} = [x, y, theta] before the motion (m, m, rad)")

    units: ClassVar[dict[str, str]] = {
        "x": "m", "y": "m", "theta": "rad", "density": "1/m^2", "table_5_1": "1/m^2",
        "mean_x": "m", "mean_y": "m", "std_along": "m", "std_across": "m", "var_along": "m^2",
        "var_across": "m^2", "along_angle": "rad", "bin_x": "m", "bin_y": "m"}

    # What a concrete motion model provides (pfx.studies.velocity_motion, odometry_motion): a
    # field ``settings`` (a list of its NamedSetting subclass, typed alphas) and these methods.

    def sample_poses(self, setting, noise: MotionNoise, count: int, random: np.random.Generator) -> np.ndarray:
        """``count`` poses (count, 3) drawn by the book's sampler."""
        raise NotImplementedError

    def log_densities(self, poses: np.ndarray, setting, noise: MotionNoise) -> tuple[np.ndarray, np.ndarray]:
        """(log of the book's value, log of the pose density) at poses (..., 3)."""
        raise NotImplementedError

    def commanded_path(self, points: int) -> np.ndarray:
        """``points`` poses (points, 3) along the noise-free motion, from the start to the end."""
        raise NotImplementedError

    def heading_spread(self, setting) -> float:
        """Standard deviation of the final heading once the final position is fixed (rad)."""
        raise NotImplementedError

    @model_validator(mode="after")
    def _distinct_names(self):
        names = [setting.name for setting in self.settings]
        if len(set(names)) != len(names):
            raise ValueError(f"settings: names must be distinct, got {names}")
        return self

    def along_angle(self) -> float:
        """Direction of the motion: from the start to the noise-free end (the start's heading if they coincide)."""
        start, end = self.commanded_path(2)
        dx, dy = end[0] - start[0], end[1] - start[1]
        return float(math.atan2(dy, dx)) if math.hypot(dx, dy) > 0 else float(start[2])

    def settings_table(self) -> pd.DataFrame:
        return pd.DataFrame([{"setting": s.name, "label": s.label or s.name, **s.alphas.model_dump()}
                             for s in self.settings])

    def path_table(self, points: int = 60) -> pd.DataFrame:
        path = self.commanded_path(points)
        rows = [{"element": "path", "x": x, "y": y, "theta": theta} for x, y, theta in path]
        rows += [{"element": "start", "x": path[0, 0], "y": path[0, 1], "theta": path[0, 2]},
                 {"element": "end", "x": path[-1, 0], "y": path[-1, 1], "theta": path[-1, 2]}]
        return pd.DataFrame(rows)


class MotionDensity(RobotMotion):
    """The density of the pose on an x-y grid, marginalised over a heading grid, and its check
    against the sampler (see :mod:`pfx.studies.robot_motion`)."""

    noise: MotionNoise = Field("normal", description="error distribution: normal or triangular (Table 5.2)")
    x_range: Interval = Field((-0.3, 1.5), description="x extent of the grid [low, high] (m)")
    y_range: Interval = Field((-0.4, 1.2), description="y extent of the grid [low, high] (m)")
    cells: tuple[StrictInt, StrictInt] = Field((90, 80), description="grid cells along x and along y")
    theta_cells: StrictInt = Field(100, ge=1, le=2000, description="headings summed over (the midpoint rule)")
    theta_halfwidth: StrictFloat = Field(
        1.5, gt=0, le=math.pi, description="half-width of the heading window about the commanded final heading (rad)")
    check_samples: StrictInt = Field(20_000, ge=100, le=10_000_000,
                                     description="sampler draws compared with the density, per setting")
    check_block: StrictInt = Field(2, ge=1, le=100, description="grid cells per side of a bin of the check")

    @model_validator(mode="after")
    def _grids(self):
        for key, (low, high) in (("x_range", self.x_range), ("y_range", self.y_range)):
            if not low < high:
                raise ValueError(f"{key}: needs low < high, got [{low}, {high}]")
        for count in self.cells:
            if not 2 <= count <= 2000:
                raise ValueError(f"cells: each count must lie in [2, 2000], got {list(self.cells)}")
            if count % self.check_block:
                raise ValueError(f"cells: {list(self.cells)} must be multiples of check_block = {self.check_block}")
        step = 2 * self.theta_halfwidth / self.theta_cells
        for setting in self.settings:
            spread = self.heading_spread(setting)
            if spread == 0:
                raise ValueError(f"settings: setting {setting.name!r} has a zero variance of the final rotation: "
                                 "the pose then has no density over (x, y, theta) to sum")
            if step > spread / 2:
                raise ValueError(
                    f"theta_cells: the heading step {step:.3g} rad exceeds half the heading spread "
                    f"{spread:.3g} rad of setting {setting.name!r}; the sum over headings would not "
                    "resolve it: use more theta_cells or a narrower theta_halfwidth")
        return self

    def grid(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Cell centres along x and y, and the cell sizes."""
        (x_low, x_high), (y_low, y_high) = self.x_range, self.y_range
        dx, dy = (x_high - x_low) / self.cells[0], (y_high - y_low) / self.cells[1]
        return (x_low + dx * (np.arange(self.cells[0]) + 0.5), y_low + dy * (np.arange(self.cells[1]) + 0.5), dx, dy)

    def headings(self) -> tuple[np.ndarray, float]:
        """The heading grid theta_k (midpoints of the window about the final heading) and its step."""
        step = 2 * self.theta_halfwidth / self.theta_cells
        final = self.commanded_path(2)[-1, 2]
        return final - self.theta_halfwidth + step * (np.arange(self.theta_cells) + 0.5), step

    def marginals(self, setting) -> tuple[np.ndarray, np.ndarray]:
        r"""(x cells, y cells) each: :math:`\sum_k p(x_i, y_j, \theta_k)\,\Delta\theta` of the book's value
        and of the pose density."""
        x, y, _, _ = self.grid()
        thetas, step = self.headings()
        xs, ys = np.meshgrid(x, y, indexing="ij")
        book, pose = np.zeros_like(xs), np.zeros_like(xs)
        for chunk in np.array_split(thetas, max(1, thetas.size // 16)):   # bounded memory
            poses = np.stack(np.broadcast_arrays(xs[..., None], ys[..., None], chunk), axis=-1)
            log_book, log_pose = self.log_densities(poses, setting, self.noise)
            book += np.exp(log_book).sum(axis=-1)
            pose += np.exp(log_pose).sum(axis=-1)
        return book * step, pose * step

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        x, y, dx, dy = self.grid()
        densities, agreement = [], []
        for setting in self.settings:
            book, pose = self.marginals(setting)
            grid_mass = float(pose.sum() * dx * dy)
            book = book / (book.sum() * dx * dy)
            xs, ys = np.meshgrid(x, y, indexing="ij")
            shown = np.maximum(pose, book) >= SHOWN_FRACTION * pose.max()
            densities.append(pd.DataFrame({"setting": setting.name, "x": _rounded(xs[shown], 12),
                                           "y": _rounded(ys[shown], 12), "density": _rounded(pose[shown]),
                                           "table_5_1": _rounded(book[shown])}))
            samples = self.sample_poses(setting, self.noise, self.check_samples, random)
            counts = self._block_counts(samples)
            for name, density in (("pose", pose), ("table_5_1", book * grid_mass)):
                probabilities = self._block_probabilities(density * dx * dy)
                agreement.append({"setting": setting.name, "density": name, "grid_mass": grid_mass,
                                  "bin_x": self.check_block * dx, "bin_y": self.check_block * dy,
                                  **histogram_agreement(counts, probabilities, random)})
        grid = pd.DataFrame({"axis": ["x", "y"], "low": [self.x_range[0], self.y_range[0]],
                             "high": [self.x_range[1], self.y_range[1]], "cells": list(self.cells)})
        return {"density": pd.concat(densities, ignore_index=True), "agreement": pd.DataFrame(agreement),
                "grid": grid, "settings": self.settings_table(), "path": self.path_table()}

    def _block_probabilities(self, cell_mass: np.ndarray) -> np.ndarray:
        """Mass per check bin (blocks of the grid, row-major), then the outside: 1 - the grid's mass."""
        nx, ny = (count // self.check_block for count in self.cells)
        blocks = cell_mass.reshape(nx, self.check_block, ny, self.check_block).sum(axis=(1, 3)).ravel()
        return np.append(blocks, max(0.0, 1.0 - cell_mass.sum()))

    def _block_counts(self, samples: np.ndarray) -> np.ndarray:
        nx, ny = (count // self.check_block for count in self.cells)
        counts, _, _ = np.histogram2d(samples[:, 0], samples[:, 1], bins=(nx, ny),
                                      range=(self.x_range, self.y_range))
        return np.append(counts.ravel(), len(samples) - counts.sum())


def _rounded(values: np.ndarray, digits: int = 5) -> np.ndarray:
    """Values to ``digits`` significant digits, so that the CSV holds short numbers (figure data)."""
    return np.array([float(f"{value:.{digits}g}") for value in values])


def histogram_agreement(counts: np.ndarray, probabilities: np.ndarray, random: np.random.Generator) -> dict:
    r"""Pearson's chi-square and the total variation of bin counts against bin probabilities.

    Bins expecting fewer than 5 counts are pooled into one. Under exact agreement the statistic
    is :math:`\chi^2` with (bins - 1) degrees of freedom. The total variation
    :math:`\tfrac12 \sum_b |n_b/n - p_b|` is returned beside its mean and 99th percentile over
    multinomial draws from ``probabilities`` of the same size (sampling noise alone).
    """
    from scipy import stats

    n = int(counts.sum())
    probabilities = probabilities / probabilities.sum()
    expected = n * probabilities
    kept = expected >= MINIMUM_EXPECTED
    pooled_counts = np.append(counts[kept], counts[~kept].sum())
    pooled_expected = np.append(expected[kept], expected[~kept].sum())
    if pooled_expected[-1] == 0:
        pooled_counts, pooled_expected = pooled_counts[:-1], pooled_expected[:-1]
    chi_square = float(np.sum((pooled_counts - pooled_expected) ** 2 / pooled_expected))
    degrees = len(pooled_expected) - 1
    null = random.multinomial(n, probabilities, size=NULL_REPLICATES)
    null_distance = 0.5 * np.abs(null / n - probabilities).sum(axis=1)
    return {"samples": n, "bins": len(pooled_expected), "chi_square": chi_square, "dof": degrees,
            "p_value": float(stats.chi2.sf(chi_square, degrees)),
            "total_variation": float(0.5 * np.abs(counts / n - probabilities).sum()),
            "tv_null_mean": float(null_distance.mean()), "tv_null_q99": float(np.quantile(null_distance, 0.99))}


class MotionSamples(RobotMotion):
    """Poses drawn by the book's sampler, normal and triangular, and their spread along and across
    the motion (see :mod:`pfx.studies.robot_motion`)."""

    samples: StrictInt = Field(500, ge=2, le=100_000,
                               description="poses kept per setting and noise (the figure; the book draws 500)")
    extended_samples: StrictInt = Field(20_000, ge=2, le=10_000_000,
                                        description="poses drawn per setting and noise for the spread statistics")
    noises: list[MotionNoise] = Field(["normal", "triangular"], min_length=1, max_length=2,
                                      description="error distributions to draw (Table 5.4)")

    @model_validator(mode="after")
    def _counts(self):
        if self.extended_samples < self.samples:
            raise ValueError(f"extended_samples: {self.extended_samples} is fewer than samples = {self.samples}")
        if len(set(self.noises)) != len(self.noises):
            raise ValueError(f"noises: listed twice: {self.noises}")
        return self

    def tables(self, random: np.random.Generator) -> dict[str, pd.DataFrame]:
        angle = self.along_angle()
        kept, spread = [], []
        for setting in self.settings:
            for noise in self.noises:
                poses = self.sample_poses(setting, noise, self.extended_samples, random)
                kept.append(pd.DataFrame({"setting": setting.name, "noise": noise,
                                          "sample": np.arange(self.samples), "x": poses[:self.samples, 0],
                                          "y": poses[:self.samples, 1], "theta": poses[:self.samples, 2]}))
                for count in dict.fromkeys((self.samples, self.extended_samples)):
                    spread.append({"setting": setting.name, "noise": noise,
                                   **spread_along_across(poses[:count, :2], angle)})
        return {"samples": pd.concat(kept, ignore_index=True), "spread": pd.DataFrame(spread),
                "settings": self.settings_table(), "path": self.path_table()}


def spread_along_across(points: np.ndarray, angle: float) -> dict:
    r"""Mean, and variances (with standard errors) of ``points`` (n, 2) along ``angle`` and across it.

    The standard error of a sample variance :math:`s^2` is :math:`\sqrt{(m_4 - s^4 (n-3)/(n-1)) / n}`
    with :math:`m_4` the fourth central moment (no normality assumed).
    """
    n = len(points)
    centred = points - points.mean(axis=0)
    along = centred @ np.array([math.cos(angle), math.sin(angle)])
    across = centred @ np.array([-math.sin(angle), math.cos(angle)])
    row = {"n": n, "along_angle": angle, "mean_x": points[:, 0].mean(), "mean_y": points[:, 1].mean()}
    for name, values in (("along", along), ("across", across)):
        variance = values.var(ddof=1)
        fourth = np.mean(values ** 4)
        row[f"var_{name}"] = variance
        row[f"var_{name}_se"] = math.sqrt(max(0.0, fourth - variance ** 2 * (n - 3) / (n - 1)) / n)
        row[f"std_{name}"] = math.sqrt(variance)
    spread = math.sqrt(row["var_along"] * row["var_across"])
    row["correlation"] = float(np.sum(along * across) / (n - 1) / spread) if spread > 0 else float("nan")
    return row
