"""The auxiliary particle filter on the JAX backend (the kernel's look-ahead, pfx/filters/particle/kernel.py), with
its first stage written once for both backends (pfx/filters/particle/auxiliary.py). The filter's
agreement with the Kalman filter and L_k = L1_k + L2_k (with ess_threshold 0 its increment is the
plain filter's) are checked on both backends in tests/test_proposals.py.

* the first stage's code is one: on JAX arrays it gives NumPy's numbers, edge cases included (a
  NaN point prediction: g = -inf and weight 0; first-stage weights that all underflow: g = 0 and
  the previous weights; a missing measurement: g = 0 and L1 = 0);
* a missing measurement adds nothing, and the genealogy records the first stage's ancestors and
  ``resampled`` flags as the NumPy engine does (both on both backends: the ``backend`` fixture);
* a model's own look-ahead runs on jax, or is refused at plan time if written for NumPy only;
* a config with ``auxiliary: true`` and ``backend: jax`` runs through the command line.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import tiny_config_dict

import pfx
from pfx.errors import ConfigError
from pfx.filters.particle.auxiliary import AuxiliaryFirstStage
from pfx.laws.initial import GaussianLaw
from pfx.laws.noise import Noise
from pfx.models.linear_gaussian import LinearGaussian

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402


def constant_velocity(steps: int = 10):
    """A moderately informative sensor (R = 0.5), where the look-ahead p(z | mu) fits."""
    return pfx.model("linear_gaussian", steps=steps, transition_matrix=[[1.0, 1.0], [0.0, 1.0]],
                     measurement_matrix=[[1.0, 0.0]], process_noise={"variance": [0.5, 0.2]},
                     measurement_noise={"variance": 0.5},
                     initial={"kind": "gaussian", "mean": [0.0, 0.0], "covariance": [1.0, 1.0]})


def one_data_set(model, runs: int):
    """One measurement sequence, repeated for ``runs`` filter runs."""
    return np.repeat(pfx.simulate(model, seeds=[11]).measurements, runs, axis=0)


def seeds(runs: int) -> list[int]:
    return list(range(1000, 1000 + runs))


def test_the_first_stage_is_one_code_with_numpy_numbers_on_jax():
    random = np.random.default_rng(3)
    log_weights = np.log(random.dirichlet(np.ones(6), size=4))
    log_weights[1, 4] = -np.inf                               # a particle lost at the previous step
    look_ahead = random.normal(size=(4, 6)) * 3.0
    look_ahead[0, 1] = np.nan                                  # a point prediction outside the domain
    look_ahead[2] = np.nan                                     # every first-stage weight vanishes
    observed = np.array([True, True, True, False])             # trial 3 has no measurement
    stage = AuxiliaryFirstStage()
    on_numpy = stage.first_stage(log_weights, look_ahead, observed)
    with jax.enable_x64(True):
        on_jax = jax.device_get(stage.first_stage(jnp.asarray(log_weights), jnp.asarray(look_ahead),
                                                  jnp.asarray(observed)))
    for numpy_value, jax_value in zip(on_numpy, on_jax):
        np.testing.assert_allclose(np.asarray(jax_value), numpy_value, rtol=1e-12, atol=1e-300)
    log_first, first, increment, g = on_numpy
    assert g[0, 1] == -np.inf and first[0, 1] == 0.0
    assert (g[2] == 0.0).all() and (g[3] == 0.0).all() and increment[3] == 0.0
    np.testing.assert_allclose(first[2:], np.exp(log_weights[2:]), rtol=1e-12)
    expected = np.log(np.sum(np.exp(log_weights[1] + look_ahead[1])))
    np.testing.assert_allclose(increment[1], expected, rtol=1e-12)
    np.testing.assert_allclose(first.sum(axis=1), 1.0, rtol=1e-12)


@pytest.mark.parametrize("proposal", ["bootstrap", "ekf"])
def test_a_missing_measurement_adds_nothing(proposal, backend):
    model = constant_velocity(steps=4)
    measurements = one_data_set(model, 4)
    blank = measurements.copy()
    blank[:, 3] = np.nan                  # the last step: the run must equal the one that stops before it
    blank[1, 1] = np.nan                  # and one trial's middle step
    settings = dict(seeds=seeds(4), particles=50, proposal=proposal, auxiliary=True, backend=backend)
    truncated = pfx.filter(model, measurements[:, :3], **settings).trace
    with_blank = pfx.filter(model, blank, **settings).trace
    others = [0, 2, 3]
    np.testing.assert_allclose(with_blank.log_likelihood[others], truncated.log_likelihood[others], rtol=1e-12)
    increments = with_blank.log_likelihood_increments
    assert (increments[:, 3] == 0).all() and increments[1, 1] == 0 and (increments[others, 1] != 0).all()
    assert np.isfinite(with_blank.estimates).all()


def test_the_genealogy_records_the_first_stages_ancestors(backend):
    """Threshold 0.5: some trials resample at the first stage, some do not. A trial that does has
    the systematic resampler's ancestors (non-decreasing), one that does not has i -> i."""
    model = constant_velocity(steps=8)
    measurements = one_data_set(model, 6)
    result = pfx.filter(model, measurements, seeds=seeds(6), particles=40, auxiliary=True, ess_threshold=0.5,
                        genealogy=True, backend=backend)
    resampled, ancestors = result.trace.resampled, result.ancestors
    assert resampled.any() and not resampled.all()
    identity = np.arange(40)
    assert (ancestors[~resampled] == identity).all()
    picked = ancestors[resampled]
    assert (np.diff(picked, axis=-1) >= 0).all() and (picked != identity).any(axis=-1).all()


class TracedLookAhead(LinearGaussian):
    """The default look-ahead, p(z | A x), written as a model's own (the step unused)."""

    def look_ahead_log_weight(self, previous, step, measurement):
        return self.log_likelihood(measurement, previous @ self.matrices[0].T)


class HostLookAhead(LinearGaussian):
    """A look-ahead written for NumPy arrays only."""

    def look_ahead_log_weight(self, previous, step, measurement):
        return self.log_likelihood(measurement, np.asarray(previous) @ self.matrices[0].T)


def own_look_ahead(model_class):
    return model_class(transition_matrix=[[1.0, 1.0], [0.0, 1.0]], measurement_matrix=[[1.0, 0.0]], steps=6,
                       process_noise=Noise(variance=[0.5, 0.2]), measurement_noise=Noise(variance=0.5),
                       initial=GaussianLaw(mean=[0.0, 0.0], covariance=[1.0, 1.0]))


def test_a_models_own_look_ahead_runs_on_jax_or_is_refused_in_one_line():
    measurements = one_data_set(constant_velocity(steps=6), 5)
    settings = dict(seeds=seeds(5), particles=30, auxiliary=True, backend="jax")
    default = pfx.filter(constant_velocity(steps=6), measurements, **settings).trace
    own = pfx.filter(own_look_ahead(TracedLookAhead), measurements, **settings).trace
    np.testing.assert_allclose(own.log_likelihood, default.log_likelihood, rtol=1e-9)
    with pytest.raises(ConfigError) as caught:
        pfx.particle_filter(own_look_ahead(HostLookAhead), auxiliary=True, backend="jax")
    message = str(caught.value)
    assert "filter.auxiliary" in message and "look_ahead_log_weight" in message and "backend: numpy" in message
    assert "\n" not in message


def test_a_config_runs_the_auxiliary_filter_on_jax_from_the_command_line(tmp_path, pfx_in_process):
    config = tiny_config_dict()
    config["filter"].update(auxiliary=True, backend="jax")
    (tmp_path / "auxiliary.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    result = pfx_in_process("run", "auxiliary.yaml", "--out", "out", cwd=tmp_path)
    assert result.returncode == 0, result.output
    trials = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert len(trials) == config["trials"] and (trials["backend"] == "jax").all()
    assert np.isfinite(trials["log_likelihood"]).all()
