r"""What a filter may ask of a model's transition beyond sampling it: whether the process noise
enters additively, :math:`x_k = f(x_{k-1}, u_k) + w_k`, so that the transition density
:math:`p(x_k \mid x_{k-1}) = p_w(x_k - f(x_{k-1}, u_k, 0))` can be evaluated (the histogram
filter's kernel, the particle filter's MCMC move)."""

from __future__ import annotations

import numpy as np


def noise_enters_additively(model, points: np.ndarray, std: np.ndarray) -> bool:
    """Whether propagate(x, u, w) - propagate(x, u, 0) = w, checked numerically on up to seven
    of ``points`` (shape (P, d)) with a fixed pattern of noises w scaled by the per-component
    noise standard deviations ``std`` (a model's code cannot be inspected; seven points and
    noises of both signs and several sizes catch a multiplicative or nonlinear noise)."""
    sample = points[np.linspace(0, len(points) - 1, min(7, len(points))).astype(int)]
    pattern = np.array([0.7, -1.3, 2.1, -0.4, 1.1, -2.2, 0.3])[:len(sample), None]
    noise = pattern * std * np.where(np.arange(len(std)) % 2 == 0, 1.0, -0.8)
    control = model.control(1)
    with np.errstate(all="ignore"):
        moved = model.propagate(sample, control, noise) - model.propagate(sample, control, np.zeros_like(sample))
    return bool(np.allclose(moved, noise, rtol=1e-6, atol=1e-9 * float(std.max())))
