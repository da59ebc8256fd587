r"""The truth: simulating a model's states and measurements, one stream per trial.

:func:`simulate_truth` draws the true states :math:`x_0, \dots, x_T` from the model's initial
law and transition, applies the model's truth events (a kidnapping: :meth:`Model.truth_event`,
never seen by a filter), and draws each measurement :math:`z_k \sim p(z_k \mid x_k)`. Each
trial's draws come from its own stream (:class:`~pfx.numerics.seeding.TrialStreams`), so a
trial's truth does not depend on the batch it is simulated in.
"""

from __future__ import annotations

import numpy as np

from pfx.errors import ModelContractError, ModelNumericalError, note_step
from pfx.numerics.seeding import TrialStreams


def simulate_truth(model, random: TrialStreams) -> tuple[np.ndarray, np.ndarray]:
    """True states x_0..x_T (R, T+1, d) and measurements z_1..z_T (R, T, m) from ``model``;
    the model's truth events (a kidnapping: :meth:`truth_event`) apply here, never in a filter."""
    trials = len(random)
    state = model.initial.sample(random)
    states = np.empty((trials, model.steps + 1, state.shape[-1]))
    measurements = np.empty((trials, model.steps, model.measurement_dimension))
    states[:, 0] = state
    k = 0
    try:
        for k in range(1, model.steps + 1):
            with np.errstate(over="ignore", invalid="ignore"):   # reported just below
                state = model.transition(state, k, random)
                _check_shape(model, f"the transition ({model.transition_method()})", state, states.shape[::2], k)
                state = model.truth_event(state, k)
                states[:, k] = state
                measurement = model.simulate_measurement(state, random)
                _check_shape(model, "simulate_measurement", measurement, measurements.shape[::2], k)
                measurements[:, k - 1] = measurement
            if not (np.isfinite(state).all() and np.isfinite(measurements[:, k - 1]).all()):
                raise ModelNumericalError(f"model {model.kind} produced NaN or infinite values at step {k} "
                                          "of the truth")
    except Exception as error:            # where it happened, for the one-line report
        note_step(error, k, "truth")
        raise
    return states, measurements


def _check_shape(model, source: str, value, expected: tuple, k: int) -> None:
    """The truth's arrays keep their shape (R, d) / (R, m): a wrong one would broadcast silently."""
    if np.shape(value) != expected:
        raise ModelContractError(f"model {model.kind}: {source} returned shape {np.shape(value)} at step {k} of "
                                 f"the truth, for {expected[0]} trials; expected {expected}")
