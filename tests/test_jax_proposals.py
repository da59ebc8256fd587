"""The guided proposals lifted to the jax backend (pfx/filters/particle/proposals.py's
``propose_from``, called by pfx/filters/particle/jax_engine.py's ``propose``).

On a linear-Gaussian model the locally optimal proposal is known in closed form and the EKF and
UKF proposals are exact, so:

* deterministically, on jax: log p(z | x) + the weight adjustment is log N(z; H f_i, H Q H' + R)
  for every particle, whatever x was drawn; the ekf proposal (the model's Jacobian, or central
  differences traced on jax) and the ukf proposal draw the locally optimal proposal's particles;
  a trial without a measurement gets adjustment 0; a covariance whose factorisation fails falls
  back to Q's factor, and the weight is still p(x | x_prev) / q exactly;
* statistically, the posterior means and the likelihood estimate against the Kalman filter, on
  both backends: tests/test_proposals.py (the ``backend`` fixture);
* a config asking for the proposal on ``filter.backend: jax`` runs through the CLI and writes
  trials.csv (a missing measurement as a predict-only step: tests/test_proposals.py, on both backends).

The ukf proposal's sigma points and moments (pfx/filters/kalman/unscented.py) are the same code
on both backends: compiled on jax in float64, its mean and factor equal NumPy's for the same
predicted cloud on nonlinear models (ranges to beacons; a bearing, wrapped). Where P_i is not
positive definite NumPy repairs it (``robust_square_root``) and JAX's factor is NaN, which
``propose_from`` replaces by Q's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from test_proposals import (
    constant_velocity,
    proposal,
)

from pfx.models.base import bind_law
from pfx.models.linear_gaussian import LinearGaussian
from pfx.numerics.seeding import TrialStreams

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

from pfx.filters.particle.proposals import ExtendedKalmanProposal, cholesky_factor  # noqa: E402
from pfx.numerics.key_streams import KeyStreams  # noqa: E402


class NumericalJacobian(LinearGaussian):
    """The linear-Gaussian model without its analytic measurement Jacobian: the ekf proposal
    takes central differences of measurement_mean."""

    def measurement_jacobian(self, mean):
        return None


def propose_on_jax(bound, previous, measurement, observed, seeds=(5, 6, 7)):
    """The proposal as the compiled step calls it: JAX arrays, float64, the trials' keys."""
    with jax.enable_x64(True):
        predicted = jnp.asarray(previous) @ jnp.asarray(bound.model.matrices[0]).T
        random = KeyStreams.from_seeds(list(seeds), jnp.float64)
        state, adjustment = jax.jit(lambda p, z, o: bound.propose_from(p, z, o, random))(
            predicted, jnp.asarray(measurement), jnp.asarray(observed))
        return np.asarray(state), np.asarray(adjustment), np.asarray(predicted)


def previous_cloud():
    return np.random.default_rng(1).standard_normal((3, 50, 2))


def test_on_jax_the_locally_optimal_weight_is_the_predictive_density_and_ekf_ukf_draw_the_same():
    model = constant_velocity(0.01)
    previous, measurement = previous_cloud(), np.array([[0.3], [-1.0], [2.0]])
    observed = np.array([True, True, True])
    A, H = model.matrices
    Q, R = model.process_noise.covariance(), model.measurement_noise.covariance()
    predictive = stats.norm.logpdf(measurement[:, None, 0], (previous @ A.T @ H.T)[..., 0],
                                   np.sqrt((H @ Q @ H.T + R)[0, 0]))
    drawn = {}
    for name, on in (("locally_optimal", model), ("ekf", model), ("ekf-differences", NumericalJacobian(**dict(model))),
                     ("ukf", model)):
        state, adjustment, _ = propose_on_jax(proposal(name.split("-")[0]).bind(on), previous, measurement, observed)
        weight = model.log_likelihood(measurement[:, None, :], state) + adjustment
        np.testing.assert_allclose(weight, predictive, rtol=1e-9, atol=1e-9)
        drawn[name] = state
    np.testing.assert_allclose(drawn["ekf"], drawn["locally_optimal"], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(drawn["ukf"], drawn["locally_optimal"], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(drawn["ekf-differences"], drawn["locally_optimal"], rtol=1e-6, atol=1e-6)


def test_on_jax_a_trial_without_a_measurement_draws_from_the_transition_with_no_adjustment():
    model = constant_velocity(0.01)
    bound = proposal("locally_optimal").bind(model)
    state, adjustment, predicted = propose_on_jax(bound, previous_cloud(), np.array([[0.3], [0.0], [2.0]]),
                                                  np.array([True, False, True]))
    assert (adjustment[1] == 0.0).all() and (adjustment[[0, 2]] != 0.0).all()
    # the transition's spread (Q = diag(0.5, 0.2)), not the proposal's (position variance ~0.01)
    deviation = state[1] - predicted[1]
    assert 0.4 < deviation[:, 0].var() < 0.7, deviation[:, 0].var()


class BrokenCovariance(ExtendedKalmanProposal):
    """The ekf proposal with a covariance that is not positive definite (its factorisation fails)."""

    def moments(self, model, predicted, noise, measurement):
        mean, _ = super().moments(model, predicted, noise, measurement)
        return mean, cholesky_factor(-jnp.ones(predicted.shape[:-1] + (1, 1)) * np.eye(predicted.shape[-1]))


def test_on_jax_a_failed_factorisation_falls_back_to_the_transition_covariance():
    model = constant_velocity(0.01)
    bound = BrokenCovariance().bind(model)
    previous, measurement = previous_cloud(), np.array([[0.3], [-1.0], [2.0]])
    state, adjustment, predicted = propose_on_jax(bound, previous, measurement, np.ones(3, bool))
    assert np.isfinite(state).all() and np.isfinite(adjustment).all()
    mean, _ = proposal("ekf").moments(model, predicted, model.process_noise.covariance(), measurement[:, None, :])
    Q = model.process_noise.covariance()
    # the weight is p(x | x_prev) / q with q = N(m_i, Q): the draw's own law, exactly
    expected = stats.multivariate_normal(cov=Q).logpdf(state - predicted) \
        - stats.multivariate_normal(cov=Q).logpdf(state - mean)
    np.testing.assert_allclose(adjustment, expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("guided", ["locally_optimal", {"kind": "ukf"}], ids=["locally_optimal", "ukf"])
def test_a_config_with_a_guided_proposal_runs_on_jax_through_the_cli(tmp_path, tiny_config_dict, write_config,
                                                                      pfx_in_process, guided):
    config = tiny_config_dict()
    config["filter"].update(backend="jax", proposal=guided)
    completed = pfx_in_process("run", str(write_config(config)), "--out", str(tmp_path / "out"))
    assert completed.returncode == 0, completed.stderr
    trials = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert (trials["backend"] == "jax").all() and np.isfinite(trials["log_likelihood"]).all()


class NumpyOnlyJacobian(LinearGaussian):
    """A measurement Jacobian written for NumPy only (np.asarray of the state)."""

    def measurement_jacobian(self, mean):
        return np.broadcast_to(np.asarray(mean)[..., None, :1] * 0.0 + 1.0, mean.shape[:-1] + (1, 2)) * [1.0, 0.0]


def test_a_numpy_only_measurement_jacobian_is_refused_at_plan_time_in_one_line():
    import pfx
    from pfx.errors import ConfigError

    model = NumpyOnlyJacobian(**dict(constant_velocity(0.5, steps=3)))
    with pytest.raises(ConfigError) as caught:
        pfx.particle_filter(model, backend="jax", proposal="ekf")
    message = str(caught.value)
    assert "ekf proposal" in message and "backend: numpy" in message and "\n" not in message, message


# -- the ukf proposal: the same unscented update on both backends -----------------------------------

def _beacons():
    import pfx

    return pfx.model("range_beacons", steps=5, beacons=[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])


def _bearings():
    import pfx

    pfx.load_plugin(str(Path(__file__).resolve().parents[1] / "examples" / "plugins" / "bearings_only.py"))
    return pfx.model("bearings_only")


@pytest.mark.usefixtures("fresh_plugins")
@pytest.mark.parametrize("make_model,settings", [(_beacons, {"alpha": 0.5, "kappa": 1.0}), (_bearings, {})],
                         ids=["range_beacons", "bearings_only"])
def test_on_jax_the_ukf_proposal_moments_equal_numpys_for_the_same_cloud(make_model, settings):
    model = make_model()
    unscented = proposal({"kind": "ukf", **settings})
    prior = bind_law(model.default_prior(), model.state_dimension, "initial")
    # the moments alone are compared: any positive definite Q will do (the bearings-only model's
    # own L Q L' has rank 2 of 4, so the proposal's bind would refuse that model)
    noise = prior.covariance_matrix()
    predicted = np.asarray(prior.sample(TrialStreams.from_seeds([3, 4]), (40,)), dtype=float)      # (2, 40, d)
    measurement = np.asarray(model.measurement_mean(predicted[:, :1]), dtype=float) \
        + 0.1 * np.random.default_rng(3).standard_normal((2, 1, model.measurement_dimension))
    numpy_mean, numpy_factor = unscented.moments(model, predicted, noise, measurement)
    with jax.enable_x64(True):
        jax_mean, jax_factor = jax.jit(lambda x, z: unscented.moments(model, x, noise, z))(
            jnp.asarray(predicted), jnp.asarray(measurement))
    assert np.isfinite(numpy_factor).all()
    np.testing.assert_allclose(np.asarray(jax_mean), numpy_mean, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(np.asarray(jax_factor), numpy_factor, rtol=1e-10, atol=1e-10)


def test_the_ukf_proposals_square_root_repairs_on_numpy_and_is_nan_on_jax_where_cholesky_fails():
    from pfx.filters.kalman.unscented import robust_square_root
    from pfx.filters.particle.proposals import proposal_square_root

    covariances = np.array([[[2.0, 0.5], [0.5, 1.0]],
                            [[1.0, 1.0], [1.0, 1.0 - 1e-13]]])     # indefinite by round-off
    repaired, _ = robust_square_root(covariances, {"jitter": 0, "clipped": 0})
    np.testing.assert_array_equal(proposal_square_root(covariances), repaired)
    with jax.enable_x64(True):
        traced = np.asarray(jax.jit(proposal_square_root)(jnp.asarray(covariances)))
    np.testing.assert_allclose(traced[0], np.linalg.cholesky(covariances[0]), rtol=1e-12)
    assert np.isnan(traced[1]).any()         # propose_from replaces it by Q's factor


def test_a_ukf_proposal_factor_repaired_by_clipped_eigenvalues_is_triangular_so_log_q_is_exact():
    """Where jitter cannot repair P_i (a correlation of 2: eigenvalues 3 and -1), the UKF's repair
    clips eigenvalues and returns a full square root; the proposal refactors that row by Cholesky.
    log q takes log |det C| as the sum of log diag C: with the triangular factor that is half the
    log-determinant of the repaired covariance (with the full factor it was not)."""
    from pfx.filters.kalman.unscented import robust_square_root
    from pfx.filters.particle.proposals import proposal_square_root

    covariances = np.array([[[2.0, 0.5], [0.5, 1.0]], [[1.0, 2.0], [2.0, 1.0]]])
    repairs = {"jitter": 0, "clipped": 0}
    full, repaired = robust_square_root(covariances, repairs)
    assert repairs["clipped"] == 1 and full[1, 0, 1] != 0.0          # the case this guards
    factor = proposal_square_root(covariances)
    np.testing.assert_array_equal(factor[0], full[0])                # a row Cholesky took is unchanged
    assert np.all(np.triu(factor, 1) == 0.0)
    np.testing.assert_allclose(factor @ np.swapaxes(factor, -1, -2), repaired, rtol=1e-9, atol=1e-12)
    half_log_determinant = 0.5 * np.linalg.slogdet(repaired)[1]
    np.testing.assert_allclose(np.sum(np.log(np.diagonal(factor, axis1=-2, axis2=-1)), axis=-1),
                               half_log_determinant, rtol=1e-4)     # P is near-singular: cond ~1e12
    with np.errstate(invalid="ignore"):      # the full factor's diagonal: not its determinant
        assert not np.sum(np.log(np.abs(np.diagonal(full[1])))) == pytest.approx(half_log_determinant[1], rel=1e-3)
