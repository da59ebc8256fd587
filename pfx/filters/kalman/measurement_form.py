r"""What the Gaussian filters assume of a model's measurement, in one place, and the plan-time
check that a plugin's model has it.

The Kalman filters (``kf``, ``ekf``, ``ukf``) and the guided proposals (``locally_optimal``,
``ekf``, ``ukf``: :mod:`pfx.filters.particle.proposals`) read the measurement as

.. math::

    z = h(x) + v, \qquad v \sim \text{measurement\_noise} \ \ (\text{covariance } R),

and update with the innovation :math:`\nu = z - h(x)` and :math:`R`; with gaussian noise that is
the model's likelihood :math:`\log p(z \mid x) = \log N(\nu; 0, R)`, with another family the
best linear update for it (docs/filters-and-models.md).

**Angles.** A model declares which measurement components are angles
(:attr:`~pfx.models.base.Model.measurement_angular_components`, in units of
:attr:`~pfx.models.base.Model.measurement_full_turn`). Their innovation is wrapped into half a
turn either side (:func:`measurement_innovation`): a bearing measured just above :math:`-\pi` and predicted
just below :math:`\pi` is a small innovation, not a turn. The EKF's finite-difference Jacobian
wraps its differences the same way, and the UKF averages the sigma points' images of an angle on
the circle (:func:`pfx.filters.kalman.unscented.unscented_moments`).

**The probe.** A model may define its own ``log_likelihood``: another noise family, a bearing
that wraps, a multiplicative noise. The filters above would then silently update with a law
that is not the model's (an EKF on a range-bearing model whose bearings wrap but are not
declared: an RMSE of 224 m against the particle filter's 7.3 m). So before they run on a
model that is not pfx's own, :func:`check_measurement_form` compares its ``log_likelihood`` with
the form above at probe points, up to a constant:

* states: 3 drawn from the model's initial law and 3 from its default prior, with a fixed
  private seed;
* measurements around each state's :math:`h(x)`: :math:`h(x)` itself, four fixed patterns of
  offsets of up to 2.2 standard deviations (of R's diagonal) in every component, and the first
  pattern shifted by a full turn in one component at a time (the declared turn for an angle;
  :math:`2\pi` and 360 for any other component, so that an undeclared wrap shows);
* the differences :math:`\log p(z_i \mid x_i) - \log p(z_0 \mid x_0)` of the model and of the
  form must agree to a relative :math:`10^{-6}` (floating point cannot trip it; a different
  family, variance or wrap misses it by orders of magnitude), and both be finite at the same
  points.

A mismatch refuses those filters in one line that says which function, which filter and what
to do. Its verdict is kept per model class and settings (PMMH plans a filter at each of
thousands of parameter values; a cell's models are probed once). pfx's own models are not
probed: every one is of this form where these filters accept it (the test suite probes them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from pfx.numerics.angles import wrap_components
from pfx.numerics.hashing import SettingsCache
from pfx.numerics.seeding import TrialStreams

PROBE_SEED = 20_240_334                     # the private stream of the probe's states
PROBE_STATES = 3                            # from each of the initial law and the default prior
OFFSET_PATTERN = np.array([0.7, -1.3, 2.1, -0.4, 1.1, -2.2, 0.3])   # in standard deviations
OFFSET_PATTERNS = 4
UNDECLARED_TURNS = (2.0 * math.pi, 360.0)   # the turns a wrap of an undeclared component may use
RELATIVE_TOLERANCE = 1e-6
ABSOLUTE_TOLERANCE = 1e-9                   # relative to the log-likelihoods' own size

_verdicts = SettingsCache()                 # measurement_form_mismatch's answers


@dataclass(frozen=True)
class MeasurementAngles:
    """The angular measurement components of a model: their indices and the full turn."""

    components: tuple[int, ...]
    full_turn: float

    def wrap(self, difference: np.ndarray) -> np.ndarray:
        """A difference of measurements (..., m) with these components wrapped."""
        return wrap_components(difference, self.components, self.full_turn)


def measurement_angles(model) -> Optional[MeasurementAngles]:
    """The model's angular measurement components, or None when it declares none."""
    components = tuple(model.measurement_angular_components)
    return MeasurementAngles(components, float(model.measurement_full_turn)) if components else None


def measurement_innovation(model, measurement: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """z - h: the measurement minus its prediction, the angular components wrapped."""
    difference = measurement - predicted
    angles = measurement_angles(model)
    return difference if angles is None else angles.wrap(difference)


# -- the plan-time probe -------------------------------------------------------------------------


def is_pfx_model(model) -> bool:
    """Whether the model's class is pfx's own (a built-in), not a plugin's or a notebook's."""
    return type(model).__module__.split(".")[0] == "pfx"


def check_measurement_form(model, user: str, key: str, remedy: str) -> None:
    """Raise ``ValueError("@<key>: ...")`` when ``user`` (``"the ekf filter"``, ``"the ukf
    proposal"``) cannot honour the model's own ``log_likelihood``: it is not the form of the
    module docstring. ``remedy`` says what to use instead. pfx's own models pass unprobed."""
    if is_pfx_model(model):
        return
    reason = measurement_form_mismatch(model)
    if reason is None:
        return
    angles = " (its angles wrapped)" if model.measurement_angular_components else ""
    raise ValueError(f"@{key}: {user} updates with z = h(x) + v, v ~ measurement_noise (covariance R), and the "
                     f"innovation z - h(x){angles}; model {model.kind}'s log_likelihood {reason}; {remedy}, or make "
                     "log_likelihood that form (docs/plugins.md, The Gaussian filters and your likelihood)")


def measurement_form_mismatch(model) -> Optional[str]:
    """How the model's ``log_likelihood`` departs from the form of the module docstring (a clause
    that follows "its log_likelihood"), or None where it agrees at every probe point. Kept per
    class and settings."""
    return _verdicts.answer(model, lambda: _probe(model))


@dataclass(frozen=True)
class _Shift:
    """A probe measurement: ``pattern`` (None: h(x) itself) of offsets, and a turn added to one
    component (``component`` None: none)."""

    pattern: Optional[int]
    component: Optional[int] = None
    turn: float = 0.0


def _shifts(model) -> list[_Shift]:
    declared = set(model.measurement_angular_components)
    shifts = [_Shift(None)] + [_Shift(k) for k in range(OFFSET_PATTERNS)]
    for j in range(model.measurement_dimension):
        turns = (float(model.measurement_full_turn),) if j in declared else UNDECLARED_TURNS
        shifts += [_Shift(0, j, turn) for turn in turns]
    return shifts


def _offsets(shifts: list[_Shift], deviations: np.ndarray) -> np.ndarray:
    """The measurement offsets z - h(x) of the shifts, (V, m)."""
    m = len(deviations)
    offsets = np.zeros((len(shifts), m))
    for row, shift in enumerate(shifts):
        if shift.pattern is not None:
            offsets[row] = OFFSET_PATTERN[(np.arange(m) + 2 * shift.pattern) % len(OFFSET_PATTERN)] * deviations
        if shift.component is not None:
            offsets[row, shift.component] += shift.turn
    return offsets


def probe_states(model) -> np.ndarray:
    """(S, d): states from the initial law and the default prior (a fixed private stream)."""
    random = TrialStreams.from_seeds([PROBE_SEED])
    prior = model.default_prior()
    prior.bind(model.state_dimension)       # a law default_prior() made afresh is not bound yet
    return np.concatenate([np.asarray(law.sample(random, (PROBE_STATES,)), dtype=float)[0]
                           for law in (model.initial, prior)])


def _probe(model) -> Optional[str]:
    states = probe_states(model)
    with np.errstate(all="ignore"):
        predicted = np.asarray(model.measurement_mean(states), dtype=float)
    valid = np.isfinite(predicted).all(axis=-1) & np.isfinite(states).all(axis=-1)
    if not valid.any():
        return None            # h(x) nowhere finite at the probe's states: nothing to compare
    states, predicted = states[valid], predicted[valid]
    noise = model.measurement_noise
    deviations = np.sqrt(np.clip(np.diag(noise.covariance()), 0.0, None))
    deviations = np.where(deviations > 0, deviations, 1.0)
    shifts = _shifts(model)
    offsets = _offsets(shifts, deviations)
    S, V, m = len(states), len(shifts), model.measurement_dimension
    measurements = (predicted[:, None, :] + offsets[None, :, :]).reshape(S * V, 1, m)
    repeated = np.repeat(states, V, axis=0)[:, None, :]
    with np.errstate(all="ignore"):
        own = np.asarray(model.log_likelihood(measurements, repeated), dtype=float).reshape(S, V)
        form = noise.log_density(measurement_innovation(model, measurements, np.repeat(predicted, V, axis=0)[:, None, :]))
    form = np.asarray(form, dtype=float).reshape(S, V)
    if not (np.isfinite(own[0, 0]) and np.isfinite(form[0, 0])):
        return f"is {own[0, 0]} at z = h(x), where the form's log-density is {form[0, 0]:.6g}"
    differences_own, differences_form = own - own[0, 0], form - form[0, 0]
    with np.errstate(all="ignore"):
        gap = np.abs(differences_own - differences_form)
        allowed = (RELATIVE_TOLERANCE * np.maximum(np.abs(differences_own), np.abs(differences_form))
                   + ABSOLUTE_TOLERANCE * (1.0 + abs(own[0, 0]) + abs(form[0, 0])))
        agree = np.where(np.isfinite(own) | np.isfinite(form), gap <= allowed, True)
    agree &= np.isfinite(own) == np.isfinite(form)
    if agree.all():
        return None
    return _diagnosis(model, shifts, own, differences_own, differences_form, agree)


def _diagnosis(model, shifts, own, differences_own, differences_form, agree) -> str:
    """The clause saying how the likelihood departs from the form (see measurement_form_mismatch)."""
    names = tuple(model.measurement_names)
    plain = [v for v, shift in enumerate(shifts) if shift.component is None]
    if agree[:, plain].all():
        declared = set(model.measurement_angular_components)
        for v, shift in enumerate(shifts):
            if agree[:, v].all():
                continue
            name = names[shift.component]
            turn = _turn_text(shift.turn)
            if shift.component in declared:
                return (f"does not wrap {name}, which the model declares an angle (measurement_angular_components): "
                        f"it gives {name} and {name} + {turn} different likelihoods")
            unshifted = plain[1]          # the pattern the turn was added to
            same = np.isclose(own[:, v], own[:, unshifted], rtol=RELATIVE_TOLERANCE, atol=0.0)
            if same.all():
                full_turn = "" if shift.turn == 2.0 * math.pi else f" and measurement_full_turn = {turn}"
                return (f"wraps {name} (it gives {name} and {name} + {turn} the same likelihood), an angle the model "
                        f"does not declare: declare measurement_angular_components = ({shift.component},){full_turn} "
                        "so that the filter wraps it too")
    v = int(np.argmin(agree.all(axis=0)))
    row = int(np.argmin(agree[:, v]))
    where = "z = h(x) + a turn" if shifts[v].component is not None else "z = h(x) + a few standard deviations"
    return (f"is not the {model.measurement_noise.family} log-density of measurement_noise at z - h(x) up to a "
            f"constant (at {where} it gives {differences_own[row, v]:.6g} relative to z = h(x), the form "
            f"{differences_form[row, v]:.6g})")


def _turn_text(turn: float) -> str:
    return "2 pi" if turn == 2.0 * math.pi else f"{turn:g}"
