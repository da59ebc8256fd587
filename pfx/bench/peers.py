"""The same bootstrap filter in the Python particle-filter libraries pfx is compared with.

One small adapter per library, each written the way the library's documentation shows, on
the model of :class:`~pfx.bench.problem.FallingBodyProblem`, the same measurements and
systematic resampling at every step; each returns the weighted-mean estimates (R, T, 3):

* ``particles`` (N. Chopin): a :class:`particles.FeynmanKac` subclass run by ``particles.SMC``
  (``ESSrmin=1``: resample at every step), and by ``particles.multiSMC`` (one process) for
  many trials.
* ``filterpy`` (R. Labbe): the predict / update / estimate / resample loop of its
  documentation (weights by ``scipy.stats.norm(...).pdf``, ``+1e-300`` against underflow),
  with ``filterpy.monte_carlo.systematic_resample``.
* ``pfilter`` (J. Williamson): ``pfilter.ParticleFilter`` with ``pfilter.systematic_resample``
  and its gaussian kernel ``squared_error`` as the weight (the likelihood up to a constant).

The process noise and prior of every adapter come from an explicit generator per trial. The
libraries' own resampling draws from NumPy's global generator: :func:`global_generator_seeded`
seeds it for them and restores it afterwards (pfx itself never uses it).
"""

from __future__ import annotations

import importlib
from contextlib import contextmanager
from typing import Callable, Optional

import numpy as np

from pfx.bench.problem import Case, FallingBodyProblem

PEERS = ("particles", "filterpy", "pfilter")


def peer_version(name: str) -> Optional[str]:
    """The installed version of a peer library, or None if it cannot be imported."""
    try:
        module = importlib.import_module(name)
    except Exception:            # not installed, or broken against this numpy
        return None
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return getattr(module, "__version__", "?")


@contextmanager
def global_generator_seeded(seed: int):
    """Seed NumPy's legacy global generator for a library that draws from it; restore it after."""
    saved = np.random.get_state()
    # The one use of the global generator in pfx, on purpose: filterpy, pfilter and particles draw
    # their resampling numbers from it, so the benchmark seeds it for them (from the case's seed)
    # and restores it after; pfx's own draws always come from its per-trial Generators.
    np.random.seed(seed % 2**32)
    try:
        yield
    finally:
        np.random.set_state(saved)


def run_particles(problem: FallingBodyProblem, case: Case) -> np.ndarray:
    import particles
    from particles.collectors import Moments

    class FallingBody(particles.FeynmanKac):
        """Bootstrap Feynman-Kac model: M0 = transition of a prior draw, M = transition, G = likelihood."""

        def __init__(self, data, random):
            super().__init__(T=len(data))
            self.data, self.random = data, random

        def M0(self, N):
            return self.M(0, problem.sample_prior(self.random, N))

        def M(self, t, xp):
            return problem.propagate(xp) + problem.process_noise(self.random, len(xp))

        def logG(self, t, xp, x):
            return problem.log_likelihood(self.data[t], x)

    def weighted_mean(W, X):
        return W @ X

    options = dict(N=case.particles, resampling="systematic", ESSrmin=1.0, collect=[Moments(mom_func=weighted_mean)])
    models = [FallingBody(case.measurements[r, :, 0], np.random.default_rng(case.filter_seeds[r]))
              for r in range(case.trials)]
    with global_generator_seeded(case.filter_seeds[0]):
        if case.trials == 1:
            smc = particles.SMC(fk=models[0], **options)
            smc.run()
            runs = [smc]
        else:
            results = particles.multiSMC(fk=models, nruns=1, nprocs=1, **options)
            by_model = {id(result["fk"]): result["output"] for result in results}
            runs = [by_model[id(model)] for model in models]
    return np.stack([np.array(run.summaries.moments) for run in runs])


def run_filterpy(problem: FallingBodyProblem, case: Case) -> np.ndarray:
    import scipy.stats
    from filterpy.monte_carlo import systematic_resample

    n = case.particles
    estimates = np.empty(case.truth.shape)
    for r in range(case.trials):
        random = np.random.default_rng(case.filter_seeds[r])
        with global_generator_seeded(case.filter_seeds[r]):
            particles = problem.sample_prior(random, n)
            weights = np.full(n, 1.0 / n)
            for t, z in enumerate(case.measurements[r, :, 0]):
                particles = problem.propagate(particles) + problem.process_noise(random, n)     # predict
                weights *= scipy.stats.norm(problem.range(particles), problem.measurement_std).pdf(z)
                weights += 1.0e-300                                                         # update
                weights /= np.sum(weights)     # the docs use the built-in sum(), far slower
                estimates[r, t] = np.average(particles, weights=weights, axis=0)            # estimate
                indexes = systematic_resample(weights)                                      # resample
                particles[:] = particles[indexes]
                weights.fill(1.0 / n)
    return estimates


def run_pfilter(problem: FallingBodyProblem, case: Case) -> np.ndarray:
    import pfilter

    n = case.particles
    estimates = np.empty(case.truth.shape)
    for r in range(case.trials):
        random = np.random.default_rng(case.filter_seeds[r])
        with global_generator_seeded(case.filter_seeds[r]):
            pf = pfilter.ParticleFilter(
                prior_fn=lambda count: problem.sample_prior(random, count),
                observe_fn=lambda x: problem.range(x)[:, None],
                dynamics_fn=problem.propagate,
                noise_fn=lambda x: x + problem.process_noise(random, len(x)),
                weight_fn=lambda hypotheses, observed: pfilter.squared_error(
                    hypotheses, observed, sigma=problem.measurement_std),
                resample_fn=pfilter.systematic_resample,
                n_particles=n, n_eff_threshold=1.0)
            for t, z in enumerate(case.measurements[r, :, 0]):
                pf.update(np.array([z]))
                estimates[r, t] = pf.mean_state
    return estimates


ADAPTERS: dict[str, Callable[[FallingBodyProblem, Case], np.ndarray]] = {
    "particles": run_particles, "filterpy": run_filterpy, "pfilter": run_pfilter}
