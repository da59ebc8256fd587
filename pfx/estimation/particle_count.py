r"""Choosing PMMH's particle count N from a pilot: the rule behind ``particles: auto``.

**Why the sd of the log-likelihood estimate.** PMMH (:mod:`pfx.estimation.pmmh`) targets the
exact posterior whatever N, but a chain that accepts a lucky overestimate of the likelihood
sticks there, so the noise of :math:`\hat\ell = \log\hat p_\theta(z_{1:T})` slows its mixing.
More particles cost more per iteration and buy fewer iterations per independent draw. Doucet,
Pitt, Deligiannidis & Kohn (2015, *Biometrika* 102) show that the computing time per independent
draw is smallest when :math:`\operatorname{sd}\hat\ell \approx 1.2` at the posterior's centre
(flat between about 1 and 1.7): that is ``target_sd``.

**The 1/N law.** For a filter whose estimate is unbiased, :math:`\operatorname{Var}\hat\ell
\approx c_\theta / N` once N is large enough, so :math:`\operatorname{sd} \propto N^{-1/2}` and
the N that gives a target sd t from a measured :math:`(N_k, s_k)` is :math:`N_k (s_k / t)^2`.

**The rule** (:func:`choose_particle_count`), with ``spread_at(N)`` measuring the sd over R runs
(:func:`pfx.estimation.likelihood_spread.log_likelihood_spread`):

1. the ladder: N = ``smallest``, 2 ``smallest``, 4 ``smallest``, ... (the last rung at
   ``largest``, the cap), measured until the sd is at or below the target, or the cap is
   measured. A rung where some run's estimate is :math:`-\infty` (every particle lost its weight
   at some step) counts as an sd above any target;
2. one more N, predicted by the 1/N law from the first rung at or below the target, k, and the
   one before it: the law fitted through both on the log scale with its slope fixed at
   :math:`-1/2`, which is the geometric mean of their two predictions,
   :math:`N^* = \sqrt{N_{k-1} (s_{k-1}/t)^2 \cdot N_k (s_k/t)^2}` (:math:`N_k (s_k/t)^2` alone when
   k is the first rung or the one before it had :math:`-\infty` runs), rounded and kept within
   [``smallest``, ``largest``]; measured too unless it was already;
3. the choice: the measured N whose sd is nearest the target on the log scale,
   :math:`|\log s - \log t|` smallest (ties: the smaller N).

Even the cap above the target is a :class:`~pfx.errors.ConfigError` in one line (the sd reached
at the cap, the point, the target, the N the law asks for, what to try), raised before any chain
runs. **Its precision**: the sd of R runs has a relative standard error of about
:math:`1/\sqrt{2(R-1)}` (for a near-normal :math:`\hat\ell`), and since :math:`N \propto
\operatorname{sd}^2` a predicted N's is about twice that: :math:`2/\sqrt{2(R-1)}`, 23 % at the
default R = 40. That is good enough: the optimum is flat. **Its cost**: about
(rungs + 1) × R filter runs, most of them at the last, largest rungs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import pandas as pd

from pfx.config.estimation import ParticleCount
from pfx.config.estimation_tables import PARTICLE_COUNT
from pfx.errors import ConfigError
from pfx.estimation.likelihood_spread import Spread

# how a config's refusal names the cap, and the ways to measure nearer the posterior's centre
CONFIG_LARGEST = "estimation.particle_count.largest"
CONFIG_NEARER = "a start nearer it, or estimation.particle_count.at"
COLUMNS = PARTICLE_COUNT.own       # particle_count.csv's own columns, after the cell's


@dataclass(frozen=True)
class ParticleChoice:
    """The rule's answer: the chosen N and every measured row, in the order measured (the
    ladder, then the predicted N if it was new)."""

    particles: int
    rows: tuple[Spread, ...]

    @property
    def chosen(self) -> Spread:
        return next(row for row in self.rows if row.particles == self.particles)

    def table(self) -> pd.DataFrame:
        """The rows as particle_count.csv has them, without the cell's columns."""
        return pd.DataFrame([{**row.columns(), "chosen": row.particles == self.particles} for row in self.rows],
                            columns=list(COLUMNS))


def effective_sd(row: Spread) -> float:
    """The sd the rule compares: +inf where some run had no likelihood (an sd above any target)."""
    return row.sd if row.finite == row.runs and math.isfinite(row.sd) else math.inf


def _log(value: float) -> float:
    """log, with log 0 = -inf (an sd of exactly 0: a filter whose estimate does not vary)."""
    return math.log(value) if value > 0 else -math.inf


def ladder(settings: ParticleCount) -> list[int]:
    """smallest, 2 smallest, 4 smallest, ..., the cap last."""
    rungs = [settings.smallest]
    while rungs[-1] < settings.largest:
        rungs.append(min(2 * rungs[-1], settings.largest))
    return rungs


def predicted(rows: Sequence[Spread], target_sd: float) -> float:
    """The N the 1/N law puts at ``target_sd`` from the measured rows with a finite sd (the
    geometric mean of each row's N (sd / target)^2: the law fitted on the log scale)."""
    logs = [math.log(row.particles) + 2 * (_log(effective_sd(row)) - math.log(target_sd))
            for row in rows if math.isfinite(effective_sd(row))]
    return math.exp(sum(logs) / len(logs)) if logs else math.inf


def choose_particle_count(spread_at: Callable[[int], Spread], settings: ParticleCount, *, key: str,
                          point_text: str, file: str | None = None, largest_name: str = CONFIG_LARGEST,
                          nearer: str = CONFIG_NEARER) -> ParticleChoice:
    """The rule of the module docstring. ``spread_at(N)`` measures; ``key`` (``filter.particles``,
    an arm's ``arms.<name>.particles``), ``point_text`` (the parameters, in words) and ``file``
    place the refusal when even ``largest`` leaves the sd above the target; ``largest_name`` and
    ``nearer`` name the cap and how to measure nearer the posterior's centre (a config's keys,
    or :func:`pfx.choose_particles`'s arguments)."""
    target = settings.target_sd
    rows: list[Spread] = []
    for particles in ladder(settings):
        rows.append(spread_at(particles))
        if effective_sd(rows[-1]) <= target:
            break
    if effective_sd(rows[-1]) > target:
        raise _refusal(rows[-1], settings, key, point_text, file, largest_name, nearer)
    wanted = predicted(rows[-2:], target)
    extra = int(min(max(round(wanted), settings.smallest), settings.largest))
    if extra not in {row.particles for row in rows}:
        rows.append(spread_at(extra))
    candidates = [row for row in rows if math.isfinite(effective_sd(row))]
    best = min(candidates, key=lambda row: (abs(_log(effective_sd(row)) - math.log(target)), row.particles))
    return ParticleChoice(best.particles, tuple(rows))


def _refusal(cap: Spread, settings: ParticleCount, key: str, point_text: str, file: str | None, largest_name: str,
             nearer: str) -> ConfigError:
    sd = effective_sd(cap)
    if math.isfinite(sd):
        reached = f"the sd of the log-likelihood estimate is {sd:.3g}"
        asks = f"the 1/N law asks for about {predicted([cap], settings.target_sd):,.0f} particles"
    else:
        reached = (f"{cap.runs - cap.finite} of {cap.runs} filter runs lost every particle's weight at some step "
                   "(a likelihood estimate of 0)")
        asks = "the 1/N law cannot say how many more would do"
    return ConfigError(f"even at the cap of {cap.particles:,} particles ({largest_name}) {reached} at "
                       f"{point_text}, above the target {settings.target_sd:g}; {asks}; raise {largest_name}, "
                       f"measure nearer the posterior's centre ({nearer}), or use a filter with a better proposal",
                       file=file, key=key)
