r"""``pfx bench``'s second table: the newer algorithms against the bootstrap filter.

The first table asks what one particle-step of *the bootstrap filter* costs in pfx and
elsewhere. This one asks what each of pfx's other particle algorithms costs *relative to the
bootstrap*, on the same problem: the falling body of :mod:`pfx.bench.problem` (the same
:data:`~pfx.bench.problem.CONFIG`), the same simulated measurements and the same filter seed
per trial, with one filter setting changed per row:

==========================  ====================================================================
row                         ``filter:`` setting, and what it changes in a step
==========================  ====================================================================
bootstrap                   none: draw from the transition, weigh by the likelihood, resample
                            systematically (the baseline: the first table's ``pfx`` filter)
ekf proposal                ``proposal: ekf``: one extended Kalman update per particle draws
                            :math:`x_k` near the measurement (the PF-EKF); the weight carries
                            :math:`p(x_k \mid x_{k-1}) / q(x_k \mid x_{k-1}, z_k)`
ukf proposal                ``proposal: ukf``: the same with an unscented update per particle
                            (7 sigma points for the 3 states: the unscented particle filter)
locally_optimal proposal    ``proposal: locally_optimal``: :math:`p(x_k \mid x_{k-1}, z_k)` in
                            closed form, which needs :math:`z = H x + v`; the radar's range
                            :math:`\sqrt{M^2 + (x_1 - H)^2}` is not linear, and pfx's validation
                            refuses it: the row says so, with pfx's reason
auxiliary (APF)             ``auxiliary: true``: resample by the look-ahead weights
                            :math:`w\, p(z_k \mid f(x))` before proposing (Pitt & Shephard)
regularise move             ``move: {kind: regularise, kernel: gaussian, bandwidth: optimal}``:
                            after resampling, jitter by a kernel shaped by the weighted
                            covariance (the regularised particle filter)
mcmc move                   ``move: {kind: mcmc, steps: 1, scale: 0.1}``: after resampling, one
                            random-walk Metropolis step per particle (resample-move)
kld adaptive                ``adaptive: {kind: kld, ...}``: KLD-sampling (Fox) draws as many
                            particles as its histogram bound asks, at most N
augmented injection         ``injection: {kind: augmented, ...}``: augmented MCL replaces
                            particles by prior draws when the likelihood's fast average falls
                            below its slow one
==========================  ====================================================================

A setting that pfx's validation refuses for this model is not dropped: its row reads "not
applicable" with validation's one-line reason (``locally_optimal`` here).

**The size.** One case, 20 trials x N = 1000 (``--quick``: 4 x N = 100): the regime of
small clouds and many trials where experiments spend their time, and where a step's fixed
costs (Python calls, small-array set-up) show as much as the work per particle.

**Reading the ratio.** ``ns/particle-step`` is wall time / (trials x N x T) with N the
configured count (KLD's maximum), so that ``x bootstrap``, the ratio of the two wall times,
is the price of switching the setting on at equal N. It is not the price of equal accuracy:
a guided proposal may need fewer particles for the same error, KLD runs fewer than N (the
``mean particles`` column, from the filter's per-step particle counts), and the altitude
RMSE (all trials and steps, the same measurements for every row) says how each fared here.
The RMSEs are of one run of 20 trials; ``tests/test_bench.py`` checks, trial by trial against
the bootstrap, only what theory supports: the proposals, the APF and the mcmc move target the
same posterior and estimate the altitude as well as the bootstrap within 4.5 standard errors.

**The settings chosen for the falling body.** KLD's histogram bins are 100 ft x 100 ft/s x
1e-4 1/ft: the range noise's standard deviation in altitude, the same number in velocity,
and a tenth of the ballistic coefficient (1e-3 1/ft); Fox's epsilon 0.05, delta 0.01.
The mcmc move's proposal is :math:`s \hat\Sigma^{1/2}` with :math:`\hat\Sigma` the cloud's
covariance; the default :math:`s = 2.38/\sqrt d` is for a target as wide as the cloud, but a
particle's target given its parent is much narrower here (the process noise of the
coefficient, 1e-6 1/ft, against a cloud some hundred times wider), and the default accepts
almost nothing; ``scale: 0.1`` accepts a fair share (``move_acceptance``). Injection uses
the book's rates (alpha_slow 0.001, alpha_fast 0.1). With N = 1000 the likelihood rarely
drops once the filter has found the body, so few or no particles are injected and the row
mostly times the bookkeeping of the two averages; with N = 100 (``--quick``) trials lose the
body and injection fires. A line under the table counts the particles injected.

**How it is timed.** Like the first table (:func:`pfx.bench.timing.time_case`): each variant
is one filter bound by :func:`pfx.bench.problem.bench_filter` with the setting added to
``filter:`` (the bootstrap's cell is the same call without one) and run as
:func:`pfx.bench.timing.run_pfx` runs it (the bound filter's call); within each repeat
every variant runs once, in an order rotating from repeat to repeat, and the best time of
``repeats`` counts. Each variant first runs once on a tiny case, so that nothing it compiles
or loads on first use is timed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Optional, Union

import numpy as np

from pfx.bench.problem import Case, FallingBodyProblem, bench_filter, make_case
from pfx.bench.timing import Timing, run_filter, time_case
from pfx.errors import ConfigError
from pfx.filtering import Filter
from pfx.filters.trace import FilterTrace

BASELINE = "bootstrap"
ALGORITHMS: dict[str, dict[str, Any]] = {
    BASELINE: {},
    "ekf proposal": {"proposal": "ekf"},
    "ukf proposal": {"proposal": "ukf"},
    "locally_optimal proposal": {"proposal": "locally_optimal"},
    "auxiliary (APF)": {"auxiliary": True},
    "regularise move": {"move": {"kind": "regularise", "kernel": "gaussian", "bandwidth": "optimal"}},
    "mcmc move": {"move": {"kind": "mcmc", "steps": 1, "scale": 0.1}},
    "kld adaptive": {"adaptive": {"kind": "kld", "epsilon": 0.05, "delta": 0.01,
                                  "bin_size": [100.0, 100.0, 1.0e-4], "min_particles": 10}},
    "augmented injection": {"injection": {"kind": "augmented", "alpha_slow": 0.001, "alpha_fast": 0.1}},
}
FULL_CASE = (1_000, 20)          # (N, trials)
QUICK_CASE = (100, 4)
WARM_UP_CASE = (20, 2)


def algorithm_filters(particles: int) -> dict[str, Union[Filter, str]]:
    """Each algorithm's filter, bound once, or the one-line reason why pfx refuses it for this model."""
    filters: dict[str, Union[Filter, str]] = {}
    for name, settings in ALGORITHMS.items():
        try:
            filters[name] = bench_filter(particles, settings)
        except ConfigError as error:
            filters[name] = " ".join(error.reason.split())
    return filters


class _Variant:
    """A runner for :func:`time_case`: one algorithm's filter on the case, keeping the last trace."""

    def __init__(self, bound: Filter):
        self.filter = bound
        self.trace: Optional[FilterTrace] = None

    def __call__(self, problem: FallingBodyProblem, case: Case) -> np.ndarray:
        self.trace = run_filter(self.filter, case)
        return self.trace.estimates


@dataclass
class AlgorithmResult:
    """One row: the timing (None: not applicable, with the reason) and what the trace showed."""

    name: str
    timing: Optional[Timing] = None
    not_applicable: Optional[str] = None
    mean_particles: float = math.nan     # the particles weighted per step, over trials and steps
    injected: Optional[int] = None       # particles injected over all trials and steps (injection only)


def run_algorithms(*, quick: bool = False, repeats: int = 3, budget: float = 20.0,
                   progress: Callable[[str], None] = lambda message: None) -> list[AlgorithmResult]:
    """Time every algorithm of :data:`ALGORITHMS` on one case (see the module docstring)."""
    particles, trials = QUICK_CASE if quick else FULL_CASE
    case = make_case(particles, trials)
    filters = algorithm_filters(particles)
    runners = {name: _Variant(bound) for name, bound in filters.items() if isinstance(bound, Filter)}

    progress(f"algorithms: each once at {WARM_UP_CASE[1]} x N={WARM_UP_CASE[0]} (warm-up)")
    small = make_case(*WARM_UP_CASE)
    small_filters = algorithm_filters(WARM_UP_CASE[0])
    for name in runners:
        try:
            run_filter(small_filters[name], small)
        except Exception:        # reported by the timed run, not here
            pass

    names = list(runners)
    timings = {timing.implementation: timing
               for timing in time_case(case, names, repeats, budget, progress, runners=runners)}
    results = []
    for name, bound in filters.items():
        if not isinstance(bound, Filter):
            results.append(AlgorithmResult(name, not_applicable=bound))
            continue
        result = AlgorithmResult(name, timings[name])
        trace = runners[name].trace
        if trace is not None:
            counts = trace.particle_counts
            result.mean_particles = float(counts.mean()) if counts is not None else float(particles)
            result.injected = int(trace.injected.sum()) if trace.injected is not None else None
        results.append(result)
    return results
