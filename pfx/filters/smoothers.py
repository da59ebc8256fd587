r"""Smoothers: the state at each step given *every* measurement, :math:`p(x_k \mid z_{1:T})`.

A filter estimates :math:`x_k` from :math:`z_{1:k}`; a smoother, run after it over the whole
record, also uses :math:`z_{k+1:T}`. A config asks for smoothers beside its filter,
``filter.smoothers: [{kind: ffbs, trajectories: 100}, {kind: fixed_lag, lag: 10}]``, and
each writes its smoothed means and standard deviations beside the filter's estimates
(``smoothed_<kind>_<state>`` in steps.csv) and its error metrics beside the filter's
(``rmse_<kind>_<state>`` in trials.csv).

=================  ==============================================================  ==============
kind               the smoother                                                    filter kinds
=================  ==============================================================  ==============
``ffbs``           forward filtering backward sampling (Godsill, Doucet & West     particle, sis
                   2004): M trajectories drawn backwards through the weighted
                   clouds, each step's ancestor chosen with probability
                   :math:`\propto w_k^i\, p(x_{k+1} \mid x_k^i)`: O(M N) per step
``ffbs_rejection`` the same law, each backward draw by rejection sampling from      particle, sis
                   the weights with the transition density's bound (Douc,
                   Garivier, Moulines & Olsson 2011): O(M) per step on average
``fixed_lag``      the genealogy L steps on: :math:`\hat x_k = \sum_i w_{k+L}^i       particle
                   x_k^{a(i)}`, the step-k ancestors of step k+L's particles
``genealogy``      the genealogy of the last step's particles (the ancestral-path  particle
                   smoother, a fixed lag of T): its path degeneracy is why the
                   others exist
``rts``            the Rauch-Tung-Striebel smoother (and its extended and          kf, ekf, ukf
                   unscented forms): exact for a linear-Gaussian model
=================  ==============================================================  ==============

A smoother's settings are declared once (a pydantic class registered at its definition in
:data:`SMOOTHERS`, as every other component); :meth:`Smoother.check` refuses, at plan time and in
one line, what it cannot do for a filter kind and a model (the backward weights need the
model's transition density; the rejection form needs it bounded; the genealogy smoothers need
particles whose ancestry is the filter's, which a move, a diffusion or an injection breaks).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from pfx.filters.backends import BOTH, Backends
from pfx.registry import Registry, with_article


@dataclass
class Smoothed:
    """A smoother's result: the smoothed mean and standard deviation of each component, (R, T, d)."""

    means: np.ndarray
    standard_deviations: np.ndarray


class Smoother(BaseModel):
    """A smoother's settings (``filter.smoothers`` entries); the subclasses do the work."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    #: the filter kinds it runs after
    filter_kinds: ClassVar[frozenset[str]] = frozenset({"particle", "sis"})
    #: what it needs the particle filter to record: the weighted clouds, and each particle's ancestor
    needs_history: ClassVar[bool] = True
    needs_genealogy: ClassVar[bool] = False
    #: where it runs (pfx.filters.backends): after either backend's filter, on the host, on the
    #: clouds and ancestors the filter recorded (the jax backend records them as outputs of its scan)
    backends: ClassVar[Backends] = Backends(BOTH)

    @property
    def label(self) -> str:
        """Its name in column names (``smoothed_<label>_<state>``): its kind."""
        return self.kind

    def check(self, filter_kind: str, model, settings) -> None:
        """Raise ValueError('@smoothers: reason') when it cannot run after this filter on this model."""
        if filter_kind not in self.filter_kinds:
            *others, last = sorted(self.filter_kinds)
            kinds = f"{', '.join(others)} or {last}" if others else last
            raise ValueError(f"@smoothers: the {self.kind} smoother runs after {with_article(kinds)} filter, "
                             f"not {filter_kind}")


SMOOTHERS: Registry[type[Smoother]] = Registry("smoother")


def check_smoothers(filter_kind: str, model, settings) -> None:
    """Every smoother of ``settings.smoothers`` can run, and no kind appears twice."""
    seen: set[str] = set()
    for smoother in getattr(settings, "smoothers", None) or ():
        if smoother.label in seen:
            raise ValueError(f"@smoothers: {smoother.label} appears twice; compare its settings in arms")
        seen.add(smoother.label)
        smoother.check(filter_kind, model, settings)
