r"""PMMH on the jax backend: a block of iterations of every chain as one compiled program.

The algorithm is :mod:`pfx.estimation.pmmh`'s, step for step (propose on the transformed scale,
estimate, accept; Haario et al.'s covariance during the warm-up, frozen after it); what changes
is where it runs. The chains' state is an explicit value carried by a ``lax.scan`` over the
iterations of a block:

    iteration(state, (i, filter keys, move keys)) -> (state, (theta, log L, log prior, accepted))

* ``state`` holds each chain's point (natural and transformed), its log-likelihood estimate, log
  prior and log Jacobian, and (with ``adapt``) its history :math:`u_0, \dots, u_{i-1}` up to the
  warm-up's end, from which the covariance is computed (it freezes after the warm-up, as on
  numpy);
* chain c's iteration i draws its proposal and accept from the threefry key of its move seed and
  its filter from that of its filter seed (:func:`pfx.numerics.seeding.chain_seeds`, the seeds
  the NumPy backend's generators use), computed on the host for the block: a chain's numbers
  depend on its seeds only, so a run stopped between blocks and resumed continues exactly;
* the filter is :class:`~pfx.estimation.compiled_filter.CompiledFilter`'s, vectorised over
  chains x particles, the parameters its arguments;
* the prior density, the transforms' Jacobian, the model's check of the proposed point and the
  initial law it implies are computed on the host from the proposal, by the same code the NumPy
  backend runs, through one ``jax.pure_callback`` per iteration.

The two backends draw from different generators: their chains agree in distribution (the
posterior), not number for number.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from pfx.estimation.compiled_filter import double_precision_everywhere
from pfx.estimation.pmmh import ADAPTIVE_SCALE, REGULARISATION, Chains, ParticleMarginalMetropolisHastings
from pfx.numerics.key_streams import threefry_keys

BLOCK = 25        # iterations per compiled call: a run can stop (and save) between blocks


class ChainState(NamedTuple):
    """What one iteration hands the next (C chains, p parameters)."""

    natural: object           # (C, p) theta
    unconstrained: object     # (C, p) u = g(theta)
    log_likelihood: object    # (C,)
    log_prior: object         # (C,)
    log_jacobian: object      # (C,) log |d theta / du| at u
    history: object           # (C, warm_up + 1, p): u_0, u_1, ... as far as known (adapt only; else (C, 0, p))


class CompiledChains:
    """The chains of one PMMH cell on the jax backend (module docstring)."""

    block_size = BLOCK        # iterations the runner hands over at once

    def __init__(self, sampler: ParticleMarginalMetropolisHastings):
        self.sampler, self.target = sampler, sampler.target
        self.filter = self.target.compiled_filter
        settings = self.target.estimation
        self.scales = np.array([settings.parameters[path].proposal_sd for path in self.target.paths])
        self.warm_up, self.adapt, self.adapt_after = settings.warm_up, settings.adapt, settings.adapt_after
        self._programs: dict[int, object] = {}

    # -- on the host --------------------------------------------------------------------------------

    def start(self) -> Chains:
        """Iteration 0, as on numpy (its filters run by the compiled filter)."""
        return self.sampler.start()

    def run(self, chains: Chains, first: int, last: int, report: Callable[[int, np.ndarray], None]) -> Chains:
        """Iterations first..last, in compiled blocks of at most :data:`BLOCK`; after each block,
        ``chains`` is set to each of its iterations in turn (as
        :meth:`ParticleMarginalMetropolisHastings.iterate` leaves it) and ``report(iteration,
        accepted)`` called."""
        for start in range(first, last + 1, BLOCK):
            self._run_block(chains, start, min(start + BLOCK - 1, last), report)
        return chains

    def _run_block(self, chains: Chains, first: int, last: int, report) -> None:
        import jax

        iterations = np.arange(first, last + 1)
        seeds = [self.sampler.seeds(int(i)) for i in iterations]
        filter_keys = np.stack([threefry_keys(filter_seeds) for filter_seeds, _ in seeds])
        move_keys = np.stack([threefry_keys(move_seeds) for _, move_seeds in seeds])
        with double_precision_everywhere():
            program = self._programs.get(len(iterations))
            if program is None:
                program = self._programs[len(iterations)] = jax.jit(self._block)
            outputs = program(self._state(chains, first), (iterations, filter_keys, move_keys),
                              self.filter.inputs(len(chains.values)))
            natural, log_likelihood, log_prior, accepted = (np.asarray(value) for value in jax.device_get(outputs))
        for index, iteration in enumerate(iterations):
            chains.values = natural[index].copy()
            chains.log_likelihood, chains.log_prior = log_likelihood[index].copy(), log_prior[index].copy()
            chains.history.append(chains.values.copy())
            report(int(iteration), accepted[index].astype(bool))

    def _state(self, chains: Chains, first: int) -> ChainState:
        """The carried state at the start of iteration ``first``; the history holds u_0 ..
        u_(k-1), k = min(first - 1, warm_up + 1), the points iteration ``first`` has not yet
        added, each u = g(theta) of the table's theta, as the callback gives it mid-block (so a
        block computes the same numbers wherever the run was stopped and resumed)."""
        target = self.target
        unconstrained = target.to_unconstrained(chains.values)
        history = np.zeros((len(chains.values), self.warm_up + 1 if self.adapt else 0, target.dimension))
        known = min(first - 1, history.shape[1])
        if known:
            history[:, :known] = target.to_unconstrained(np.stack(chains.history[:known], axis=1))
        return ChainState(natural=chains.values, unconstrained=unconstrained, log_likelihood=chains.log_likelihood,
                          log_prior=chains.log_prior, log_jacobian=target.log_jacobian(unconstrained), history=history)

    def host_view(self, proposed: np.ndarray):
        """For proposed points u' (C, p): theta' = g^-1(u'), u = g(theta') again (the point the
        chain carries if it accepts: the one a resumed run reads back from the table), the log
        prior and log Jacobian there, whether the model accepts each point, and the initial laws
        there; the NumPy backend's own code."""
        target = self.target
        natural = target.to_natural(np.asarray(proposed, dtype=float))
        unconstrained = target.to_unconstrained(natural)
        log_prior = np.asarray(target.log_prior(natural), dtype=float)
        inside = np.isfinite(log_prior)
        valid, means, factors = self.filter.host_laws(np.where(inside[:, None], natural, np.nan))
        return (natural, unconstrained, log_prior, np.asarray(target.log_jacobian(unconstrained), dtype=float),
                valid, means, factors)

    # -- traced -------------------------------------------------------------------------------------

    def _block(self, state: ChainState, per_iteration, inputs):
        import jax

        def iteration(carried, place):
            carried, outputs = self._iteration(carried, place, inputs)
            return carried, outputs

        _, outputs = jax.lax.scan(iteration, state, per_iteration)
        return outputs

    def _iteration(self, state: ChainState, place, inputs):
        import jax
        import jax.numpy as jnp

        iteration, filter_keys, move_keys = place
        chains, dimension = state.natural.shape
        state, covariances = self._adapted(state, iteration)
        steps = jax.vmap(lambda key: jax.random.normal(jax.random.fold_in(key, 0), (dimension,), jnp.float64))(move_keys)
        uniforms = jax.vmap(lambda key: jax.random.uniform(jax.random.fold_in(key, 1), (), jnp.float64))(move_keys)
        proposed = state.unconstrained + jnp.einsum("cij,cj->ci", jnp.linalg.cholesky(covariances), steps)
        rows, points = jax.ShapeDtypeStruct((chains,), jnp.float64), jax.ShapeDtypeStruct((chains, dimension), jnp.float64)
        d = self.filter.state_dimension
        shapes = (points, points, rows, rows, jax.ShapeDtypeStruct((chains,), jnp.bool_),
                  jax.ShapeDtypeStruct((chains, d), jnp.float64), jax.ShapeDtypeStruct((chains, d, d), jnp.float64))
        natural, unconstrained, log_prior, log_jacobian, valid, means, factors = jax.pure_callback(
            self.host_view, shapes, proposed)
        safe = jnp.where(valid[:, None], natural, state.natural)      # a refused row's filter runs at its current point
        log_likelihood = self.filter.log_likelihood(safe, filter_keys, means, factors, inputs)
        log_likelihood = jnp.where(valid, log_likelihood, -jnp.inf)
        log_ratio = (log_likelihood + log_prior + log_jacobian
                     - state.log_likelihood - state.log_prior - state.log_jacobian)
        accepted = jnp.isfinite(log_likelihood) & (jnp.log(uniforms) < log_ratio)

        def chosen(new, old):
            return jnp.where(accepted.reshape(accepted.shape + (1,) * (new.ndim - 1)), new, old)

        state = state._replace(natural=chosen(natural, state.natural), unconstrained=chosen(unconstrained, state.unconstrained),
                               log_likelihood=chosen(log_likelihood, state.log_likelihood),
                               log_prior=chosen(log_prior, state.log_prior),
                               log_jacobian=chosen(log_jacobian, state.log_jacobian))
        return state, (state.natural, state.log_likelihood, state.log_prior, accepted)

    def _adapted(self, state: ChainState, iteration):
        """Sigma_i of every chain (C, p, p), as :meth:`ParticleMarginalMetropolisHastings.covariances`:
        diag(s^2) until more than ``adapt_after`` points are known, then 2.38^2 / p (the
        covariance of u_0 .. u_(k-1), k = min(i - 1, warm_up) + 1, + 1e-10 I); u_(i-1), the
        chain's point before iteration i, joins the history first while i - 1 <= warm_up."""
        import jax.numpy as jnp

        chains, dimension = state.natural.shape
        initial = jnp.broadcast_to(jnp.diag(jnp.asarray(self.scales**2)), (chains, dimension, dimension))
        if not self.adapt:
            return state, initial
        place = jnp.minimum(iteration - 1, self.warm_up)
        joins = iteration - 1 <= self.warm_up
        history = state.history.at[:, place].set(jnp.where(joins, state.unconstrained, state.history[:, place]))
        known = place + 1
        kept = (jnp.arange(self.warm_up + 1) < known)[None, :, None]
        mean = jnp.sum(jnp.where(kept, history, 0.0), axis=1) / known
        centred = jnp.where(kept, history - mean[:, None, :], 0.0)
        covariance = jnp.einsum("cki,ckj->cij", centred, centred) / jnp.maximum(known - 1, 1)
        adapted = ADAPTIVE_SCALE / dimension * (covariance + REGULARISATION * jnp.eye(dimension))
        return state._replace(history=history), jnp.where(known > self.adapt_after, adapted, initial)
