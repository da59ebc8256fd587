"""What the JAX backend runs, and the one-line refusal of what it does not run yet.

``filter.backend: jax`` runs the bootstrap particle filter (``kind: particle`` with the ESS rule,
or ``sis``) with the likelihood as weight and one of the unbiased resamplers. Every other
setting that changes the algorithm is refused here, at plan time, by its key: a config never
runs on the NumPy backend behind its author's back. The refusals name what to do instead.
(docs/backends.md keeps the same list for readers.)
"""

from __future__ import annotations

import importlib.util
from typing import Optional

from pfx.filters.particle.resampling import RESAMPLERS

# the resamplers the JAX backend has (pfx.filters.particle.jax_resampling): the unbiased ones
JAX_RESAMPLER_NAMES = ("systematic", "stratified", "multinomial", "residual")

# What the JAX backend runs but does not record yet, by what asks for it. A config is refused by
# its key (pfx.config.plan_checks), a call of pfx.filter by its argument (pfx.filtering), in
# these words, rather than run without what was asked for.
NOT_RECORDED = {"consistency": "record the posterior covariances and NIS",
                "particles": "keep particle clouds (particles.csv)"}


def jax_installed() -> bool:
    return importlib.util.find_spec("jax") is not None


def check_jax_settings(settings) -> None:
    """ValueError('@key: reason') for the first setting of ``filter:`` the JAX backend cannot run."""
    if not jax_installed():
        raise ValueError("@backend: jax is not installed in this Python; install the extra: pip install 'pfx[jax]' "
                         "(docs/backends.md: the extra for NVIDIA GPUs), or set backend: numpy")
    if settings.resampler not in JAX_RESAMPLER_NAMES:
        unbiased = "" if RESAMPLERS[settings.resampler].unbiased else " (it is the biased one kept to show its bias)"
        raise ValueError(f"@resampler: the jax backend has the resamplers {', '.join(JAX_RESAMPLER_NAMES)}; not "
                         f"{settings.resampler}{unbiased}: use backend: numpy for it")
    if not settings.weighting.is_likelihood:
        raise ValueError(f"@weighting: the jax backend weighs by the model's likelihood (gaussian); "
                         f"{settings.weighting.label()} runs on backend: numpy")
    refusals = {
        "proposal": settings.proposal.guided and f"guided proposals ({settings.proposal.kind})",
        "auxiliary": settings.auxiliary and "the auxiliary particle filter",
        "move": settings.move.kind != "none" and f"moves after resampling ({settings.move.kind})",
        "adaptive": getattr(settings, "adaptive", None) is not None and "adaptive particle counts (KLD)",
        "injection": getattr(settings, "injection", None) is not None and "particle injection",
        "smoothers": bool(getattr(settings, "smoothers", None)) and "smoothers",
    }
    for key, what in refusals.items():
        if what:
            raise ValueError(f"@{key}: the jax backend does not run {what} yet; set backend: numpy for this "
                             "filter (docs/backends.md lists what each backend runs)")


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


def not_recorded(what: str, drop: str, numpy: str) -> str:
    """The refusal of ``what`` (a key of :data:`NOT_RECORDED`) on the JAX backend, saying what to
    drop (``drop``: the key or argument) or how to run on the NumPy backend instead (``numpy``)."""
    return f"the jax backend does not {NOT_RECORDED[what]} yet; drop {drop} or set {numpy}"
