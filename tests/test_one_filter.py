"""One particle filter from Python (pfx/filtering.py, docs/python-api.md), bound once.

* The Python entry point gives, for the same model, settings and filter seeds, the very arrays
  the config path gives (estimates, ESS, log-likelihood, to the last bit), for several filter
  algorithms; and trials.csv's numbers.
* The genealogy: each particle's recorded ancestor is the particle of the previous step it was
  propagated from.
* A model's own look-ahead (the auxiliary filter's first-stage weight) from a plugin: with the
  exact predictive density and the exact proposal the filter is fully adapted, so its
  second-stage weights are equal and the ESS is N at every step.
* Changing a model's parameters with ``model_copy`` leaves no stale cache.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import write_config_file

import pfx
from pfx.config.plan import build_plan
from pfx.filters.particle.recorders import Recording, SnapshotRequest
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams, filter_seed, truth_seed

CASES = {
    "bootstrap, ESS rule, roughening": (
        {"kind": "range_beacons", "steps": 15, "beacons": [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]],
         "motion": "random_walk", "process_noise": {"variance": 0.05}},
        {"particles": 300, "resampler": "stratified", "ess_threshold": 0.5, "diffusion": {"kind": "roughening"}}),
    "ekf proposal": ({"kind": "growth", "steps": 20}, {"particles": 200, "proposal": "ekf"}),
    "auxiliary filter": ({"kind": "growth", "steps": 20}, {"particles": 200, "auxiliary": True}),
    "mcmc move, multinomial": ({"kind": "growth", "steps": 20},
                               {"particles": 150, "resampler": "multinomial", "move": {"kind": "mcmc", "steps": 2}}),
}


@pytest.mark.numpy_only
@pytest.mark.parametrize("case", list(CASES))
def test_the_python_entry_point_gives_the_config_paths_numbers(case, tmp_path):
    model_section, settings = CASES[case]
    config = {"name": "same", "seed": 5, "trials": 3, "model": model_section, "filter": settings,
              "outputs": {"figures": [], "trace_trials": 3}}
    write_config_file(tmp_path, config)
    result = pfx.run(tmp_path / "config.yaml", out=tmp_path / "out")
    plan = build_plan(config, "config.yaml")
    cell = plan.cells[0]
    trials = result.trials
    seeds = [filter_seed(5, cell.stream_key, t) for t in range(3)]
    assert list(trials["filter_seed"]) == seeds
    _, measurements = simulate_truth(cell.truth_model, TrialStreams.from_seeds([truth_seed(5, t) for t in range(3)]))

    # the config path's arrays: the cell's planned filter on a batch, as a worker runs it
    planned = cell.planned_filter.run(cell.filter_model, measurements, TrialStreams.from_seeds(seeds),
                                      settings=cell.filter, prior=cell.prior)
    # the Python entry point: the model, the settings as keyword arguments, the seeds
    model = pfx.model(**model_section)
    python = pfx.particle_filter(model, **settings)(measurements, seeds=seeds)
    for name in ("estimates", "ess", "log_likelihood"):
        np.testing.assert_array_equal(getattr(python, name), getattr(planned, name), err_msg=name)
    np.testing.assert_array_equal(python.log_likelihood, trials["log_likelihood"].to_numpy())
    steps = result.steps
    first = steps[steps["trial"] == 0]
    state = model.state_names[0]
    np.testing.assert_array_equal(python.estimates[0, :, 0], first[f"estimate_{state}"].to_numpy())


def test_a_seed_gives_its_own_streams_and_a_repeated_call_the_same_numbers():
    model = pfx.model("growth", steps=25)
    measurements = simulate_truth(model, TrialStreams.from_seeds([1]))[1][0]       # (T, m)
    bound = pfx.particle_filter(model, particles=100)
    first, again, other = bound(measurements, seed=1, trials=4), bound(measurements, seed=1, trials=4), \
        bound(measurements, seed=2, trials=4)
    np.testing.assert_array_equal(first.estimates, again.estimates)
    assert first.estimates.shape == (4, 25, 1) and len(set(first.seeds) | set(other.seeds)) == 8
    assert not np.array_equal(first.estimates, other.estimates)


def test_settings_are_checked_as_a_configs_are():
    model = pfx.model("growth", steps=5)
    with pytest.raises(pfx.ConfigError, match=r"^<python>: filter.resampler: .*'systematc'"):
        pfx.particle_filter(model, resampler="systematc")
    with pytest.raises(pfx.ConfigError, match="filter.proposal: a guided proposal's importance weight needs"):
        pfx.particle_filter(model, proposal="ukf", weighting="euclidean")
    with pytest.raises(pfx.ConfigError, match="measurements: shape"):
        pfx.particle_filter(model)(np.zeros((5, 2)))


def test_the_genealogy_names_the_particle_each_one_was_propagated_from():
    """With a tiny process noise, particle i of step k lies next to its recorded ancestor among
    step k-1's weighted particles and far from the others (the prior spreads them apart)."""
    model = pfx.model("linear_gaussian", steps=12, transition_matrix=[[1.0]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1e-14}, measurement_noise={"variance": 4.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 100.0})
    measurements = np.linspace(0.0, 3.0, 12)[:, None]
    particles = 64
    snapshot = SnapshotRequest(rows=np.arange(2), steps="all", stages=frozenset({"weighted", "predicted"}))
    bound = pfx.particle_filter(model, particles=particles, resampler="multinomial", ess_threshold=0.6)
    trace = bound.planned.bound.run(np.repeat(measurements[None], 2, axis=0), TrialStreams.from_seeds([4, 5]),
                                    Recording(snapshot=snapshot, genealogy=True))
    ancestors = trace.ancestors
    assert ancestors.shape == (2, 12, particles) and ancestors.dtype == np.int32
    np.testing.assert_array_equal(ancestors[:, 0], np.broadcast_to(np.arange(particles), (2, particles)))
    clouds = {(cloud.stage, cloud.step): cloud.state[..., 0] for cloud in trace.snapshots}
    resampled_somewhere = False
    for k in range(2, 13):
        before, after = clouds[("weighted", k - 1)], clouds[("predicted", k)]
        parent = np.take_along_axis(before, ancestors[:, k - 1], axis=1)
        assert np.abs(after - parent).max() < 1e-5
        resampled = trace.resampled[:, k - 2]
        identity = (ancestors[:, k - 1] == np.arange(particles)).all(axis=1)
        assert (identity | resampled).all()            # a trial that did not resample keeps i -> i
        resampled_somewhere |= bool(resampled.any() and not identity[resampled].all())
    assert resampled_somewhere


LOOK_AHEAD_PLUGIN = '''
from typing import Literal

import numpy as np

import pfx
from pfx.models.linear_gaussian import LinearGaussian


@pfx.register_model
class AdaptedWalk(LinearGaussian):
    """A linear-Gaussian model that gives the auxiliary filter the exact predictive density."""

    kind: Literal["adapted_walk"] = "adapted_walk"

    def look_ahead_log_weight(self, previous, step, measurement):
        A, H = self.matrices
        Q, R = self.process_noise.covariance(), self.measurement_noise.covariance()
        S = H @ Q @ H.T + R
        innovation = measurement - previous @ A.T @ H.T
        solved = np.linalg.solve(S, np.moveaxis(innovation, -1, 0).reshape(len(S), -1)).T.reshape(innovation.shape)
        return (-0.5 * np.sum(innovation * solved, axis=-1) - 0.5 * np.linalg.slogdet(2 * np.pi * S)[1])
'''


def test_a_plugin_models_own_look_ahead_makes_the_auxiliary_filter_fully_adapted(tmp_path):
    """Exact look-ahead p(z_k | x_k-1) and exact proposal p(x_k | x_k-1, z_k): the second-stage
    weight p(z | x) p(x | x') / (q(x | x', z) p(z | x')) is 1 for every particle, so the ESS after
    the weight update is N at every step (Pitt & Shephard 1999, the fully adapted filter)."""
    from pfx.config.plugins import load_plugin

    (tmp_path / "adapted.py").write_text(LOOK_AHEAD_PLUGIN)
    load_plugin("adapted.py", tmp_path)
    parameters = {"steps": 30, "transition_matrix": [[0.9]], "measurement_matrix": [[1.0]],
                  "process_noise": {"variance": 1.0}, "measurement_noise": {"variance": 0.5}}
    adapted, plain = pfx.model("adapted_walk", **parameters), pfx.model("linear_gaussian", **parameters)
    measurements = simulate_truth(plain, TrialStreams.from_seeds([2, 3]))[1]
    particles = 400
    runs = {name: pfx.filter(model, measurements, seeds=[7, 8], particles=particles, auxiliary=True,
                             proposal="locally_optimal") for name, model in (("adapted", adapted), ("plain", plain))}
    np.testing.assert_allclose(runs["adapted"].ess, particles, rtol=1e-9)
    assert (runs["plain"].ess < particles * (1 - 1e-6)).any()
    # ... and the model's own look-ahead is what the first stage used: the same seeds, other numbers
    assert not np.array_equal(runs["adapted"].estimates, runs["plain"].estimates)


def test_model_copy_with_new_parameters_leaves_no_stale_cache():
    model = pfx.model("linear_gaussian", steps=5, transition_matrix=[[1.0]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0})
    model.transition_density()                                  # derived and cached
    changed = model.model_copy(update={"transition_matrix": [[0.5]], "process_noise": pfx.Noise(variance=4.0)})
    np.testing.assert_array_equal(changed.matrices[0], [[0.5]])
    np.testing.assert_array_equal(changed.transition_density().covariance, [[4.0]])
    state = np.array([[[2.0]]])
    np.testing.assert_array_equal(changed.propagate(state, None, np.zeros_like(state)), [[[1.0]]])
    np.testing.assert_array_equal(model.matrices[0], [[1.0]])        # the original is unchanged
    with pytest.raises(ValueError):
        model.model_copy(update={"transition_matrix": [[1.0, 0.0]]})    # checked as a config's would be
    assert isinstance(model.model_copy(), type(model))


def test_genealogy_is_refused_for_a_filter_without_particles():
    model = pfx.model("linear_gaussian", steps=5, transition_matrix=[[1.0]], measurement_matrix=[[1.0]])
    with pytest.raises(pfx.ConfigError, match="no genealogy"):
        pfx.particle_filter(model, kind="kf")(np.zeros((5, 1)), genealogy=True)
