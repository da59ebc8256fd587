"""What a filter kind is: the interface every way of estimating the state implements.

A filter kind is a subclass of :class:`FilterKind`, registered at its definition with
``@FILTERS.register_kind`` under its ``kind`` (the name a config gives as ``filter.kind``). It
declares, once:

* ``reads``: the shared settings of ``filter:`` it reads besides ``kind``, ``initial`` and
  ``model`` (which every kind reads): for a particle filter ``particles``, ``resampler``,
  ``ess_threshold``, ``weighting``, ``diffusion``. ``pfx validate`` and a result folder's
  ``config.yaml`` leave out settings that none of a config's kinds reads.
* ``settings``: its own settings blocks, ``{key: (pydantic model, description)}``, which become
  fields of ``filter:`` (``grid:`` for ``histogram``, ``unscented:`` for ``ukf``): the config
  schema, its JSON Schema and the config reference are built from them.
* ``model_needs``: what it asks of a model beyond the transition and the measurement mean,
  as names of model attributes that must not be None (``kf`` needs ``matrices``).
* ``carries_particles``: whether its cells have a particle count, resampler and weighting in
  their labels, and may keep particle clouds (``outputs.particles``).
* ``takes_trace_rows``: whether its ``run`` accepts ``trace_rows=``, the rows of the batch whose
  per-step traces steps.csv keeps, to record costly per-step diagnostics (the particle
  filter's posterior standard deviations) for those rows only. Kinds that carry a covariance
  need not: steps.csv's ``sd_<state>`` columns come from its diagonal.
* ``computes_scores``: whether its ``run`` accepts ``scores=True`` and then fills the trace's
  ``predictive`` (:class:`~pfx.filters.trace.Predictive`): the one-step-ahead predictive
  distribution of the measurement and its proper scores (``metrics.scores``). The particle
  kinds and the Gaussian filters do; for the others those columns stay empty.

Measurements may hold NaN rows: a missing measurement (recorded data, :mod:`pfx.config.data`).
Every kind treats such a step as predict-only for that trial (no update, log-likelihood
increment 0, NIS NaN); the built-in kinds do.

Two methods do the work. :meth:`FilterKind.plan` runs at plan time, once per cell: it checks
that the kind can run on the cell's model (raising ``ValueError("@key: reason")``, key under
``filter``, or a :class:`~pfx.errors.ConfigError`: the config is then refused before anything
runs) and resolves what is fixed for the cell (the histogram filter's grid), returning the kind
bound to it. The plan is kept on the cell, so every batch of trials reuses it. :meth:`FilterKind.run`
filters one batch of trials and returns a :class:`~pfx.filters.trace.FilterTrace`.

:func:`run_filter` plans and runs in one call, for tests and notebooks.

May import :mod:`pfx.filters.trace`, :mod:`pfx.laws`, :mod:`pfx.numerics`, :mod:`pfx.registry`
and :mod:`pfx.errors`.
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import BaseModel

from pfx.errors import located_value_error
from pfx.filters.trace import FilterTrace
from pfx.registry import Registry


class FilterKind:
    """A filter kind: its declarations (class attributes) and its plan-time resolution (the instance)."""

    kind: ClassVar[str]
    reads: ClassVar[frozenset[str]] = frozenset()
    settings: ClassVar[dict[str, tuple[type[BaseModel], str]]] = {}
    model_needs: ClassVar[tuple[str, ...]] = ()
    carries_particles: ClassVar[bool] = False
    takes_trace_rows: ClassVar[bool] = False
    computes_scores: ClassVar[bool] = False

    @classmethod
    def plan(cls, model, settings, prior) -> "FilterKind":
        """Check that this kind can run on ``model`` with ``settings`` and ``prior``, and resolve
        what is fixed per cell; the default checks ``model_needs`` and keeps nothing."""
        cls.check_model_needs(model)
        return cls()

    @classmethod
    def check_model_needs(cls, model) -> None:
        """Raise ValueError('@kind: ...') when the model lacks something in ``model_needs``."""
        missing = [need for need in cls.model_needs if getattr(model, need, None) is None]
        if missing:
            raise ValueError(f"@kind: the {cls.kind} filter needs a model with {', '.join(missing)}; "
                             f"model {model.kind} has none")

    def run(self, model, measurements, random, *, settings, prior, spread_criterion=None,
            consistency: bool = False, snapshot=None) -> FilterTrace:
        """Filter measurements (trials, T, m) with one random stream per trial (``random``, a
        :class:`~pfx.numerics.seeding.TrialStreams`); ``model`` is the model the filter assumes,
        ``settings`` the cell's ``filter:`` settings, ``prior`` the bound initial law.
        ``snapshot`` (particle kinds only) asks for particle clouds to be kept."""
        raise NotImplementedError


FILTERS: Registry[type[FilterKind]] = Registry("filter")


def run_filter(kind: str, model, measurements, random=None, *, settings, prior,
               spread_criterion=None, consistency: bool = False, snapshot=None,
               trace_rows=None, scores: bool = False) -> FilterTrace:
    """Plan the filter kind for ``model`` and run it on ``measurements`` (see :class:`FilterKind`);
    a plan-time refusal becomes a :class:`~pfx.errors.ConfigError` keyed under ``filter``.
    ``trace_rows`` (kinds that take them) are the rows whose costly per-step diagnostics to keep;
    ``scores`` asks a kind that computes them for the predictive scores."""
    try:
        planned = FILTERS[kind].plan(model, settings, prior)
    except ValueError as error:
        raise located_value_error(error, prefix="filter") from None
    options = {"snapshot": snapshot} if snapshot is not None else {}
    if trace_rows is not None and planned.takes_trace_rows:
        options["trace_rows"] = trace_rows
    if scores and planned.computes_scores:
        options["scores"] = True
    return planned.run(model, measurements, random, settings=settings, prior=prior,
                       spread_criterion=spread_criterion, consistency=consistency, **options)

