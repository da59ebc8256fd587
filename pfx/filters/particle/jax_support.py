"""What the JAX backend runs, and the one-line refusal of what it does not run yet.

``filter.backend: jax`` runs the particle filter (``kind: particle`` with the ESS rule, or
``sis``) with the components that declare the jax backend (:mod:`pfx.filters.backends`): the
bootstrap, locally optimal, ekf and ukf proposals, the built-in weightings, resamplers, diffusions and moves, the adaptive count (kld), injection. A
component that does not is refused here, at plan time, by its key and with the reason it
declares: a config never runs on the NumPy backend behind its author's back. docs/backends.md's
table says the same for readers, and a test holds it to the declarations.
"""

from __future__ import annotations

import importlib.util
from typing import Optional

from pfx.filters.backends import JAX, declared
from pfx.filters.particle.auxiliary import AuxiliaryFirstStage
from pfx.filters.particle.resampling import RESAMPLERS


def jax_installed() -> bool:
    return importlib.util.find_spec("jax") is not None


def jax_components(settings) -> list[tuple[str, str, object]]:
    """The components of a ``filter:`` section that decide what the step computes, as (key,
    name, component), in the order a refusal names them: each declares where it runs
    (:mod:`pfx.filters.backends`)."""
    adaptive, injection = getattr(settings, "adaptive", None), getattr(settings, "injection", None)
    components = [("resampler", settings.resampler, RESAMPLERS[settings.resampler]),
                  ("weighting", settings.weighting.label(), settings.weighting),
                  ("proposal", settings.proposal.kind, settings.proposal),
                  ("auxiliary", "", AuxiliaryFirstStage if settings.auxiliary else None),
                  ("move", settings.move.kind, settings.move),
                  ("diffusion", settings.diffusion.kind, settings.diffusion),
                  ("adaptive", getattr(adaptive, "kind", ""), adaptive),
                  ("injection", getattr(injection, "kind", ""), injection)]
    components += [("smoothers", smoother.kind, smoother) for smoother in getattr(settings, "smoothers", None) or ()]
    return [(key, name, component) for key, name, component in components if component is not None]


def check_jax_settings(settings) -> None:
    """ValueError('@key: reason') for the first component of ``filter:`` that does not declare the
    jax backend (:mod:`pfx.filters.backends`), with the reason it declares."""
    if not jax_installed():
        raise ValueError("@backend: jax is not installed in this Python; install the extra: pip install 'pfx[jax]' "
                         "(docs/backends.md: the extra for NVIDIA GPUs), or set backend: numpy")
    for key, name, component in jax_components(settings):
        backends = declared(component)
        if not backends.runs_on(JAX):
            raise ValueError(f"@{key}: {backends.refusal(JAX, name)}; set backend: numpy for this filter "
                             "(docs/backends.md lists what each backend runs)")


def measurement_draw_fault(model, precision: str = "float64") -> Optional[str]:
    """Why the jax backend cannot draw the model's measurements: the error of tracing its
    ``simulate_measurement`` on a tiny batch (2 trials x 3 particles; nothing computed), as the
    compiled filter calls it for ``metrics.scores`` (:func:`pfx.filters.particle.predictive.predictive_step`),
    in a few words; None where it traces. The engine's own probe (``JaxParticleFilter.check_model``)
    traces the laws every filter runs; this one, the method only scores call."""
    import jax
    import jax.numpy as jnp

    from pfx.numerics.key_streams import KeyStreams

    dtype = jnp.float32 if precision == "float32" else jnp.float64
    with jax.enable_x64(True):
        keys = jnp.zeros((2, 2), jnp.uint32)
        state = jax.ShapeDtypeStruct((2, 3, model.state_dimension), dtype)
        try:
            jax.eval_shape(lambda k, x: model.simulate_measurement(x, KeyStreams(k, dtype)), keys, state)
        except Exception as error:      # any failure to trace: the method is NumPy-only
            text = str(error).strip()
            return (text.splitlines()[0] if text else type(error).__name__)[:160]
    return None

