"""Where IF2's random walk takes a parameter the model refuses: one line naming it, and the cure.

IF2 (:mod:`pfx.estimation.if2`) moves every particle's parameters by a random walk on the
transformed scale, at every step. With ``transform: none`` (or any scale wider than the model's
range) the walk soon carries some particle where the model refuses the value: a variance below
zero, a probability above 1. The model may say so itself (a noise's check of its variance, a
field's bound such as ``Field(gt=0, lt=1)``), or only later, when a law is drawn with the value
(``binomial: probability must be in [0, 1]``) or its log-likelihood turns NaN. Whatever says it,
the run stops with one :class:`~pfx.errors.ConfigError` at the parameter's ``transform`` key
that names the parameter, the value the walk reached, the model's reason, and the transform
that keeps the walk inside: ``logit`` for a parameter bounded on both sides (a probability),
``log`` for a positive one (docs/estimation.md, "Transforms").

:func:`refused_parameter` finds the parameter, from the cheapest evidence to the costliest:

1. the model's own check of the arrays (:meth:`pfx.models.base.Model.with_parameter_arrays`:
   a noise's variance below zero);
2. the model's validation at the walk's extreme values of one parameter, the others at the
   config's values (:meth:`pfx.estimation.target.EstimationTarget.refusal`: a field's bounds,
   the model's ``check()``);
3. where the caller can repeat what failed (``probe``), the parameter whose walk alone makes it
   fail again (a plugin whose fields declare no bounds).

Where none names one and there was nothing to probe (the jax backend, whose compiled pass cannot
stop at the failing step: it reports the law's refusal after the pass, and the swarm it leaves may
be back inside the range), a law's refusal is put down to the parameters on ``transform: none``,
which are named, as the likely cause.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from pfx.errors import ConfigError, split_location

# What to estimate a parameter on, by the range the model accepts it in.
BOUNDED = "transform: logit, with a prior on that interval (uniform, or beta on (0, 1))"
POSITIVE = "transform: log, with a prior on (0, inf) (flat with lower 0, lognormal, gamma)"
EITHER = ("transform: log for a positive value, logit for a bounded one (a probability), with a prior whose support "
          "is that range")


def refused_parameter(target, model, natural: np.ndarray,
                      probe: Optional[Callable[[int], bool]] = None) -> Optional[tuple[int, str, str]]:
    """(index, where the walk took it, the model's reason) of the first estimated parameter that
    the model refuses among the particles' parameters ``natural`` (..., p, natural scale); None
    if no check names one (module docstring). ``probe(j)``: whether what failed fails again with
    parameter j alone moving (it names no value: the particles' range is given)."""
    flat = np.asarray(natural, dtype=float).reshape(-1, target.dimension)
    for j, path in enumerate(target.paths):          # 1. the model's own check of the arrays
        try:
            model.with_parameter_arrays({path[len("model."):]: np.asarray(natural)[..., j:j + 1]})
        except ValueError as error:
            return j, f"{_extreme(flat[:, j]):.4g}", _reason(error)
    for j, path in enumerate(target.paths):          # 2. the model's validation, one parameter at a time
        for value in (flat[:, j].min(), flat[:, j].max()):
            reason = target.refusal({path: value})
            if reason is not None:
                return j, f"{value:.4g}", reason
    for j in range(target.dimension) if probe is not None else ():     # 3. the failure again, j alone moving
        if probe(j):
            return j, f"values from {flat[:, j].min():.4g} to {flat[:, j].max():.4g}", ""
    return None


def walk_error(target, model, iteration: int, natural: np.ndarray, error: Exception,
               probe: Optional[Callable[[int], bool]] = None) -> Optional[ConfigError]:
    """The ConfigError for pass ``iteration`` of IF2 failing with ``error`` while its particles'
    parameters were ``natural`` (..., p): naming the parameter the model refuses, else, where
    no probe could tell and a law refused a parameter, the parameters on ``transform: none``;
    None where neither applies (the error is not the walk's)."""
    reason = _reason(error)
    found = refused_parameter(target, model, natural, probe)
    if found is not None:
        culprit, value, refusal = found
        path, lowest = target.paths[culprit], float(np.min(np.asarray(natural)[..., culprit]))
        return ConfigError(f"IF2's random walk (transform: {target.transforms[culprit].name}) moved {path} to "
                           f"{value} in pass {iteration}, where model {model.kind} refuses it ({refusal or reason}); "
                           f"estimate it on a scale that stays inside the model's range: "
                           f"{suggested_transform(model, path, lowest, refusal or reason)}",
                           key=f"estimation.parameters.{path}.transform")
    unbounded = [j for j, transform in enumerate(target.transforms) if transform.name == "none"]
    if not unbounded or not _law_refused(error) or probe is not None:     # a probe that names none: not the walk
        return None
    named = ", ".join(target.paths[j] for j in unbounded)
    one = len(unbounded) == 1
    cure = suggested_transform(model, target.paths[unbounded[0]], float(np.min(np.asarray(natural)[..., unbounded[0]])),
                               reason) if one else EITHER
    return ConfigError(f"IF2's random walk took the particles' parameters where model {model.kind} refuses them in "
                       f"pass {iteration} ({reason}); {named} move{'s' if one else ''} on transform: none: estimate "
                       f"{'it' if one else 'them'} on a scale that stays inside the model's range: {cure}",
                       key=f"estimation.parameters.{target.paths[unbounded[0]]}.transform")


def _law_refused(error: Exception) -> bool:
    """Whether ``error`` is how a law refuses a parameter: a ValueError on NumPy; on the jax
    backend, which cannot raise inside a compiled pass, the engine's report of the rule the
    transition broke (:func:`pfx.filters.particle.kernel.first_failure`)."""
    return isinstance(error, ValueError) or "raised ValueError: " in str(error)


def suggested_transform(model, path: str, lowest: float, reason: str) -> str:
    """The transform for a parameter of ``model`` at ``path`` that the model refused for
    ``reason`` when the walk took it as low as ``lowest``: by the bounds the model's field
    declares, else by what the refusal says (a probability) or where the values went (to zero
    or below)."""
    lower, upper = _field_bounds(model, path)
    if path.endswith(".variance"):
        lower = 0.0 if lower is None else lower
    if lower is not None and upper is not None or "probabilit" in reason or "[0, 1]" in reason:
        return BOUNDED
    if lower == 0.0 or (lower is None and upper is None and lowest <= 0):
        return POSITIVE
    return EITHER


def _field_bounds(model, path: str) -> tuple[Optional[float], Optional[float]]:
    """The (lower, upper) bounds the model's pydantic field at ``path`` declares (gt/ge, lt/le)."""
    field = type(model).model_fields.get(path[len("model."):]) if hasattr(type(model), "model_fields") else None
    lower = upper = None
    for rule in getattr(field, "metadata", ()):
        for name in ("gt", "ge"):
            if getattr(rule, name, None) is not None:
                lower = float(getattr(rule, name))
        for name in ("lt", "le"):
            if getattr(rule, name, None) is not None:
                upper = float(getattr(rule, name))
    return lower, upper


def _extreme(values: np.ndarray) -> float:
    """The value a walk that left the model's range most likely left it at: the least if any is
    at or below zero (a variance, a rate), else the greatest (a probability above 1)."""
    return float(values.min() if np.any(values <= 0) else values.max())


def _reason(error: Exception) -> str:
    """An error's text without its location (``@key: ``) and on one line."""
    return " ".join(split_location(str(error))[1].split())
