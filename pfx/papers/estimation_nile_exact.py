r"""The exact answers the Nile estimation benchmark is checked against: the local-level model's
likelihood by the Kalman filter (pfx's ``kf``, and its diffuse form), its maximum, the grid
posterior of (r, q) under the runs' priors, and the curvature at the maximum. Pure functions of
the data and the runs' settings, cached where the report's parts share them;
:mod:`pfx.papers.estimation_nile` reads them into its tables and verdicts.
"""

from __future__ import annotations

import functools
import json
import math

import numpy as np
from scipy import optimize

from pfx.config.estimation import EstimationConfig
from pfx.filtering import model as build_model
from pfx.filtering import particle_filter
from pfx.papers.base import PaperResults

BENCHMARK = "estimation-nile"
MEASUREMENT, LEVEL = "model.measurement_noise.variance", "model.process_noise.variance"   # r, q
LOG_BOX = (math.log(10.0), math.log(1.0e7))   # the grid's range of log r and of log q
GRID_POINTS = 401                             # per axis; the error bound compares GRID_POINTS with
COARSE_GRID_POINTS = 201                      # a grid of half the resolution
QUANTILES = (0.025, 0.5, 0.975)
OPTIMISER_START = (1.0e4, 1.0e3)              # (r, q) where Nelder-Mead starts
AGREEMENT_POINTS = ((1.5e4, 1.5e3), (2.0e3, 50.0), (1.0e5, 2.0e4), (3.0e4, 300.0))   # grid recursion vs kf


def local_level(settings: dict) -> dict:
    """The runs' model section (config.yaml), checked to be the local level this report knows."""
    matrices = (settings.get("transition_matrix"), settings.get("measurement_matrix"))
    initial = settings.get("initial") or {}
    if (settings.get("kind") != "linear_gaussian" or matrices != ([[1.0]], [[1.0]]) or initial.get("kind") != "gaussian"
            or settings.get("control_matrix") is not None):
        raise ValueError(f"{BENCHMARK}: the runs' model is not the local level with a Gaussian initial level")
    return settings


def initial_level(settings: dict) -> tuple[float, float]:
    """(m_0, P_0): the mean and variance of the runs' initial level x_0."""
    initial = settings["initial"]
    return float(np.ravel(initial["mean"])[0]), float(np.ravel(initial["covariance"])[0])


def _model(settings: dict, r: float, q: float, **changes):
    fields = {**settings, **changes}
    fields["measurement_noise"] = {**settings["measurement_noise"], "variance": float(r)}
    fields["process_noise"] = {**settings["process_noise"], "variance": float(q)}
    kind = fields.pop("kind")
    return build_model(kind, **fields)


def kalman_log_likelihood(settings: dict, data: np.ndarray, r: float, q: float) -> float:
    r"""pfx's exact :math:`\log p(z_{1:n} \mid r, q)`: its Kalman filter (``kind="kf"``) on the
    model ``settings`` (the runs' model section) with the two variances set."""
    return float(particle_filter(_model(settings, r, q), kind="kf")(data[:, None]).log_likelihood[0])


def diffuse_log_likelihood(settings: dict, data: np.ndarray, r: float, q: float) -> float:
    r"""Durbin & Koopman's diffuse log-likelihood,

    .. math::

        \log L_d = -\tfrac n2 \log 2\pi - \tfrac12 \sum_{t=2}^n \left(\log F_t + v_t^2 / F_t\right),

    the Kalman filter's innovations :math:`v_t` and variances :math:`F_t` from the level after
    :math:`z_1`, :math:`N(z_1, r)` (the limit of an initial variance going to infinity): pfx's
    ``kf`` started there on :math:`z_{2:n}`, and the constant of the first observation."""
    initial = {"kind": "gaussian", "mean": [float(data[0])], "covariance": float(r)}
    model = _model(settings, r, q, initial=initial, steps=len(data) - 1)
    after_first = float(particle_filter(model, kind="kf")(data[1:, None]).log_likelihood[0])
    return after_first - 0.5 * math.log(2.0 * math.pi)


def maximise(log_likelihood, start: tuple[float, float]) -> tuple[float, float, float]:
    """(r, q, log L) at the maximum of ``log_likelihood(r, q)``: Nelder-Mead on (log r, log q)."""
    found = optimize.minimize(lambda u: -log_likelihood(math.exp(u[0]), math.exp(u[1])), np.log(start),
                              method="Nelder-Mead", options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 4000})
    return float(math.exp(found.x[0])), float(math.exp(found.x[1])), float(-found.fun)


def local_level_log_likelihood(data: np.ndarray, r: np.ndarray, q: np.ndarray, mean: float,
                               variance: float) -> np.ndarray:
    r"""The local level's exact log-likelihood at many (r, q) at once (arrays of one shape): the
    Kalman recursion from :math:`x_0 \sim N(m_0, P_0)`,

    .. math::

        P_t^- = P_{t-1} + q,\quad F_t = P_t^- + r,\quad v_t = z_t - m_{t-1},\quad
        m_t = m_{t-1} + \frac{P_t^-}{F_t} v_t,\quad P_t = P_t^- \frac{r}{F_t},

    :math:`\log L = -\frac12 \sum_t (\log 2\pi F_t + v_t^2 / F_t)`: pfx's ``kf`` on this model,
    written for a grid (pfx's Kalman filter takes one pair of variances per run)."""
    r, q = np.broadcast_arrays(np.asarray(r, dtype=float), np.asarray(q, dtype=float))
    level, level_variance = np.full(r.shape, float(mean)), np.full(r.shape, float(variance))
    total = np.zeros(r.shape)
    for value in data:
        predicted = level_variance + q
        innovation_variance = predicted + r
        innovation = value - level
        total -= 0.5 * (np.log(2.0 * np.pi * innovation_variance) + innovation**2 / innovation_variance)
        level = level + predicted / innovation_variance * innovation
        level_variance = predicted * r / innovation_variance
    return total


def grid_posterior(data: np.ndarray, settings: dict, estimation: EstimationConfig, points: int) -> dict:
    r"""The exact posterior of (r, q) on a grid of ``points`` x ``points`` values of
    :math:`(\log r, \log q)` over :data:`LOG_BOX`: parameter -> mean, sd and :data:`QUANTILES`;
    and ``edge_mass``, the posterior weight of the grid's border (what the box may cut off)."""
    axis = np.linspace(*LOG_BOX, points)
    log_r, log_q = np.meshgrid(axis, axis, indexing="ij")
    r, q = np.exp(log_r), np.exp(log_q)
    log_density = (local_level_log_likelihood(data, r, q, *initial_level(settings))
                   + estimation.parameters[MEASUREMENT].prior.log_density(r)
                   + estimation.parameters[LEVEL].prior.log_density(q) + log_r + log_q)
    weight = np.exp(log_density - log_density.max())
    weight /= weight.sum()
    summary = {"edge_mass": float(weight[0].sum() + weight[-1].sum() + weight[1:-1, 0].sum() + weight[1:-1, -1].sum())}
    for name, values, marginal in (("r", r[:, 0], weight.sum(axis=1)), ("q", q[0], weight.sum(axis=0))):
        mean = float(np.sum(marginal * values))
        cumulative = np.cumsum(marginal) - 0.5 * marginal            # the marginal's CDF at the points
        summary[name] = {"mean": mean, "sd": math.sqrt(float(np.sum(marginal * (values - mean) ** 2))),
                         **{p: float(np.exp(np.interp(p, cumulative, np.log(values)))) for p in QUANTILES}}
    return summary


def curvature(log_likelihood, at: np.ndarray, step: float = 1e-3) -> dict:
    r"""The asymptotic standard deviations of (log r, log q) and their correlation at the maximum:
    the inverse of the observed information :math:`-\nabla^2 \log L`, by central differences."""
    hessian = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            corners = []
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                point = np.array(at, dtype=float)
                point[i] += si * step
                point[j] += sj * step
                corners.append(si * sj * log_likelihood(point))
            hessian[i, j] = sum(corners) / (4.0 * step**2)
    covariance = np.linalg.inv(-hessian)
    sd = np.sqrt(np.diag(covariance))
    return {"sd_log_r": float(sd[0]), "sd_log_q": float(sd[1]), "correlation": float(covariance[0, 1] / (sd[0] * sd[1]))}


@functools.lru_cache(maxsize=8)
def _maxima(data: tuple, settings_json: str) -> dict:
    """The two maxima and the curvature at pfx's (cached: the parts share them)."""
    data, settings = np.asarray(data), json.loads(settings_json)
    maximum = maximise(lambda r, q: kalman_log_likelihood(settings, data, r, q), OPTIMISER_START)
    return {"maximum": maximum,
            "diffuse_maximum": maximise(lambda r, q: diffuse_log_likelihood(settings, data, r, q), OPTIMISER_START),
            "curvature": curvature(lambda u: kalman_log_likelihood(settings, data, *np.exp(u)), np.log(maximum[:2]))}


@functools.lru_cache(maxsize=8)
def _posterior(data: tuple, settings_json: str, estimation_json: str) -> dict:
    """The grid posterior, its error bound, and the grid recursion's agreement with pfx's ``kf``."""
    data, settings = np.asarray(data), json.loads(settings_json)
    estimation = EstimationConfig.model_validate(json.loads(estimation_json))
    fine = grid_posterior(data, settings, estimation, GRID_POINTS)
    coarse = grid_posterior(data, settings, estimation, COARSE_GRID_POINTS)
    agreement = max(abs(float(local_level_log_likelihood(data, r, q, *initial_level(settings)))
                        - kalman_log_likelihood(settings, data, r, q)) for r, q in AGREEMENT_POINTS)
    return {"grid": fine, "grid_error": {name: abs(fine[name]["mean"] - coarse[name]["mean"]) for name in ("r", "q")},
            "grid_agreement": agreement}


def flows(results: PaperResults) -> np.ndarray:
    """The 100 flows, from paper.yaml."""
    return np.asarray(results.numbers["flows"], dtype=float)


def exact_maxima(results: PaperResults, experiment: str) -> dict:
    """pfx's maximum (r, q, log L) under the model of ``experiment``'s runs, the diffuse maximum,
    and the asymptotic spread of (log r, log q) at pfx's maximum."""
    settings = local_level(results.config(experiment)["model"])
    return _maxima(tuple(flows(results)), json.dumps(settings, sort_keys=True))


def exact_posterior(results: PaperResults, experiment: str) -> dict:
    """The exact posterior under the model and priors of ``experiment``'s runs (:func:`grid_posterior`)."""
    config = results.config(experiment)
    settings = local_level(config["model"])
    return _posterior(tuple(flows(results)), json.dumps(settings, sort_keys=True),
                      json.dumps(config["estimation"], sort_keys=True))
