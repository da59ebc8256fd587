"""The GBP/USD stochastic-volatility example (examples/plugins/gbp-usd-volatility.yaml;
docs/recorded-data.md, "Example: GBP/USD daily returns").

* the data: the returns file is 100 x the differences of the log-rates of the rates file, to
  the 10 decimals it is printed with; 202 rates, 201 returns;
* the bootstrap filter on the recorded returns, through the command line: the variance of its
  log-likelihood estimate falls like 1/N (a ratio of sample variances against the F
  distribution), and its mean, corrected for the log's bias, agrees with the exact
  log-likelihood, computed here by quadrature on a fine grid (independently of pfx).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from conftest import REPO_ROOT
from scipy import stats

CONFIG = REPO_ROOT / "examples" / "plugins" / "gbp-usd-volatility.yaml"
RATES = REPO_ROOT / "examples" / "data" / "gbp-usd-rates.csv"
RETURNS = REPO_ROOT / "examples" / "data" / "gbp-usd-returns.csv"
MU, PHI, SIGMA = 2 * math.log(0.5992), 0.9702, 0.178          # Pitt & Shephard (1999)


def returns() -> np.ndarray:
    return pd.read_csv(RETURNS)["z1"].to_numpy(dtype=float)


def quadrature_log_likelihood(y: np.ndarray, points: int = 1500, width: float = 10.0) -> float:
    """log p(y_1..T) of the stochastic-volatility model, by the grid recursion: the filtering
    distribution as masses on `points` equally spaced states over mu +- `width` stationary sd;
    predict with the AR(1) transition density, weight with N(y; 0, e^x). x_0 is stationary, so
    x_1 is too (pfx's x_1 is the book's X_0: the same law for the whole path). The grid's error
    is far below the particle filters' (doubling the points moves the result by < 1e-9)."""
    stationary_sd = SIGMA / math.sqrt(1 - PHI**2)
    x = np.linspace(MU - width * stationary_sd, MU + width * stationary_sd, points)
    mass = np.exp(-0.5 * ((x - MU) / stationary_sd) ** 2)
    mass /= mass.sum()
    step = x[1] - x[0]
    kernel = np.exp(-0.5 * ((x[:, None] - MU - PHI * (x[None, :] - MU)) / SIGMA) ** 2) * step / (
        SIGMA * math.sqrt(2 * math.pi))                                    # p(x_i | x_j) dx
    total = 0.0
    for value in y:
        joint = (kernel @ mass) * np.exp(-0.5 * (math.log(2 * math.pi) + x + value**2 * np.exp(-x)))
        evidence = joint.sum()
        total += math.log(evidence)
        mass = joint / evidence
    return total


def test_returns_are_derived_from_the_rates():
    rates = pd.read_csv(RATES, dtype={"date": str})
    assert list(rates.columns) == ["date", "rate"] and len(rates) == 202
    assert rates["date"].iloc[0] == "1997/01/02" and rates["date"].iloc[-1] == "1997/10/20"
    assert rates["rate"].iloc[0] == 0.59296 and rates["rate"].iloc[-1] == 0.6135
    data = pd.read_csv(RETURNS)
    assert list(data.columns) == ["step", "z1"] and data["step"].tolist() == list(range(1, 202))
    derived = 100.0 * np.diff(np.log(rates["rate"].to_numpy()))
    # printed with 10 decimals: rounding moves a value by at most 5e-11 (plus float error)
    assert np.max(np.abs(data["z1"].to_numpy() - derived)) <= 0.5e-10 + 1e-12


def test_the_quadrature_reference_has_converged():
    y = returns()
    assert abs(quadrature_log_likelihood(y) - quadrature_log_likelihood(y, points=2400, width=12.0)) < 1e-8


def test_log_likelihood_variance_falls_like_one_over_n(pfx_in_process, tmp_path):
    """The shipped config at N = 100 and 400, 100 trials each (independent filter seeds).

    For fixed T the log of the particle likelihood estimate is asymptotically normal with
    variance c / N (Berard, Del Moral & Doucet 2014). With R trials per N, the sample variances
    s_N^2 are independent and (R - 1) s_N^2 / (c / N) ~ chi-square(R - 1), so

        F = (s_100^2 / s_400^2) / (400 / 100) ~ F(R - 1, R - 1);

    the test accepts F within the central 99.9 % of that law (for R = 100 about [0.51, 1.95]:
    the variance ratio between 2.0 and 7.8, where 1/N scaling says 4). Then the mean: the
    likelihood estimate is unbiased, its log biased low by var / 2, so mean + s^2 / 2 at
    N = 400 must lie within 4 standard errors of the exact log-likelihood (quadrature), with
    se^2 = s^2 / R + s^4 / (2 (R - 1)) (the mean's and the half-variance's, for normal data)."""
    trials = 100
    result = pfx_in_process("run", CONFIG, "--out", tmp_path / "gbp", "--trials", str(trials),
                            "--set", "sweep.filter.particles=[100, 400]")
    assert result.returncode == 0, result.output
    table = pd.read_csv(tmp_path / "gbp" / "trials.csv")
    estimates = {n: group["log_likelihood"].to_numpy() for n, group in table.groupby("n_particles")}
    assert sorted(estimates) == [100, 400] and all(len(v) == trials for v in estimates.values())
    seeds = {n: set(group["filter_seed"]) for n, group in table.groupby("n_particles")}
    assert not seeds[100] & seeds[400]                   # independent cells: F, not a paired law

    variance = {n: v.var(ddof=1) for n, v in estimates.items()}
    ratio = (variance[100] / variance[400]) / (400 / 100)
    low, high = stats.f.ppf([0.0005, 0.9995], trials - 1, trials - 1)
    assert low < ratio < high, (variance, ratio, (low, high))

    exact = quadrature_log_likelihood(returns())
    s2 = variance[400]
    standard_error = math.sqrt(s2 / trials + s2**2 / (2 * (trials - 1)))
    corrected = estimates[400].mean() + s2 / 2
    assert abs(corrected - exact) < 4 * standard_error, (corrected, exact, standard_error)
