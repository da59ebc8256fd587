r"""Accuracy and speed of pfx's inverse-CDF draws (pfx/numerics/count_quantiles.py for Poisson and
binomial counts, pfx/numerics/gamma_quantiles.py for gammas) against the exact laws, in float64
and float32: the tables of docs/plugins.md, "Count draws: exact or inverse-CDF".

Run it from the repository root (a few minutes on two cores; it needs numpy and scipy, and the
jax extra for the JAX columns and the fast 1e7-draw checks):

    python examples/benchmarks/count_sampler_accuracy.py [--draws 10000000] [--quick]

**The largest CDF difference.** A sampler X = Q(u) of one uniform has the CDF
F_approx(k) = sup{u : Q(u) <= k}. For every count k of the law's range (all of them up to 48,
then up to 4096 spread over mean +- 9 sd), that u is found by bisection over the floats' bit
patterns (exact to one float), on NumPy and on JAX, and its distance from the exact F(k) is taken;
the table gives the largest over k and over the two backends. The exact CDF is the pmf summed
from its mode outwards in float64 (pmf ratios, normalised over mean +- 14 sd): it agrees with
mpmath to 1e-13 where checked, where scipy's pdtr is off by up to 1.3e-7 near a rate of 1e7.
Float32 rows draw from the law at the float32-rounded parameters, against which they are judged.
The gamma's rows give the largest |F(x(u)) - u| of the inverse CDF at shape a + 5 over 2e5 u
(the draw at shape a is that inverse CDF times five boosts, and its CDF error is at most that).

**Draws against the exact laws.** 1e7 draws per case (uniforms from NumPy's Generator, seeds
1000, 1001, ... one per case, in the dtype; drawn on JAX if it is installed, else NumPy: the same function), binned
into the counts of expected number >= 100 (the tails merged into the end cells; gammas: 100
cells of equal exact probability); the chi-square statistic's p-value, and the sample mean and
variance against the exact ones in standard errors (the variance's from the sample's fourth
central moment).

**Speed.** Nanoseconds per draw over 1e6 draws, the best of 5 runs, the uniforms' generation
included: the inverse CDF on NumPy (Generator.random + the quantile) and on JAX on the CPU (one
jit-compiled call: jax.random.uniform + the quantile), beside NumPy's exact Generator.poisson,
.binomial, .gamma and jax.random's.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy import special, stats

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from pfx.numerics.count_quantiles import binomial_quantile, poisson_quantile  # noqa: E402
from pfx.numerics.gamma_quantiles import GAMMA_UNIFORMS, gamma_quantile, gamma_variate  # noqa: E402

HAVE_JAX = importlib.util.find_spec("jax") is not None
if HAVE_JAX:
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)

LENGTH = 4096
DTYPES = (np.float64, np.float32)
RATES = (1e-3, 0.1, 1.0, 3.9, 4.5, 10.0, 17.0, 24.0, 30.0, 100.0, 1e3, 1e4, 1e5, 1e6)
BINOMIALS = ((10, 0.3), (100, 0.01), (60, 0.5), (100, 0.5), (2000, 0.012), (300, 0.1), (1000, 0.3),
             (1e4, 0.002), (1e5, 0.5), (1e6, 0.05), (1e7, 1e-6), (1e7, 0.3), (1e7, 0.999))
SHAPES = (0.01, 0.1, 0.36, 1.0, 4.5, 30.0, 1e3)
FIT_RATES = (0.5, 3.9, 4.5, 17.0, 24.0, 40.0, 1e4, 1e6)
FIT_BINOMIALS = ((30, 0.4), (48, 0.5), (2000, 0.012), (100, 0.75), (1e4, 0.2), (1e7, 0.3))
FIT_SHAPES = (0.1, 0.36, 1.0, 4.5, 30.0, 1e3)


# -- exact CDFs ---------------------------------------------------------------------------------------


def lattice_cdf(counts: np.ndarray, ratio, mode: int, low: int, high: int) -> np.ndarray:
    """The CDF at ``counts`` of a law on the integers with pmf ratios P(k+1)/P(k) = ratio(k): the
    pmf from the mode outwards in logs, normalised over [low, high] (which holds all but a
    negligible mass), summed."""
    upward = np.arange(mode, high, dtype=float)
    downward = np.arange(mode - 1, low - 1, -1, dtype=float)
    logs = np.concatenate([-np.cumsum(np.log(ratio(downward)))[::-1] if len(downward) else [],
                           [0.0], np.cumsum(np.log(ratio(upward)))])
    with np.errstate(under="ignore"):
        pmf = np.exp(logs - logs.max())
    cdf = np.cumsum(pmf) / pmf.sum()
    return np.interp(counts, np.arange(low, high + 1, dtype=float), cdf, left=0.0, right=1.0)


def poisson_law(rate: float) -> tuple:
    spread = np.sqrt(rate)
    low, high = max(0, int(rate - 14 * spread - 30)), int(rate + 14 * spread + 60)
    return (lambda counts: lattice_cdf(counts, lambda k: rate / (k + 1), int(rate), low, high)), rate, rate, spread


def binomial_law(count: float, probability: float) -> tuple:
    mean = count * probability
    spread = np.sqrt(mean * (1 - probability))
    low, high = max(0, int(mean - 14 * spread - 30)), int(min(count, mean + 14 * spread + 60))
    mode = int(min(max(np.floor((count + 1) * probability), low), high))
    odds = probability / (1 - probability) if probability < 1 else np.inf

    def cdf(counts):
        return lattice_cdf(counts, lambda k: (count - k) / (k + 1) * odds, mode, low, high)

    return cdf, mean, mean * (1 - probability), spread


# -- the sampler's CDF --------------------------------------------------------------------------------


def evaluator(backend: str, function, dtype):
    """``function`` on arrays of LENGTH (or of any length on NumPy) in ``dtype``, on ``backend``."""
    if backend == "numpy":
        return lambda *arrays: function(*(np.asarray(array, dtype) for array in arrays))
    compiled = jax.jit(function)
    return lambda *arrays: np.asarray(compiled(*(jnp.asarray(np.asarray(array, dtype)) for array in arrays)))


def largest_cdf_difference(quantile, dtype, parameters: tuple, exact_cdf, mean: float, spread: float,
                           top: float) -> float:
    """The largest distance of F(k) from where the sampler passes k, over counts k and backends."""
    counts = np.arange(0.0, min(48.0, top) + 1)
    around = np.round(mean + spread * np.linspace(-9, 9, LENGTH - len(counts)))
    counts = np.unique(np.concatenate([counts, around[(around >= 0) & (around <= top)]]))
    exact = exact_cdf(counts)
    padded = np.resize(counts, LENGTH).astype(dtype)
    integer = np.uint32 if dtype == np.float32 else np.uint64
    worst = 0.0
    for backend in ("numpy", "jax") if HAVE_JAX else ("numpy",):
        call = evaluator(backend, quantile, dtype)
        arguments = [np.full(LENGTH, value, dtype) for value in parameters]
        low = np.zeros(LENGTH, integer)
        high = np.full(LENGTH, np.array(1.0, dtype).view(integer))
        for _ in range(8 * np.dtype(dtype).itemsize):
            middle = low + (high - low) // 2
            below = call(middle.view(dtype), *arguments) <= padded
            low, high = np.where(below, middle, low), np.where(below, high, middle)
        passing_low = low[:len(counts)].view(dtype).astype(float)
        passing_high = high[:len(counts)].view(dtype).astype(float)
        worst = max(worst, float(np.max(np.maximum(np.maximum(passing_low - exact, exact - passing_high), 0.0))))
    return worst


def gamma_cdf_difference(shape: float, dtype) -> float:
    """The largest |F(x(u)) - u| of the inverse CDF at shape + 5 over 2e5 u, on both backends."""
    level = np.unique(np.concatenate([np.linspace(0, 1, 200001)[1:-1], np.geomspace(1e-30, 1e-5, 2000),
                                      1 - np.geomspace(1e-7, 1e-5, 200)]).astype(dtype))
    level = level[(level > 0) & (level < 1)]
    boosted = float(np.asarray(shape + 5.0, dtype))
    worst = 0.0
    for backend in ("numpy", "jax") if HAVE_JAX else ("numpy",):
        quantiles = evaluator(backend, gamma_quantile, dtype)(level, np.full(len(level), boosted, dtype))
        worst = max(worst, float(np.max(np.abs(special.gammainc(boosted, quantiles.astype(float)) - level))))
    return worst


# -- draws against the exact laws -----------------------------------------------------------------------


def draw(function, dtype, draws: int, uniforms_per_draw: int, seed: int, *parameters) -> np.ndarray:
    """``draws`` draws from uniforms of NumPy's Generator (``seed``: one per case, so that the
    cases' tests are independent), in chunks of 1e6, on JAX if it is installed."""
    generator = np.random.default_rng(seed)
    call = evaluator("jax" if HAVE_JAX else "numpy", function, dtype)
    out = []
    for start in range(0, draws, 10**6):
        size = min(10**6, draws - start)
        shape = (uniforms_per_draw, size) if uniforms_per_draw > 1 else (size,)
        out.append(call(generator.random(shape, dtype=dtype), *(np.full(size, value, dtype) for value in parameters)))
    return np.concatenate(out).astype(float)


def fit(draws: np.ndarray, cell_of, cells: int, cell_probabilities: np.ndarray, mean: float, variance: float) -> tuple:
    """The chi-square p-value over ``cells`` and the mean's and variance's deviations in standard errors."""
    observed = np.bincount(cell_of(draws), minlength=cells).astype(float)
    expected = cell_probabilities * len(draws)
    statistic = float(np.sum((observed - expected) ** 2 / expected))
    centred = draws - draws.mean()
    mean_error = np.sqrt(variance / len(draws))
    variance_error = np.sqrt((np.mean(centred**4) - draws.var() ** 2) / len(draws))
    return (stats.chi2.sf(statistic, cells - 1), cells - 1, (draws.mean() - mean) / mean_error,
            (draws.var(ddof=1) - variance) / variance_error)


def count_fit(draws: np.ndarray, exact_cdf, mean: float, variance: float, top: float) -> tuple:
    support = np.arange(0.0, top + 1)
    probabilities = np.diff(np.concatenate([[0.0], exact_cdf(support)]))
    keep = np.flatnonzero(probabilities * len(draws) >= 100)
    edges = support[keep]
    cumulative = np.cumsum(probabilities)
    cell_probabilities = np.diff(np.concatenate([[0.0], cumulative[keep[1:] - 1], [1.0]]))
    return fit(draws, lambda values: np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 1),
               len(edges), cell_probabilities, mean, variance)


def gamma_fit(draws: np.ndarray, shape: float) -> tuple:
    cells = 100
    return fit(draws, lambda values: np.clip(np.floor(stats.gamma.cdf(values, shape) * cells), 0, cells - 1).astype(int),
               cells, np.full(cells, 1.0 / cells), shape, shape)


# -- speed ----------------------------------------------------------------------------------------------


def nanoseconds(run, draws: int = 10**6, repeats: int = 5) -> float:
    run()
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return best / draws * 1e9


def speed_rows(dtype) -> list:
    """(law, parameters, inverse CDF on NumPy, on JAX, NumPy's exact, jax.random's) per row."""
    size = 10**6
    generator = np.random.default_rng(2)
    rows = []
    cases = (("Poisson", "rate 3", poisson_quantile, (3.0,), "poisson"),
             ("Poisson", "rate 300", poisson_quantile, (300.0,), "poisson"),
             ("binomial", "n 1000, p 0.01", binomial_quantile, (1000.0, 0.01), "binomial"),
             ("binomial", "n 1000, p 0.3", binomial_quantile, (1000.0, 0.3), "binomial"),
             ("gamma", "shape 0.36", gamma_variate, (0.36,), "gamma"),
             ("gamma", "shape 30", gamma_variate, (30.0,), "gamma"))
    for law, label, function, parameters, exact_name in cases:
        uniforms_per_draw = GAMMA_UNIFORMS if law == "gamma" else 1
        shape = (uniforms_per_draw, size) if uniforms_per_draw > 1 else (size,)
        arrays = [np.full(size, value, dtype) for value in parameters]
        on_numpy = nanoseconds(lambda: function(generator.random(shape, dtype=dtype), *arrays))
        on_numpy_exact = float("nan")           # NumPy's exact samplers draw float64 only
        if dtype == np.float64:
            exact_arguments = [np.full(size, value) for value in parameters]
            if law == "binomial":
                exact_arguments[0] = exact_arguments[0].astype(np.int64)
            on_numpy_exact = nanoseconds(lambda: getattr(generator, exact_name)(*exact_arguments))
        on_jax = on_jax_exact = float("nan")
        if HAVE_JAX:
            jax_arrays = [jnp.asarray(array) for array in arrays]
            key = jax.random.key(3)
            inverse = jax.jit(lambda key, *values: function(jax.random.uniform(key, shape, dtype), *values))
            on_jax = nanoseconds(lambda: inverse(key, *jax_arrays).block_until_ready())
            if law == "Poisson":
                exact = jax.jit(lambda key, rate: jax.random.poisson(key, rate, (size,)).astype(dtype))
            elif law == "binomial":
                exact = jax.jit(lambda key, n, p: jax.random.binomial(key, n, p, (size,), dtype))
            else:
                exact = jax.jit(lambda key, a: jax.random.gamma(key, a, (size,), dtype))
            on_jax_exact = nanoseconds(lambda: exact(key, *jax_arrays).block_until_ready())
        rows.append((law, label, on_numpy, on_jax, on_numpy_exact, on_jax_exact))
    return rows


# -- the report -----------------------------------------------------------------------------------------


def machine_line() -> str:
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = f"NumPy {np.__version__}" + (f", JAX {jax.__version__} (CPU)" if HAVE_JAX else ", no JAX")
    return (f"{datetime.date.today().isoformat()}, {model}, {os.cpu_count()} logical cores, Python "
            f"{platform.python_version()}, {versions}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=10**7, help="draws per goodness-of-fit case (default 1e7)")
    parser.add_argument("--quick", action="store_true", help="fewer cases and 1e6 draws: a smoke run")
    arguments = parser.parse_args()
    draws = 10**6 if arguments.quick else arguments.draws
    rates, binomials, shapes = (RATES[::3], BINOMIALS[::3], SHAPES[::3]) if arguments.quick else (RATES, BINOMIALS, SHAPES)
    print(f"Machine: {machine_line()}\n")

    print("| law | parameters | largest CDF difference, float64 | float32 |")
    print("|---|---|---|---|")
    for rate in rates:
        row = []
        for dtype in DTYPES:
            value = float(np.asarray(rate, dtype))
            cdf, mean, _, spread = poisson_law(value)
            row.append(largest_cdf_difference(poisson_quantile, dtype, (value,), cdf, mean, spread, np.inf))
        print(f"| Poisson | rate {rate:g} | {row[0]:.1e} | {row[1]:.1e} |", flush=True)
    for count, probability in binomials:
        row = []
        for dtype in DTYPES:
            value = float(np.asarray(probability, dtype))
            cdf, mean, _, spread = binomial_law(count, value)
            row.append(largest_cdf_difference(binomial_quantile, dtype, (count, value), cdf, mean, spread, count))
        print(f"| binomial | n {count:g}, p {probability:g} | {row[0]:.1e} | {row[1]:.1e} |", flush=True)
    for shape in shapes:
        row = [gamma_cdf_difference(shape, dtype) for dtype in DTYPES]
        print(f"| gamma | shape {shape:g} (inverse CDF at {shape + 5:g}) | {row[0]:.1e} | {row[1]:.1e} |", flush=True)

    print(f"\n| law | parameters | dtype | chi-square p-value (dof) | mean, in se | variance, in se |"
          f" ({draws:.0e} draws each)")
    print("|---|---|---|---|---|---|")
    seed = 999
    for dtype in DTYPES:
        name = np.dtype(dtype).name
        for rate in (FIT_RATES[::3] if arguments.quick else FIT_RATES):
            value = float(np.asarray(rate, dtype))
            cdf, mean, variance, spread = poisson_law(value)
            seed += 1
            result = count_fit(draw(poisson_quantile, dtype, draws, 1, seed, value), cdf, mean, variance,
                               np.ceil(mean + 14 * spread + 60))
            print(f"| Poisson | rate {rate:g} | {name} | {result[0]:.2f} ({result[1]}) | {result[2]:+.1f} | {result[3]:+.1f} |",
                  flush=True)
        for count, probability in (FIT_BINOMIALS[::3] if arguments.quick else FIT_BINOMIALS):
            value = float(np.asarray(probability, dtype))
            cdf, mean, variance, spread = binomial_law(count, value)
            seed += 1
            result = count_fit(draw(binomial_quantile, dtype, draws, 1, seed, count, value), cdf, mean, variance,
                               min(count, np.ceil(mean + 14 * spread + 60)))
            print(f"| binomial | n {count:g}, p {probability:g} | {name} | {result[0]:.2f} ({result[1]}) "
                  f"| {result[2]:+.1f} | {result[3]:+.1f} |", flush=True)
        for shape in (FIT_SHAPES[::3] if arguments.quick else FIT_SHAPES):
            value = float(np.asarray(shape, dtype))
            seed += 1
            result = gamma_fit(draw(gamma_variate, dtype, draws, GAMMA_UNIFORMS, seed, value), value)
            print(f"| gamma | shape {shape:g} | {name} | {result[0]:.2f} ({result[1]}) | {result[2]:+.1f} "
                  f"| {result[3]:+.1f} |", flush=True)

    print("\n| law | parameters | dtype | inverse CDF on NumPy, ns | on JAX (CPU) | NumPy's exact | jax.random's |")
    print("|---|---|---|---|---|---|---|")
    for dtype in DTYPES:
        for law, label, on_numpy, on_jax, exact_numpy, exact_jax in speed_rows(dtype):
            exact_numpy_text = f"{exact_numpy:.0f}" if dtype == np.float64 else "float64 only"
            print(f"| {law} | {label} | {np.dtype(dtype).name} | {on_numpy:.0f} | {on_jax:.0f} | {exact_numpy_text} "
                  f"| {exact_jax:.0f} |", flush=True)


if __name__ == "__main__":
    main()
