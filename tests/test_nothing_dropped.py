"""Nothing silently dropped (issue 47, item 4, and the jax backend's late failure of item 2).

A request pfx cannot honour is refused at plan time in one line naming the file and the key;
where part of it can be made, the run makes that part and says in one line what it left out
(``--quiet`` silences the line):

* a forecast horizon past the record's end from every origin is refused
  (``outputs.forecasts.horizons[i]``); one past it from some origins only is made from the
  others, and the run says so;
* ``origins: []`` is refused (``outputs.forecasts.origins``);
* more PMMH posterior draws than the chains keep are refused (``outputs.forecasts.trials``);
* a figure that draws what the config does not ask for (``forecast_fan`` without
  ``outputs.forecasts``, ``pit_histogram`` without ``metrics.scores``) is refused
  (``outputs.figures[i]``);
* ``metrics.scores`` where no cell's filter computes scores (a histogram-only config, an
  estimation config) is refused, naming the kinds that do; where some cells' kinds compute none,
  the run says so;
* ``metrics.scores`` (or forecasts) on a plugin model that writes its own ``log_likelihood`` but
  keeps pfx's default measurement draws is refused, naming the model, its plugin file and
  ``simulate_measurement``;
* on the jax backend, ``metrics.scores`` on a model whose ``simulate_measurement`` is NumPy-only
  is refused at plan time, naming the method, not met as JAX's TracerArrayConversionError;
* a prior written with ``kind:`` instead of ``law:`` gets one line naming ``law`` and its choices.
"""

from __future__ import annotations

import importlib.util

import pytest
import yaml
from conftest import tiny_config_dict, write_config_file

from pfx.config.plan import build_plan
from pfx.errors import ConfigError

pytestmark = pytest.mark.usefixtures("fresh_plugins")


def plan_of(folder, config: dict, name: str = "config.yaml"):
    path = write_config_file(folder, config, name)
    return build_plan(yaml.safe_load(path.read_text()), str(path))


def refusal(folder, config: dict, name: str = "config.yaml") -> str:
    """The one-line message of the config's refusal, which names the config file."""
    with pytest.raises(ConfigError) as caught:
        plan_of(folder, config, name)
    message = str(caught.value)
    assert "\n" not in message and name in message, message
    return message


def with_forecasts(**forecasts) -> dict:
    config = tiny_config_dict()              # 5 steps at times 1..5
    config["outputs"]["forecasts"] = forecasts
    return config


PMMH = {"method": "pmmh", "chains": 2, "iterations": 12, "warm_up": 2,
        "parameters": {"model.measurement_noise.variance": {"prior": {"law": "flat", "lower": 0.0},
                                                             "transform": "log", "start": 1.0}}}


def pmmh_config(**outputs) -> dict:
    config = tiny_config_dict()
    del config["trials"]
    config["estimation"] = PMMH
    config["outputs"] = {"figures": [], **outputs}
    return config


# -- forecasts -----------------------------------------------------------------------------------

def test_a_horizon_past_the_record_from_every_origin_is_refused_by_its_index(tmp_path):
    message = refusal(tmp_path, with_forecasts(horizons=[1, 4], origins=[2, 3]))
    assert "outputs.forecasts.horizons[1]: horizon 4 reaches past the record's last step (time 5)" in message
    assert "first origin, time 2, is 3 step(s) before it" in message
    plan_of(tmp_path, with_forecasts(horizons=[1, 3], origins=[2, 3]))       # 2 + 3 is step 5: fine


def test_an_empty_list_of_origins_is_refused(tmp_path):
    message = refusal(tmp_path, with_forecasts(horizons=[1], origins=[]))
    assert "outputs.forecasts.origins: an empty list names no origin" in message and "`all`" in message


def test_forecasts_cut_at_the_record_s_end_are_said_in_one_line_and_quiet_silences_it(tmp_path, pfx_in_process):
    config = write_config_file(tmp_path, with_forecasts(horizons=[1, 3], origins="all", trials=6))
    result = pfx_in_process("run", config, "--out", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if "outputs.forecasts" in line]
    # 5 origins: horizon 1 from step 5 and horizon 3 from steps 3, 4 and 5 pass step 5
    assert lines == [f"{config}: outputs.forecasts: a forecast past the record's last step (time 5) is left out: "
                     "horizon 1 from 1 of 5 origins, horizon 3 from 3 of 5 origins",
                     f"{config}: outputs.forecasts.trials: 6 forecast trials asked, and the run has 4 trials per "
                     "cell: all 4 are forecast"], result.stderr
    quiet = pfx_in_process("run", config, "--out", tmp_path / "quiet", "--quiet")
    assert quiet.returncode == 0 and "outputs.forecasts" not in quiet.stderr, quiet.stderr


def test_more_posterior_draws_than_the_chains_keep_are_refused(tmp_path):
    message = refusal(tmp_path, pmmh_config(forecasts={"horizons": [1], "origins": [3], "trials": 200}))
    assert "outputs.forecasts.trials: 200 posterior draws asked, and the chains keep 20" in message, message
    assert "2 chain(s) x (12 iterations - 2 warm-up)" in message
    plan_of(tmp_path, pmmh_config(forecasts={"horizons": [1], "origins": [3], "trials": 20}))


# -- figures -------------------------------------------------------------------------------------

@pytest.mark.parametrize("figure, key", [("forecast_fan", "outputs.forecasts"), ("pit_histogram", "metrics.scores"),
                                         ("score_over_time", "metrics.scores")])
def test_a_figure_of_what_the_config_does_not_ask_for_is_refused(tmp_path, figure, key):
    config = tiny_config_dict()
    config["outputs"]["figures"] = ["error_over_time", figure]
    message = refusal(tmp_path, config)
    assert f"outputs.figures[1]: figure {figure} draws what {key} writes, and this config does not ask for it" \
        in message, message
    if key == "metrics.scores":
        config["metrics"] = {"scores": True}
    else:
        config["outputs"]["forecasts"] = {"horizons": [1]}
    plan_of(tmp_path, config)


def test_a_figure_added_to_a_folder_without_its_output_says_which_key_writes_it(tmp_path, pfx_in_process):
    config = write_config_file(tmp_path, tiny_config_dict(), "config.yaml")
    assert pfx_in_process("run", config, "--out", tmp_path / "out", "--quiet").returncode == 0
    added = pfx_in_process("figures", tmp_path / "out", "--figure", "forecast_fan")
    assert added.returncode == 0, added.output
    assert added.stderr.strip().splitlines() == [
        "forecast_fan: nothing to draw from this folder's tables: it draws what outputs.forecasts writes, which "
        "this folder's config did not ask for (not added)"]
    assert not (tmp_path / "out" / "figures" / "forecast_fan.png").exists()


# -- scores --------------------------------------------------------------------------------------

def test_scores_that_no_filter_computes_are_refused_naming_the_kinds_that_do(tmp_path):
    config = tiny_config_dict(metrics={"scores": True})
    config["filter"] = {"kind": "histogram"}
    message = refusal(tmp_path, config)
    assert "metrics.scores: no cell's filter computes the predictive scores (this config runs histogram)" in message
    assert "particle, sis" in message and "kf" in message, message
    config = pmmh_config()
    config["metrics"] = {"scores": True}
    message = refusal(tmp_path, config)
    assert "metrics.scores: an estimation run writes no per-step tables, so no scores" in message, message


def test_scores_from_some_cells_only_are_said_in_one_line(tmp_path, pfx_in_process):
    config = tiny_config_dict(metrics={"scores": True})
    config["arms"] = {"kf": {"kind": "kf"}, "grid": {"kind": "histogram"}}
    path = write_config_file(tmp_path, config)
    result = pfx_in_process("run", path, "--out", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if "metrics.scores" in line]
    assert len(lines) == 1 and "the histogram filter computes no predictive scores" in lines[0], result.stderr


COUNTS_PLUGIN = '''
from typing import Literal

import numpy as np
from scipy.special import gammaln

import pfx


@pfx.register_model
class PoissonWalk(pfx.Model):
    """A log-rate random walk observed through Poisson counts."""

    kind: Literal["poisson_walk"] = "poisson_walk"

    def presets(self):
        return {"steps": 6, "process_noise": pfx.Noise(variance=0.1), "measurement_noise": pfx.Noise(variance=1.0),
                "initial": pfx.GaussianLaw(mean=[1.0], covariance=0.1)}

    @property
    def state_names(self):
        return ("log_rate",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return state + noise

    def measurement_mean(self, state):
        return np.exp(state)

    def log_likelihood(self, measurement, state):
        rate = np.exp(state[..., 0])
        counts = measurement[..., 0]
        return counts * np.log(rate) - rate - gammaln(counts + 1.0)
DRAWS
'''

POISSON_DRAWS = '''
    def simulate_measurement(self, state, random):
        return random.poisson(np.exp(state)).astype(float)
'''


def counts_config(tmp_path, draws: str, **changes) -> dict:
    (tmp_path / "counts.py").write_text(COUNTS_PLUGIN.replace("DRAWS", draws))
    config = tiny_config_dict(plugins=["counts.py"], model={"kind": "poisson_walk"}, **changes)
    config["outputs"] = {"figures": []}
    return config


def test_scores_on_a_plugin_likelihood_with_the_default_draws_are_refused_naming_the_method(tmp_path):
    message = refusal(tmp_path, counts_config(tmp_path, "", metrics={"scores": True}))
    assert "metrics.scores: model poisson_walk" in message and "counts.py" in message, message
    assert "defines its own log_likelihood but not simulate_measurement" in message and "add simulate_measurement(self, state, random)" in message
    forecasts = counts_config(tmp_path, "")
    forecasts["outputs"]["forecasts"] = {"horizons": [1]}
    message = refusal(tmp_path, forecasts)
    assert "outputs.forecasts: model poisson_walk" in message and "simulate_measurement" in message, message
    plan_of(tmp_path, counts_config(tmp_path, ""))                        # without scores: nothing to draw
    plan_of(tmp_path, counts_config(tmp_path, POISSON_DRAWS, metrics={"scores": True}))


NUMPY_DRAWS_PLUGIN = '''
from typing import Literal

import numpy as np

import pfx


@pfx.register_model
class NumpyDrawsWalk(pfx.Model):
    """A random walk written for both backends, but for its measurement draws."""

    kind: Literal["numpy_draws_walk"] = "numpy_draws_walk"

    def presets(self):
        return {"steps": 5, "process_noise": pfx.Noise(variance=1.0), "measurement_noise": pfx.Noise(variance=1.0),
                "initial": pfx.GaussianLaw(mean=[0.0], covariance=1.0)}

    @property
    def state_names(self):
        return ("x",)

    @property
    def measurement_dimension(self):
        return 1

    def propagate(self, state, control, noise):
        return state + noise

    def measurement_mean(self, state):
        return state

    def simulate_measurement(self, state, random):
        return np.asarray(state) + random.standard_normal(np.shape(state)[1:-1] + (1,))
'''


@pytest.mark.skipif(importlib.util.find_spec("jax") is None, reason="the jax backend needs the 'jax' extra")
def test_numpy_only_measurement_draws_on_jax_with_scores_are_refused_at_plan_time(tmp_path):
    (tmp_path / "numpy_draws.py").write_text(NUMPY_DRAWS_PLUGIN)
    config = tiny_config_dict(plugins=["numpy_draws.py"], model={"kind": "numpy_draws_walk"},
                              metrics={"scores": True})
    config["filter"]["backend"] = "jax"
    message = refusal(tmp_path, config)
    assert "metrics.scores: model numpy_draws_walk's simulate_measurement does not run on the jax backend" in message
    assert "pfx.namespace" in message and "filter.backend: numpy" in message, message
    del config["metrics"]
    plan_of(tmp_path, config)                      # without scores the draws are the host's: it runs
    config["metrics"] = {"scores": True}
    config["filter"]["backend"] = "numpy"
    plan_of(tmp_path, config)


def test_the_python_door_refuses_the_same_measurement_draws_for_scores(tmp_path):
    """pfx.filter(..., scores=True) is judged as a config's metrics.scores: a plugin likelihood
    with pfx's default draws, and on jax a NumPy-only simulate_measurement, are refused naming
    the argument; the same filters run without scores."""
    import numpy as np

    import pfx

    measurements = np.zeros((5, 1))
    (tmp_path / "counts.py").write_text(COUNTS_PLUGIN.replace("DRAWS", ""))
    pfx.load_plugin(tmp_path / "counts.py")
    counts = pfx.model("poisson_walk")
    with pytest.raises(ConfigError, match="scores: model poisson_walk .*defines its own log_likelihood but not "
                                          "simulate_measurement"):
        pfx.filter(counts, measurements, particles=20, scores=True)
    pfx.filter(counts, measurements, particles=20)
    if importlib.util.find_spec("jax") is None:
        return
    (tmp_path / "numpy_draws.py").write_text(NUMPY_DRAWS_PLUGIN)
    pfx.load_plugin(tmp_path / "numpy_draws.py")
    walk = pfx.model("numpy_draws_walk")
    with pytest.raises(ConfigError, match="scores: model numpy_draws_walk's simulate_measurement does not run on "
                                          "the jax backend .*set backend='numpy'"):
        pfx.filter(walk, measurements, particles=20, backend="jax", scores=True)
    pfx.filter(walk, measurements, particles=20, backend="jax")
    pfx.filter(walk, measurements, particles=20, scores=True)


# -- priors --------------------------------------------------------------------------------------

def test_a_prior_written_with_kind_names_law_and_its_choices(tmp_path):
    config = pmmh_config()
    config["estimation"] = {**PMMH, "parameters": {"model.measurement_noise.variance": {
        "prior": {"kind": "flat", "lower": 0.0}, "transform": "log", "start": 1.0}}}
    message = refusal(tmp_path, config)
    assert message.endswith("estimation.parameters.model.measurement_noise.variance.prior.law: required key is "
                            "missing (one of: uniform, normal, lognormal, gamma, inverse_gamma, beta, flat); "
                            "write law: instead of kind:"), message
    assert "None" not in message
    config["estimation"]["parameters"]["model.measurement_noise.variance"]["prior"] = {"law": "flt", "lower": 0.0}
    assert refusal(tmp_path, config).endswith("prior.law: unknown prior law 'flt' (did you mean 'flat'?)")
    config["estimation"]["parameters"]["model.measurement_noise.variance"]["prior"] = {"law": "normal", "mean": "a",
                                                                                       "sd": 1.0}
    assert "variance.prior.mean: input should be a valid number" in refusal(tmp_path, config)
