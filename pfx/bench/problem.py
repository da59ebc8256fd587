r"""The benchmark problem: the falling body, its measurements, and the model in plain NumPy.

Simon's falling body (variant B, feet; :mod:`pfx.models.falling_body`) with one explicit
Euler step per interval of :math:`\Delta t = 0.1` s, :math:`T = 100` steps (10 s, up to the
moment the body passes the radar's altitude), additive Gaussian process noise on all three
states (std 10 ft, 10 ft/s, 1e-6 1/ft) and radar range noise of std 100 ft:

.. math::

    x_{1,k} &= x_{1,k-1} + \Delta t\, x_{2,k-1} + w_1, \\
    x_{2,k} &= x_{2,k-1} + \Delta t \left(\tfrac{\rho_0}{2} e^{-x_{1,k-1}/k} x_{2,k-1}^2 x_{3,k-1} - g\right) + w_2, \\
    x_{3,k} &= x_{3,k-1} + w_3, \qquad z_k = \sqrt{M^2 + (x_{1,k} - H)^2} + v_k .

The bootstrap filter starts from :math:`N([3\cdot10^5, -2\cdot10^4, 10^{-3}], \mathrm{diag}(10^6,
4\cdot10^6, 10^{-7}))` and resamples systematically at every step. (Simon's own prior has
variance 10 for :math:`x_3 = 10^{-3}`, which gives half the particles a negative drag that
blows up; the Euler step over 0.5 s is unstable for fast, dense particles. This set-up keeps
every implementation's particles finite, so that all of them do the same work.)

pfx runs it through its Python entry point (:mod:`pfx.filtering`: the model and the filter's
settings as a config gives them, bound once); the reference filter and the peer adapters share
:class:`FallingBodyProblem`, the same model written as plain NumPy functions of an (N, 3)
particle array, with its constants taken from pfx's resolved model.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Optional

import numpy as np

from pfx.filtering import Filter, model, particle_filter
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, filter_seed, truth_seed

SEED = 20240611
STEPS = 100
# The model, the filter's prior and the filter, as a config would give them (the workers
# benchmark, :mod:`pfx.bench.scaling`, runs them as a config: :data:`CONFIG`).
MODEL = {"kind": "falling_body", "variant": "simon", "integrator": "euler", "substeps": 1, "dt": 0.1,
         "steps": STEPS, "process_noise": {"family": "gaussian", "variance": [100.0, 100.0, 1.0e-12]}}
PRIOR = {"kind": "gaussian", "mean": [3.0e5, -2.0e4, 1.0e-3], "covariance": [1.0e6, 4.0e6, 1.0e-7]}
FILTER = {"kind": "particle", "resampler": "systematic", "ess_threshold": 1.0, "initial": PRIOR}
CONFIG = {
    "name": "bench",
    "description": "pfx bench: falling body, bootstrap filter, systematic resampling every step",
    "seed": SEED,
    "model": MODEL,
    "filter": FILTER,
    "metrics": {"convergence": {"criterion": "truth"}},
    "outputs": {"trace_trials": 0, "figures": []},
}


def bench_model():
    """The falling body of the benchmark (module docstring)."""
    return model(**copy.deepcopy(MODEL))


def bench_filter(particles: int, settings: Optional[dict] = None) -> Filter:
    """pfx's filter bound once for N particles, with ``settings`` added to the filter's
    (:mod:`pfx.bench.algorithms`), through the Python entry point (:mod:`pfx.filtering`); raises
    ConfigError if pfx refuses them."""
    return particle_filter(bench_model(), **{**copy.deepcopy(FILTER), "particles": particles,
                                             **copy.deepcopy(settings or {})})


@dataclass
class Case:
    """One benchmark size: R trials of N particles on the same measurements for everyone."""

    particles: int
    trials: int
    filter: Filter
    truth: np.ndarray            # (R, T, 3) true states x_1..x_T
    measurements: np.ndarray     # (R, T, 1)
    filter_seeds: list[int]      # one per trial

    @property
    def label(self) -> str:
        return f"{self.trials} x N={self.particles}" if self.trials > 1 else f"N={self.particles}"

    @property
    def particle_steps(self) -> int:
        return self.particles * self.trials * self.truth.shape[1]

    def altitude_rmse(self, estimates: np.ndarray) -> float:
        """RMSE of the altitude over every trial and step: sqrt(mean((x1_hat - x1)^2))."""
        return float(np.sqrt(np.mean((estimates[..., 0] - self.truth[..., 0]) ** 2)))


def make_case(particles: int, trials: int) -> Case:
    bound = bench_filter(particles)
    states, measurements = simulate_truth(bound.model,
                                          TrialStreams.from_seeds([truth_seed(SEED, t) for t in range(trials)]))
    seeds = [filter_seed(SEED, 0, t) for t in range(trials)]
    return Case(particles, trials, bound, states[:, 1:], measurements, seeds)


@dataclass(frozen=True)
class FallingBodyProblem:
    """The bench model as plain NumPy functions of particles shaped (N, 3)."""

    dt: float
    radar_distance: float
    radar_altitude: float
    half_density: float          # rho0 / 2
    scale_height: float
    gravity: float
    process_std: np.ndarray      # (3,)
    measurement_std: float
    prior_mean: np.ndarray       # (3,)
    prior_std: np.ndarray        # (3,)

    @classmethod
    def from_filter(cls, bound: Filter) -> "FallingBodyProblem":
        model, prior = bound.model, bound.prior
        return cls(dt=model.dt, radar_distance=model.radar_distance, radar_altitude=model.radar_altitude,
                   half_density=0.5 * model.air_density, scale_height=model.scale_height, gravity=model.gravity,
                   process_std=np.sqrt(np.diag(model.process_noise.covariance())),
                   measurement_std=float(np.sqrt(model.measurement_noise.covariance()[0, 0])),
                   prior_mean=prior.mean_vector(), prior_std=np.sqrt(np.diag(prior.covariance_matrix())))

    def sample_prior(self, random: np.random.Generator, n: int) -> np.ndarray:
        return self.prior_mean + self.prior_std * random.standard_normal((n, 3))

    def propagate(self, x: np.ndarray) -> np.ndarray:
        """One Euler step of the drag equations (no noise)."""
        altitude, velocity, coefficient = x[:, 0], x[:, 1], x[:, 2]
        drag = self.half_density * np.exp(-altitude / self.scale_height) * velocity ** 2 * coefficient
        return np.stack([altitude + self.dt * velocity, velocity + self.dt * (drag - self.gravity), coefficient],
                        axis=1)

    def process_noise(self, random: np.random.Generator, n: int) -> np.ndarray:
        return self.process_std * random.standard_normal((n, 3))

    def range(self, x: np.ndarray) -> np.ndarray:
        """h(x) = sqrt(M^2 + (x1 - H)^2), shape (N,)."""
        return np.sqrt(self.radar_distance ** 2 + (x[:, 0] - self.radar_altitude) ** 2)

    def log_likelihood(self, z: float, x: np.ndarray) -> np.ndarray:
        """log p(z | x) up to a constant: -(z - h(x))^2 / (2 sigma^2)."""
        innovation = (z - self.range(x)) / self.measurement_std
        return -0.5 * innovation * innovation

    @property
    def log_likelihood_constant(self) -> float:
        """The constant :meth:`log_likelihood` leaves out: log p(z | x) = log_likelihood(z, x) + c,
        c = -log(sigma) - log(2 pi) / 2."""
        return float(-np.log(self.measurement_std) - 0.5 * np.log(2.0 * np.pi))


def plan_cell(particles: int):
    """The benchmark's filter as a config's planned cell, one trial: what ``pfx run`` runs for a
    batch (:func:`pfx.bench.small_filters.entry_point_overhead` times the Python entry point against it)."""
    from pfx.config.plan import build_plan

    raw = copy.deepcopy(CONFIG)
    raw["trials"] = 1
    raw["filter"]["particles"] = particles
    return build_plan(raw, "<pfx bench>").cells[0]
