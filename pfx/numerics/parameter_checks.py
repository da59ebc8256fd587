r"""The random laws' parameters, checked the same way on both backends: one rule per argument.

A law given a parameter outside its domain (a negative Poisson rate, a probability above 1, a
NaN exit rate) must stop the run with one line naming the law and the argument. Left to
themselves, NumPy raises from inside its own draw about something else, and JAX draws -1 or NaN
without a word. Each :class:`Rule` below says what one argument of one law must be; it is the
one statement of that rule, read by NumPy's streams (:class:`~pfx.numerics.seeding.TrialStreams`),
JAX's (:class:`~pfx.numerics.key_streams.KeyStreams`) and the count laws
(:mod:`pfx.laws.count_transitions`). :func:`check` applies a rule to values:

* **values it can see** (NumPy arrays, Python numbers, JAX arrays outside a compiled function)
  are checked at once: ``ValueError("poisson: rate must be non-negative and at most 9.223e+18,
  got -1.0")``, before any generator moves;
* **traced values** (JAX arrays inside a compiled step) have no value yet, and nothing traced
  can raise. The outcome, per trial, goes to the innermost :func:`collecting` block: a (trials,)
  integer array holding the code of the first rule each trial broke, in the order the code
  checks (0: none; the code of a rule is its place in :data:`RULES`, from 1). The JAX particle
  filter opens one around the model's transition, carries the codes out of its scan with the
  step's other failures, and raises :func:`broken_rule_message` after the scan
  (:mod:`pfx.filters.particle.jax_engine`). Traced values outside any block (a model called
  under a ``jax.jit`` of one's own) are not checked.

A loop body is traced apart from its surroundings, so a check inside one needs a block of its
own whose codes the loop carries out: the engine's scan over substeps and :func:`pfx.repeat`
open one (:func:`merge_codes` hands the loop's codes to the block around it).

The checks run at every substep of a filter with thousands of particles, so each is a few
vectorised reductions over its argument and no Python loop: on NumPy its minimum and maximum
(NaN in either if a value is NaN; a whole number's also compares it with its floor), a plain
number tested by :mod:`math`; on JAX a reduction per trial. Nothing is drawn, so no number changes.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, Callable, Iterator, NamedTuple, Optional

import numpy as np

# How far the probabilities of a multinomial may sum from 1: float64 sums of a few rounded
# probabilities are within 1e-15 of it, float32 ones within 1e-6; beyond these, the last category
# would take a share the caller never gave it.
SUM_TOLERANCE_FLOAT64 = 1e-9
SUM_TOLERANCE_FLOAT32 = 1e-5

# NumPy's own bound on a Poisson rate (POISSON_LAM_MAX), beyond which the draws overflow int64.
LARGEST_POISSON_RATE = float(np.iinfo(np.int64).max) - 10 * math.sqrt(np.iinfo(np.int64).max)


class Rule(NamedTuple):
    """What argument ``argument`` of law ``law`` must ``meaning`` (a predicate: "be in [0, 1]").

    ``valid(xp, values)`` is True where the values are allowed, elementwise (``xp`` numpy or
    jax.numpy); ``holds(values)`` says whether all of a NumPy array's are, in as few passes as
    can be (a minimum and a maximum: both are NaN if a value is, and NaN compares False), as it
    runs at every draw; ``measured(xp, values)``, when given, is what the rule judges instead of
    the values themselves (a row's sum). ``shown`` precedes the bad value in a refusal,
    ``unseen`` stands for it where it was traced."""

    law: str
    argument: str
    meaning: str
    valid: Callable[[Any, Any], Any]
    holds: Callable[[np.ndarray], bool]
    measured: Optional[Callable[[Any, Any], Any]] = None
    shown: str = ""
    unseen: str = "a value that is not"


def _non_negative(xp, values):
    return xp.isfinite(values) & (values >= 0)


def _all_non_negative(values) -> bool:
    return values.size == 0 or bool(values.min() >= 0 and values.max() < np.inf)


def _positive(xp, values):
    return xp.isfinite(values) & (values > 0)


def _all_positive(values) -> bool:
    return values.size == 0 or bool(values.min() > 0 and values.max() < np.inf)


def _whole(xp, values):
    return _non_negative(xp, values) & (values % 1 == 0) & (values < 2.0**63)      # inf % 1 is NaN


def _all_whole(values) -> bool:
    return values.size == 0 or bool(values.min() >= 0 and values.max() < 2.0**63
                                    and (values == np.floor(values)).all())


def _probability(xp, values):
    return (values >= 0) & (values <= 1)            # NaN fails both


def _all_probabilities(values) -> bool:
    return values.size == 0 or bool(values.min() >= 0 and values.max() <= 1)


def _poisson_rate(xp, values):
    return _non_negative(xp, values) & (values <= LARGEST_POISSON_RATE)


def _all_poisson_rates(values) -> bool:
    return values.size == 0 or bool(values.min() >= 0 and values.max() <= LARGEST_POISSON_RATE)


def _row_sums(xp, values):
    return xp.sum(values, axis=-1)


def _sum_tolerance(sums) -> float:
    return SUM_TOLERANCE_FLOAT64 if sums.dtype == np.float64 else SUM_TOLERANCE_FLOAT32


def _near_one(xp, sums):
    return xp.abs(sums - 1.0) <= _sum_tolerance(sums)


def _all_near_one(sums) -> bool:
    tolerance = _sum_tolerance(sums)
    return sums.size == 0 or bool(sums.min() >= 1.0 - tolerance and sums.max() <= 1.0 + tolerance)


_SUMS_TO_ONE = (f"sum to 1 along the last axis (within {SUM_TOLERANCE_FLOAT64:g}, or "
                f"{SUM_TOLERANCE_FLOAT32:g} in float32)")
_DURATION = "be finite and non-negative (a duration)"

BINOMIAL_COUNT = Rule("binomial", "count", "be a non-negative integer", _whole, _all_whole)
BINOMIAL_PROBABILITY = Rule("binomial", "probability", "be in [0, 1]", _probability, _all_probabilities)
POISSON_RATE = Rule("poisson", "rate", f"be non-negative and at most {LARGEST_POISSON_RATE:.4g}", _poisson_rate,
                    _all_poisson_rates)
GAMMA_SHAPE = Rule("gamma", "shape_parameter", "be finite and non-negative", _non_negative, _all_non_negative)
GAMMA_SCALE = Rule("gamma", "scale", "be finite and non-negative", _non_negative, _all_non_negative)
EXPONENTIAL_SCALE = Rule("exponential", "scale", "be finite and non-negative", _non_negative, _all_non_negative)
NORMAL_SD = Rule("normal", "sd", "be finite and non-negative", _non_negative, _all_non_negative)
EULER_COUNT = Rule("euler_multinomial", "count", "be a non-negative integer", _whole, _all_whole)
EULER_RATES = Rule("euler_multinomial", "rates", "be finite and non-negative", _non_negative, _all_non_negative)
EULER_STEP = Rule("euler_multinomial", "step", _DURATION, _non_negative, _all_non_negative)
MULTINOMIAL_COUNT = Rule("multinomial", "count", "be a non-negative integer", _whole, _all_whole)
MULTINOMIAL_PROBABILITIES = Rule("multinomial", "probabilities", "be in [0, 1]", _probability, _all_probabilities)
MULTINOMIAL_TOTAL = Rule("multinomial", "probabilities", _SUMS_TO_ONE, _near_one, _all_near_one, _row_sums,
                         "a row summing to ", "a row that does not")
NOISE_SIGMA = Rule("gamma_white_noise", "sigma", "be finite and positive", _positive, _all_positive)
NOISE_STEP = Rule("gamma_white_noise", "step", _DURATION, _non_negative, _all_non_negative)

# The codes carried out of a compiled step: a rule's place here, from 1. Append new rules at
# the end, so that a code keeps its meaning.
RULES = (BINOMIAL_COUNT, BINOMIAL_PROBABILITY, POISSON_RATE, GAMMA_SHAPE, GAMMA_SCALE, EXPONENTIAL_SCALE,
         NORMAL_SD, EULER_COUNT, EULER_RATES, EULER_STEP, MULTINOMIAL_COUNT, MULTINOMIAL_PROBABILITIES,
         MULTINOMIAL_TOTAL, NOISE_SIGMA, NOISE_STEP)


def numbers(rule: Rule, values: Any) -> np.ndarray:
    """``values`` as a NumPy array of floats (a floating dtype is kept: a float32 sum is judged
    as float32), or a ValueError naming the law and the argument."""
    try:
        array = np.asarray(values)
        if array.dtype.kind not in "fiub":
            raise TypeError
        return array if array.dtype.kind == "f" else array.astype(float)
    except (TypeError, ValueError):
        raise ValueError(f"{rule.law}: {rule.argument} must be numbers (a number or an array), got "
                         f"{type(values).__name__}") from None


def refuse_unless_valid(rule: Rule, values: np.ndarray) -> None:
    """ValueError naming the law, the argument and the first value that breaks ``rule``, if one
    does; ``values`` a NumPy array."""
    judged = rule.measured(np, values) if rule.measured is not None else values
    if not rule.holds(judged):
        with np.errstate(invalid="ignore"):        # inf % 1, on the way to naming the bad value
            bad = np.asarray(judged)[~np.asarray(rule.valid(np, judged))]
        raise _refusal(rule, bad.flat[0])


def _refusal(rule: Rule, value) -> ValueError:
    return ValueError(f"{rule.law}: {rule.argument} must {rule.meaning}, got {rule.shown}{float(value)!r}")


def check(rule: Rule, values: Any, *, event_axes: int = 0) -> None:
    """Apply ``rule`` to ``values`` (module docstring): raise now if they can be seen, else
    record each trial's outcome in the innermost :func:`collecting` block. Traced values are laid
    out as the streams read parameters (the trial axis first, or none: shared by every trial);
    ``event_axes`` trailing axes belong to one draw (a multinomial's categories)."""
    if isinstance(values, (int, float)) and not isinstance(values, bool) and rule.measured is None:
        if not rule.valid(math, values):         # a plain number (a step, a sigma): no array to make
            raise _refusal(rule, values)
        return
    if not _traced(values):
        refuse_unless_valid(rule, numbers(rule, values))
        return
    checks = _active.get()
    if checks is None:
        return
    xp = values.__array_namespace__()
    judged = rule.measured(xp, values) if rule.measured is not None else values
    valid = rule.valid(xp, judged)
    if event_axes and rule.measured is None:
        valid = xp.all(valid, axis=tuple(range(valid.ndim - event_axes, valid.ndim)))
    checks.fail_where(RULES.index(rule) + 1, valid)


def _traced(values: Any) -> bool:
    if not type(values).__module__.startswith("jax"):
        return False
    import jax

    return isinstance(values, jax.core.Tracer)


class ParameterChecks:
    """The outcome of the checks of traced values in one :func:`collecting` block: ``codes``,
    (trials,) int32, the code of the first rule each trial broke (0: none)."""

    def __init__(self, trials: int):
        self.trials = trials
        self._codes = None

    @property
    def recorded(self) -> bool:
        """Whether any check reached this block (a model without count laws adds nothing to its step)."""
        return self._codes is not None

    @property
    def codes(self) -> Any:
        import jax.numpy as jnp

        return self._codes if self._codes is not None else jnp.zeros(self.trials, jnp.int32)

    def fail_where(self, code: int, valid: Any) -> None:
        """Record ``code`` for the trials where ``valid`` is False anywhere: ``valid`` has the trial
        axis first (length trials, or 1) or no axis (shared)."""
        import jax.numpy as jnp

        if valid.ndim and valid.shape[0] in (self.trials, 1):
            valid = jnp.all(valid.reshape(valid.shape[0], -1), axis=1)
        elif valid.ndim:                                  # no trial axis: the same for every trial
            valid = jnp.all(valid)
        self.merge(jnp.where(jnp.broadcast_to(valid, (self.trials,)), 0, code).astype(jnp.int32))

    def merge(self, codes: Any) -> None:
        """Add later codes (trials,): a trial keeps the first rule it broke."""
        import jax.numpy as jnp

        self._codes = codes if self._codes is None else jnp.where(self._codes != 0, self._codes, codes)


_active: ContextVar[Optional[ParameterChecks]] = ContextVar("pfx_parameter_checks", default=None)


@contextmanager
def collecting(trials: int) -> Iterator[ParameterChecks]:
    """A block whose checks of traced values are recorded in the :class:`ParameterChecks` it yields."""
    token = _active.set(ParameterChecks(trials))
    try:
        yield _active.get()
    finally:
        _active.reset(token)


def active_checks() -> Optional[ParameterChecks]:
    """The innermost open :func:`collecting` block, or None."""
    return _active.get()


def merge_codes(codes_per_pass: Any) -> None:
    """After a loop whose passes each returned their block's codes (passes, trials): the first
    code of each trial, handed to the block around the loop (if one is open)."""
    import jax.numpy as jnp

    checks = _active.get()
    if checks is None:
        return
    first = jnp.argmax(codes_per_pass != 0, axis=0)
    checks.merge(jnp.take_along_axis(codes_per_pass, first[None, :], axis=0)[0])


def broken_rule_message(code: int) -> str:
    """The refusal of the rule with ``code``, as NumPy words it, for a value that was traced."""
    rule = RULES[code - 1]
    return f"{rule.law}: {rule.argument} must {rule.meaning}, got {rule.unseen}"
