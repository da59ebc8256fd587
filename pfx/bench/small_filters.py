r"""Small filters: one trial of a plugin-style model, where the engine's fixed cost per step counts.

The falling body of the main table has a compiled step (:meth:`pfx.models.base.Model.compiled_step`);
a model a user writes in a plugin usually has not. In a notebook, or in each of the thousands of
sequential filters inside particle MCMC, such a model runs one trial of a few hundred particles,
and what each step costs apart from the particles (NumPy calls, checks, bookkeeping) decides the
time. This case measures it: the stochastic-volatility model written as a plugin would write it,

.. math::

    x_k = \mu + \phi (x_{k-1} - \mu) + \sigma w_k, \qquad y_k = e^{x_k / 2} v_k,
    \qquad w_k, v_k \sim N(0, 1),

in plain NumPy (:class:`PluginStyleVolatility`, no compiled step), :math:`T = 200` returns
simulated once, one trial of N = 100 and N = 1000 particles, the bootstrap filter with
systematic resampling at every step, against ``particles``' ``StochVol`` bootstrap filter
(``ESSrmin=1``; its cheapest run, without a collector, and with its ``Moments`` collector, which
gives the filtered means pfx's estimates are) and a plain NumPy loop, in this process,
interleaved, best of several runs. It reports milliseconds per run and microseconds per step,
and the RMSE of the log-variance as the check of equal work.

:func:`entry_point_overhead` times the other half of the question: one filter through the Python
entry point (:func:`pfx.particle_filter`, bound once, then called) against the same engine
called as ``pfx run`` calls it for a batch (a config's planned cell), on the falling body.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Literal, Optional

import numpy as np
from pydantic import Field

from pfx.filtering import Filter, particle_filter
from pfx.laws.initial import GaussianLaw
from pfx.laws.noise import Noise
from pfx.models.base import Model
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, filter_seed, truth_seed

SEED = 20261124
STEPS = 200
PARAMETERS = {"mu": -1.02, "phi": 0.975, "sigma": 0.15}    # GBP/USD's posterior means (Pitt & Shephard)
SIZES = (100, 1_000)
QUICK_SIZES = (100,)


class PluginStyleVolatility(Model):
    """Stochastic volatility as a plugin would write it: plain NumPy, no compiled step (not registered)."""

    kind: Literal["bench_stochastic_volatility"] = "bench_stochastic_volatility"
    mu: float = Field(PARAMETERS["mu"])
    phi: float = Field(PARAMETERS["phi"], gt=-1.0, lt=1.0)
    sigma: float = Field(PARAMETERS["sigma"], gt=0.0)

    def presets(self):
        return {"steps": STEPS, "process_noise": Noise(variance=1.0), "measurement_noise": Noise(variance=1.0),
                "initial": GaussianLaw(mean=[self.mu], covariance=self.sigma ** 2 / (1.0 - self.phi ** 2))}

    @property
    def state_names(self):
        return ("log_variance",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return self.mu + self.phi * (state - self.mu) + self.sigma * noise

    def measurement_mean(self, state):
        return np.zeros(state.shape[:-1] + (1,))

    def simulate_measurement(self, state, random):
        return np.exp(state / 2.0) * self.measurement_noise.sample(random, state.shape[1:-1])

    def log_likelihood(self, measurement, state):
        variance = float(self.measurement_noise.covariance()[0, 0])
        terms = np.log(2.0 * np.pi) + state + np.log(variance) + measurement ** 2 / (variance * np.exp(state))
        return -0.5 * terms[..., 0]


@dataclass
class SmallCase:
    """One trial of N particles on the simulated returns."""

    particles: int
    filter: Filter
    truth: np.ndarray             # (T,) the true log-variances x_1..x_T
    returns: np.ndarray           # (T, 1)
    seed: int

    @property
    def label(self) -> str:
        return f"N={self.particles}, 1 trial"

    def rmse(self, estimates: np.ndarray) -> float:
        return float(np.sqrt(np.mean((np.ravel(estimates) - self.truth) ** 2)))


def make_small_case(particles: int) -> SmallCase:
    model = PluginStyleVolatility()
    states, returns = simulate_truth(model, TrialStreams.from_seeds([truth_seed(SEED, 0)]))
    bound = particle_filter(model, particles=particles, resampler="systematic", ess_threshold=1.0)
    return SmallCase(particles, bound, states[0, 1:, 0], returns[0], filter_seed(SEED, 0, 0))


def run_pfx(case: SmallCase, repeat: int) -> np.ndarray:
    return case.filter(case.returns, seeds=[case.seed + repeat]).estimates[0, :, 0]


def run_numpy(case: SmallCase, repeat: int) -> np.ndarray:
    """The same bootstrap filter as a plain NumPy loop: one (N,) array, systematic resampling."""
    random = np.random.default_rng(case.seed + repeat)
    mu, phi, sigma = PARAMETERS["mu"], PARAMETERS["phi"], PARAMETERS["sigma"]
    n = case.particles
    x = mu + sigma / math.sqrt(1.0 - phi ** 2) * random.standard_normal(n)
    estimates = np.empty(len(case.returns))
    for k, y in enumerate(case.returns[:, 0]):
        x = mu + phi * (x - mu) + sigma * random.standard_normal(n)
        log_weights = -0.5 * (x + y * y * np.exp(-x))
        log_weights -= log_weights.max()
        weights = np.exp(log_weights)
        weights /= weights.sum()
        estimates[k] = weights @ x
        positions = (np.arange(n) + random.random()) / n
        x = x[np.minimum(np.searchsorted(np.cumsum(weights), positions), n - 1)]
    return estimates


def _particles_smc(case: SmallCase, collect):
    import particles
    from particles import state_space_models

    model = state_space_models.StochVol(mu=PARAMETERS["mu"], rho=PARAMETERS["phi"], sigma=PARAMETERS["sigma"])
    return particles.SMC(fk=state_space_models.Bootstrap(ssm=model, data=list(case.returns[:, 0])),
                         N=case.particles, resampling="systematic", ESSrmin=1.0, collect=collect)


def run_particles(case: SmallCase, repeat: int) -> Optional[np.ndarray]:
    """``particles``' own stochastic-volatility model and bootstrap filter, its cheapest run (no
    collector: it computes the ESS and the log-likelihood, not the weighted means): the time the goal
    compares with."""
    from pfx.bench.peers import global_generator_seeded

    with global_generator_seeded(case.seed + repeat):
        _particles_smc(case, None).run()
    return None


def run_particles_moments(case: SmallCase, repeat: int) -> np.ndarray:
    """The same with its ``Moments`` collector, which gives the weighted means (and variances)
    pfx's estimates are compared with."""
    from particles.collectors import Moments

    from pfx.bench.peers import global_generator_seeded

    with global_generator_seeded(case.seed + repeat):
        smc = _particles_smc(case, [Moments()])
        smc.run()
    return np.array([float(moments["mean"]) for moments in smc.summaries.moments])


RUNNERS: dict[str, Callable[[SmallCase, int], Optional[np.ndarray]]] = {
    "pfx": run_pfx, "numpy": run_numpy, "particles": run_particles, "particles+moments": run_particles_moments}


@dataclass
class SmallTiming:
    case: SmallCase
    implementation: str
    seconds: float = math.inf
    runs: int = 0
    rmse: float = math.nan
    error: Optional[str] = None
    times: list[float] = field(default_factory=list)


def time_small_filters(*, quick: bool = False, repeats: int = 5, peers: bool = True,
                       progress: Callable[[str], None] = lambda message: None) -> list[SmallTiming]:
    """Best wall time of each implementation on each size, interleaved (module docstring)."""
    from pfx.bench.peers import peer_version

    names = ["pfx", "numpy"] + (["particles", "particles+moments"] if peers and peer_version("particles") else [])
    timings = []
    for particles in (QUICK_SIZES if quick else SIZES):
        case = make_small_case(particles)
        rows = {name: SmallTiming(case, name) for name in names}
        for repeat in range(repeats + 1):                 # the first round warms up and is not counted
            for name in names[repeat % len(names):] + names[:repeat % len(names)]:
                row = rows[name]
                if row.error:
                    continue
                progress(f"small filters, {case.label}: {name} (run {repeat + 1})")
                started = time.perf_counter()
                try:
                    with np.errstate(all="ignore"), warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        estimates = RUNNERS[name](case, repeat)
                except Exception as error:                # a peer that breaks is reported, not fatal
                    row.error = f"{type(error).__name__}: {error}".splitlines()[0][:80]
                    continue
                if repeat:
                    row.times.append(time.perf_counter() - started)
                    row.runs += 1
                    row.seconds = min(row.times)
                    row.rmse = case.rmse(estimates) if estimates is not None else math.nan
        timings += rows.values()
    return timings


def entry_point_overhead(particles: int = 1_000, repeats: int = 20) -> dict:
    """Best time of one falling-body filter (1 trial, N particles) through the Python entry point
    (bound once, then called) and through a config's planned cell as ``pfx run`` runs a batch."""
    from pfx.bench.problem import make_case, plan_cell

    case = make_case(particles, 1)
    cell = plan_cell(particles)
    random = lambda: TrialStreams.from_seeds(case.filter_seeds)    # noqa: E731  (each run's fresh streams)

    def through_config():
        cell.planned_filter.run(cell.filter_model, case.measurements, random(), settings=cell.filter, prior=cell.prior)

    def through_python():
        case.filter(case.measurements, seeds=case.filter_seeds)

    best = {"config": math.inf, "python": math.inf}
    for _ in range(repeats):
        for name, function in (("config", through_config), ("python", through_python)):
            started = time.perf_counter()
            function()
            best[name] = min(best[name], time.perf_counter() - started)
    return {"particles": particles, **best, "ratio": best["python"] / best["config"]}
