"""The ``estimation:`` section: which model parameters to estimate from the data, and how.

A config with this section is a parameter-estimation experiment (docs/estimation.md): each
cell (arm x sweep combination) runs the method on one dataset (the recorded data, or the
simulated dataset of trial 0) with the cell's filter inside. The keys of ``parameters`` are
dotted paths into the model, the same paths ``--set`` takes (``model.mu``,
``model.process_noise.variance``); each names a number of the filter's model.
"""

from __future__ import annotations

import math
from typing import Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, model_validator

from pfx.config.estimation_tables import reserved_names, tables_with
from pfx.errors import ConfigError
from pfx.laws.priors import Prior, TransformName, make_transform
from pfx.registry import with_article

# The figures an estimation config draws unless its outputs name others (a filter run's defaults
# draw trials, which it has none of).
ESTIMATION_FIGURES = {"pmmh": ("chain_traces", "posterior_marginals", "posterior_pairs"), "if2": ("if2_convergence",)}


class EstimatedParameter(BaseModel):
    """One estimated parameter: its prior, the scale it moves on, where chains start."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    prior: Prior = Field(description="prior law (`law`: uniform, normal, lognormal, gamma, inverse_gamma, beta, "
                                     "flat) and its parameters; IF2 reads only its support")
    transform: Optional[TransformName] = Field(
        None, description="scale the random walks move on: none, log (variances), logit (probabilities, or any "
                          "bounded interval); default from the prior's support")
    start: Union[StrictFloat, list[StrictFloat], Literal["prior"]] = Field(
        "prior", description="starting value: one number for every chain, one per chain, or `prior` (each chain "
                             "draws its own from the prior, from its own stream)")
    proposal_sd: StrictFloat = Field(0.1, gt=0, description="PMMH: the random walk's initial standard deviation on the "
                                                            "transformed scale (adapted during warm-up if `adapt`)")
    random_walk_sd: StrictFloat = Field(0.02, gt=0, description="IF2: the perturbation's standard deviation on the "
                                                                "transformed scale at the first iteration")
    name: Optional[str] = Field(None, pattern=r"^[A-Za-z_][A-Za-z0-9_.]*$",
                                description="column name in the tables (default: the path without `model.`)")

    @model_validator(mode="after")
    def _check(self):
        transform = make_transform(self.transform, self.prior.support)      # ValueError('@transform: ...')
        if self.start == "prior" and self.prior.law == "flat":
            raise ValueError("@start: a flat prior cannot be drawn from (start: prior, the default); give the "
                             "chains a start: one number, or one per chain")
        starts = [self.start] if isinstance(self.start, float) else self.start if isinstance(self.start, list) else []
        for value in starts:
            if not math.isfinite(float(self.prior.log_density(value))):
                raise ValueError(f"@start: {value:g} lies outside the prior's support {self.prior.support}")
            if not math.isfinite(float(transform.to_unconstrained(value))):
                raise ValueError(f"@start: {value:g} is on the boundary of the {transform.name} transform's range")
        return self


class EstimationConfig(BaseModel):
    """Parameter estimation from the data: PMMH (a posterior sample) or IF2 (maximum likelihood)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    method: Literal["pmmh", "if2"] = Field(
        description="pmmh: particle marginal Metropolis-Hastings (Andrieu, Doucet & Holenstein 2010); if2: "
                    "iterated filtering (Ionides et al. 2015)")
    parameters: dict[str, EstimatedParameter] = Field(
        min_length=1, description="dotted path into the model (as `--set` takes it, e.g. model.mu) -> prior, "
                                  "transform, start")
    chains: StrictInt = Field(4, ge=1, le=100_000, description="PMMH chains, or IF2 replicates, run as rows of "
                                                               "one batch")
    iterations: StrictInt = Field(ge=1, le=10_000_000,
                                  description="PMMH iterations per chain, or IF2 passes through the data; a "
                                              "finished folder is extended by asking for more")
    warm_up: StrictInt = Field(0, ge=0, description="PMMH: the first iterations, where the proposal adapts; left out "
                                                   "of posterior.csv")
    adapt: StrictBool = Field(True, description="PMMH: adapt the random walk's covariance during warm-up "
                                               "(Haario et al. 2001: 2.38^2 / d times the chain's covariance so far)")
    adapt_after: StrictInt = Field(100, ge=2, description="PMMH: iterations before the first adaptation")
    cooling_fraction_50: StrictFloat = Field(
        0.5, gt=0, le=1, description="IF2: the perturbations' sd after 50 iterations, as a fraction of the first "
                                     "(geometric cooling, as pomp's mif2)")
    evaluations: StrictInt = Field(10, ge=1, le=10_000, description="IF2: filter runs at each replicate's final "
                                                                   "estimate, for its log-likelihood and standard "
                                                                   "error (maximum_likelihood.csv)")

    @model_validator(mode="before")
    @classmethod
    def _model_paths(cls, data):
        # before the parameters' own settings are read: `--set estimation.parameters.model.misspelt.x=1`
        # makes a key `model` whose settings are all missing, and the path is what is wrong
        parameters = data.get("parameters") if isinstance(data, dict) else None
        for path in parameters if isinstance(parameters, dict) else ():
            if not isinstance(path, str) or not path.startswith("model.") or path == "model.":
                raise ValueError(f"@parameters.{path}: give a dotted path into the model, e.g. model.mu (with "
                                 "--set, a path that names none of the estimated parameters makes a new key)")
        return data

    @model_validator(mode="after")
    def _check(self):
        for path, parameter in self.parameters.items():
            if isinstance(parameter.start, list) and len(parameter.start) != self.chains:
                raise ValueError(f"@parameters.{path}.start: {len(parameter.start)} values for {self.chains} chains")
        names = [self.column(path) for path in self.parameters]
        if len(set(names)) != len(names):
            raise ValueError("@parameters: two parameters have the same column name; give one a `name`")
        reserved = reserved_names()
        for path in self.parameters:
            name = self.column(path)
            if name in reserved:
                raise ValueError(f"@{self.name_key(path)}: {name!r} is a column of {', '.join(tables_with(name))}, "
                                 "which the parameter's own column would overwrite; give it another `name`")
        if self.method == "pmmh" and self.warm_up >= self.iterations:
            raise ValueError(f"@warm_up: {self.warm_up} warm-up iterations leave none of the {self.iterations} for "
                             "the posterior")
        return self

    def column(self, path: str) -> str:
        """The column name of the parameter at ``path``."""
        return self.parameters[path].name or path[len("model."):]

    def name_key(self, path: str) -> str:
        """The key (below ``estimation``) that gives the parameter at ``path`` its column name:
        its ``name``, or the path itself."""
        return f"parameters.{path}.name" if self.parameters[path].name else f"parameters.{path}"

    @property
    def columns(self) -> list[str]:
        return [self.column(path) for path in self.parameters]


def check_figures_apply(figures: list[str], estimation: Optional[EstimationConfig], file: str) -> None:
    """ConfigError for a figure the config names (``outputs.figures``) that the folder it makes
    cannot draw: a filter run's figure in an estimation config, an estimation figure in a filter
    run's (:func:`pfx.figures.registry.refusal_in_config`)."""
    from pfx.figures.registry import refusal_in_config

    for index, name in enumerate(figures):
        reason = refusal_in_config(name, estimation.method if estimation is not None else None)
        if reason:
            raise ConfigError(f"{reason}; `pfx list figures` says what each figure draws", file=file,
                              key=f"outputs.figures[{index}]")


def check_column_names(estimation: EstimationConfig, labels: list[str], file: str, cell_text: str = "") -> None:
    """ConfigError if a parameter's column name is one of the cell's columns (``arm``, ``n_particles``,
    a swept key's column), which the tables put beside the parameters (:mod:`pfx.config.estimation_tables`)."""
    for path in estimation.parameters:
        name = estimation.column(path)
        if name in labels:
            raise ConfigError(f"{name!r} is one of the cell's label columns{cell_text}, which every estimation table "
                              "has and the parameter's own column would overwrite; give it another `name`", file=file,
                              key=f"estimation.{estimation.name_key(path)}")


def check_estimated_paths(estimation: EstimationConfig, model, file: str, cell_text: str = "") -> None:
    """ConfigError unless every estimated path names a number of ``model`` (a cell's filter model)."""
    for path in estimation.parameters:
        value = model
        for part in path.split(".")[1:]:
            value = getattr(value, part, None) if not isinstance(value, dict) else value.get(part)
            if value is None:
                break
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            found = "nothing" if value is None else with_article(type(value).__name__)
            raise ConfigError(f"{path} names {found} in model {model.kind}{cell_text}; an estimated parameter is "
                              "a number of the model (a scalar variance, a coefficient)", file=file,
                              key=f"estimation.parameters.{path}")
