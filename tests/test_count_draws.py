"""``filter.count_draws``: the filter's binomial, Poisson and gamma draws by NumPy's (JAX's) exact
samplers or by branch-free inverse CDFs (pfx/numerics/count_quantiles.py), on both backends.

* the streams: ``with_count_draws`` is the same generators (a draw from one advances the other),
  and the streams derived from them (a subset, the score and forecast streams) keep the setting;
* the count laws drawn the inverse-CDF way have their exact moments, within 4 standard errors,
  as test_count_transitions.py asks of the exact samplers;
* the SIR example filtered with inverse-CDF draws has the likelihood distribution of the exact
  draws' (means within 3 standard errors over 120 runs), on each backend;
* the setting in a config: recorded in config.yaml only when it is not ``exact`` (so every
  config without it keeps its record and its cell keys), and a bad value is one line, exit 2.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from test_count_transitions import PARTICLES, TRIALS, assert_moments, on, sir_model, streams

import pfx
from pfx.laws.count_transitions import euler_multinomial
from pfx.models.simulation import simulate_truth
from pfx.numerics.seeding import TrialStreams

pytestmark = pytest.mark.usefixtures("fresh_plugins")


def test_the_inverse_cdf_streams_are_the_same_generators_and_pass_the_setting_on():
    plain = TrialStreams.from_seeds([11, 12])
    fresh = TrialStreams.from_seeds([11, 12])
    view = plain.with_count_draws("inverse_cdf")
    assert view.count_draws == "inverse_cdf" and plain.count_draws == "exact" and view.seeds == [11, 12]
    view.uniform((3,))
    assert np.array_equal(plain.uniform((1,)), fresh.uniform((4,))[:, 3:])      # one stream, advanced by both
    assert view.subset([1]).count_draws == "inverse_cdf"
    assert view.derived(1).count_draws == "inverse_cdf"
    with pytest.raises(ValueError, match="count_draws must be one of exact, inverse_cdf"):
        plain.with_count_draws("fast")


def inverse(random):
    return random.with_count_draws("inverse_cdf")


def test_the_count_laws_drawn_by_inverse_cdfs_have_their_exact_moments(backend):
    random = inverse(streams(backend, 7000))
    count = np.repeat(np.array([3.0, 40.0, 2.0e5]), -(-TRIALS // 3))[:TRIALS, None]    # (R, 1): one n per trial
    draws = on(backend, random, lambda xp, random: random.binomial(xp.asarray(count), 0.3, shape=(PARTICLES,)))
    assert draws.shape == (TRIALS, PARTICLES) and np.all(draws == np.round(draws))
    for n in (3.0, 40.0, 2.0e5):
        assert_moments(draws[count[:, 0] == n], n * 0.3, n * 0.3 * 0.7, f"binomial n={n}")
    for rate in (0.02, 7.5, 3.0e4):         # the summed terms, Giles' region, far in it
        rates = np.full((TRIALS, PARTICLES), rate)
        assert_moments(on(backend, random, lambda xp, random: random.poisson(xp.asarray(rates))), rate, rate,
                       f"poisson {rate}")
    rates = np.array([0.3, 0.1, 0.05])
    counts = np.full((TRIALS, PARTICLES), 50.0)
    exits = on(backend, random, lambda xp, random: euler_multinomial(
        random, xp.asarray(counts), xp.asarray(np.broadcast_to(rates, (TRIALS, PARTICLES, 3))), 1.5))
    share = -np.expm1(-rates.sum() * 1.5) * rates / rates.sum()
    assert np.all(exits.sum(axis=-1) <= 50)
    assert_moments(exits, 50 * share, 50 * share * (1 - share), "euler_multinomial")


@pytest.mark.parametrize("backend_name", ["numpy", "jax"])
def test_the_sir_filtered_with_inverse_cdf_draws_has_the_exact_draws_likelihood(backend_name):
    """Log-likelihood means within 3 standard errors over 120 runs each (10 weeks, 2 substeps a
    week, N = 60), the exact draws against the inverse-CDF ones, on one backend."""
    model = sir_model(substeps=2, steps=10)
    _, measurements = simulate_truth(model, TrialStreams.from_seeds([3]))
    runs = 120
    estimates = {mode: pfx.filter(model, measurements[0], trials=runs, particles=60, backend=backend_name,
                                  count_draws=mode, seed=5 if mode == "exact" else 6).log_likelihood
                 for mode in ("exact", "inverse_cdf")}
    exact, inverse_cdf = estimates["exact"], estimates["inverse_cdf"]
    assert np.isfinite(exact).all() and np.isfinite(inverse_cdf).all()
    error = np.sqrt(exact.var(ddof=1) / runs + inverse_cdf.var(ddof=1) / runs)
    assert abs(exact.mean() - inverse_cdf.mean()) < 3 * error, (exact.mean(), inverse_cdf.mean(), error)


def test_the_setting_is_recorded_only_when_it_changes_the_draws(pfx_in_process, tmp_path, tiny_config_dict):
    config = tiny_config_dict()
    runs = {}
    for mode in (None, "exact", "inverse_cdf"):
        if mode is not None:
            config["filter"]["count_draws"] = mode
        path = tmp_path / f"{mode}.yaml"
        path.write_text(yaml.safe_dump(config))
        result = pfx_in_process("run", path, "--out", tmp_path / str(mode), "--quiet", cwd=tmp_path)
        assert result.returncode == 0, result.output
        runs[mode] = yaml.safe_load((tmp_path / str(mode) / "config.yaml").read_text())
    assert "count_draws" not in runs[None]["filter"] and "count_draws" not in runs["exact"]["filter"]
    assert runs["inverse_cdf"]["filter"]["count_draws"] == "inverse_cdf"
    keys = {mode: (tmp_path / str(mode) / "trials.csv").read_text().splitlines()[1].split(",")[0] for mode in runs}
    assert keys[None] == keys["exact"] != keys["inverse_cdf"]          # a changed setting is a changed cell
    config["filter"]["count_draws"] = "fast"
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(config))
    refused = pfx_in_process("run", tmp_path / "bad.yaml", "--out", tmp_path / "bad", cwd=tmp_path)
    assert refused.returncode == 2 and "filter.count_draws" in refused.output and len(refused.output.splitlines()) == 1
    assert not (tmp_path / "bad").exists()
