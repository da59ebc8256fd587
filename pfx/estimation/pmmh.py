r"""Particle marginal Metropolis-Hastings (Andrieu, Doucet & Holenstein 2010), many chains at once.

Metropolis-Hastings on the parameters :math:`\theta`, with the particle filter's unbiased
estimate :math:`\hat p_\theta(z_{1:T})` in place of the likelihood. Each chain moves on the
transformed scale :math:`u = g(\theta)` (:mod:`pfx.laws.priors`) by a Gaussian random walk; at
iteration i, from the current :math:`(u, \hat\ell)`:

1. **propose** :math:`u' = u + L\,\varepsilon`, :math:`\varepsilon \sim N(0, I)`, with
   :math:`L L^\top = \Sigma_i`, and :math:`\theta' = g^{-1}(u')`;
2. **estimate** :math:`\hat\ell' = \log \hat p_{\theta'}(z_{1:T})` with a fresh run of the
   filter (skipped, and the proposal rejected, where :math:`\pi(\theta') = 0`);
3. **accept** with probability :math:`\min(1, e^{a})`,

   .. math::

       a = \hat\ell' + \log\pi(\theta') + \log|J(u')| - \hat\ell - \log\pi(\theta) - \log|J(u)|,

   :math:`|J(u)| = |d\theta/du|`; on acceptance the chain keeps :math:`\hat\ell'` (never
   re-estimated: that is what makes the chain's limit the exact posterior whatever N).

The random walk's covariance is :math:`\Sigma = \mathrm{diag}(s_j^2)` (``proposal_sd``) until
``adapt_after`` iterations; then, during the warm-up only, Haario, Saksman & Tamminen's (2001)
adaptive Metropolis: :math:`\Sigma_i = \frac{2.38^2}{p} (\widehat{\mathrm{Cov}}(u_0, \dots,
u_{i-1}) + 10^{-10} I)` from the chain's own history, frozen at the end of the warm-up, so that
the iterations after it (the ones summarised) are a plain Metropolis-Hastings chain.

All chains advance together: step 2 is one batch of the engine (:mod:`pfx.estimation.target`).
Chain c's iteration i draws its proposal and its accept from its own generator and its filter
from its own stream (:func:`pfx.numerics.seeding.chain_seeds`), so a chain's numbers are the
same whatever the other chains, and a run resumed from its table continues exactly as it would
have.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from pfx.estimation.target import EstimationTarget
from pfx.numerics.seeding import chain_seeds

ADAPTIVE_SCALE = 2.38**2
REGULARISATION = 1e-10


@dataclass
class Chains:
    """The chains' current state and their history (natural scale)."""

    values: np.ndarray            # (C, p) current parameters
    log_likelihood: np.ndarray    # (C,) current estimate
    log_prior: np.ndarray         # (C,)
    history: list = field(default_factory=list)    # one (C, p) array per iteration so far, from 0


class ParticleMarginalMetropolisHastings:
    """PMMH for one cell (module docstring): ``start`` gives iteration 0, :meth:`iterate` the next."""

    def __init__(self, target: EstimationTarget, root_seed: int, cell_key: int):
        self.target, self.root_seed, self.cell_key = target, root_seed, cell_key
        self.settings = target.estimation
        self.chain_count = self.settings.chains

    def seeds(self, iteration: int) -> tuple[list[int], list[int]]:
        pairs = [chain_seeds(self.root_seed, self.cell_key, chain, iteration) for chain in range(self.chain_count)]
        return [pair[0] for pair in pairs], [pair[1] for pair in pairs]

    def start(self) -> Chains:
        """Iteration 0: each chain's starting point (fixed, or drawn from the prior with its own
        generator) and the filter's estimate there; a ConfigError naming the chain and the
        parameters where the model refuses a start or the data have zero likelihood
        (:meth:`EstimationTarget.check_starts`)."""
        filter_seeds, _ = self.seeds(0)
        values = self.target.starting_values(self.root_seed, self.cell_key)
        log_likelihood = self.target.log_likelihoods(values, filter_seeds)
        self.target.check_starts(values, log_likelihood)
        chains = Chains(values, log_likelihood, self.target.log_prior(values))
        chains.history.append(values.copy())
        return chains

    def covariances(self, chains: Chains, iteration: int) -> np.ndarray:
        """Sigma_i of every chain, (C, p, p) (module docstring)."""
        settings, dimension = self.settings, self.target.dimension
        scales = np.array([settings.parameters[path].proposal_sd for path in self.target.paths])
        initial = np.broadcast_to(np.diag(scales**2), (self.chain_count, dimension, dimension)).copy()
        known = min(iteration - 1, settings.warm_up) + 1        # u_0 .. u_{known-1}, frozen after warm-up
        if not settings.adapt or known <= settings.adapt_after:
            return initial
        history = self.target.to_unconstrained(np.stack(chains.history[:known], axis=1))    # (C, known, p)
        centred = history - history.mean(axis=1, keepdims=True)
        covariance = np.einsum("cki,ckj->cij", centred, centred) / (known - 1)
        return ADAPTIVE_SCALE / dimension * (covariance + REGULARISATION * np.eye(dimension))

    def iterate(self, chains: Chains, iteration: int) -> np.ndarray:
        """One iteration of every chain (module docstring); returns which chains accepted."""
        filter_seeds, move_seeds = self.seeds(iteration)
        generators = [np.random.default_rng(seed) for seed in move_seeds]
        steps = np.stack([generator.standard_normal(self.target.dimension) for generator in generators])
        log_uniforms = np.log([generator.random() for generator in generators])
        factors = np.linalg.cholesky(self.covariances(chains, iteration))
        current = self.target.to_unconstrained(chains.values)
        proposed = current + np.einsum("cij,cj->ci", factors, steps)
        values = self.target.to_natural(proposed)
        log_prior = self.target.log_prior(values)
        log_likelihood = np.full(self.chain_count, -np.inf)
        inside = np.flatnonzero(np.isfinite(log_prior))
        if inside.size:
            log_likelihood[inside] = self.target.log_likelihoods(values[inside], [filter_seeds[c] for c in inside])
        with np.errstate(invalid="ignore"):
            log_ratio = (log_likelihood + log_prior + self.target.log_jacobian(proposed)
                         - chains.log_likelihood - chains.log_prior - self.target.log_jacobian(current))
        accepted = np.isfinite(log_likelihood) & (log_uniforms < log_ratio)
        chains.values = np.where(accepted[:, None], values, chains.values)
        chains.log_likelihood = np.where(accepted, log_likelihood, chains.log_likelihood)
        chains.log_prior = np.where(accepted, log_prior, chains.log_prior)
        chains.history.append(chains.values.copy())
        return accepted

    block_size = 1          # iterations the runner hands over at once (the jax backend's are compiled blocks)

    def run(self, chains: Chains, first: int, last: int, report: Callable[[int, np.ndarray], None]) -> Chains:
        """Iterations first..last; ``report(iteration, accepted)`` after each."""
        for iteration in range(first, last + 1):
            report(iteration, self.iterate(chains, iteration))
        return chains
