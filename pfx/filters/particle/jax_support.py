"""What the JAX backend runs, and the one-line refusal of what it does not run yet.

``filter.backend: jax`` runs the bootstrap particle filter (``kind: particle`` with the ESS rule,
or ``sis``) with the likelihood as weight and one of the unbiased resamplers. Every other
setting that changes the algorithm is refused here, at plan time, by its key: a config never
runs on the NumPy backend behind its author's back. The refusals name what to do instead.
(docs/backends.md keeps the same list for readers.)
"""

from __future__ import annotations

import importlib.util

from pfx.filters.particle.resampling import RESAMPLERS

# the resamplers the JAX backend has (pfx.filters.particle.jax_resampling): the unbiased ones
JAX_RESAMPLER_NAMES = ("systematic", "stratified", "multinomial", "residual")


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
