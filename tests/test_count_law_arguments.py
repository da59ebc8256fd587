"""The count laws' arguments, checked and named (pfx/laws/count_transitions.py, the rules of
pfx/numerics/parameter_checks.py; docs/plugins.md, "Count-valued transitions").

``pfx.euler_multinomial``, ``pfx.multinomial``, ``pfx.gamma_white_noise`` and ``pfx.repeat`` are
public: a bad argument is a ValueError naming the law and the argument, never a message about
``binomial: probability``, a ZeroDivisionError or numbers drawn from a law nobody asked for. On
the jax backend a parameter traced inside the compiled step cannot raise: the engine carries the
broken rule out of its scan and raises after it, so that a model drawing Poisson at a negative
rate fails on both backends with the same line. A ``sample_substep`` of the wrong shape is
blamed on ``sample_substep``.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

import pfx
from pfx.errors import ModelContractError
from pfx.numerics.seeding import TrialStreams

pytestmark = pytest.mark.usefixtures("fresh_plugins")
TRIALS, PARTICLES = 2, 5
PREFIX = "pfx: error: "


def streams() -> TrialStreams:
    return TrialStreams.from_seeds(range(TRIALS))


def counts(value: float = 40.0) -> np.ndarray:
    return np.full((TRIALS, PARTICLES), value)


def rates(*values: float) -> np.ndarray:
    return np.broadcast_to(np.array(values), (TRIALS, PARTICLES, len(values))).copy()


# -- euler_multinomial --------------------------------------------------------------------------


def test_a_nan_rate_is_named_as_a_rate():
    exits = rates(0.3, 0.1)
    exits[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"^euler_multinomial: rates must be finite and non-negative, got nan$"):
        pfx.euler_multinomial(streams(), counts(), exits, 0.5)


def test_a_negative_exit_rate_is_refused_rather_than_drawn():
    """The total rate stays positive, so the old code drew counts from it."""
    with pytest.raises(ValueError, match=r"^euler_multinomial: rates must be finite and non-negative, got -0\.1$"):
        pfx.euler_multinomial(streams(), counts(), rates(0.5, -0.1), 0.5)


def test_a_negative_step_is_named_and_a_step_of_zero_moves_nobody():
    with pytest.raises(ValueError, match=r"^euler_multinomial: step must be finite and non-negative \(a duration\), "
                                         r"got -0\.25$"):
        pfx.euler_multinomial(streams(), counts(), rates(0.5, 0.1), -0.25)
    assert np.all(pfx.euler_multinomial(streams(), counts(), rates(0.5, 0.1), 0.0) == 0.0)


def test_a_count_that_is_not_a_whole_number_is_named_as_the_count():
    with pytest.raises(ValueError, match=r"^euler_multinomial: count must be a non-negative integer, got 2\.5$"):
        pfx.euler_multinomial(streams(), counts(2.5), rates(0.5, 0.1), 0.5)


def test_count_and_rate_shapes_that_do_not_broadcast_are_named_with_both_shapes():
    exits = np.full((TRIALS, 4, 2), 0.5)
    with pytest.raises(ValueError, match=r"^euler_multinomial: count of shape \(2, 5\) and rates of shape "
                                         r"\(2, 4, 2\) do not broadcast to one shape"):
        pfx.euler_multinomial(streams(), counts(), exits, 0.5)
    with pytest.raises(ValueError, match=r"^euler_multinomial: count of shape \(3, 5\) must have the trial axis "
                                         r"first, of length 2"):
        pfx.euler_multinomial(streams(), np.full((3, PARTICLES), 4.0), rates(0.5, 0.1), 0.5)
    with pytest.raises(ValueError, match=r"^euler_multinomial: rates must hold its exits on its last axis"):
        pfx.euler_multinomial(streams(), counts(), 0.5, 0.5)


def test_the_random_argument_must_be_the_trials_streams():
    with pytest.raises(ValueError, match=r"^euler_multinomial: random must be the trials' streams .* got Generator"):
        pfx.euler_multinomial(np.random.default_rng(0), counts(), rates(0.5, 0.1), 0.5)


# -- multinomial -----------------------------------------------------------------------------------


def test_probabilities_that_do_not_sum_to_one_are_refused():
    """The last category used to take the rest silently: 0.4 of the count nobody gave it."""
    probabilities = np.broadcast_to([0.2, 0.3, 0.1], (TRIALS, PARTICLES, 3))
    with pytest.raises(ValueError, match=r"^multinomial: probabilities must sum to 1 along the last axis \(within "
                                         r"1e-09, or 1e-05 in float32\), got a row summing to 0\.6"):
        pfx.multinomial(streams(), counts(), probabilities)


def test_the_sum_tolerance_is_the_documented_one_for_each_precision():
    exact = np.broadcast_to([0.2, 0.3, 0.5], (TRIALS, PARTICLES, 3))
    assert pfx.multinomial(streams(), counts(), exact + np.array([0.0, 0.0, 5e-10])).sum(axis=-1).tolist() == \
        counts().tolist()
    with pytest.raises(ValueError, match="got a row summing to 1.000001"):
        pfx.multinomial(streams(), counts(), exact + np.array([0.0, 0.0, 1e-6]))
    in_float32 = (exact + np.array([0.0, 0.0, 1e-6])).astype(np.float32)      # within float32's 1e-5
    assert pfx.multinomial(streams(), counts(), in_float32).shape == (TRIALS, PARTICLES, 3)


def test_a_probability_outside_the_unit_interval_is_named():
    with pytest.raises(ValueError, match=r"^multinomial: probabilities must be in \[0, 1\], got 1\.5$"):
        pfx.multinomial(streams(), counts(), np.broadcast_to([1.5, -0.5], (TRIALS, PARTICLES, 2)))


# -- gamma_white_noise ----------------------------------------------------------------------------


@pytest.mark.parametrize("sigma", [0.0, -0.5, float("nan")])
def test_sigma_must_be_positive(sigma):
    """sigma = 0 raised ZeroDivisionError; sigma = -0.5 drew as if it were 0.5."""
    with pytest.raises(ValueError, match=r"^gamma_white_noise: sigma must be finite and positive, got "):
        pfx.gamma_white_noise(streams(), sigma, 0.1, shape=(PARTICLES,))


def test_the_noises_step_and_shape_are_named():
    with pytest.raises(ValueError, match=r"^gamma_white_noise: step must be finite and non-negative"):
        pfx.gamma_white_noise(streams(), 0.2, -1.0, shape=(PARTICLES,))
    with pytest.raises(ValueError, match=r"^gamma_white_noise: shape must be a tuple of non-negative integers"):
        pfx.gamma_white_noise(streams(), 0.2, 0.1, shape=(-3,))
    with pytest.raises(ValueError, match=r"^gamma_white_noise: sigma of shape \(2, 4\) does not broadcast to "
                                         r"draws of shape \(2, 5\)"):
        pfx.gamma_white_noise(streams(), np.full((TRIALS, 4), 0.2), 0.1, shape=(PARTICLES,))


# -- repeat ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("times", [-2, 2.5, True, "3"])
def test_repeat_needs_a_non_negative_integer(times):
    """pfx.repeat(-2, ...) used to return the carry unchanged."""
    with pytest.raises(ValueError, match=r"^repeat: times must be a non-negative integer, got "):
        pfx.repeat(times, lambda value: value + 1.0, 0.0)


def test_repeat_needs_a_function_and_counts_from_zero():
    with pytest.raises(ValueError, match=r"^repeat: body must be a function of the carry, got float"):
        pfx.repeat(3, 1.0, 0.0)
    assert pfx.repeat(0, lambda value: value + 1.0, 2.0) == 2.0
    assert pfx.repeat(np.int64(3), lambda value: value + 1.0, 2.0) == 5.0


def test_each_pass_of_repeat_draws_new_numbers_on_both_backends(backend):
    """A loop body is traced once on jax: without the pass folded into the keys, all three passes
    drew the same normals there, where numpy's Python loop draws new ones."""
    if backend == "jax":
        import jax.numpy as xp

        from pfx.numerics.key_streams import KeyStreams

        random = KeyStreams.from_seeds([1, 2])
    else:
        xp, random = np, TrialStreams.from_seeds([1, 2])

    def one_pass(carry):
        index, draws = carry
        row = xp.arange(3)[:, None] == index              # the pass's row, without an in-place write
        return index + 1, xp.where(row, random.standard_normal(())[None, :], draws)

    _, draws = pfx.repeat(3, one_pass, (xp.asarray(0), xp.zeros((3, 2))))
    draws = np.asarray(draws)
    assert len({tuple(row) for row in draws.round(12)}) == 3, draws
    assert np.all(draws[0] != draws[1]) and np.all(draws[1] != draws[2])


# -- in a run: the same line on both backends; a wrong shape blamed on sample_substep -------------

ARRIVALS = '''from typing import Literal

import pfx


@pfx.register_model
class Arrivals(pfx.Model):
    """A count that gains Poisson(count - 50) arrivals per substep: fine for the truth's 100,
    a negative rate for a filter whose prior starts at 10."""

    kind: Literal["arrivals"] = "arrivals"
    integrates_substeps = True

    def presets(self):
        return {"steps": 3, "dt": 1.0, "substeps": SUBSTEPS, "process_noise": pfx.Noise(variance=0.0),
                "measurement_noise": pfx.Noise(variance=1.0), "initial": pfx.PointLaw(state=[100.0])}

    @property
    def state_names(self):
        return ("count",)

    @property
    def measurement_dimension(self):
        return 1

    def sample_substep(self, state, control, time, random):
        return RESULT

    def propagate(self, state, control, noise):
        return state

    def measurement_mean(self, state):
        return state
'''
DRAWS = "state + random.poisson(state[..., 0] - 50.0)[..., None]"


def arrivals_case(folder, backend: str, result: str = DRAWS, substeps: int = 2) -> str:
    (folder / "arrivals.py").write_text(ARRIVALS.replace("RESULT", result).replace("SUBSTEPS", str(substeps)))
    config = {"name": "arrivals", "plugins": ["arrivals.py"], "seed": 1, "trials": 2, "model": {"kind": "arrivals"},
              "filter": {"kind": "particle", "particles": 20, "backend": backend,
                         "initial": {"kind": "point", "state": [10.0]}}}
    (folder / "arrivals.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    return "arrivals.yaml"


def error_line(result) -> str:
    assert "Traceback" not in result.output, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(PREFIX), result.output
    return lines[0].removeprefix(PREFIX)


@pytest.mark.parametrize("substeps", [1, 2])
def test_a_negative_poisson_rate_fails_alike_on_both_backends(pfx_in_process, tmp_path, substeps):
    """NumPy refused it; JAX drew -1 arrivals and exited 0. Now both exit 1 with one line naming
    the model, sample_substep, the law, the argument and the step (NumPy shows the value and the
    plugin's line as well: JAX's was traced)."""
    lines = {}
    for backend in ("numpy", "jax"):
        if backend == "jax":
            pytest.importorskip("jax")
        folder = tmp_path / backend
        folder.mkdir()
        result = pfx_in_process("run", arrivals_case(folder, backend, substeps=substeps), "--out", "out", cwd=folder)
        assert result.returncode == 1, result.output
        lines[backend] = error_line(result)
        assert not (folder / "out").exists()
    common = ("model arrivals: sample_substep raised ValueError: poisson: rate must be non-negative and at most "
              "9.223e+18, got ")
    ending = " (step 1 of the filter); no cell had finished, so nothing was kept"
    assert lines["numpy"].startswith("arrivals.py:") and common + "-40.0" + ending in lines["numpy"]
    assert lines["jax"] == "arrivals.py: " + common + "a value that is not" + ending


def test_a_sample_substep_of_the_wrong_shape_is_blamed_on_sample_substep(pfx_in_process, tmp_path):
    """It was blamed on propagate, at the truth's first step, after the run had started."""
    config = arrivals_case(tmp_path, "numpy", "pfx.namespace(state).concatenate([state, state], axis=-1)")
    result = pfx_in_process("run", config, "--out", "out", cwd=tmp_path)
    assert result.returncode == 2, result.output
    line = error_line(result)
    definition = next(number for number, text in enumerate(ARRIVALS.splitlines(), 1) if "def sample_substep" in text)
    assert line == (f"arrivals.py:{definition}: model arrivals: sample_substep returned shape (2, 3, 2) for a batch of "
                    "2 trials x 3 particles; expected (2, 3, 1)")
    assert not (tmp_path / "out").exists()


class Doubling(pfx.Model):
    """Not a plugin (no plan-time contract check): the engines' own shape checks speak."""

    kind: str = "doubling"

    def presets(self):
        return {"steps": 2, "dt": 1.0, "process_noise": pfx.Noise(variance=0.0),
                "measurement_noise": pfx.Noise(variance=1.0), "initial": pfx.PointLaw(state=[1.0])}

    @property
    def state_names(self):
        return ("x",)

    @property
    def measurement_dimension(self):
        return 1

    def sample_substep(self, state, control, time, random):
        return pfx.namespace(state).concatenate([state, state], axis=-1)

    def propagate(self, state, control, noise):
        return state

    def measurement_mean(self, state):
        return state


def test_the_engines_name_the_method_that_made_the_transition(backend):
    model = Doubling()
    with pytest.raises(ModelContractError, match=r"model doubling: the transition \(sample_substep\) returned shape"):
        pfx.filter(model, np.ones((2, 1)), seed=0, backend=backend, particles=10)
    assert Doubling.transition_method() == "sample_substep" and pfx.Model.transition_method() == "propagate"


# -- on jax: values seen at once, traced values carried out of loops -----------------------------


def test_concrete_jax_values_are_checked_at_once():
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    from pfx.numerics.key_streams import KeyStreams

    with jax.enable_x64(True):
        keys = KeyStreams.from_seeds(range(TRIALS))
        with pytest.raises(ValueError, match=r"^euler_multinomial: rates must be finite and non-negative, got nan$"):
            pfx.euler_multinomial(keys, jnp.asarray(counts()), jnp.asarray(rates(0.5, np.nan)), 0.5)
        with pytest.raises(ValueError, match=r"^poisson: rate must be non-negative"):
            keys.poisson(jnp.full((TRIALS, PARTICLES), -1.0))


def test_a_traced_check_inside_pfx_repeat_reaches_the_block_around_the_loop():
    """A loop's body is traced apart: pfx.repeat carries its checks' codes out of the loop."""
    jax = pytest.importorskip("jax")
    import jax.numpy as jnp

    from pfx.numerics.key_streams import KeyStreams
    from pfx.numerics.parameter_checks import POISSON_RATE, RULES, collecting

    def codes(rate):
        keys = KeyStreams(jnp.zeros((TRIALS, 2), jnp.uint32))
        with collecting(TRIALS) as checks:
            pfx.repeat(3, lambda value: value + keys.poisson(rate), jnp.zeros((TRIALS, PARTICLES)))
        return checks.codes

    with jax.enable_x64(True):
        rate = jnp.asarray([[1.0] * PARTICLES, [1.0] * (PARTICLES - 1) + [-2.0]])
        assert np.asarray(jax.jit(codes)(rate)).tolist() == [0, RULES.index(POISSON_RATE) + 1]
