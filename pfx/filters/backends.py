"""Where each component of a particle filter runs: declared once, at the component.

A resampler, a weighting, a proposal, a move, a diffusion, the adaptive count, injection, the
auxiliary filter's first stage and a smoother each carry a :class:`Backends` declaration: the
backends it runs on and, where that is not every backend, what it is called in a refusal and why
it does not run there. Everything that asks "does this run on jax?" reads these declarations:

* the plan's refusal of a ``filter:`` section on ``backend: jax``
  (:func:`pfx.filters.particle.jax_support.check_jax_settings`, which names the key and the
  reason),
* docs/backends.md's table, which tests/test_backend_declarations.py checks row by row against
  them.

A component declares ``backends = Backends(BOTH)`` where it runs on both. A plugin's component
inherits its base class's declaration, NumPy only: the compiled step cannot call NumPy code, and
a plugin says so itself when it is written for both (``backends = pfx.Backends(pfx.BOTH)``
where the base class is public).

Lifting a refusal is a change of declaration, with the component's check on the jax backend
beside it; nothing else lists what jax runs.
"""

from __future__ import annotations

from dataclasses import dataclass

NUMPY, JAX = "numpy", "jax"
BOTH = frozenset({NUMPY, JAX})
NUMPY_ONLY = frozenset({NUMPY})


@dataclass(frozen=True)
class Backends:
    """The backends a component runs on; ``what`` names it in a refusal ("moves after
    resampling"), ``why`` says why it does not run on the others."""

    on: frozenset = NUMPY_ONLY
    what: str = ""
    why: str = ""

    def runs_on(self, backend: str) -> bool:
        return backend in self.on

    def refusal(self, backend: str, name: str) -> str:
        """The reason a filter with this component (called ``name``: its kind) is refused on
        ``backend``, without the key."""
        what = f"{self.what} ({name})" if self.what and name else (self.what or name)
        return f"the {backend} backend does not run {what} yet" + (f" ({self.why})" if self.why else "")


def declared(component) -> Backends:
    """A component's declaration (an instance or its class); NumPy only when it declares none."""
    declaration = getattr(component, "backends", None)
    return declaration if isinstance(declaration, Backends) else Backends()
