"""The Lorenz-63 and Lorenz-96 plugin (examples/plugins/lorenz.py), DAPPER's benchmark models.

Checked here without running a filter: one RK4 substep against an RK4 step written out
separately, component by component, from the equations; the exact RK4 Jacobian against central
differences of the step; shapes over leading axes; the presets against DAPPER's model files
(sakov2012.py, bocquet2010.py). Where DAPPER itself can be imported (its own virtual
environment: ``pip install dapper==1.7.1``, then this file run with that environment's python),
25 substeps of the plugin follow DAPPER's own integrator from the same initial state to 1e-12;
elsewhere that test is skipped.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO_ROOT

import pfx
from pfx.config.plugins import load_plugin
from pfx.models.base import MODELS

PLUGIN = load_plugin("lorenz.py", REPO_ROOT / "examples" / "plugins")
MODULE = __import__("sys").modules[PLUGIN.module]
SUBSTEPS_API = "substep_duration" in dir(pfx.Model)     # the observation-interval API of issue 28
needs_substeps = pytest.mark.skipif(not SUBSTEPS_API, reason="pfx.Model has no substeps yet (issue 28)")

SIGMA, RHO, BETA, FORCING = 10.0, 28.0, 8.0 / 3.0, 8.0


def lorenz63_rate(x):
    """The Lorenz-63 equations for one state (a list of three floats)."""
    return [SIGMA * (x[1] - x[0]), RHO * x[0] - x[1] - x[0] * x[2], x[0] * x[1] - BETA * x[2]]


def lorenz96_rate(x):
    """The Lorenz-96 equations for one state, with the ring's indices written modulo n."""
    n = len(x)
    return [(x[(i + 1) % n] - x[(i - 2) % n]) * x[(i - 1) % n] - x[i] + FORCING for i in range(n)]


def hand_rk4(rate, x, h):
    """One classical Runge-Kutta step on plain lists, one component at a time."""
    k1 = [h * value for value in rate(x)]
    k2 = [h * value for value in rate([a + b / 2 for a, b in zip(x, k1)])]
    k3 = [h * value for value in rate([a + b / 2 for a, b in zip(x, k2)])]
    k4 = [h * value for value in rate([a + b for a, b in zip(x, k3)])]
    return [a + (b1 + 2 * b2 + 2 * b3 + b4) / 6 for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]


def lorenz63(**fields):
    return MODELS["lorenz63"](kind="lorenz63", **fields)


def lorenz96(**fields):
    return MODELS["lorenz96"](kind="lorenz96", **fields)


STATES_63 = np.random.default_rng(63).normal([0.0, 0.0, 25.0], 8.0, size=(4, 5, 3))
STATES_96 = np.random.default_rng(96).normal(2.0, 3.0, size=(4, 5, 10))


@pytest.mark.parametrize("model, rate, states, h", [
    (lorenz63(), lorenz63_rate, STATES_63, 0.01),
    (lorenz96(), lorenz96_rate, STATES_96, 0.05),
])
def test_one_rk4_step_is_the_hand_written_one(model, rate, states, h):
    stepped = MODULE.rk4_step(model.tendency, states, h)
    assert stepped.shape == states.shape and stepped.dtype == np.float64
    expected = np.array([[hand_rk4(rate, list(state), h) for state in row] for row in states])
    np.testing.assert_allclose(stepped, expected, rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("model, states, h", [(lorenz63(), STATES_63, 0.01), (lorenz96(), STATES_96, 0.05)])
def test_rk4_jacobian_is_the_derivative_of_the_step(model, states, h):
    jacobian = MODULE.rk4_step_jacobian(model.tendency, model.tendency_jacobian, states, h)
    d = states.shape[-1]
    assert jacobian.shape == states.shape + (d,)
    # Central differences: the step is a polynomial of degree 16 in x; at epsilon 1e-5 the
    # truncation error (~ epsilon^2 times third derivatives of size ~h) is far below 1e-7.
    epsilon = 1e-5
    for j in range(d):
        shift = np.zeros(d)
        shift[j] = epsilon
        column = (MODULE.rk4_step(model.tendency, states + shift, h)
                  - MODULE.rk4_step(model.tendency, states - shift, h)) / (2 * epsilon)
        np.testing.assert_allclose(jacobian[..., :, j], column, atol=1e-7)


@needs_substeps
@pytest.mark.parametrize("make, rate, states, h", [
    (lambda: lorenz63(dt=0.25, substeps=25), lorenz63_rate, STATES_63, 0.01),
    (lorenz96, lorenz96_rate, STATES_96, 0.05),
])
def test_propagate_is_one_substep_plus_the_noise(make, rate, states, h):
    model = make()
    assert model.substep_duration == pytest.approx(h, rel=1e-15)
    noise = np.random.default_rng(5).normal(size=states.shape)
    moved = model.propagate(states, None, noise)
    expected = np.array([[hand_rk4(rate, list(state), h) for state in row] for row in states]) + noise
    np.testing.assert_allclose(moved, expected, rtol=1e-13, atol=1e-12)
    assert model.transition_jacobian(states, None).shape == states.shape + (states.shape[-1],)


def test_measurements_and_shapes():
    l63, l96 = lorenz63(), lorenz96()
    assert (l63.state_dimension, l63.measurement_dimension) == (3, 3)
    assert (l96.state_dimension, l96.measurement_dimension) == (10, 5)
    np.testing.assert_array_equal(l63.measurement_mean(STATES_63), STATES_63)
    np.testing.assert_array_equal(l96.measurement_mean(STATES_96), STATES_96[..., [0, 2, 4, 6, 8]])
    assert l96.measurement_jacobian(STATES_96).shape == (4, 5, 5, 10)
    np.testing.assert_array_equal(l96.measurement_jacobian(STATES_96)[0, 0] @ STATES_96[0, 0],
                                  STATES_96[0, 0, [0, 2, 4, 6, 8]])
    assert l96.process_noise_jacobian(STATES_96, None).shape == (4, 5, 10, 10)
    # the Gaussian log-likelihood of the measured components only: (R, N) from (R, 1, m)
    measurement = STATES_96[:, :1, [0, 2, 4, 6, 8]] + 1.0
    log_likelihood = l96.log_likelihood(measurement, STATES_96)
    assert log_likelihood.shape == (4, 5)
    residual = measurement - STATES_96[..., [0, 2, 4, 6, 8]]
    expected = -0.5 * (np.sum(residual**2, axis=-1) / 2.25 + 5 * np.log(2 * np.pi * 2.25))
    np.testing.assert_allclose(log_likelihood, expected, rtol=1e-12)
    assert lorenz96(dimension=40, observed=[1, 5, 39]).measurement_mean(np.ones((2, 40))).shape == (2, 3)


def test_presets_are_dapper_files():
    # sakov2012.py: X0 = GaussRV(C=2, mu=x0), Obs noise 2, Dyn noise 0, dko 25 of dt 0.01, Ko = 1000
    l63 = lorenz63()
    np.testing.assert_array_equal(l63.initial.mean_vector(), [1.509, -1.531, 25.46])
    np.testing.assert_allclose(l63.initial.covariance_matrix(), 2.0 * np.eye(3), rtol=1e-15)
    np.testing.assert_allclose(l63.measurement_noise.covariance(), 2.0 * np.eye(3), rtol=1e-15)
    assert not np.any(l63.process_noise.covariance())
    assert (l63.steps, l63.dt) == (1001, 0.25)
    # bocquet2010.py: X0 = GaussRV(M=10, C=0.001), obs every other component, T = 64 at dt 0.05
    l96 = lorenz96()
    np.testing.assert_array_equal(l96.initial.mean_vector(), np.zeros(10))
    np.testing.assert_allclose(l96.initial.covariance_matrix(), 0.001 * np.eye(10), rtol=1e-15)
    np.testing.assert_allclose(l96.measurement_noise.covariance(), 2.25 * np.eye(5), rtol=1e-15)
    assert not np.any(l96.process_noise.covariance())
    assert (l96.steps, l96.dt, l96.observed) == (1280, 0.05, [0, 2, 4, 6, 8])


@pytest.mark.parametrize("observed, reason", [([], "at least one"), ([0, 10], "0..9"), ([2, 2], "at most once")])
def test_bad_observed_components_are_refused(observed, reason):
    with pytest.raises(ValueError, match=reason):
        lorenz96(observed=observed)


def test_trajectory_follows_dappers_integrator():
    """25 substeps of 0.01 (one Lorenz-63 observation interval) and 25 Lorenz-96 steps of 0.05,
    from the same initial states, against DAPPER's own ``step`` functions, to 1e-12."""
    Lorenz63_dapper = pytest.importorskip("dapper.mods.Lorenz63")
    Lorenz96_dapper = pytest.importorskip("dapper.mods.Lorenz96")
    l63, l96 = lorenz63(), lorenz96()
    for model, dapper_step, start, h in [
        (l63, Lorenz63_dapper.step, np.array([[1.509, -1.531, 25.46], [-5.0, 3.0, 20.0]]), 0.01),
        (l96, Lorenz96_dapper.step, np.random.default_rng(1).normal(2.0, 3.0, size=(2, 10)), 0.05),
    ]:
        ours, theirs = start.copy(), start.copy()
        for substep in range(25):
            ours = MODULE.rk4_step(model.tendency, ours, h)
            theirs = dapper_step(theirs, substep * h, h)
        assert np.abs(ours - start).max() > 1.0          # the states moved: the check is not vacuous
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12)
