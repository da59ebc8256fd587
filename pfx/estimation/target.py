r"""What parameter estimation targets: the log-likelihood estimate of one cell's filter at given
parameter values, and the log-prior.

For parameters :math:`\theta` at the dotted paths of ``estimation.parameters``, the model at
:math:`\theta` is the cell's filter model with those values set and everything derived from them
derived again (its presets, its checks: a stationary initial law follows :math:`\mu, \phi,
\sigma`). :meth:`EstimationTarget.log_likelihoods` runs the cell's filter on the dataset for
several parameter vectors at once, one per row, each with its own random stream, and returns
each row's :math:`\log \hat p_\theta(z_{1:T})`:

* **batched**: when the model declares every estimated path among its
  ``vectorised_parameters`` and the filter is the bootstrap particle filter (the transition and
  the likelihood are all it reads of the model), the rows are one batch of the engine: one model
  whose parameters are arrays (R, 1, 1), each row's initial particles drawn from its own model's
  prior;
* **row by row** otherwise (any filter kind, any model): the same numbers, one filter call per
  row;
* **compiled**, on the jax backend (which needs the batched case): the parameters are arguments
  of one compiled program (:mod:`pfx.estimation.compiled_filter`).

Either way row r's numbers depend only on its parameters and its seed.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
from pydantic import ValidationError

from pfx.config.dotted_paths import set_path
from pfx.config.estimation import EstimationConfig
from pfx.config.plan import Cell
from pfx.config.validation import validate
from pfx.errors import ConfigError, ModelNumericalError
from pfx.filters import FILTERS
from pfx.filters.particle.bound import bind_particle_filter
from pfx.laws.priors import make_transform
from pfx.models import MODELS
from pfx.models.base import bind_law
from pfx.models.simulation import simulate_truth
from pfx.numerics.arrays import namespace
from pfx.numerics.seeding import TrialStreams, chain_seeds, truth_seed


class RowPriors:
    """Initial laws that differ by row: row r's particles are drawn from ``laws[r]``, from row
    r's own stream (what the engine's ``prior.sample(random, (N,))`` asks)."""

    def __init__(self, laws: list):
        self.laws = laws

    def sample(self, random: TrialStreams, shape=()) -> np.ndarray:
        return np.concatenate([law.sample(random.subset([row]), shape) for row, law in enumerate(self.laws)])


@dataclass
class EstimationTarget:
    """One cell's estimation problem: its dataset, its filter, the estimated parameters."""

    cell: Cell
    estimation: EstimationConfig
    measurements: np.ndarray           # (T, m), NaN for a missing measurement

    def __post_init__(self):
        parameters = self.estimation.parameters
        self.paths = list(parameters)
        self.columns = self.estimation.columns
        self.priors = [parameters[path].prior for path in self.paths]
        self.transforms = [make_transform(parameters[path].transform, prior.support)
                           for path, prior in zip(self.paths, self.priors)]
        model = self.cell.filter_model
        derived = model.preset_fields()       # derived again at each θ (a stationary initial law)
        self.raw_model = {name: _plain(copy.deepcopy(getattr(model, name))) for name in type(model).model_fields
                          if name not in derived}
        self.recorded_times = model._recorded_times
        settings = self.cell.filter
        declared = type(model).vectorised_parameters
        self._compiled = None
        self.batched = (settings.kind in ("particle", "sis") and settings.bootstrap_stages
                        and all(path[len("model."):] in declared for path in self.paths))

    @property
    def compiled_filter(self):
        """The filter as a compiled function of the parameters (backend: jax), made once."""
        if self._compiled is None:
            from pfx.estimation.compiled_filter import CompiledFilter

            self._compiled = CompiledFilter(self)
        return self._compiled

    @property
    def dimension(self) -> int:
        return len(self.paths)

    def with_particles(self, particles: int) -> "EstimationTarget":
        """The same problem with the cell's filter at ``particles`` particles."""
        cell = replace(self.cell, filter=self.cell.filter.model_copy(update={"particles": int(particles)}))
        return EstimationTarget(cell, self.estimation, self.measurements)

    # -- the prior and the transformed scale ------------------------------------------------------

    def log_prior(self, values: np.ndarray) -> np.ndarray:
        """log pi(theta) for values (R, p) on the natural scale: (R,)."""
        values = np.atleast_2d(values)
        return sum(prior.log_density(values[:, j]) for j, prior in enumerate(self.priors))

    def to_unconstrained(self, values: np.ndarray) -> np.ndarray:
        return np.stack([t.to_unconstrained(values[..., j]) for j, t in enumerate(self.transforms)], axis=-1)

    def to_natural(self, values: np.ndarray) -> np.ndarray:
        """theta = g^-1(u), NumPy or JAX (IF2's compiled pass maps its particles' parameters)."""
        return namespace(values).stack([t.to_natural(values[..., j]) for j, t in enumerate(self.transforms)], axis=-1)

    def log_jacobian(self, unconstrained: np.ndarray) -> np.ndarray:
        """log |d theta / d u| summed over the parameters: (R,) from (R, p)."""
        return sum(t.log_jacobian(unconstrained[..., j]) for j, t in enumerate(self.transforms))

    def starting_values(self, root_seed: int, cell_key: int) -> np.ndarray:
        """Each chain's (or IF2 replicate's) starting point, (C, p): the parameter's ``start``
        (one number, or one per chain), or a draw from its prior with the chain's own generator
        (its iteration-0 move stream, one per parameter)."""
        count = self.estimation.chains
        values = np.empty((count, self.dimension))
        for j, path in enumerate(self.paths):
            start = self.estimation.parameters[path].start
            for chain in range(count):
                if start == "prior":
                    generator = np.random.default_rng([chain_seeds(root_seed, cell_key, chain, 0)[1], j])
                    values[chain, j] = float(self.priors[j].sample(generator))
                else:
                    values[chain, j] = start[chain] if isinstance(start, list) else start
        return values

    def parameter_arrays(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """The values (R, p), one per row, or (R, N, p), one per particle, as the arrays
        :meth:`pfx.models.base.Model.with_parameter_arrays` takes: (R, 1, 1) or (R, N, 1) per path."""
        values = values if values.ndim == 3 else values[:, None, :]
        return {path[len("model."):]: values[..., j:j + 1] for j, path in enumerate(self.paths)}

    # -- models at given parameters ---------------------------------------------------------------

    def model_at(self, values: np.ndarray):
        """The filter model with the parameters set to ``values`` (p,), validated (presets derived
        again, checks run); None if the model refuses them (outside its domain)."""
        model, _ = self._model_or_refusal(dict(zip(self.paths, values)))
        return model

    def refusal(self, values: dict[str, float]) -> Optional[str]:
        """The model's reason for refusing the parameters at ``values`` (path -> value; the
        others at the config's values), or None if it accepts them."""
        model, reason = self._model_or_refusal(values)
        return reason if model is None else None

    def _model_or_refusal(self, values: dict[str, float]) -> tuple[object, str]:
        """The filter model with the parameters at ``values`` (path -> value) set, and "", or
        None and the model's reason for refusing them."""
        raw = copy.deepcopy(self.raw_model)
        for path, value in values.items():
            set_path(raw, path[len("model."):], float(value))
        try:
            model = validate(MODELS[raw["kind"]], raw, file="<estimation>", prefix="model")
        except ConfigError as error:           # a value the model refuses
            return None, f"{error.key}: {error.reason}" if error.key else error.reason
        except (ValueError, ValidationError) as error:
            return None, " ".join(str(error).split())
        if self.recorded_times is not None:
            model.use_recorded_times(self.recorded_times)
        return model, ""

    def check_starts(self, values: np.ndarray, log_likelihood: np.ndarray, chain: str = "chain") -> None:
        """ConfigError (its file left to the caller) for the first chain (or IF2 replicate:
        ``chain``) whose start ``values`` (C, p) the model refuses, or where the log-likelihood
        estimate ``log_likelihood`` (C,) is not finite (the data have zero likelihood there).
        It names the parameters and their key: the start of the one parameter the model refuses
        on its own (the others at the config's values), else ``estimation.parameters``."""
        bad = np.flatnonzero(~np.isfinite(log_likelihood))
        if not bad.size:
            return
        row = int(bad[0])
        point = dict(zip(self.paths, values[row]))
        model, reason = self._model_or_refusal(point)
        if model is None:
            blamed = [path for path in self.paths if self._model_or_refusal({path: point[path]})[0] is None]
            what = f"where the model refuses {'it' if len(blamed) == 1 else 'them'}: {reason}"
        else:
            blamed = list(self.paths)
            what = ("where the data have zero likelihood (the filter's estimate is 0 there: at some step no "
                    "particle explains the measurement)" if log_likelihood[row] == -np.inf
                    else f"where the filter's log-likelihood is {log_likelihood[row]}")
        shown = blamed if len(blamed) == 1 else self.paths
        drawn = any(self.estimation.parameters[path].start == "prior" for path in shown)
        text = ", ".join(f"{self.estimation.column(path)}={point[path]:.6g}" for path in shown)
        origin = " (drawn from the prior: start: prior)" if drawn else ""
        remedy = (f"give each {chain} a start the model accepts, or a prior inside the model's range" if model is None
                  else f"start each {chain} elsewhere, or use more particles")
        key = f"estimation.parameters.{blamed[0]}.start" if len(blamed) == 1 else "estimation.parameters"
        raise ConfigError(f"{chain} {row} starts at {text}{origin}, {what}; {remedy}", key=key)

    def prior_of(self, model):
        settings = self.cell.filter
        law = settings.initial or model.default_prior()
        return bind_law(law, model.state_dimension, "initial")

    def log_likelihoods(self, values: np.ndarray, seeds: list[int]) -> np.ndarray:
        """log p_hat(z_1:T | theta_r) for each row r of ``values`` (R, p), with filter seed
        ``seeds[r]``; -inf for a row whose parameters the model refuses."""
        if self.cell.filter.backend == "jax":       # one compiled program (pfx.estimation.compiled_filter)
            return self.compiled_filter.log_likelihoods(values, seeds)
        models = [self.model_at(row) for row in values]
        result = np.full(len(values), -np.inf)
        valid = [r for r, model in enumerate(models) if model is not None]
        if not valid:
            return result
        if self.batched:
            stacked = models[valid[0]].with_parameter_arrays(self.parameter_arrays(values[valid]))
            prior = RowPriors([self.prior_of(models[r]) for r in valid])
            bound = bind_particle_filter(self.cell.filter.kind, stacked, self.cell.filter, prior)
            data = np.broadcast_to(self.measurements, (len(valid),) + self.measurements.shape)
            try:
                trace = bound.run(np.ascontiguousarray(data), TrialStreams.from_seeds([seeds[r] for r in valid]))
            except ModelNumericalError:
                pass        # a row's parameters broke the model: find which, row by row (the same numbers)
            else:
                result[valid] = trace.log_likelihood
                return result
        for r in valid:
            result[r] = self._one_row(models[r], seeds[r])
        return result

    def _one_row(self, model, seed: int) -> float:
        """One filter run at one parameter vector; -inf where the filter's set-up refuses the model
        there (a grid it cannot cover, say) or every particle leaves the model's domain: a
        parameter value the data rule out, not an error of the run."""
        settings = self.cell.filter
        try:
            prior = self.prior_of(model)
            planned = FILTERS[settings.kind].plan(model, settings, prior)
            trace = planned.run(model, self.measurements[None], TrialStreams.from_seeds([seed]),
                                settings=settings, prior=prior)
        except (ValueError, ConfigError, ModelNumericalError):
            return -np.inf
        return float(trace.log_likelihood[0])


def _plain(value):
    """A field's value as plain data (pydantic models dumped), for comparing and re-validating."""
    if hasattr(value, "model_dump"):
        return value.model_dump(mode="python")
    return value


def dataset(cell: Cell, root_seed: int) -> np.ndarray:
    """The measurements a cell estimates from, (T, m): the recorded ones, or the dataset of trial
    0 simulated from the true model (its truth stream, as every run's trial 0 sees it)."""
    if cell.data is not None:
        return np.asarray(cell.data.measurements, dtype=float)
    _, measurements = simulate_truth(cell.truth_model, TrialStreams.from_seeds([truth_seed(root_seed, 0)]))
    return measurements[0]
