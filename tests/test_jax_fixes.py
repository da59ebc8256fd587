"""Three faults of the jax backend (issue 47, item 2), each checked where a user meets it.

* **One trial.** The trace's arrays came from JAX as read-only NumPy views, and with one trial
  swapping the (step, trial) axes copies nothing: the first write into the trace (the untraced
  rows' spread, set to NaN) raised ``assignment destination is read-only``. A config with
  ``trials: 1`` and the truth convergence criterion, and ``pfx.filter(..., traced=True)`` on one
  trial, now run; every array of a jax trace is the trace's own, writable as the NumPy
  backend's are.
* **An arm's precision.** An arm inherits the ``filter:`` section's keys, so an arm that sets
  ``precision: float32`` under a shared ``backend: jax`` runs on jax in single precision; one
  that would run float32 on numpy is still refused, naming the arm's key.
* **consistency on jax.** ``pfx.filter(..., backend="jax", consistency=True)`` returned without
  the covariances and NIS; the jax backend now records them, through both doors: the Python
  call's trace has them, and a config's ``metrics.consistency`` writes NEES and NIS
  (tests/test_jax_diagnostics.py checks their values). Every flag of ``pfx.filter`` is honoured
  on jax.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import write_config_file

import pfx
from pfx.config.plan import build_plan
from pfx.errors import ConfigError

pytest.importorskip("jax")

pytestmark = pytest.mark.usefixtures("fresh_plugins")


def walk(steps: int = 8):
    return pfx.model("linear_gaussian", steps=steps, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                     process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0})


def measurements(steps: int = 8) -> np.ndarray:
    return pfx.simulate(walk(steps), seed=3).measurements[0]


def jax_config(tiny_config_dict, **filter_settings) -> dict:
    config = tiny_config_dict()
    config["filter"].update(backend="jax", **filter_settings)
    return config


# -- one trial ----------------------------------------------------------------------------------------

def test_a_one_trial_config_with_the_truth_criterion_runs_on_jax(tmp_path, tiny_config_dict, pfx_in_process):
    config = jax_config(tiny_config_dict, particles=50)
    config.update(trials=1, metrics={"convergence": {"criterion": "truth", "radius": 3.0, "hold": 1}})
    config["outputs"]["figures"] = []          # the fault was in the trace, not in drawing it
    path = write_config_file(tmp_path, config)
    result = pfx_in_process("run", path, "--out", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    trials = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert len(trials) == 1 and trials["backend"].tolist() == ["jax"]
    assert trials["converged"].notna().all()        # the truth criterion was scored


@pytest.mark.parametrize("trials", [1, 3])        # 3: the flag tests' shape (FLAG_TRIALS, FLAG_PARTICLES)
def test_a_traced_jax_filter_gives_a_trace_of_writable_arrays(trials):
    result = pfx.filter(walk(), measurements(), trials=trials, backend="jax", traced=True, particles=50, seed=1)
    trace = result.trace
    assert trace.spread.shape == (trials, 8) and np.isfinite(trace.spread).all()
    assert np.isfinite(trace.standard_deviations).all()
    arrays = {name: value for name, value in vars(trace).items() if isinstance(value, np.ndarray)}
    assert {"estimates", "ess", "spread", "log_likelihood", "resampled"} <= set(arrays)
    read_only = sorted(name for name, value in arrays.items() if not value.flags.writeable)
    assert read_only == [], f"read-only arrays in a jax trace: {read_only}"


# -- an arm's precision ----------------------------------------------------------------------------------

def test_an_arm_setting_float32_under_a_shared_jax_backend_runs_in_single_precision(tmp_path, tiny_config_dict):
    config = jax_config(tiny_config_dict)
    config["outputs"]["figures"] = []          # what is checked is trials.csv's labels
    # consistency on, as in the consistency test's config: its float64 arm's program serves both
    config["metrics"] = {"consistency": True}
    config["arms"] = {"single": {"precision": "float32"}, "double": {}}
    result = pfx.run(config, out=tmp_path / "out")
    precisions = result.trials.drop_duplicates("arm").set_index("arm")["precision"]
    assert precisions.to_dict() == {"single": "float32", "double": "float64"}
    assert set(result.trials["backend"]) == {"jax"}


PRECISION_CASES = [      # the filter: section, an arm's own keys, and the key refused (None: it runs)
    ({"backend": "jax"}, {"precision": "float32"}, None),                                  # inherits jax
    ({}, {"precision": "float32"}, "arms.single.precision"),                               # inherits numpy
    ({"backend": "jax"}, {"backend": "numpy", "precision": "float32"}, "arms.single.precision"),
    ({"backend": "jax", "precision": "float32"}, {"backend": "numpy"}, "arms.single.backend"),   # inherits float32
    ({"precision": "float32"}, {}, "filter.precision"),
]


def test_float32_is_refused_exactly_where_a_cell_would_run_it_on_numpy(tiny_config_dict):
    """An arm is judged with what it inherits: accepted where its cell runs on jax, refused by
    the key that puts float32 on numpy otherwise (and from Python, by the setting)."""
    for shared, arm, key in PRECISION_CASES:
        config = tiny_config_dict()
        config["filter"].update(shared)
        config["arms"] = {"single": arm, "double": {}}
        if key is None:
            cells = build_plan(config, "config.yaml").cells
            assert {cell.labels["arm"]: cell.filter.precision for cell in cells} == \
                {"single": "float32", "double": "float64"}
            continue
        with pytest.raises(ConfigError) as caught:
            build_plan(config, "config.yaml")
        assert caught.value.key == key and "the numpy backend computes in float64" in caught.value.reason, \
            (shared, arm, str(caught.value))
    with pytest.raises(ConfigError) as caught:
        pfx.particle_filter(walk(), precision="float32")
    assert (caught.value.file, caught.value.key) == ("<python>", "filter.precision")


# -- consistency on jax ------------------------------------------------------------------------------------

# The flag runs below share one shape (3 trials of 50 particles on walk()), so that a flag's program,
# compiled once, serves every test that asks for it; what they check does not depend on the size.
FLAG_TRIALS, FLAG_PARTICLES = 3, 50


def test_consistency_on_jax_is_recorded_through_the_argument_and_the_config_key(tmp_path, tiny_config_dict):
    trace = pfx.filter(walk(), measurements(), trials=FLAG_TRIALS, backend="jax", particles=FLAG_PARTICLES,
                       consistency=True).trace
    assert trace.nis.shape == (FLAG_TRIALS, 8) and trace.covariances.shape == (FLAG_TRIALS, 8, 1, 1)
    assert np.isfinite(trace.nis).all() and (trace.covariances > 0).all()
    config = jax_config(tiny_config_dict)
    config["outputs"]["figures"] = []          # what is checked is trials.csv's NEES and NIS
    config["metrics"] = {"consistency": True}
    trials = pfx.run(config, out=tmp_path / "out").trials
    assert trials[["nees_mean", "nis_mean"]].notna().all().all() and (trials["nis_mean"] > 0).all()


def test_no_flag_of_pfx_filter_is_dropped_on_jax():
    """Each of pfx.filter's recording flags on jax gives what it asks for, or is refused."""
    given = {"genealogy": lambda result: result.ancestors is not None,
             "scores": lambda result: result.predictive is not None,
             "traced": lambda result: result.trace.standard_deviations is not None,
             "consistency": lambda result: result.trace.nis is not None and result.trace.covariances is not None}
    dropped = []
    for flag, kept in given.items():
        try:
            result = pfx.filter(walk(), measurements(), trials=FLAG_TRIALS, backend="jax", particles=FLAG_PARTICLES,
                                **{flag: True})
        except ConfigError as error:
            assert error.key == flag, str(error)
            continue
        if not kept(result):
            dropped.append(flag)
    assert dropped == []
