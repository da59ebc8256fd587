"""The model's time axis and composed operations on both array backends (pfx/models/time_axis.py,
pfx/models/base.py; "models written once", docs/backends.md).

Backend-invariant group: the same model, given JAX arrays (and, inside ``jax.jit``, a traced
time), computes what it computes on NumPy arrays, to rounding (1e-12; the formulas are the same,
so only the compilers' rounding differs):

* ``covariates_at`` at a traced time (a compiled scan's substep time) interpolates the table as
  the NumPy path does: between rows, at rows, at both ends, and holds the end rows beyond them
  (the span is checked before a run, not on a traced value);
* ``reset_accumulators`` on a JAX array sets the same components to 0 and leaves its input as it
  was (functionally: a copy);
* ``mean_transition`` on a JAX array, for a model with accumulators, substeps and covariates read
  at each substep's time, equals NumPy's.

And a check of the split: the contract checks see the properties the time-axis mixin declares.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
import pytest

from pfx.laws.initial import PointLaw
from pfx.laws.noise import Noise
from pfx.models.base import Model
from pfx.models.contract_checks import methods_meant_as_properties, missing_methods
from pfx.numerics.arrays import namespace

# An irregular table (rows at uneven times), three covariates of different signs and scales.
TABLE = {"time": [0.0, 0.25, 1.0, 1.5, 3.0],
         "inflow": [2.0, 3.5, -1.0, 0.5, 4.0],
         "rate": [0.1, 0.3, 0.2, 0.25, 0.15],
         "scale": [1.0e3, -2.0e3, 5.0e2, 0.0, 7.5e2]}
# Times inside rows, at rows, and at both ends of the table.
TIMES = (0.0, 0.1, 0.25, 0.6, 1.0, 1.2, 1.5, 2.9999, 3.0)
TOLERANCE = 1e-12


class Tank(Model):
    """A tank with inflow c_1(t) and outflow rate c_2(t): per substep of h,
    level <- level + (c_1 - c_2 level) h + w, drained <- drained + c_2 level h; ``drained`` is an
    accumulator (the outflow since the last measurement), and the measurement is the level.
    Written against the array namespace, as a model for both backends is."""

    kind: Literal["tank"] = "tank"
    integrates_substeps: ClassVar[bool] = True

    @property
    def state_names(self):
        return ("level", "drained")

    @property
    def measurement_dimension(self):
        return 1

    @property
    def covariate_names(self):
        return ("inflow", "rate", "scale")

    @property
    def accumulating_components(self):
        return (1,)

    def propagate(self, state, control, noise, time):
        xp = namespace(state, noise)
        covariates = self.covariates_at(time)
        inflow, rate, h = covariates[0], covariates[1], self.substep_duration
        level, drained = state[..., 0], state[..., 1]
        outflow = rate * level * h
        return xp.stack([level + inflow * h - outflow + noise[..., 0], drained + outflow], axis=-1)

    def measurement_mean(self, state):
        return state[..., :1]


def tank(**changes) -> Tank:
    parameters = dict(steps=3, dt=1.0, substeps=4, covariates=TABLE, process_noise=Noise(variance=0.01),
                      measurement_noise=Noise(variance=0.1), initial=PointLaw(state=[5.0, 0.0]))
    parameters.update(changes)
    return Tank(**parameters)


@pytest.fixture
def jax_x64():
    """JAX with 64-bit types, for this test only (other tests' JAX settings are left as they are)."""
    jax = pytest.importorskip("jax")
    with jax.enable_x64(True):
        yield jax


def test_covariates_at_a_traced_time_equals_the_numpy_interpolation(jax_x64):
    jax, model = jax_x64, tank()
    jnp = jax.numpy
    traced_times = []

    def covariates(time):
        traced_times.append(isinstance(time, jax.core.Tracer))
        return model.covariates_at(time)

    compiled = jax.jit(covariates)
    for time in TIMES:
        expected = model.covariates_at(time)
        assert isinstance(expected, np.ndarray)                 # a number takes the NumPy path
        got = compiled(jnp.asarray(time))
        assert got.shape == expected.shape and got.dtype == jnp.float64
        np.testing.assert_allclose(np.asarray(got), expected, rtol=TOLERANCE, atol=TOLERANCE)
    assert traced_times == [True]                               # compiled once, on a tracer


def test_a_traced_time_beyond_the_table_holds_its_end_rows(jax_x64):
    """No check on a traced value (the span is checked before a run): beyond the ends, the end rows."""
    jax, model = jax_x64, tank()
    compiled = jax.jit(model.covariates_at)
    first, last = model.covariates_at(0.0), model.covariates_at(3.0)
    np.testing.assert_array_equal(np.asarray(compiled(jax.numpy.asarray(-0.5))), first)
    np.testing.assert_array_equal(np.asarray(compiled(jax.numpy.asarray(3.5))), last)
    with pytest.raises(ValueError, match="outside their table"):      # a number is still checked
        model.covariates_at(3.5)


def test_a_one_row_table_is_constant_at_a_traced_time(jax_x64):
    jax = jax_x64
    row = {name: values[:1] for name, values in TABLE.items()}
    model = tank(covariates=row)
    got = jax.jit(model.covariates_at)(jax.numpy.asarray(7.0))
    np.testing.assert_array_equal(np.asarray(got), [2.0, 0.1, 1.0e3])


def test_reset_accumulators_on_jax_equals_numpy_and_leaves_its_input(jax_x64):
    jax, model = jax_x64, tank()
    state = np.random.default_rng(1).normal(size=(2, 3, 2))
    expected = model.reset_accumulators(state)
    assert np.all(expected[..., 1] == 0.0) and np.array_equal(expected[..., 0], state[..., 0])
    for reset in (model.reset_accumulators, jax.jit(model.reset_accumulators)):
        given = jax.numpy.asarray(state)
        got = reset(given)
        assert namespace(got) is jax.numpy
        np.testing.assert_array_equal(np.asarray(got), expected)
        np.testing.assert_array_equal(np.asarray(given), state)          # the input is unchanged


def test_mean_transition_on_jax_equals_numpy(jax_x64):
    """Accumulators reset, four substeps, each reading the covariates at its own time."""
    jax, model = jax_x64, tank()
    previous = np.abs(np.random.default_rng(2).normal(5.0, 1.0, size=(2, 3, 2)))
    for step in (1, 2, 3):
        expected = model.mean_transition(previous, step)
        assert np.all(expected[..., 1] > 0.0)                   # the drained accumulator restarted from 0
        got = jax.jit(model.mean_transition, static_argnums=1)(jax.numpy.asarray(previous), step)
        assert namespace(got) is jax.numpy and got.dtype == jax.numpy.float64
        np.testing.assert_allclose(np.asarray(got), expected, rtol=TOLERANCE, atol=TOLERANCE)


def test_mean_transition_on_numpy_is_the_hand_composition():
    """NumPy: reset, then the substeps with zero noise at t_(k-1) + j h, as written out here."""
    model, previous = tank(), np.array([[[4.0, 9.0]]])
    level, drained, h = 4.0, 0.0, 0.25
    for substep in range(4):
        inflow, rate, _ = model.covariates_at(1.0 + substep * h)             # step 2 starts at t_1 = 1
        level, drained = level + inflow * h - rate * level * h, drained + rate * level * h
    np.testing.assert_array_equal(model.mean_transition(previous, 2), [[[level, drained]]])


def test_the_contract_checks_see_the_time_axis_properties():
    """A property the time-axis mixin declares, written as a method, is a slip the checks name."""

    class Slipped(Tank):
        def propagations_per_step(self):
            return 1

    assert missing_methods(Slipped, Model) == []
    assert [name for name, _ in methods_meant_as_properties(Slipped, Model)] == ["propagations_per_step"]


class Clock(Model):
    """A model whose presets read the time of the initial state: its initial law is a point at
    start_time (a population read from a covariate at t_0 would be the use)."""

    kind: Literal["clock"] = "clock"

    @property
    def state_names(self):
        return ("time",)

    @property
    def measurement_dimension(self):
        return 1

    def presets(self):
        return {"steps": 4, "dt": 0.5, "process_noise": Noise(variance=0.01), "measurement_noise": Noise(variance=0.1),
                "initial": PointLaw(state=[self.start_time])}

    def propagate(self, state, control, noise):
        return state + self.dt + noise

    def measurement_mean(self, state):
        return state


def test_presets_see_the_time_of_the_initial_state_and_follow_recorded_times():
    """start_time is t_1 - dt: 0 for the evenly spaced default; with recorded times, the first
    time less dt, and the fields the presets filled are derived again from it; a field the config
    gave stays as given."""
    clock = Clock()
    assert clock.start_time == 0.0 and clock.initial.state == [0.0]
    clock.use_recorded_times(np.array([1900.0, 1900.5, 1901.0, 1901.5]))
    assert clock.start_time == 1899.5 and clock.initial.state == [1899.5]
    assert clock.substep_time(1, 0) == 1899.5
    given = Clock(initial=PointLaw(state=[7.0]))
    given.use_recorded_times(np.array([1900.0, 1900.5, 1901.0, 1901.5]))
    assert given.initial.state == [7.0]


class DrawingTank(Tank):
    """The tank with a substep of its own (as a count model's ``sample_substep``), reading the
    covariates at the substep's time."""

    kind: Literal["drawing_tank"] = "drawing_tank"

    def sample_substep(self, state, control, time, random):
        inflow = self.covariates_at(time)[0]
        return state + inflow * self.substep_duration * random.uniform(state.shape[1:])


def test_a_plugins_own_substep_reading_covariates_passes_the_plan_time_probe():
    """Before the data's times are known the default time axis starts at 0; the reproducibility
    probe calls the transition at step 1's substep times moved into the covariate table (as it
    does propagate), not outside it (a measles plugin's table starts in 1950)."""
    from pfx.models.contract_checks import reproducibility_fault

    table = {**TABLE, "time": [1950.0 + t for t in TABLE["time"]]}
    assert reproducibility_fault(DrawingTank(steps=3, dt=1.0, substeps=4, covariates=table,
                                             process_noise=Noise(variance=0.01), measurement_noise=Noise(variance=0.1),
                                             initial=PointLaw(state=[5.0, 0.0]))) is None
