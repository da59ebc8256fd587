"""King et al.'s cholera model as a pfx plugin (examples/plugins/dacca_cholera.py), checked on
its own, outside pfx's engine (docs/benchmarks/dacca-cholera.md):

* the data files (examples/data/dacca-*.csv): 600 months on the grid 1891 + k/12, the
  covariates on their 0.01-year grid from t0 = 1891 past the last month;
* one Euler-Maruyama substep against the equations written out here in scalar arithmetic, in
  the order of pomp's C code; the positivity rule (a negative compartment marks ``count``, the
  particle is frozen and its likelihood is the floor);
* the measurement density against scipy's normal;
* the whole model: a bootstrap particle filter written here in NumPy (its own substep loop,
  accumulator resets, systematic resampling, an explicit Generator) runs the plugin's
  ``propagate`` and ``log_likelihood`` over the 600 months at J = 1000, and its log-likelihood
  must land on pomp's -3748.6 by pypomp's own criterion (the log-mean-exp of replicate
  estimates within 2.5), and its mean agree with pypomp's measured mean at the same J within
  three standard errors of the difference.

The model reads its covariates through pfx (``Model.covariates_at``); the hand computation of a
substep interpolates the table itself. The filter here drives the substeps itself (accumulators
reset, substep times t_(k-1) + j h), so what it checks is the model's mathematics, not pfx's
engine (the benchmark config, configs/benchmarks/dacca-cholera/dacca.yaml, runs it there).
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pandas as pd
import pytest
from conftest import REPO_ROOT
from scipy import stats

from pfx.config.plugins import load_plugin

PLUGINS = REPO_ROOT / "examples" / "plugins"
DEATHS_FILE = REPO_ROOT / "examples" / "data" / "dacca-deaths.csv"
COVARIATES_FILE = REPO_ROOT / "examples" / "data" / "dacca-covariates.csv"
PUBLISHED_LOG_LIKELIHOOD = -3748.6          # R pomp at the MLE; pypomp's test: 6 x J = 1000 within 2.5
PYPOMP_TOLERANCE = 2.5
# pypomp 1.1.0's bootstrap filter at J = 1000 on this machine, 30 replicates
# (examples/benchmarks/dacca_pypomp_reference.py; configs/benchmarks/dacca-cholera/paper.yaml):
PYPOMP_MEAN_J1000, PYPOMP_STANDARD_ERROR_J1000 = -3750.067, 0.376


def plugin():
    return sys.modules[load_plugin("dacca_cholera.py", PLUGINS).module]


COVARIATE_TABLE = pd.read_csv(COVARIATES_FILE)


def table_covariates_at(time: float) -> np.ndarray:
    """The covariates linearly interpolated at ``time``, in the plugin's order."""
    grid = COVARIATE_TABLE["time"].to_numpy()
    return np.array([np.interp(time, grid, COVARIATE_TABLE[name].to_numpy()) for name in plugin().COVARIATES])


def model(**parameters):
    """The plugin's model with the covariates table (as ``data: {covariates: ...}`` gives it)."""
    module = plugin()
    table = {name: COVARIATE_TABLE[name].tolist() for name in COVARIATE_TABLE.columns}
    model_class = module.DaccaCholera
    if not hasattr(model_class, "substep_duration"):      # until pfx's substeps land beside the covariates

        class WithSubsteps(model_class):
            @property
            def substep_duration(self) -> float:
                return self.dt / self.substeps

        model_class = WithSubsteps
    return model_class(covariates=table, **parameters)


def test_data_files_are_on_pomps_time_grids():
    deaths = pd.read_csv(DEATHS_FILE)
    assert list(deaths.columns) == ["time", "cholera_deaths"] and len(deaths) == 600
    assert np.allclose(deaths["time"], 1891.0 + np.arange(1, 601) / 12.0, rtol=0.0, atol=1e-9)
    assert deaths["cholera_deaths"].iloc[0] == 2641 and deaths["cholera_deaths"].iloc[-1] == 42
    assert (deaths["cholera_deaths"] >= 0).all() and deaths["cholera_deaths"].sum() == 354_275
    names = ["time", "trend", "dpopdt", "pop"] + [f"seas_{i}" for i in range(1, 7)]
    assert list(COVARIATE_TABLE.columns) == names and len(COVARIATE_TABLE) == 5017
    assert np.allclose(COVARIATE_TABLE["time"], 1891.0 + 0.01 * np.arange(5017), rtol=0.0, atol=1e-9)
    # the periodic B-spline basis sums to 1; the trend is centred; the first census
    seasons = COVARIATE_TABLE[[f"seas_{i}" for i in range(1, 7)]].to_numpy()
    assert np.allclose(seasons.sum(axis=1), 1.0, atol=1e-9)
    assert abs(COVARIATE_TABLE["trend"].mean()) < 1e-9
    assert COVARIATE_TABLE["pop"].iloc[0] == pytest.approx(2_420_656, abs=1e-3)
    dacca = model()
    assert dacca.initial_time == pytest.approx(deaths["time"].iloc[0] - 1.0 / 12.0, abs=1e-9)
    assert dacca.dt * 600 == pytest.approx(deaths["time"].iloc[-1] - dacca.initial_time, abs=1e-9)
    assert dacca.substeps == 20 and dacca.substep_duration == pytest.approx(1.0 / 240.0)


def test_the_printed_times_meet_the_covariate_tables_first_row():
    """The deaths' times are printed to 15 digits: the start of step 1, t_1 - dt with dt their
    spacing, falls about 1e-11 years before the table's first row (1891 exactly). pfx counts
    times within a relative 1e-9 as equal: the span check passes and the first row is read
    there. A time really before the table is still refused."""
    deaths = pd.read_csv(DEATHS_FILE)
    dacca = model(steps=600, dt=float(np.diff(deaths["time"])[0]))
    dacca.use_recorded_times(deaths["time"].to_numpy())
    start = dacca.times()[0] - dacca.step_duration(1)
    assert 0.0 < 1891.0 - start < 1e-9
    dacca.check_covariate_span()
    assert np.array_equal(dacca.covariates_at(start), COVARIATE_TABLE.iloc[0, 1:].to_numpy())
    with pytest.raises(ValueError, match="outside their table"):
        dacca.covariates_at(1890.999)


def test_initial_state_is_the_fractions_of_the_first_population():
    dacca = model()
    fractions = np.array([0.621, 0.378, 0.0, 0.000843, 0.000972, 1.16e-07])
    population = 2420655.99999985                                # the table's pop at 1891.0
    expected = np.concatenate([np.rint(population * fractions / fractions.sum()), [0.0, 0.0, 0.0]])
    assert np.array_equal(np.asarray(dacca.initial.state), expected)
    assert expected[5] == 0.0 and expected[0] == 1_502_003.0      # R3: 0.28 people round to none


def hand_euler_substep(x: list[float], w: float, t: float, h: float) -> list[float]:
    """One substep of pomp's dacca C code at the MLE, in scalar arithmetic."""
    trend, dpopdt, pop, *seas = table_covariates_at(t)
    gamma, eps, rho, delta, delta_i, clin, alpha = 20.8, 19.1, 0.0, 0.02, 0.06, 1.0, 1.0
    beta_trend, sd_beta = -0.00498, 3.13
    logbeta = [0.747, 6.38, -3.44, 4.23, 3.33, 4.55]
    logomega = [math.log(v) for v in (0.184, 0.0786, 0.0584, 0.00917, 0.000208, 0.0124)]
    S, I, Y, R1, R2, R3, deaths, W, count = x          # noqa: E741 (pomp's names)
    neps = 3 * eps
    beta = math.exp(sum(s * b for s, b in zip(seas, logbeta)) + beta_trend * trend)
    omega = math.exp(sum(s * o for s, o in zip(seas, logomega)))
    dw = w * math.sqrt(h)
    effI = (I / pop) ** alpha
    births = dpopdt + delta * pop
    passages = [gamma * I, R1 * neps, R2 * neps, R3 * neps]
    rdeaths = [R1 * delta, R2 * delta, R3 * delta]
    infections = (omega + (beta + sd_beta * dw / h) * effI) * S
    S_new = S + (births - infections - delta * S + passages[3] + rho * Y) * h
    I_new = I + (clin * infections - delta_i * I - delta * I - passages[0]) * h
    Y_new = Y + ((1 - clin) * infections - delta * Y - rho * Y) * h
    R = [r + (passages[j] - passages[j + 1] - rdeaths[j]) * h for j, r in enumerate((R1, R2, R3))]
    return [S_new, I_new, Y_new, *R, deaths + delta_i * I * h, W + dw, count]


@pytest.mark.parametrize("noise", [0.0, 1.3, -2.1])
def test_one_euler_substep_against_the_equations(noise):
    dacca = model()
    state = np.array([2.6e6, 1.2e4, 300.0, 4.0e3, 2.5e3, 1.5e3, 17.0, -0.4, 0.0])
    time, h = 1903.37, 1.0 / 240.0
    result = dacca.propagate(state[None, None, :], None, np.array([[[noise]]]), time=time)
    assert result.shape == (1, 1, 9)
    assert np.allclose(result[0, 0], hand_euler_substep(state.tolist(), noise, time, h), rtol=1e-13, atol=1e-9)
    # (particles, trials) batches give the same rows
    batch = dacca.propagate(np.repeat(state[None, None, :], 3, axis=1), None, np.full((1, 3, 1), noise), time=time)
    assert np.array_equal(batch, np.repeat(result, 3, axis=1))


def test_a_negative_compartment_marks_count_and_freezes_the_particle():
    dacca = model()
    few_infected = np.array([[[2.5e6, 100.0, 0.0, 10.0, 10.0, 10.0, 3.0, 0.0, 0.0]]])
    # a huge negative noise: "infections" (beta + sigma dW / h) (I / P) S h of about -800 empty I;
    # pomp then sets I and S to 0 and adds 1e3 to count
    marked = dacca.propagate(few_infected, None, np.array([[[-40.0]]]), time=1900.5)
    assert marked[0, 0, 0] == 0.0 and marked[0, 0, 1] == 0.0 and marked[0, 0, 8] == 1.0e3
    assert marked[0, 0, 3] > 0.0 and marked[0, 0, 6] > 3.0        # the rest moves on as usual
    frozen = dacca.propagate(marked, None, np.array([[[0.5]]]), time=1900.5 + 1 / 240)
    assert np.array_equal(frozen, marked)
    measurement = np.array([[[3.0]]])
    assert dacca.log_likelihood(measurement, marked)[0, 0] == pytest.approx(math.log(1e-18))
    # an unmarked particle of the same deaths gets the normal density
    clean = marked.copy()
    clean[..., 8] = 0.0
    assert dacca.log_likelihood(measurement, clean)[0, 0] > math.log(1e-18)


def test_measurement_density_is_pomps():
    dacca = model()
    state = np.zeros((2, 3, 9))
    state[..., 6] = [[100.0, 2500.0, 40.0], [0.0, 1e-30, 7.0]]
    measurement = np.array([[[120.0]], [[7.0]]])
    log_likelihood = dacca.log_likelihood(measurement, state)
    deaths = state[..., 6]
    scale = 0.23 * deaths + 1e-18
    expected = np.log(stats.norm.pdf(measurement[..., 0], loc=deaths, scale=scale) + 1e-18)
    assert log_likelihood.shape == (2, 3)
    assert np.allclose(log_likelihood, expected, rtol=1e-12, atol=1e-12)
    assert log_likelihood[1, 0] == pytest.approx(math.log(1e-18))     # C = 0 and y > 0: the floor


def systematic_resample(log_weights: np.ndarray, generator: np.random.Generator) -> np.ndarray:
    """Indices (R, J): one uniform per row, J evenly spaced points through the cumulative weights."""
    rows, particles = log_weights.shape
    weights = np.exp(log_weights - log_weights.max(axis=1, keepdims=True))
    cumulative = np.cumsum(weights, axis=1)
    cumulative /= cumulative[:, -1:]
    points = (generator.uniform(size=(rows, 1)) + np.arange(particles)) / particles
    indices = np.stack([np.searchsorted(row, point, side="right") for row, point in zip(cumulative, points)])
    return np.minimum(indices, particles - 1)


def bootstrap_filter(dacca, deaths: np.ndarray, particles: int, replicates: int,
                     generator: np.random.Generator) -> tuple[np.ndarray, int]:
    """log p_hat(y_1..T) of ``replicates`` independent bootstrap filters (R,), resampling every
    month, and how many particle-months ended marked by a positivity violation."""
    state = np.broadcast_to(np.asarray(dacca.initial.state), (replicates, particles, 9)).copy()
    log_likelihood = np.zeros(replicates)
    marked = 0
    rows = np.arange(replicates)[:, None]
    previous_time = dacca.initial_time
    for month, observed in enumerate(deaths, start=1):
        state[..., list(dacca.accumulating_components)] = 0.0
        for substep in range(dacca.substeps):
            noise = generator.standard_normal((replicates, particles, 1))
            state = dacca.propagate(state, None, noise, time=previous_time + substep * dacca.substep_duration)
        marked += int(np.count_nonzero(state[..., 8]))
        log_weights = dacca.log_likelihood(np.full((replicates, 1, 1), observed), state)
        top = log_weights.max(axis=1)
        log_likelihood += top + np.log(np.mean(np.exp(log_weights - top[:, None]), axis=1))
        state = state[rows, systematic_resample(log_weights, generator)]
        previous_time = dacca.initial_time + month * dacca.dt
    return log_likelihood, marked


def log_mean_exp(values: np.ndarray) -> float:
    top = values.max()
    return float(top + np.log(np.mean(np.exp(values - top))))


@pytest.mark.slow        # pypomp's size (J = 1000, 8 replicates, 600 months): its standard errors are the tolerance
def test_standalone_bootstrap_filter_lands_on_pomps_log_likelihood():
    """J = 1000, 8 replicates, over the 600 months (about 20 s)."""
    dacca = model()
    deaths = pd.read_csv(DEATHS_FILE)["cholera_deaths"].to_numpy(dtype=float)
    estimates, marked = bootstrap_filter(dacca, deaths, particles=1000, replicates=8,
                                                generator=np.random.default_rng(20080828))
    mean = float(estimates.mean())
    standard_error = float(estimates.std(ddof=1) / math.sqrt(len(estimates)))
    print(f"standalone J=1000: estimates {np.round(estimates, 2).tolist()} mean {mean:.3f} "
          f"se {standard_error:.3f} log-mean-exp {log_mean_exp(estimates):.3f}; "
          f"{marked} of {8 * 1000 * 600} particle-months marked by a positivity violation")
    assert np.isfinite(estimates).all()
    assert abs(log_mean_exp(estimates) - PUBLISHED_LOG_LIKELIHOOD) < PYPOMP_TOLERANCE
    difference_error = math.hypot(standard_error, PYPOMP_STANDARD_ERROR_J1000)
    assert abs(mean - PYPOMP_MEAN_J1000) < 3.0 * difference_error


@pytest.mark.parametrize("shift, agree", [(0.0, True), (-20.0, False)])
def test_the_jax_runs_are_judged_against_the_numpy_runs_and_the_published_value(tmp_path, shift, agree):
    """The report's backends part (pfx.papers.dacca_backends) on copies of the committed numpy
    folder: jax runs equal to the numpy runs agree (z = 0) and pass pypomp's test exactly when
    the numpy runs do; shifted 20 down (far beyond 3 standard errors and 2.5) they fail both."""
    import shutil

    from pfx.papers import REPORTS
    from pfx.papers.base import PaperResults
    from pfx.papers.dacca_backends import JAX, NUMPY

    committed = REPO_ROOT / "results" / "benchmarks" / "dacca-cholera"
    folder = tmp_path / "dacca-cholera"
    shutil.copytree(committed / NUMPY, folder / NUMPY)
    shutil.copytree(committed / NUMPY, folder / JAX)
    shutil.copy(committed / "paper.yaml", folder / "paper.yaml")
    trials = pd.read_csv(folder / JAX / "trials.csv")
    trials.assign(log_likelihood=trials["log_likelihood"] + shift).to_csv(folder / JAX / "trials.csv", index=False)
    section = REPORTS["dacca-cholera"](PaperResults(folder))
    [backends] = [entry for entry in section.verdicts if "agrees with the numpy backend" in entry.claim]
    [published] = [entry for entry in section.verdicts if "jax backend in 32-bit floats" in entry.claim]
    [numpy_published] = [entry for entry in section.verdicts if "King et al. 2008" in entry.claim]
    assert (backends.verdict == "reproduced") == agree, backends.evidence
    assert "z = 0.0" in backends.evidence if agree else "z = -" in backends.evidence
    assert published.verdict == (numpy_published.verdict if agree else "not reproduced"), published.evidence
