r"""Iterated filtering, IF2 (Ionides, Nguyen, Atchadé, Stoev & King 2015): maximum likelihood
by a particle filter whose particles carry their own, randomly walking, parameters.

Each particle j carries a parameter vector :math:`\Theta_j` (on the transformed scale
:math:`u = g(\theta)`, :mod:`pfx.laws.priors`). Iteration m = 1..M is one bootstrap filter pass
over the data in which, before every transition (and once before the first step),

.. math::

    \Theta_j \leftarrow \Theta_j + \sigma_{m,k}\,\varepsilon_j, \qquad
    \sigma_{m,k} = \sigma\, c^{(m - 1 + k/T)/50},

with :math:`\sigma` each parameter's ``random_walk_sd`` and :math:`c` ``cooling_fraction_50``
(the perturbation after 50 iterations is that fraction of the first: pomp's geometric cooling).
The particle's state then moves and is weighted under its own :math:`\theta_j = g^{-1}(\Theta_j)`,
and resampling carries :math:`\Theta_j` with its state. The swarm left at the end of the pass
(resampled by the last weights if the last step did not resample) starts the next iteration;
as the perturbations cool, it concentrates at the maximum-likelihood estimate. The iteration's
estimate is the swarm's mean (natural scale), its log-likelihood the pass's estimate (of the
perturbed model: close to the likelihood once the perturbations are small).

Replicates (``chains``) are rows of one batch of the engine; each starts its swarm at its own
starting point. The initial state of row r's particles is drawn from the model at row r's
current estimate (the swarm's mean), not at each particle's parameters: an approximation for a
model whose initial law depends on estimated parameters. At the end, :meth:`IteratedFiltering.evaluate`
runs the unperturbed filter ``evaluations`` times at each replicate's estimate: the
log of the mean likelihood, and its standard error by the delta method.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from pfx.errors import ModelNumericalError
from pfx.estimation.target import EstimationTarget, RowPriors
from pfx.estimation.walk_domain import walk_error
from pfx.filters.particle.bound import bind_particle_filter
from pfx.filters.particle.engine import ParticleFilter
from pfx.numerics.log_mean_exp import log_mean_likelihood
from pfx.numerics.log_weights import normalise_rows
from pfx.numerics.seeding import TrialStreams, chain_seeds

COOLING_HORIZON = 50
EVALUATION_STREAMS = 2**40      # the final evaluations' streams: past any iteration's


class PerturbedParameters:
    """The model as IF2's filter sees it: state (R, N, d + p), the last p components each
    particle's parameters on the transformed scale. The engine calls :meth:`transition` and
    :meth:`log_likelihood`; both use the model with the particles' own parameters."""

    def __init__(self, target: EstimationTarget, model, iteration: int, row_priors, row_values):
        self.target, self.model, self.iteration = target, model, iteration
        self.kind = f"{model.kind} (IF2)"
        self.state_dimension = model.state_dimension + target.dimension
        self.angular_components = tuple(model.angular_components)
        self.full_turn = model.full_turn
        self.propagations_per_step = model.propagations_per_step
        self.accumulating_components = tuple(model.accumulating_components)
        self.steps = model.steps
        self.row_priors, self.row_values = row_priors, row_values
        self.sd = np.array([target.estimation.parameters[path].random_walk_sd for path in target.paths])
        self.cooling = target.estimation.cooling_fraction_50
        self.current = None          # the model at the particles' parameters of this step

    def perturbation_sd(self, step: int) -> np.ndarray:
        """sigma_(m,k) of each parameter (module docstring)."""
        return self.sd * self.cooling ** ((self.iteration - 1 + step / self.steps) / COOLING_HORIZON)

    def perturb(self, parameters: np.ndarray, step: int, random: TrialStreams) -> np.ndarray:
        return parameters + self.perturbation_sd(step) * random.standard_normal(parameters.shape[1:])

    def at(self, parameters: np.ndarray):
        natural = self.target.to_natural(parameters)
        try:
            return self.model.with_parameter_arrays(self.target.parameter_arrays(natural))
        except ValueError as error:
            raise walk_error(self.target, self.model, self.iteration, natural, error) or error from None

    def refuse_swarm(self, swarm: np.ndarray, error: Exception) -> None:
        """Raise the ConfigError naming the parameter the model refuses among the particles'
        parameters ``swarm`` (on the transformed scale) after a pass failed with ``error``
        (:func:`pfx.estimation.walk_domain.walk_error`); nothing if the model refuses none."""
        refused = walk_error(self.target, self.model, self.iteration, self.target.to_natural(swarm), error)
        if refused is not None:
            raise refused

    def compiled_step(self):
        return None

    def transition(self, state: np.ndarray, step: int, random: TrialStreams) -> np.ndarray:
        d = self.model.state_dimension
        parameters = self.perturb(state[..., d:], step, random)
        self.current = self.at(parameters)
        try:
            moved = self.current.transition(state[..., :d], step, random)
        except ValueError as error:      # a law refused a parameter (binomial: probability above 1)
            natural = self.target.to_natural(parameters)
            raise walk_error(self.target, self.model, self.iteration, natural, error,
                             self._probe(natural, state[..., :d], step, random)) or error from None
        return np.concatenate([moved, parameters], axis=-1)

    def _probe(self, natural: np.ndarray, state: np.ndarray, step: int, random: TrialStreams):
        """Whether the transition fails again with only parameter j at the particles' values,
        the others at their replicate's estimate (the run stops either way: the draws it takes
        from the streams are never used)."""
        def fails(j: int) -> bool:
            alone = np.broadcast_to(np.asarray(self.row_values)[:, None, :], natural.shape).copy()
            alone[..., j] = natural[..., j]
            try:
                self.model.with_parameter_arrays(self.target.parameter_arrays(alone)).transition(state, step, random)
            except ValueError:
                return True
            except Exception:       # another failure: not the one being explained
                return False
            return False
        return fails if self.row_values is not None else None

    def log_likelihood(self, measurement: np.ndarray, state: np.ndarray) -> np.ndarray:
        return self.current.log_likelihood(measurement, state[..., :self.model.state_dimension])


class SwarmPrior:
    """IF2's initial cloud: each row's states from its model's prior, its parameters the swarm
    perturbed once (step 0)."""

    def __init__(self, perturbed: PerturbedParameters, swarm: np.ndarray):
        self.perturbed, self.swarm = perturbed, swarm

    def sample(self, random: TrialStreams, shape=()) -> np.ndarray:
        states = self.perturbed.row_priors.sample(random, shape)
        parameters = self.perturbed.perturb(self.swarm, 0, random)
        return np.concatenate([states, parameters], axis=-1)


class IteratedFiltering:
    """IF2 for one cell: :meth:`start` the swarms, :meth:`iterate` a pass, :meth:`evaluate` the end."""

    def __init__(self, target: EstimationTarget, root_seed: int, cell_key: int):
        self.target, self.root_seed, self.cell_key = target, root_seed, cell_key
        self.settings = target.estimation
        self.replicates = self.settings.chains
        self.particles = target.cell.filter.particles

    def seeds(self, iteration: int) -> list[int]:
        return [chain_seeds(self.root_seed, self.cell_key, replicate, iteration)[0]
                for replicate in range(self.replicates)]

    def start(self) -> np.ndarray:
        """Iteration 0: every particle of replicate r at r's starting point (transformed), (R, N, p).

        Each start is checked as PMMH's are (:meth:`EstimationTarget.check_starts`): the model
        must accept it and the unperturbed filter find a likelihood above zero there, in a run
        on the replicate's iteration-0 stream, which no pass uses."""
        values = self.target.starting_values(self.root_seed, self.cell_key)
        self.target.check_starts(values, self.target.log_likelihoods(values, self.seeds(0)), "replicate")
        unconstrained = self.target.to_unconstrained(values)
        return np.repeat(unconstrained[:, None, :], self.particles, axis=1)

    def estimates(self, swarm: np.ndarray) -> np.ndarray:
        """Each replicate's estimate: the swarm's mean on the natural scale, (R, p)."""
        return self.target.to_natural(swarm).mean(axis=1)

    def outside_the_domain(self, estimates: np.ndarray, replicate: int, iteration: int = 0) -> Exception:
        """The error of pass ``iteration`` whose replicate's estimate (the swarm's mean) the model
        refuses: the walk's ConfigError naming the parameter, else a ValueError naming the estimate."""
        error = ValueError(f"IF2 replicate {replicate}'s estimate {dict(zip(self.target.columns, estimates[replicate]))} "
                           "is outside the model's domain")
        template = self.target.cell.filter_model
        return walk_error(self.target, template, iteration, estimates[replicate:replicate + 1, None, :], error) or error

    def iterate(self, swarm: np.ndarray, iteration: int) -> tuple[np.ndarray, np.ndarray]:
        """One pass (module docstring): the new swarm and each replicate's log-likelihood estimate."""
        target = self.target
        estimates = self.estimates(swarm)
        models = [target.model_at(row) for row in estimates]
        if any(model is None for model in models):
            raise self.outside_the_domain(estimates, next(r for r, model in enumerate(models) if model is None),
                                          iteration)
        perturbed = PerturbedParameters(target, models[0], iteration, RowPriors([target.prior_of(m) for m in models]),
                                        estimates)
        bound = bind_particle_filter("particle", perturbed, target.cell.filter, SwarmPrior(perturbed, swarm))
        random = TrialStreams.from_seeds(self.seeds(iteration))
        data = np.ascontiguousarray(np.broadcast_to(target.measurements, (self.replicates,) + target.measurements.shape))
        engine = ParticleFilter(bound, data, random)
        try:
            trace = engine.run()
        except ModelNumericalError as error:     # a NaN likelihood where the walk left the model's range?
            finite = np.isfinite(engine.log_weights)
            perturbed.refuse_swarm(engine.state[..., models[0].state_dimension:][finite][None], error)
            raise
        parameters = engine.state[..., models[0].state_dimension:]
        # The swarm that starts the next pass is an equally weighted sample: resample rows whose
        # last weights are not uniform (their last step did not resample).
        log_weights, weights, _ = normalise_rows(engine.log_weights)
        uneven = np.flatnonzero(~trace.resampled[:, -1])
        if uneven.size:
            indices = bound.resampling.indices(weights[uneven], random.subset(uneven))
            parameters = parameters.copy()
            parameters[uneven] = np.take_along_axis(parameters[uneven], indices[..., None], axis=1)
        return parameters, trace.log_likelihood

    block_size = 1          # passes the runner hands over at once (the jax backend's are compiled blocks)

    def run(self, swarm: np.ndarray, first: int, last: int,
            report: Callable[[int, np.ndarray, np.ndarray], None]) -> np.ndarray:
        """Passes first..last; ``report(iteration, swarm, log_likelihood)`` after each."""
        for iteration in range(first, last + 1):
            swarm, log_likelihood = self.iterate(swarm, iteration)
            report(iteration, swarm, log_likelihood)
        return swarm

    def evaluate(self, estimates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""log-likelihood at each replicate's estimate (R, p) by ``evaluations`` runs of the
        unperturbed filter: :math:`\log \frac1K \sum_k \hat L_k`, and its standard error
        :math:`\mathrm{sd}(\hat L_k / \bar L) / \sqrt K` (delta method)."""
        runs = self.settings.evaluations
        rows = np.repeat(estimates, runs, axis=0)
        seeds = [chain_seeds(self.root_seed, self.cell_key, replicate, EVALUATION_STREAMS + run)[0]
                 for replicate in range(self.replicates) for run in range(runs)]
        return log_mean_likelihood(self.target.log_likelihoods(rows, seeds).reshape(self.replicates, runs))
