r"""PMMH: what one iteration of particle marginal Metropolis-Hastings costs, in pfx and in ``particles``.

An iteration of PMMH (:mod:`pfx.estimation.pmmh`) proposes :math:`\theta'` by a Gaussian random
walk, runs one particle filter at :math:`\theta'` for :math:`\hat\ell' = \log \hat
p_{\theta'}(z_{1:T})`, and accepts with probability

.. math::

    \min\Bigl(1, \frac{\hat p_{\theta'}(z_{1:T})\, \pi(\theta')\, q(\theta \mid \theta')}
                     {\hat p_{\theta}(z_{1:T})\, \pi(\theta)\, q(\theta' \mid \theta)}\Bigr).

Thousands of iterations each run a small sequential filter (T of a few hundred, N of a few
hundred), so what a filter costs apart from its particles, and what the sampler does around it,
decide the time. This case times it on two problems, the bootstrap filter with systematic
resampling when the ESS falls below N/2 (``particles``' default inside its PMMH), N = 100 and
1000:

* **sv**: the stochastic-volatility plugin (``examples/plugins/stochastic_volatility.py``;
  :math:`x_k = \mu + \phi (x_{k-1} - \mu) + \sigma w_k`, :math:`y_k = e^{x_k/2} v_k`) on the 201
  GBP/USD returns of ``examples/data/gbp-usd-returns.csv``, against ``particles``' own
  ``StochVol``; priors :math:`\mu \sim N(0, 2^2)`, :math:`\phi \sim \mathrm{Beta}(9, 1)`,
  :math:`\sigma \sim \mathrm{Gamma}(2, \text{rate } 2)` (Chopin & Papaspiliopoulos' scripts for
  these returns), chains started at Pitt & Shephard's values;
* **nile**: the local level (pfx's ``linear_gaussian``: :math:`x_k = x_{k-1} + w_k`,
  :math:`z_k = x_k + v_k`, :math:`x_0 \sim N(0, 10^7)`) on the 100 flows of
  ``examples/data/nile.csv``, against a ``particles`` ``StateSpaceModel`` written here with the
  same law (its first state is observed, so its initial law is pfx's :math:`x_1`,
  :math:`N(0, 10^7 + q)`); both variances uniform on :math:`[10^2, 10^6]`, chains started at
  Durbin & Koopman's maximum-likelihood values.

Implementations, in this one process, interleaved (the order rotates from round to round), best
of several rounds: pfx's sampler with 1 chain, and with 16 chains advancing as one batch of the
engine (:mod:`pfx.estimation.target`), both with a fixed random walk (``adapt: false``), on the
numpy backend and (where JAX is installed) on the jax backend, whose blocks of iterations are
one compiled program (:mod:`pfx.estimation.compiled_pmmh`; an untimed round compiles them
first); and ``particles``' ``mcmc.PMMH`` (one chain; ``adaptive=False``). Each first runs 10 iterations
that are not timed (first use of compiled code, caches); then each round times a block of 50
iterations (short blocks, many rounds: on a shared machine the best round is the one least
disturbed; ``--quick``: 3 and 3, a warm-up as long as a round, so that the jax rows compile one
block length only). pfx walks on its transformed scale (logit for :math:`\phi` and the Nile variances,
log for :math:`\sigma`), ``particles`` on the parameters as its prior names them: its random
walk's standard deviations are pfx's times :math:`|d\theta/du|` at the start
(:func:`natural_scale_sds`), the same steps where the chains begin. A proposal outside the
prior's support runs no filter in either, so the table counts the filters run per
chain-iteration beside the acceptance rate; and, as the check that both compute the same
likelihood, the mean of 16 log-likelihood estimates of each at the starting point (for the
Nile, with the Kalman filter's exact value).

The figure of merit is seconds per chain-iteration; the ratio is ``particles``' over pfx's.
``particles`` runs one chain per sampler, so 16 of its chains cost 16 times one. Below the table,
where a pfx iteration goes: the filter, the per-row model validation
(:meth:`~pfx.estimation.target.EstimationTarget.model_at`), the rows' initial laws, the prior
density, and the rest (seeds, proposals, transforms, the accept step), from the best round.
"""

from __future__ import annotations

import copy
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

import pfx

EXAMPLES = Path(pfx.__file__).resolve().parents[1] / "examples"
SIZES = (100, 1_000)
QUICK_SIZES = (100,)
CHAINS = 16
ITERATIONS, WARM_UP = 50, 10                # timed per round; untimed first
QUICK_ITERATIONS, QUICK_WARM_UP = 3, 3          # one block length: the jax rows compile it once
START_RUNS = 16                             # filters at the starting point, for the likelihood check
FILTER = {"kind": "particle", "resampler": "systematic", "ess_threshold": 0.5}
STAGES = ("filter", "model validation", "initial laws", "prior density", "rest")

PITT_SHEPHARD = {"mu": 2.0 * math.log(0.5992), "phi": 0.9702, "sigma": 0.178}
DURBIN_KOOPMAN = {"measurement": 15099.0, "level": 1469.1}
LEVEL_PRIOR_VARIANCE = 1.0e7
VARIANCE_BOUNDS = (1.0e2, 1.0e6)


@dataclass(frozen=True)
class PmmhProblem:
    """One model and dataset: pfx's config (without N and the chain count) and what ``particles`` needs."""

    name: str
    label: str
    config: dict
    peer_names: tuple[str, ...]        # particles' name of each estimated parameter, in pfx's order
    steps: int

    @property
    def seed(self) -> int:
        """The config's root seed: pfx's chains' streams, and particles' global generator."""
        return self.config["seed"]


def _sv_problem() -> PmmhProblem:
    parameters = {
        "model.mu": {"prior": {"law": "normal", "mean": 0.0, "sd": 2.0}, "start": PITT_SHEPHARD["mu"],
                     "proposal_sd": 0.25},
        "model.phi": {"prior": {"law": "beta", "a": 9.0, "b": 1.0}, "start": PITT_SHEPHARD["phi"],
                      "proposal_sd": 0.35},
        "model.sigma": {"prior": {"law": "gamma", "shape": 2.0, "rate": 2.0}, "start": PITT_SHEPHARD["sigma"],
                        "proposal_sd": 0.28}}
    config = {"name": "bench-pmmh-sv", "seed": 1997,
              "plugins": [str(EXAMPLES / "plugins" / "stochastic_volatility.py")],
              "model": {"kind": "stochastic_volatility", **PITT_SHEPHARD},
              "data": {"measurements": str(EXAMPLES / "data" / "gbp-usd-returns.csv")},
              "filter": dict(FILTER), "estimation": {"method": "pmmh", "adapt": False, "parameters": parameters}}
    return PmmhProblem("sv", "SV GBP/USD", config, ("mu", "rho", "sigma"), 201)


def _nile_problem() -> PmmhProblem:
    lower, upper = VARIANCE_BOUNDS
    uniform = {"law": "uniform", "lower": lower, "upper": upper}
    parameters = {
        "model.measurement_noise.variance": {"prior": dict(uniform), "start": DURBIN_KOOPMAN["measurement"],
                                             "proposal_sd": 0.2},
        "model.process_noise.variance": {"prior": dict(uniform), "start": DURBIN_KOOPMAN["level"],
                                         "proposal_sd": 0.6}}
    config = {"name": "bench-pmmh-nile", "seed": 1871,
              "model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                        "names": ["level"], "process_noise": {"variance": DURBIN_KOOPMAN["level"]},
                        "measurement_noise": {"variance": DURBIN_KOOPMAN["measurement"]},
                        "initial": {"kind": "gaussian", "mean": [0.0], "covariance": LEVEL_PRIOR_VARIANCE}},
              "data": {"measurements": str(EXAMPLES / "data" / "nile.csv")},
              "filter": dict(FILTER), "estimation": {"method": "pmmh", "adapt": False, "parameters": parameters}}
    return PmmhProblem("nile", "Nile", config, ("measurement_variance", "level_variance"), 100)


PROBLEMS: dict[str, Callable[[], PmmhProblem]] = {"sv": _sv_problem, "nile": _nile_problem}


def examples_found() -> bool:
    """The problems read the source tree's examples/ (a plugin and two data files)."""
    return (EXAMPLES / "data" / "nile.csv").is_file() and (EXAMPLES / "plugins" / "stochastic_volatility.py").is_file()


def build_target(problem: PmmhProblem, particles: int, chains: int, iterations: int, filter_kind: str = "particle",
                 backend: str = "numpy"):
    """pfx's estimation target for the problem's one cell (its dataset, its filter, the priors)."""
    from pfx.config.plan import build_plan
    from pfx.estimation.target import EstimationTarget, dataset

    raw = copy.deepcopy(problem.config)
    raw["filter"].update(particles=particles, backend=backend)
    if filter_kind != "particle":
        raw["filter"] = {"kind": filter_kind}
    raw["estimation"].update(chains=chains, iterations=iterations)
    # relative paths in a config are read from its folder: the examples' plugins folder here
    plan = build_plan(raw, str(EXAMPLES / "plugins" / f"<pfx bench pmmh {problem.name}>"))
    cell = plan.cells[0]
    return EstimationTarget(cell, plan.experiment.estimation, dataset(cell, plan.experiment.seed)), cell


def start_values(target) -> np.ndarray:
    """The chains' common starting point (p,), natural scale."""
    return np.array([float(target.estimation.parameters[path].start) for path in target.paths])


def natural_scale_sds(target) -> np.ndarray:
    r"""The random walk's standard deviations on the natural scale at the starting point:
    :math:`s_j\, |d\theta_j / du_j|` for pfx's ``proposal_sd`` :math:`s_j` on the transformed scale
    :math:`u_j = g_j(\theta_j)` (``log``: :math:`s\theta`; ``logit`` on (a, b):
    :math:`s (\theta - a)(b - \theta)/(b - a)`; ``none``: :math:`s`), what ``particles``, which walks
    on :math:`\theta` itself, needs for the same first steps."""
    start = start_values(target)
    scales = np.array([target.estimation.parameters[path].proposal_sd for path in target.paths])
    unconstrained = target.to_unconstrained(start)
    jacobians = np.array([math.exp(float(transform.log_jacobian(unconstrained[j])))
                          for j, transform in enumerate(target.transforms)])
    return scales * jacobians


class StageClock:
    """Seconds spent in the target's stages (module docstring), and the filters asked for.

    It wraps the methods on one target instance (:meth:`attach`); the sampler calls them through
    the instance, so nothing else changes. Its own cost is a clock read per call: microseconds
    in iterations of milliseconds.
    """

    def __init__(self):
        self.seconds = dict.fromkeys(("log_likelihoods", "model_at", "prior_of", "log_prior"), 0.0)
        self.filters = 0

    def attach(self, target) -> None:
        for name in self.seconds:
            setattr(target, name, self._timed(name, getattr(target, name)))

    def _timed(self, name: str, method):
        def timed(*arguments):
            started = time.perf_counter()
            try:
                return method(*arguments)
            finally:
                self.seconds[name] += time.perf_counter() - started
                if name == "log_likelihoods":
                    self.filters += len(arguments[0])
        return timed

    def snapshot(self) -> dict:
        return {**self.seconds, "filters": self.filters}


@dataclass
class PmmhTiming:
    """One implementation on one problem and N: the best round's seconds per iteration."""

    problem: PmmhProblem
    particles: int
    implementation: str
    chains: int
    seconds: float = math.inf          # per iteration (all chains), best round
    rounds: int = 0
    filters: int = 0                   # filters run, over the timed chain-iterations
    accepted: int = 0
    chain_iterations: int = 0
    stages: dict = field(default_factory=dict)      # pfx: seconds per iteration of each stage, best round
    start_log_likelihoods: Optional[np.ndarray] = None
    error: Optional[str] = None

    @property
    def label(self) -> str:
        return f"{self.problem.label}, N={self.particles}"

    @property
    def per_chain_iteration(self) -> float:
        return self.seconds / self.chains

    @property
    def acceptance(self) -> float:
        return self.accepted / self.chain_iterations if self.chain_iterations else math.nan

    @property
    def filters_per_chain_iteration(self) -> float:
        return self.filters / self.chain_iterations if self.chain_iterations else math.nan


class PfxRunner:
    """pfx's PMMH sampler on the problem (C chains as rows of one batch), on either backend: on
    jax, blocks of iterations compiled (:mod:`pfx.estimation.compiled_pmmh`), every chain's filter
    computed at every iteration (a proposal the prior refuses is masked, not skipped)."""

    def __init__(self, problem: PmmhProblem, particles: int, chains: int, total: int, backend: str = "numpy"):
        from pfx.estimation.compiled_pmmh import CompiledChains
        from pfx.estimation.pmmh import ParticleMarginalMetropolisHastings

        self.backend = backend
        self.target, cell = build_target(problem, particles, chains, total, backend=backend)
        sampler = ParticleMarginalMetropolisHastings(self.target, problem.seed, cell.stream_key)
        self.sampler = CompiledChains(sampler) if backend == "jax" else sampler
        self.clock = StageClock()
        self.clock.attach(self.target)
        self.chains = self.sampler.start()
        self.start_log_likelihoods = self.chains.log_likelihood.copy()
        self.iteration, self.compiled_filters = 0, 0

    @property
    def filters(self) -> int:
        return self.compiled_filters if self.backend == "jax" else self.clock.filters

    def snapshot(self) -> Optional[dict]:
        return {**self.clock.snapshot(), "backend": self.backend}

    def advance(self, count: int) -> int:
        """``count`` more iterations of every chain; returns the accepted moves."""
        accepted = []
        self.sampler.run(self.chains, self.iteration + 1, self.iteration + count,
                         lambda iteration, moved: accepted.append(int(moved.sum())))
        self.iteration += count
        self.compiled_filters += count * len(self.chains.values)
        return sum(accepted)


def jax_installed() -> bool:
    from importlib.util import find_spec

    return find_spec("jax") is not None


def _peer_problem(problem: PmmhProblem, target) -> dict:
    """``particles``' model class, prior, data and starting point for the problem."""
    from particles import distributions, state_space_models

    if problem.name == "sv":
        model = state_space_models.StochVol
        laws = OrderedDict(mu=distributions.Normal(loc=0.0, scale=2.0), rho=distributions.Beta(a=9.0, b=1.0),
                           sigma=distributions.Gamma(a=2.0, b=2.0))      # Gamma(a, b): b is the rate
    else:
        class LocalLevel(state_space_models.StateSpaceModel):
            """x_k = x_(k-1) + N(0, q), z_k = x_k + N(0, r); the first state observed is pfx's x_1."""

            default_params = {"measurement_variance": DURBIN_KOOPMAN["measurement"],
                              "level_variance": DURBIN_KOOPMAN["level"]}

            def PX0(self):
                return distributions.Normal(loc=0.0, scale=math.sqrt(LEVEL_PRIOR_VARIANCE + self.level_variance))

            def PX(self, t, xp):
                return distributions.Normal(loc=xp, scale=math.sqrt(self.level_variance))

            def PY(self, t, xp, x):
                return distributions.Normal(loc=x, scale=math.sqrt(self.measurement_variance))

        model = LocalLevel
        lower, upper = VARIANCE_BOUNDS
        laws = OrderedDict((name, distributions.Uniform(a=lower, b=upper)) for name in problem.peer_names)
    prior = distributions.StructDist(laws)
    start = np.empty(1, dtype=prior.dtype)
    for name, value in zip(problem.peer_names, start_values(target)):
        start[name] = value
    return {"model": model, "prior": prior, "data": np.asarray(target.measurements[:, 0], dtype=float),
            "start": start}


class ParticlesRunner:
    """``particles``' ``mcmc.PMMH`` on the problem, one chain, driven step by step (what its
    ``run()`` does), the filters it runs counted."""

    def __init__(self, problem: PmmhProblem, particles: int, total: int, target, seed: int):
        import particles as library
        from particles import mcmc, state_space_models

        from pfx.bench.peers import global_generator_seeded

        pieces = _peer_problem(problem, target)
        order = {name: j for j, name in enumerate(problem.peer_names)}
        sds = natural_scale_sds(target)
        names = [entry[0] for entry in pieces["prior"].dtype]      # a list of (name, type) pairs
        covariance = np.diag([sds[order[name]] ** 2 for name in names])
        runner = self

        class CountedPMMH(mcmc.PMMH):
            def alg_instance(self, theta):
                runner.filters += 1
                return super().alg_instance(theta)

        self.filters, self.seed, self.iteration = 0, seed, 0
        self.seeded = global_generator_seeded
        self.sampler = CountedPMMH(ssm_cls=pieces["model"], prior=pieces["prior"], data=pieces["data"], Nx=particles,
                                   niter=total + 1, theta0=pieces["start"], adaptive=False, rw_cov=covariance)
        start = {name: float(pieces["start"][name][0]) for name in names}
        with self.seeded(seed):             # particles draws from NumPy's global generator
            self.sampler.step0()
            estimates = []
            for _ in range(START_RUNS):      # its filter as its PMMH runs it (SMC's defaults)
                run = library.SMC(fk=state_space_models.Bootstrap(ssm=pieces["model"](**start), data=pieces["data"]),
                                  N=particles, collect="off")
                run.run()
                estimates.append(run.logLt)
        self.start_log_likelihoods = np.array(estimates)
        self.filters = 0

    def snapshot(self) -> Optional[dict]:
        return None                          # its stages are not clocked

    def advance(self, count: int) -> int:
        accepted = self.sampler.nacc
        with self.seeded(self.seed + self.iteration + 1):
            for _ in range(count):
                self.iteration += 1
                self.sampler.step(self.iteration)
        return self.sampler.nacc - accepted


def exact_start_log_likelihood(problem: PmmhProblem) -> Optional[float]:
    """The Kalman filter's exact log-likelihood at the Nile's starting point (None for SV)."""
    if problem.name != "nile":
        return None
    target, _ = build_target(problem, 1, 1, 1, filter_kind="kf")
    return float(target.log_likelihoods(start_values(target)[None], [0])[0])


def time_pmmh(*, quick: bool = False, repeats: int = 3, peers: bool = True,
              progress: Callable[[str], None] = lambda message: None, problems: Optional[tuple[str, ...]] = None,
              sizes: Optional[tuple[int, ...]] = None) -> list[PmmhTiming]:
    """Best seconds per iteration of each implementation on each problem and N (module docstring)."""
    import warnings

    from pfx.bench.peers import peer_version

    iterations, warm_up = (QUICK_ITERATIONS, QUICK_WARM_UP) if quick else (ITERATIONS, WARM_UP)
    total = warm_up + repeats * iterations
    with_particles = peers and peer_version("particles") is not None
    timings = []
    for name, make in PROBLEMS.items():
        if problems is not None and name not in problems:
            continue
        problem = make()
        for particles in sizes or (QUICK_SIZES if quick else SIZES):
            rows, runners = {}, {}
            for implementation, chains in implementations(with_particles):
                row = rows[implementation] = PmmhTiming(problem, particles, implementation, chains)
                progress(f"pmmh, {row.label}: {implementation} (start, {warm_up} untimed iterations)")
                try:
                    with np.errstate(all="ignore"), warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        if implementation.startswith("pfx"):
                            backend = "jax" if implementation.startswith("pfx jax") else "numpy"
                            runner = PfxRunner(problem, particles, chains, total + iterations, backend)
                        else:
                            target = runners["pfx, 1 chain"].target
                            runner = ParticlesRunner(problem, particles, total, target, problem.seed)
                        runner.advance(warm_up)
                        if implementation.startswith("pfx jax") and warm_up != iterations:
                            runner.advance(iterations)      # compiles the timed rounds' blocks, untimed
                except Exception as error:         # a peer that breaks is reported, not fatal
                    row.error = f"{type(error).__name__}: {error}".splitlines()[0][:80]
                    if implementation.startswith("pfx"):
                        raise
                    continue
                runners[implementation] = runner
                row.start_log_likelihoods = runner.start_log_likelihoods
            names = list(runners)
            for repeat in range(repeats):
                for implementation in names[repeat % len(names):] + names[:repeat % len(names)]:
                    row, runner = rows[implementation], runners[implementation]
                    progress(f"pmmh, {row.label}: {implementation} (round {repeat + 1}, {iterations} iterations)")
                    before, filters = runner.snapshot(), runner.filters
                    with np.errstate(all="ignore"), warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        started = time.perf_counter()
                        accepted = runner.advance(iterations)
                        seconds = (time.perf_counter() - started) / iterations
                    row.rounds += 1
                    row.accepted += accepted
                    row.chain_iterations += iterations * row.chains
                    row.filters += runner.filters - filters
                    if seconds < row.seconds:
                        row.seconds = seconds
                        if before is not None:
                            row.stages = _stages(before, runner.snapshot(), seconds, iterations)
            timings += rows.values()
    return timings


def implementations(with_particles: bool) -> tuple[tuple[str, int], ...]:
    """The rows of each case: pfx on numpy and (where JAX is installed) on jax, 1 and
    :data:`CHAINS` chains; particles' one chain."""
    backends = ("pfx", "pfx jax") if jax_installed() else ("pfx",)
    rows = tuple((f"{name}, {label}", chains) for name in backends
                 for label, chains in (("1 chain", 1), (f"{CHAINS} chains", CHAINS)))
    return rows + ((("particles, 1 chain", 1),) if with_particles else ())


def _stages(before: dict, after: dict, seconds: float, iterations: int) -> dict:
    """Seconds per iteration of each stage (:data:`STAGES`) from two clock snapshots. On jax the
    host's stages are those of the callback, and "filter" is the compiled rest (the filter, the
    proposals and the accept step, one program): "rest" is 0."""
    spent = {name: (after[name] - before[name]) / iterations for name in before if name not in ("filters", "backend")}
    if before.get("backend") == "jax":
        host = spent["model_at"] + spent["prior_of"] + spent["log_prior"]
        return {"filter": max(seconds - host, 0.0), "model validation": spent["model_at"],
                "initial laws": spent["prior_of"], "prior density": spent["log_prior"], "rest": 0.0}
    return {"filter": spent["log_likelihoods"] - spent["model_at"] - spent["prior_of"],
            "model validation": spent["model_at"], "initial laws": spent["prior_of"],
            "prior density": spent["log_prior"],
            "rest": seconds - spent["log_likelihoods"] - spent["log_prior"]}
