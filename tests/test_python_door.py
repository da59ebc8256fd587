"""The Python door (pfx/filtering.py, pfx/python_arguments.py, docs/python-api.md): every
argument checked as a config's keys are.

* A bad argument of ``pfx.model``, ``pfx.particle_filter``, ``pfx.filter`` or a bound filter's
  call raises ``pfx.ConfigError``, one line naming ``<python>`` and the argument, before
  anything runs: never a number (empty measurements gave log L = 0, a partly NaN row was
  dropped whole, ``trials=0`` ran one trial), never an error from inside numpy.
* A prior may be a dict, read as a config's ``filter.initial``: the same numbers as the object.
* A model with per-step controls filters at most the steps it has controls for.
"""

from __future__ import annotations

import numpy as np
import pytest

import pfx

WALK = {"kind": "linear_gaussian", "steps": 4, "transition_matrix": [[1.0, 0.0], [0.0, 1.0]],
        "measurement_matrix": [[1.0, 0.0], [0.0, 1.0]]}
MEASUREMENTS = np.zeros((4, 2))


@pytest.fixture(scope="module")
def walk():
    """A 2-D random walk measured in both components, and a small particle filter bound to it."""
    model = pfx.model(**WALK)
    return model, pfx.particle_filter(model, particles=20)


def refusal(call) -> str:
    """The line of the ConfigError ``call()`` raises (one line, naming <python>)."""
    with pytest.raises(pfx.ConfigError) as caught:
        call()
    line = str(caught.value)
    assert "\n" not in line and line.startswith("<python>: "), line
    return line


# -- measurements --------------------------------------------------------------------------------

PARTLY_NAN = np.array([[0.0, 0.0], [np.nan, 1.0], [0.0, 0.0], [0.0, 0.0]])

BAD_MEASUREMENTS = {
    "empty": (np.zeros((0, 2)), "<python>: measurements: no steps (shape (0, 2))"),
    "no trials": (np.zeros((0, 4, 2)), "<python>: measurements: no"),
    "a partly NaN row": (PARTLY_NAN, "<python>: measurements[1]: partly NaN (component 0 of 2)"),
    "inf": (np.array([[0.0, 0.0], [0.0, 0.0], [0.0, np.inf], [0.0, 0.0]]), "<python>: measurements[2, 1]: inf"),
    "complex": (MEASUREMENTS + 1j, "<python>: measurements: complex values"),
    "text in a list": ([[0.0, 0.0], [0.0, "x"], [0.0, 0.0], [0.0, 0.0]], "<python>: measurements[1, 1]: 'x'"),
    "a text array": (np.full((4, 2), "1.5"), "<python>: measurements: text"),
    "an object array with None": (np.array([[0.0, None]] * 4, dtype=object), "<python>: measurements[0, 1]: None"),
    "booleans": (np.ones((4, 2), dtype=bool), "<python>: measurements: booleans"),
    "ragged rows": ([[0.0, 0.0], [0.0]], "<python>: measurements: rows of different lengths"),
    "the wrong dimension": (np.zeros((4, 3)), "<python>: measurements: shape (4, 3)"),
    "nothing": (None, "<python>: measurements: none given"),
}


@pytest.mark.parametrize("case", list(BAD_MEASUREMENTS))
def test_bad_measurements_are_refused_naming_them(case, walk):
    measurements, expected = BAD_MEASUREMENTS[case]
    _, bound = walk
    assert refusal(lambda: bound(measurements)).startswith(expected)


def test_a_row_of_nan_is_a_missing_measurement_as_a_blank_row_of_a_data_file(walk):
    """A whole row of NaN is a predict-only step (log-likelihood increment 0), in the particle
    filter and the Kalman filter alike; half a row is refused (above), never half-used."""
    model, bound = walk
    gap = MEASUREMENTS.copy()
    gap[2] = np.nan
    for run in (bound(gap, seed=3), pfx.particle_filter(model, kind="kf")(gap)):
        increments = run.trace.log_likelihood_increments[0]
        assert increments[2] == 0.0 and np.all(increments[[0, 1, 3]] < 0.0)
        assert np.isfinite(run.log_likelihood).all()


# -- trials, seeds and the other options ---------------------------------------------------------

BAD_OPTIONS = {
    "trials=0": ({"trials": 0}, "<python>: trials: must be a whole number from 1"),
    "trials=-1": ({"trials": -1}, "<python>: trials: must be a whole number from 1"),
    "trials=2.5": ({"trials": 2.5}, "<python>: trials: must be a whole number from 1"),
    "trials=True": ({"trials": True}, "<python>: trials: must be a whole number from 1"),
    "seed=-1": ({"seed": -1}, "<python>: seed: must be a whole number from 0 to 2**63 - 1"),
    "seed=1.5": ({"seed": 1.5}, "<python>: seed: must be a whole number"),
    "seed=True": ({"seed": True}, "<python>: seed: must be a whole number"),
    "seed=2**63": ({"seed": 2**63}, "<python>: seed: must be a whole number"),
    "seed='1'": ({"seed": "1"}, "<python>: seed: must be a whole number"),
    "seeds=[]": ({"seeds": []}, "<python>: seeds: empty"),
    "seeds=[1, -1]": ({"seeds": [1, -1]}, "<python>: seeds[1]: must be a whole number"),
    "seeds=['a']": ({"seeds": ["a"]}, "<python>: seeds[0]: must be a whole number"),
    "seeds=[1.0]": ({"seeds": [1.0]}, "<python>: seeds[0]: must be a whole number"),
    "seeds='12'": ({"seeds": "12"}, "<python>: seeds: must be a list of seeds"),
    "seeds and seed": ({"seeds": [1, 2], "seed": 3}, "<python>: seed: give seeds"),
    "seeds and other trials": ({"seeds": [1, 2], "trials": 3}, "<python>: trials: 3, and seeds gives 2"),
    "genealogy='yes'": ({"genealogy": "yes"}, "<python>: genealogy: must be True or False"),
    "consistency=None": ({"consistency": None}, "<python>: consistency: must be True or False"),
    "traced=1": ({"traced": 1}, "<python>: traced: must be True or False"),
}


@pytest.mark.parametrize("case", list(BAD_OPTIONS))
def test_bad_trials_seeds_and_options_are_refused_naming_them(case, walk):
    options, expected = BAD_OPTIONS[case]
    _, bound = walk
    assert refusal(lambda: bound(MEASUREMENTS, **options)).startswith(expected)


def test_numpy_integers_are_trials_seeds_and_settings(walk):
    model, bound = walk
    first = bound(MEASUREMENTS, trials=np.int64(2), seed=np.uint32(4))
    again = pfx.filter(model, MEASUREMENTS, seeds=np.array(first.seeds), particles=np.int64(20))
    np.testing.assert_array_equal(first.estimates, again.estimates)
    assert pfx.model("growth", steps=np.int64(7)).steps == 7


# -- the model and its prior ---------------------------------------------------------------------

@pytest.mark.parametrize("given, expected", [
    (dict(WALK), "<python>: model: a dict, not a model: build it with pfx.model(kind, **parameters)"),
    (type(pfx.model(**WALK)), "<python>: model: the class LinearGaussian, not a model: pass an instance, "
                              "pfx.model('linear_gaussian', ...)"),
    ("linear_gaussian", "<python>: model: the text 'linear_gaussian', not a model: build it with "
                        "pfx.model('linear_gaussian', ...)"),
    (None, "<python>: model: None (NoneType), not a model"),
])
def test_a_model_must_be_a_model_object(given, expected):
    assert refusal(lambda: pfx.particle_filter(given, particles=20)).startswith(expected)
    assert refusal(lambda: pfx.filter(given, MEASUREMENTS, particles=20)).startswith(expected)


@pytest.mark.parametrize("call, expected", [
    (lambda: pfx.model("growht"), "<python>: model.kind: unknown model 'growht' (did you mean 'growth'?)"),
    (lambda: pfx.model(3), "<python>: model.kind: must be a model's name"),
    (lambda: pfx.model(["growth"]), "<python>: model.kind: must be a model's name"),
    (lambda: pfx.model({"kind": "growth"}), "<python>: model.kind: a dict: for a config's model: section, write "
                                            "pfx.model(**section)"),
    (lambda: pfx.model("growth", a="x"), "<python>: model.a: input should be a valid number"),
    (lambda: pfx.model("growth", wobble=1.0), "<python>: model.wobble: unknown key 'wobble'"),
])
def test_pfx_model_arguments_are_checked_as_a_model_section(call, expected):
    assert refusal(call).startswith(expected)


def test_a_prior_may_be_a_dict_read_as_a_configs_filter_initial(walk):
    model, _ = walk
    law = {"kind": "gaussian", "mean": [1.0, -1.0], "covariance": [4.0, 0.5]}
    from_dict = pfx.filter(model, MEASUREMENTS, prior=law, seeds=[5, 6], particles=50)
    from_object = pfx.filter(model, MEASUREMENTS, prior=pfx.GaussianLaw(**law), seeds=[5, 6], particles=50)
    from_setting = pfx.filter(model, MEASUREMENTS, initial=law, seeds=[5, 6], particles=50)
    np.testing.assert_array_equal(from_dict.estimates, from_object.estimates)
    np.testing.assert_array_equal(from_dict.estimates, from_setting.estimates)
    default = pfx.filter(model, MEASUREMENTS, seeds=[5, 6], particles=50)
    assert not np.array_equal(from_dict.estimates, default.estimates)


@pytest.mark.parametrize("prior, expected", [
    ({"kind": "gaussian", "mean": [0.0, 0.0]}, "<python>: prior.covariance: required key is missing"),
    ({"kind": "gaussian", "mean": [0.0], "covariance": 1.0}, "<python>: prior.mean: expected 2 value(s), got 1"),
    ({"kind": "gausian", "mean": [0.0, 0.0], "covariance": 1.0}, "<python>: prior.kind: unknown"),
    (pfx.GaussianLaw(mean=[0.0], covariance=1.0), "<python>: prior.mean: expected 2 value(s), got 1"),
    ([0.0, 0.0], "<python>: prior: [0.0, 0.0] (list) is not an initial law: pass pfx.GaussianLaw("),
])
def test_a_bad_prior_is_refused_naming_it(prior, expected, walk):
    model, _ = walk
    assert refusal(lambda: pfx.particle_filter(model, prior=prior, particles=20)).startswith(expected)


def test_a_prior_and_the_initial_setting_are_not_both_given(walk):
    model, _ = walk
    law = {"kind": "gaussian", "mean": [0.0, 0.0], "covariance": 1.0}
    assert refusal(lambda: pfx.particle_filter(model, prior=law, initial=law)).startswith(
        "<python>: prior: give the filter's initial law once")


# -- a model's per-step inputs ---------------------------------------------------------------------

def test_measurements_beyond_a_models_controls_are_refused_naming_both():
    controlled = pfx.model("linear_gaussian", steps=5, transition_matrix=[[1.0]], measurement_matrix=[[1.0]],
                           control_matrix=[[1.0]], controls=[[float(k)] for k in range(5)])
    bound = pfx.particle_filter(controlled, particles=20)
    line = refusal(lambda: bound(np.zeros((7, 1))))
    assert line.startswith("<python>: measurements: 7 steps, and model linear_gaussian has inputs for steps 1..5 "
                           "only (controls: 5 control vectors, for steps 1..5; none for step 6): give at most 5 rows")
    assert refusal(lambda: pfx.particle_filter(controlled, kind="kf")(np.zeros((6, 1)))).startswith(
        "<python>: measurements: 6 steps")
    assert bound(np.zeros((5, 1))).estimates.shape == (1, 5, 1)      # the steps it has controls for: fine
    constant = controlled.model_copy(update={"controls": [[1.0]]})   # one control for every step
    assert pfx.particle_filter(constant, particles=20)(np.zeros((9, 1))).estimates.shape == (1, 9, 1)
