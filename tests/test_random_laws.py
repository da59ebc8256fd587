"""Draws of other laws from each trial's own stream (pfx.numerics.seeding.TrialStreams).

* Exactness: trial r's slice of ``binomial``, ``poisson``, ``gamma``, ``exponential`` and
  ``normal`` is what ``numpy.random.default_rng(seed_r)`` draws with the same method on trial r's
  parameters, in the same call order (mixed with the compiled normal and uniform draws), and a
  batch of trials draws what its parts draw one part at a time.
* The laws: for fixed seeds, the sample mean and variance agree with scipy.stats' within 4
  standard errors, and the whole law passes a chi-square (counts) or Kolmogorov-Smirnov (gamma)
  goodness-of-fit test at the fixed level 1e-3, for small and large counts and rates (NumPy
  switches algorithm with them) and a gamma shape below 1.
* Parameters broadcast with the trial axis first; bad parameters are refused, naming the law and
  the value, before any generator moves.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy import stats

from pfx.numerics.seeding import TrialStreams

SEEDS = [3, 14, 15, 92, 65, 35, 89, 79, 32, 38]
PARTICLES = 7


def _parameters(trials: int = len(SEEDS)) -> dict[str, np.ndarray]:
    """Per-trial and per-particle parameters, from a generator of their own."""
    source = np.random.default_rng(2718)
    return {
        "count": source.integers(0, 60, size=(trials, PARTICLES)).astype(float),
        "probability": source.uniform(0, 1, size=(trials, PARTICLES)),
        "rate": source.uniform(0, 40, size=(trials, 1)),
        "shape_parameter": source.uniform(0.1, 5, size=(trials, PARTICLES)),
        "scale": source.uniform(0.5, 3, size=(trials,)),
        "mean": source.normal(size=(1, PARTICLES)),
        "sd": source.uniform(0, 2, size=(trials, PARTICLES)),
    }


def _draw_sequence(streams: TrialStreams, parameters: dict[str, np.ndarray]) -> list[np.ndarray]:
    """One call of each law, mixed with the compiled normal and uniform draws."""
    p = parameters
    return [
        streams.binomial(p["count"], p["probability"]),
        streams.standard_normal((3,)),
        streams.poisson(p["rate"], shape=(PARTICLES,)),
        streams.gamma(p["shape_parameter"], p["scale"]),
        streams.uniform((2,)),
        streams.exponential(p["scale"], shape=(4,)),
        streams.normal(p["mean"], p["sd"]),
        streams.gamma(0.4, shape=(5,)),
    ]


def _numpy_sequence(seed: int, row: int, parameters: dict[str, np.ndarray]) -> list[np.ndarray]:
    """What trial ``row``'s own NumPy generator draws for the same calls."""
    p = {name: values[row if len(values) > 1 else 0] for name, values in parameters.items()}
    generator = np.random.default_rng(seed)
    return [
        generator.binomial(p["count"].astype(np.int64), p["probability"]),
        generator.standard_normal(3),
        generator.poisson(p["rate"], size=PARTICLES),
        generator.gamma(p["shape_parameter"], p["scale"][..., None]),
        generator.random(2),
        generator.exponential(p["scale"], size=4),
        generator.normal(p["mean"], p["sd"]),
        generator.gamma(0.4, size=5),
        generator.random(3),                       # where the generator was left
    ]


@pytest.mark.numpy_only
def test_each_trials_draws_are_its_own_generators_numpy_draws():
    streams = TrialStreams.from_seeds(SEEDS)
    parameters = _parameters()
    draws = _draw_sequence(streams, parameters) + [streams.uniform((3,))]
    for row, seed in enumerate(SEEDS):
        expected = _numpy_sequence(seed, row, parameters)
        for call, (ours, numpys) in enumerate(zip(draws, expected)):
            assert ours.dtype == np.float64
            np.testing.assert_array_equal(ours[row], numpys, err_msg=f"call {call}, trial {row}")


def test_a_batch_draws_what_its_parts_draw():
    parameters = _parameters()
    whole = _draw_sequence(TrialStreams.from_seeds(SEEDS), parameters)
    first = _draw_sequence(TrialStreams.from_seeds(SEEDS[:5]),
                           {name: values[:5] if len(values) > 1 else values for name, values in parameters.items()})
    second = _draw_sequence(TrialStreams.from_seeds(SEEDS[5:]),
                            {name: values[5:] if len(values) > 1 else values for name, values in parameters.items()})
    for together, apart in zip(whole, (np.concatenate(parts) for parts in zip(first, second))):
        np.testing.assert_array_equal(together, apart)


@pytest.mark.numpy_only
def test_subsets_and_pickled_copies_keep_drawing_the_same_streams():
    streams = TrialStreams.from_seeds(SEEDS[:3])
    streams.standard_normal((2,))                  # the compiled loops have found the generators
    subset = streams.subset([2, 0])
    from_subset = subset.binomial(np.array([[10.0], [20.0]]), 0.3, shape=(4,))
    copy = pickle.loads(pickle.dumps(streams))
    from_copy = copy.gamma(2.0, shape=(3,))
    from_original = streams.gamma(2.0, shape=(3,))
    np.testing.assert_array_equal(from_copy, from_original)
    for row, (seed, count) in enumerate([(SEEDS[2], 10), (SEEDS[0], 20)]):
        generator = np.random.default_rng(seed)
        generator.standard_normal(2)
        np.testing.assert_array_equal(from_subset[row], generator.binomial(count, 0.3, size=4))


# --- the laws against scipy.stats ----------------------------------------------------------------

# 20 trials x 10 000 draws = 200 000 draws per parameter set: the mean test then detects a bias of
# 4 sqrt(variance / 200 000), under 1 % of the standard deviation, and the variance test a relative
# error of 4 sqrt((kurtosis + 2) / 200 000), about 1.3 % for a law close to normal.
TRIALS, DRAWS = 20, 10_000
LEVEL = 1e-3            # the goodness-of-fit tests' significance level, fixed in advance

LAWS = [
    # (TrialStreams method, its parameters, the scipy.stats law)
    ("binomial", (5, 0.3), stats.binom(5, 0.3)),                 # NumPy's inversion (n p < 30)
    ("binomial", (40, 0.85), stats.binom(40, 0.85)),             # p > 1/2: drawn as n - Bin(n, 1 - p)
    ("binomial", (2000, 0.4), stats.binom(2000, 0.4)),           # NumPy's BTPE (n p >= 30)
    ("binomial", (10**7, 1e-3), stats.binom(10**7, 1e-3)),       # large count, small probability
    ("poisson", (0.05,), stats.poisson(0.05)),                   # almost always 0
    ("poisson", (6.5,), stats.poisson(6.5)),                     # NumPy's multiplication method
    ("poisson", (250.0,), stats.poisson(250.0)),                 # NumPy's PTRS (rate >= 10)
    ("poisson", (1e6,), stats.poisson(1e6)),
    ("gamma", (0.2, 3.0), stats.gamma(0.2, scale=3.0)),          # shape < 1: Johnk-type rejection
    ("gamma", (1.0, 0.5), stats.gamma(1.0, scale=0.5)),          # exponential
    ("gamma", (7.5, 2.0), stats.gamma(7.5, scale=2.0)),          # Marsaglia & Tsang
    ("gamma", (500.0, 0.01), stats.gamma(500.0, scale=0.01)),
    ("exponential", (2.5,), stats.expon(scale=2.5)),
    ("normal", (-1.0, 3.0), stats.norm(-1.0, 3.0)),
]
LAW_IDS = [f"{method}{parameters}" for method, parameters, _ in LAWS]


def _sample(method: str, parameters: tuple, seed: int) -> np.ndarray:
    streams = TrialStreams.from_seeds(range(seed, seed + TRIALS))
    draws = getattr(streams, method)(*parameters, shape=(DRAWS,))
    assert draws.shape == (TRIALS, DRAWS)
    return draws.ravel()


@pytest.mark.parametrize("method, parameters, law", LAWS, ids=LAW_IDS)
def test_sample_mean_and_variance_are_the_laws(method, parameters, law):
    draws = _sample(method, parameters, seed=1000)
    mean, variance, excess_kurtosis = (float(moment) for moment in law.stats(moments="mvk"))
    count = draws.size
    # Standard errors: of the mean, sqrt(σ²/n); of the sample variance, sqrt((μ4 - σ⁴)/n) with
    # the fourth central moment μ4 = (excess kurtosis + 3) σ⁴.
    mean_error = np.sqrt(variance / count)
    variance_error = variance * np.sqrt((excess_kurtosis + 2) / count)
    assert abs(draws.mean() - mean) < 4 * mean_error, (draws.mean(), mean, mean_error)
    assert abs(draws.var(ddof=1) - variance) < 4 * variance_error, (draws.var(ddof=1), variance, variance_error)


@pytest.mark.parametrize("method, parameters, law", [law for law in LAWS if law[0] in ("binomial", "poisson")],
                         ids=[name for name in LAW_IDS if name.startswith(("binomial", "poisson"))])
def test_counts_pass_a_chi_square_test(method, parameters, law):
    """Pearson's chi-square over the values, the tails pooled so that every cell expects >= 5."""
    draws = _sample(method, parameters, seed=2000)
    assert np.all(draws == np.round(draws))
    low, high = law.ppf(1e-5), law.ppf(1 - 1e-5)
    values = np.arange(low, high + 1)
    # Cells: (-inf, v0], {v1}, ..., {v_{k-1}}, [v_k, inf), then neighbours merged until each
    # cell expects 5 draws.
    edges = np.concatenate(([-np.inf], values[:-1] + 0.5, [np.inf]))
    probabilities = np.diff(law.cdf(np.concatenate(([-np.inf], values[:-1], [np.inf]))))
    observed = np.histogram(draws, bins=edges)[0]
    expected = probabilities * draws.size
    merged_observed, merged_expected, cell_observed, cell_expected = [], [], 0, 0.0
    for seen, wanted in zip(observed, expected):
        cell_observed, cell_expected = cell_observed + seen, cell_expected + wanted
        if cell_expected >= 5:
            merged_observed.append(cell_observed)
            merged_expected.append(cell_expected)
            cell_observed, cell_expected = 0, 0.0
    merged_observed[-1] += cell_observed
    merged_expected[-1] += cell_expected
    if len(merged_expected) < 2:
        pytest.skip("a law with one cell has nothing to test")
    merged_expected = np.array(merged_expected) * draws.size / np.sum(merged_expected)
    result = stats.chisquare(merged_observed, merged_expected)
    assert result.pvalue > LEVEL, result


@pytest.mark.parametrize("method, parameters, law", [law for law in LAWS if law[0] in ("gamma", "exponential", "normal")],
                         ids=[name for name in LAW_IDS if name.startswith(("gamma", "exponential", "normal"))])
def test_continuous_draws_pass_a_kolmogorov_smirnov_test(method, parameters, law):
    draws = _sample(method, parameters, seed=3000)
    result = stats.kstest(draws, law.cdf)
    assert result.pvalue > LEVEL, result


def test_parameters_that_vary_per_particle_give_each_particle_its_law():
    """Standardised binomial draws with a different (n, p) per particle and trial: mean 0, variance 1."""
    source = np.random.default_rng(5)
    count = source.integers(1, 500, size=(TRIALS, DRAWS)).astype(float)
    probability = source.uniform(0.05, 0.95, size=(TRIALS, DRAWS))
    draws = TrialStreams.from_seeds(range(TRIALS)).binomial(count, probability)
    standardised = (draws - count * probability) / np.sqrt(count * probability * (1 - probability))
    # Standard errors for 200 000 draws of mean 0 and variance 1 whose fourth moment is at most
    # 3 + 1 / min(n p (1 - p)) < 3.5 here: sqrt(1/n) and sqrt(2.5/n).
    assert abs(standardised.mean()) < 4 * np.sqrt(1 / standardised.size)
    assert abs(standardised.var() - 1) < 4 * np.sqrt(2.5 / standardised.size)


# --- shapes --------------------------------------------------------------------------------------

def test_parameters_broadcast_with_the_trial_axis_first():
    streams = TrialStreams.from_seeds(range(4))
    per_trial, per_particle = np.arange(4.0) + 1, np.full((4, 6), 0.5)
    assert streams.binomial(per_trial, per_particle).shape == (4, 6)        # (R,) with (R, N)
    assert streams.binomial(10, per_particle).shape == (4, 6)               # scalar with (R, N)
    assert streams.binomial(np.full((1, 6), 3.0), 0.5).shape == (4, 6)     # shared by the trials
    assert streams.poisson(2.0).shape == (4,)                               # one draw per trial
    assert streams.poisson(2.0, shape=(6, 2)).shape == (4, 6, 2)
    assert streams.poisson(per_trial, shape=(6,)).shape == (4, 6)
    assert streams.gamma(per_trial, np.ones((1, 6))).shape == (4, 6)        # (R, 1) x (1, N)
    assert streams.exponential(per_trial).shape == (4,)
    assert streams.normal(np.zeros((1, 3)), per_trial).shape == (4, 3)
    assert TrialStreams([]).poisson(1.0, shape=(3,)).shape == (0, 3)


def test_a_per_trial_parameter_reaches_its_own_trial_only():
    streams = TrialStreams.from_seeds(range(3))
    draws = streams.binomial(np.array([0.0, 5.0, 1e6]), 1.0, shape=(4,))
    np.testing.assert_array_equal(draws, [[0] * 4, [5] * 4, [1e6] * 4])
    rates = streams.poisson(np.array([[0.0, 1e6], [1e6, 0.0], [0.0, 0.0]]))
    assert np.all((rates > 0) == [[False, True], [True, False], [False, False]])


@pytest.mark.parametrize("call, message", [
    (lambda s: s.poisson(np.ones(5)), "poisson: a parameter of shape (5,) must have the trial axis first, of length 3"),
    (lambda s: s.binomial(np.ones((3, 2)), np.ones((3, 4)) / 2), "binomial: parameters of shapes [(3, 2), (3, 4)] do not broadcast"),
    (lambda s: s.gamma(np.ones((3, 2)), shape=(4,)), "gamma: parameters of shapes [(3, 2), ()] do not broadcast to draws of shape (3, 4)"),
    (lambda s: s.normal(np.zeros((3, 2, 2)), shape=(2,)), "normal: parameters of shapes [(3, 2, 2)] have more axes than draws of shape (3, 2)"),
])
def test_shapes_that_do_not_fit_are_refused(call, message):
    with pytest.raises(ValueError) as refused:
        call(TrialStreams.from_seeds(range(3)))
    assert message in str(refused.value)


# --- bad parameters ------------------------------------------------------------------------------

@pytest.mark.parametrize("call, message", [
    (lambda s: s.binomial(np.array([3.0, -1.0]), 0.5), "binomial: count must be a non-negative integer, got -1.0"),
    (lambda s: s.binomial(2.5, 0.5), "binomial: count must be a non-negative integer, got 2.5"),
    (lambda s: s.binomial(np.inf, 0.5), "binomial: count must be a non-negative integer, got inf"),
    (lambda s: s.binomial(3, np.array([[0.5], [1.5]])), "binomial: probability must be in [0, 1], got 1.5"),
    (lambda s: s.binomial(3, -0.1), "binomial: probability must be in [0, 1], got -0.1"),
    (lambda s: s.binomial(3, np.nan), "binomial: probability must be in [0, 1], got nan"),
    (lambda s: s.poisson(np.array([1.0, -2.0])), "poisson: rate must be non-negative and at most 9.223e+18, got -2.0"),
    (lambda s: s.poisson(1e20), "poisson: rate must be non-negative and at most 9.223e+18, got 1e+20"),
    (lambda s: s.poisson(np.nan), "poisson: rate must be non-negative and at most 9.223e+18, got nan"),
    (lambda s: s.gamma(-0.5), "gamma: shape_parameter must be finite and non-negative, got -0.5"),
    (lambda s: s.gamma(2.0, np.array([1.0, -3.0])), "gamma: scale must be finite and non-negative, got -3.0"),
    (lambda s: s.exponential(-1.0), "exponential: scale must be finite and non-negative, got -1.0"),
    (lambda s: s.normal(0.0, -1.0), "normal: sd must be finite and non-negative, got -1.0"),
])
def test_bad_parameters_are_refused_before_any_draw(call, message):
    streams = TrialStreams.from_seeds([1, 2])
    with pytest.raises(ValueError) as refused:
        call(streams)
    assert str(refused.value) == message
    untouched = [np.random.default_rng(seed).random() for seed in (1, 2)]
    np.testing.assert_array_equal(streams.uniform(()), untouched)
