"""Count draws in the transition, on both backends (pfx/laws/count_transitions.py, the count laws
of pfx/numerics/key_streams.py, and the SIR example plugin).

Backend-invariant checks: every law's sample moments against its exact moments, within 4
standard errors of the sample mean and of the sample variance (the latter from the sample's
fourth central moment), with fixed seeds, on NumPy's streams and on JAX's keys.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pfx
from pfx.laws.count_transitions import euler_multinomial, gamma_white_noise, multinomial
from pfx.numerics.seeding import TrialStreams

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

from pfx.numerics.key_streams import KeyStreams  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_plugins")
REPOSITORY = Path(__file__).resolve().parents[1]
TRIALS, PARTICLES = 400, 250           # 1e5 draws of each law
SIGMA, STEP = 0.3, 0.25                # the gamma white noise: Gamma(STEP / SIGMA^2, SIGMA^2) draws


def streams(backend: str, seed: int = 0):
    seeds = range(seed, seed + TRIALS)
    return TrialStreams.from_seeds(seeds) if backend == "numpy" else KeyStreams.from_seeds(seeds)


def on(backend: str, random, draw):
    """``draw(xp, random)``: eagerly on NumPy; on JAX under jax.jit with 64-bit types, the trials'
    keys the program's argument, as in the filter's compiled step (so two draws of one law with
    the same numbers from fresh streams of any seeds are one program, compiled once: JAX's
    compilation cache). ``random``'s draw counter advances as the draws made it."""
    if backend == "numpy":
        return np.asarray(draw(np, random))

    def traced(keys):
        streams = KeyStreams(keys, random.dtype, counter=random.counter)
        drawn = draw(jnp, streams)
        random.counter = streams.counter
        return drawn

    with jax.enable_x64(True):
        return np.asarray(jax.jit(traced)(random.keys))


def assert_moments(draws: np.ndarray, mean, variance, label: str = "") -> None:
    """Sample mean and variance of ``draws`` (flattened over their leading axes; the last axis,
    if ``mean`` is a vector, holds components) within 4 standard errors of the exact values."""
    draws = draws.reshape(-1, *np.shape(mean))
    count = len(draws)
    centred = draws - draws.mean(axis=0)
    sample_variance = centred.var(axis=0, ddof=1)
    mean_error = np.sqrt(np.asarray(variance) / count)
    variance_error = np.sqrt(np.maximum(np.mean(centred**4, axis=0) - sample_variance**2, 0.0) / count)
    assert np.all(np.abs(draws.mean(axis=0) - mean) < 4 * mean_error + 1e-12), (label, draws.mean(axis=0), mean)
    assert np.all(np.abs(sample_variance - variance) < 4 * variance_error + 1e-12), (label, sample_variance, variance)


def test_binomial_poisson_and_gamma_have_their_moments_with_a_value_per_trial(backend):
    random = streams(backend)
    count = np.repeat(np.array([3.0, 40.0]), TRIALS // 2)[:, None]          # (R, 1): one n per trial
    draws = on(backend, random, lambda xp, random: random.binomial(xp.asarray(count), 0.3, shape=(PARTICLES,)))
    assert draws.shape == (TRIALS, PARTICLES)
    for rows, n in ((slice(0, TRIALS // 2), 3.0), (slice(TRIALS // 2, None), 40.0)):
        assert_moments(draws[rows], n * 0.3, n * 0.3 * 0.7, f"binomial n={n}")
    rate = np.full((TRIALS, PARTICLES), 7.5)
    assert_moments(on(backend, random, lambda xp, random: random.poisson(xp.asarray(rate))), 7.5, 7.5, "poisson")
    # the law of the gamma white noise below, drawn directly (on JAX, the same program as its:
    # compiled once), from fresh streams of seeds apart from its
    scale = SIGMA * SIGMA
    shape_parameter = STEP / scale
    draws = on(backend, streams(backend, 5000),
               lambda xp, random: random.gamma(shape_parameter, scale, shape=(PARTICLES,)))
    assert_moments(draws, shape_parameter * scale, shape_parameter * scale**2, "gamma")


def test_euler_multinomial_has_the_exact_multinomial_moments(backend):
    """n = 50 individuals, exits at rates (0.3, 0.1, 0.05) over h = 1.5: counts by exit with
    E = n q, Var = n q (1 - q), Cov = -n q_i q_j, q_j = (1 - e^(-R h)) r_j / R."""
    random = streams(backend, 1)
    rates = np.array([0.3, 0.1, 0.05])
    count = np.full((TRIALS, PARTICLES), 50.0)
    draws = on(backend, random, lambda xp, random: euler_multinomial(
        random, xp.asarray(count), xp.asarray(np.broadcast_to(rates, (TRIALS, PARTICLES, 3))), 1.5))
    assert draws.shape == (TRIALS, PARTICLES, 3)
    assert np.all(draws == np.round(draws)) and np.all(draws >= 0) and np.all(draws.sum(axis=-1) <= 50)
    total = rates.sum()
    share = -np.expm1(-total * 1.5) * rates / total
    assert_moments(draws, 50 * share, 50 * share * (1 - share), "euler_multinomial")
    flat = draws.reshape(-1, 3)
    covariance = np.cov(flat[:, 0], flat[:, 1])[0, 1]
    product = (flat[:, 0] - flat[:, 0].mean()) * (flat[:, 1] - flat[:, 1].mean())
    assert abs(covariance - (-50 * share[0] * share[1])) < 4 * product.std() / np.sqrt(len(flat))


def test_multinomial_splits_the_count_by_its_probabilities(backend):
    random = streams(backend, 2)
    probabilities = np.array([0.5, 0.2, 0.3])
    draws = on(backend, random, lambda xp, random: multinomial(
        random, xp.full((TRIALS, PARTICLES), 20.0), xp.asarray(np.broadcast_to(probabilities, (TRIALS, PARTICLES, 3)))))
    assert np.all(draws.sum(axis=-1) == 20)
    assert_moments(draws, 20 * probabilities, 20 * probabilities * (1 - probabilities), "multinomial")


def test_gamma_white_noise_has_mean_h_and_variance_sigma_squared_h(backend):
    random = streams(backend, 3)
    draws = on(backend, random, lambda xp, random: gamma_white_noise(random, SIGMA, STEP, shape=(PARTICLES,)))
    assert_moments(draws, STEP, SIGMA * SIGMA * STEP, "gamma white noise")


def sir_model(**parameters):
    pfx.load_plugin(str(REPOSITORY / "examples" / "plugins" / "sir.py"))
    return pfx.model("sir", **parameters)


def test_sir_substep_has_the_exact_binomial_moments(backend):
    """One substep from S = 5000, I = 300: the new infections are the infection exit of S's
    Euler multinomial, Bin(S, q) with q = (1 - e^(-(beta I / P + mu) h)) (beta I / P) / (beta I / P + mu)."""
    model = sir_model(substeps=4)
    state = np.broadcast_to(np.array([5000.0, 300.0, 4700.0, 0.0]), (TRIALS, PARTICLES, 4))
    random = streams(backend, 4)
    moved = on(backend, random, lambda xp, random: model.sample_transition(xp.asarray(state), None, [0.0], random))
    h = model.substep_duration
    infection = model.contact_rate * 300.0 / model.population
    q = -np.expm1(-(infection + model.death_rate) * h) * infection / (infection + model.death_rate)
    assert np.all(moved == np.round(moved))
    assert_moments(moved[..., 3], 5000 * q, 5000 * q * (1 - q), "new infections")


def test_sir_filters_on_both_backends_with_the_same_likelihood_distribution():
    """Log-likelihood means within 3 standard errors over 150 runs of each backend (15 weeks,
    2 substeps a week, N = 100)."""
    model = sir_model(substeps=2, steps=15)
    from pfx.models.simulation import simulate_truth

    _, measurements = simulate_truth(model, TrialStreams.from_seeds([3]))
    runs = 150
    estimates = {backend: pfx.filter(model, measurements[0], trials=runs, particles=100, backend=backend,
                                     seed=5).log_likelihood for backend in ("numpy", "jax")}
    numpy_runs, jax_runs = estimates["numpy"], estimates["jax"]
    assert np.isfinite(numpy_runs).all() and np.isfinite(jax_runs).all()
    error = np.sqrt(numpy_runs.var(ddof=1) / runs + jax_runs.var(ddof=1) / runs)
    assert abs(numpy_runs.mean() - jax_runs.mean()) < 3 * error, (numpy_runs.mean(), jax_runs.mean(), error)


def test_the_sir_of_the_docs_is_the_example_plugin():
    """docs/plugins.md shows the SIR's transition and likelihood; each line it shows is in the
    example plugin the tests run, so the docs show code that works."""
    page = (REPOSITORY / "docs" / "plugins.md").read_text()
    start = page.index("<!-- the SIR example: examples/plugins/sir.py -->")
    block = page[page.index("```python", start) + len("```python"):page.index("```", page.index("```python", start) + 9)]
    plugin = (REPOSITORY / "examples" / "plugins" / "sir.py").read_text()
    shown = [line for line in block.splitlines() if line.strip() and line.strip() != "..."]
    assert len(shown) > 15
    missing = [line for line in shown if line not in plugin]
    assert not missing, missing

