r"""IF2 on the jax backend: a block of passes of every replicate's swarm as one compiled program.

The algorithm is :mod:`pfx.estimation.if2`'s: each pass is a bootstrap filter over the data
whose particles carry their own parameters, perturbed before every transition by
:math:`\sigma_{m,k} = \sigma c^{(m - 1 + k/T)/50}` and resampled with their states. Here the
passes of a block are a ``lax.scan`` whose carried value is the swarm (R replicates, N
particles, p parameters on the transformed scale), and each pass is the jax engine's own scan
over the steps (:class:`PerturbedPass`), vectorised over replicates x particles:

    pass(swarm, (m, keys)) -> (swarm, (log L, failures, accepted estimates))

* the particles' state is (R, N, d + p), the parameters in its last p components, as on numpy;
  at each step the model is the cell's with the estimated paths set to every particle's
  parameters, (R, N, 1) traced arrays (:meth:`pfx.models.base.Model.with_parameter_arrays`);
* replicate r's pass m draws from the threefry key of its seed
  (:func:`pfx.numerics.seeding.chain_seeds`, the seed of its NumPy generator), so a run stopped
  between blocks and resumed from the saved swarm computes the same numbers;
* the initial state of a replicate's particles is drawn from the model at its swarm's mean, as
  on numpy; the model's check of that mean and the initial law it implies come from the host
  (``jax.pure_callback``, :meth:`~pfx.estimation.compiled_filter.CompiledFilter.host_laws`).

A pass whose filter fails (every particle of a replicate lost, a NaN likelihood) stops the run
after the passes before it are kept, with the NumPy backend's message; a random walk that takes
a parameter where the model refuses it is named as on numpy where the pass's swarm shows it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from pfx.estimation.compiled_filter import RowGaussians, double_precision_everywhere
from pfx.estimation.if2 import COOLING_HORIZON, IteratedFiltering, PerturbedParameters
from pfx.filters.particle.jax_engine import JaxParticleFilter
from pfx.filters.particle.kernel import first_failure
from pfx.numerics.key_streams import KeyStreams, threefry_keys

BLOCK = 5         # passes per compiled call: a run saves its swarm (and can stop) between blocks


class PerturbedModel:
    """The model as IF2's jax pass sees it: state (R, N, d + p); its likelihood is the model's
    at each particle's parameters of the current step (set by :meth:`PerturbedPass.predict`)."""

    def __init__(self, model, parameters: int):
        self.model, self.kind = model, f"{model.kind} (IF2)"
        self.state_dimension = model.state_dimension + parameters
        self.angular_components = tuple(model.angular_components)
        self.full_turn = model.full_turn
        self.current = None

    def log_likelihood(self, measurement, state):
        return self.current.log_likelihood(measurement, state[..., :self.model.state_dimension])


class SwarmStart:
    """A pass's initial cloud: each replicate's states from its initial law, its parameters the
    swarm perturbed once (step 0)."""

    def __init__(self, states, swarm, sd):
        self.states, self.swarm, self.sd = states, swarm, sd

    def sample(self, random, shape=()):
        import jax.numpy as jnp

        states = self.states.sample(random, shape)
        parameters = self.swarm + self.sd * random.standard_normal(self.swarm.shape[1:])
        return jnp.concatenate([states, parameters.astype(states.dtype)], axis=-1)


class PerturbedPass(JaxParticleFilter):
    """One IF2 pass on the jax engine: its predict perturbs each particle's parameters, then
    moves its state under them."""

    def __init__(self, bound, swarm: "CompiledSwarm", iteration):
        super().__init__(bound)
        self.swarm, self.iteration = swarm, iteration

    def perturbation_sd(self, step):
        """sigma_(m,k) of each parameter (pfx.estimation.if2)."""
        swarm = self.swarm
        return swarm.sd * swarm.cooling ** ((self.iteration - 1 + step / swarm.steps) / COOLING_HORIZON)

    def transition(self, cloud, inputs, random, model=None):
        import jax.numpy as jnp

        d, target = self.swarm.state_dimension, self.swarm.target
        parameters = cloud.particles[..., d:]
        parameters = parameters + (self.perturbation_sd(inputs.step)
                                   * random.standard_normal(parameters.shape[1:])).astype(parameters.dtype)
        current = self.swarm.template.with_parameter_arrays(target.parameter_arrays(target.to_natural(parameters)))
        self.model.current = current
        state, likelihood, failures = super().transition(cloud._replace(particles=cloud.particles[..., :d]), inputs,
                                                         random, model=current)
        return jnp.concatenate([state.astype(self.dtype), parameters], axis=-1), likelihood, failures


class CompiledSwarm:
    """The IF2 replicates of one cell on the jax backend (module docstring)."""

    block_size = BLOCK

    def __init__(self, method: IteratedFiltering):
        self.method, self.target = method, method.target
        self.filter = self.target.compiled_filter
        self.template, self.state_dimension = self.filter.template, self.filter.state_dimension
        settings = self.target.estimation
        self.sd = np.array([settings.parameters[path].random_walk_sd for path in self.target.paths])
        self.cooling, self.steps = settings.cooling_fraction_50, self.template.steps
        self._programs: dict[int, object] = {}

    def run(self, swarm: np.ndarray, first: int, last: int,
            report: Callable[[int, np.ndarray, np.ndarray], None]) -> np.ndarray:
        """Passes first..last in compiled blocks of at most :data:`BLOCK`; ``report(iteration,
        swarm, log_likelihood)`` after each pass, in order."""
        for start in range(first, last + 1, BLOCK):
            swarm = self._run_block(swarm, start, min(start + BLOCK - 1, last), report)
        return swarm

    def _run_block(self, swarm: np.ndarray, first: int, last: int, report) -> np.ndarray:
        import jax

        iterations = np.arange(first, last + 1)
        keys = np.stack([threefry_keys(self.method.seeds(int(i))) for i in iterations])
        with double_precision_everywhere():
            program = self._programs.get(len(iterations))
            if program is None:
                program = self._programs[len(iterations)] = jax.jit(self._block)
            outputs = program(swarm, (iterations, keys), self.filter.inputs(self.method.replicates))
            swarms, log_likelihoods, failures, valid = (np.asarray(value) for value in jax.device_get(outputs))
        for index, iteration in enumerate(iterations):
            if not valid[index].all():
                raise self.method.outside_the_domain(self.method.estimates(swarm), int(np.argmin(valid[index])))
            if failures[index].any():
                self._raise_failure(swarms[index], int(iteration), failures[index])
            swarm = swarms[index].astype(float)
            report(int(iteration), swarm, log_likelihoods[index].astype(float))
        return swarm

    def _raise_failure(self, swarm: np.ndarray, iteration: int, failures: np.ndarray) -> None:
        """The pass's failure as the NumPy backend names it: the random walk's parameter the
        model refuses (a ConfigError naming the transform to use), else the filter's failure."""
        failure = first_failure(self.template, failures)
        PerturbedParameters(self.target, self.template, iteration, None, None).refuse_swarm(swarm, failure)
        raise failure

    # -- traced -------------------------------------------------------------------------------------

    def _block(self, swarm, per_pass, inputs):
        import jax

        def one_pass(carried, place):
            return self._pass(carried, place, inputs)

        _, outputs = jax.lax.scan(one_pass, swarm, per_pass)
        return outputs

    def _pass(self, swarm, place, inputs):
        import jax
        import jax.numpy as jnp

        iteration, keys = place
        replicates, d = swarm.shape[0], self.state_dimension
        estimates = jnp.mean(self.target.to_natural(swarm), axis=1)
        shapes = (jax.ShapeDtypeStruct((replicates,), jnp.bool_), jax.ShapeDtypeStruct((replicates, d), jnp.float64),
                  jax.ShapeDtypeStruct((replicates, d, d), jnp.float64))
        valid, means, factors = jax.pure_callback(self.filter.host_laws, shapes, estimates)
        perturbed = PerturbedModel(self.template, self.target.dimension)
        states = RowGaussians(means, factors) if self.filter.follows else self.filter.bound.prior
        bound = replace(self.filter.bound, model=perturbed, prior=None)
        engine = PerturbedPass(bound, self, iteration)
        engine.bound = replace(bound, prior=SwarmStart(states, swarm, engine.perturbation_sd(0)))
        cloud, outputs = engine.traced_run(keys, inputs, self.filter.flags)
        parameters = cloud.particles[..., d:].astype(swarm.dtype)
        # the next pass starts from an equally weighted swarm: resample the replicates whose last
        # step did not (their weights are not uniform)
        indices = engine.resampler(jnp.exp(cloud.log_weights), KeyStreams(keys, engine.dtype).at(self.steps + 1))
        resampled = jnp.take_along_axis(parameters, indices[..., None], axis=1)
        parameters = jnp.where(outputs.resampled[-1][:, None, None], parameters, resampled)
        return parameters, (parameters, cloud.log_likelihood, outputs.failures, valid)
