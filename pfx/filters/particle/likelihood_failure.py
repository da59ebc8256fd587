"""What a particle filter says when a model's log-likelihood is NaN (or +inf) at finite particles.

Both engines (:mod:`pfx.filters.particle.engine` and, after its scan, the jax engine) stop the
run there, and one line must say where to look. The particles are finite (the engines have
already given every NaN or infinite particle weight zero), so the fault is in the model's
``log_likelihood`` itself: the line names it, with its file and the line of its ``def``, and the
usual cause (pfx's own likelihoods, the built-in models' and the measurement noise's density,
point at the noise and the parameters instead). The commonest is 0 * log 0: a Poisson or binomial log-probability written as
``z * log(mu) - mu - lgamma(z + 1)`` is NaN where the mean is 0 and the count is 0 (IEEE
arithmetic makes 0 * -inf NaN, where the mathematics makes it 0); ``xlogy(z, mu)`` of
``pfx.special_functions(xp)`` (scipy's or jax's) is 0 there, or the mean can be kept above 0.
"""

from __future__ import annotations

import inspect
import os
from typing import Optional

# What the log-likelihood was, as the engines name it ("an infinite" is +inf: -inf is a zero weight).
RETURNED = {"NaN": "NaN", "an infinite": "+inf", "NaN or an infinite": "NaN or +inf"}


def bad_log_likelihood_message(model, step: int, bad: str) -> str:
    """The one line for a log-likelihood that is ``bad`` ("NaN", "an infinite", or "NaN or an
    infinite" where the engine cannot tell) at step ``step`` of the filter, for particles that
    are finite."""
    where = _definition(model)
    if where is None:            # pfx's own likelihood (a law's density): its parameters are the suspects
        return (f"model {model.kind} gave {bad} log-likelihood at step {step} of the filter for particles that are "
                "finite (check the measurement noise and the model's parameters)")
    returned = f"its log_likelihood ({where}) returned {RETURNED.get(bad, bad)} for particles that are finite"
    if bad == "an infinite":
        cause = "a common cause is a density evaluated where its spread is zero (a zero variance)"
    else:
        cause = ("a common cause is 0 * log 0 (a zero mean with a zero count, as in z*log(mu) - mu - lgamma(z+1)): "
                 "use pfx.special_functions(xp).xlogy(z, mu), which is 0 there, or keep the mean above 0")
    return f"model {model.kind} gave {bad} log-likelihood at step {step} of the filter: {returned}; {cause}"


def _definition(model) -> Optional[str]:
    """``file:line`` of the ``def`` of the model's ``log_likelihood``; None if unknown or pfx's
    own (a built-in model's, or the contract's default, the measurement noise's density)."""
    while not hasattr(type(model), "model_fields") and hasattr(model, "model"):
        model = model.model          # IF2's perturbed model wraps the user's model
    function = inspect.unwrap(getattr(type(model), "log_likelihood", None) or (lambda: None))
    try:
        lines, first = inspect.getsourcelines(function)
        file = inspect.getsourcefile(function)
    except (OSError, TypeError):
        return None
    if file is None or function.__name__ != "log_likelihood" or _inside_pfx(file):
        return None
    offset = next((index for index, text in enumerate(lines) if text.lstrip().startswith("def ")), 0)
    return f"{file}:{first + offset}"


def _inside_pfx(file: str) -> bool:
    """Whether ``file`` is part of pfx itself (this package's folder)."""
    package = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return os.path.commonpath([package, os.path.abspath(file)]) == package
