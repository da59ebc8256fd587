"""The estimation figures (chain traces, posterior marginals and pairs, IF2 convergence) on
result folders written by hand to the tables' contract (docs/output-files.md).

Two cells (arms ``bootstrap`` and ``guided``, N = 100) estimate two parameters, ``mu`` and
``measurement_noise.variance`` (a dotted name, as the config's paths are). PMMH: 3 chains of
:data:`ITERATIONS` iterations after the starting point, the first :data:`WARM_UP` of them
warm-up, which starts far from the posterior (so a figure that kept warm-up draws would show
it). IF2: 3 replicates of :data:`IF2_ITERATIONS` iterations from scattered starts, each
replicate's final estimate in maximum_likelihood.csv, where the best one is not the last.
"""

from __future__ import annotations

import json

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from pfx.figures import FIGURES, render_figures
from pfx.figures.estimation_chains import chain_traces, parameter_columns, posterior_marginals
from pfx.figures.estimation_pairs import MOST_POINTS_PER_CELL, evenly_thinned, posterior_pairs
from pfx.figures.if2 import if2_convergence
from pfx.result_folder import ResultFolder, write_csv

matplotlib.use("Agg")                  # no screen: draw into memory

PARAMETERS = ["mu", "measurement_noise.variance"]
CELLS = {"a1b2c3d4e5f6": "bootstrap", "0123456789ab": "guided"}   # the second key starts with 0 on purpose
CHAINS, ITERATIONS, WARM_UP = 3, 60, 20
REPLICATES, IF2_ITERATIONS = 3, 15
CENTRE = {"mu": 1.0, "measurement_noise.variance": 50.0}
SPREAD = {"mu": 0.1, "measurement_noise.variance": 5.0}
FIGURE_NAMES = ["chain_traces", "posterior_marginals", "posterior_pairs", "if2_convergence"]


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def _labels(cell: str) -> dict:
    return {"cell": cell, "arm": CELLS[cell], "n_particles": 100}


def _manifest(figures: list[str]) -> dict:
    """The keys of a run's manifest.json that figures read."""
    return {
        "name": "estimation-test", "complete": True, "figures": figures, "formats": ["png"], "trials": 1,
        "config_hash": "0" * 16, "results_hash": "1" * 16, "seed": 7,
        "label_columns": ["arm", "n_particles"], "legend_columns": ["arm"], "units": {"time": "step"},
        "cells": [_labels(cell) for cell in CELLS],
    }


def chains_table(rng, cells=CELLS, chains=CHAINS, iterations=ITERATIONS, warm_up=WARM_UP) -> pd.DataFrame:
    """chains.csv: warm-up iterations near 10x the posterior's centre, then draws around it."""
    rows = []
    for cell in cells:
        for chain in range(chains):
            for iteration in range(iterations + 1):
                in_warm_up = iteration <= warm_up
                row = {**_labels(cell), "chain": chain, "iteration": iteration, "warm_up": in_warm_up}
                for name in PARAMETERS:
                    centre = 10 * CENTRE[name] if in_warm_up else CENTRE[name]
                    row[name] = centre + SPREAD[name] * rng.normal()
                row |= {"log_likelihood": -600 + rng.normal(), "log_prior": -3.0,
                        "accepted": bool(iteration > 0 and rng.uniform() < 0.3)}
                rows.append(row)
    return pd.DataFrame(rows)


def posterior_table(chains: pd.DataFrame) -> pd.DataFrame:
    """posterior.csv's columns the figures read, from the chains' draws after warm-up."""
    rows = []
    for cell, draws in chains[~chains["warm_up"]].groupby("cell", sort=False):
        for index, name in enumerate(PARAMETERS):
            rows.append({**_labels(cell), "parameter": name, "n": len(draws), "mean": draws[name].mean(),
                         "sd": draws[name].std(), "r_hat": 1.001 + index / 100, "ess_bulk": 123.4 + index,
                         "chains": CHAINS})
    return pd.DataFrame(rows)


def priors_table() -> pd.DataFrame:
    """priors.csv: a normal prior on mu, a uniform one on the variance, 200 points each."""
    rows = []
    for value in np.linspace(0.5, 1.5, 200):
        rows.append({"parameter": "mu", "value": value, "density": np.exp(-0.5 * (value - 1) ** 2) / np.sqrt(2 * np.pi)})
    for value in np.linspace(30.0, 70.0, 200):
        rows.append({"parameter": "measurement_noise.variance", "value": value, "density": 1 / 100})
    return pd.DataFrame(rows)


def if2_tables(rng) -> tuple[pd.DataFrame, pd.DataFrame]:
    """if2.csv (starts scattered over two orders of magnitude, converging to the centre) and
    maximum_likelihood.csv (replicate 1 the best in both cells)."""
    rows, finals = [], []
    for cell in CELLS:
        for replicate in range(REPLICATES):
            start = {name: CENTRE[name] * 10.0 ** (replicate - 1) for name in PARAMETERS}
            for iteration in range(IF2_ITERATIONS + 1):
                shrink = 0.7 ** iteration
                row = {**_labels(cell), "replicate": replicate, "iteration": iteration}
                for name in PARAMETERS:
                    row[name] = CENTRE[name] + (start[name] - CENTRE[name]) * shrink
                row["log_likelihood"] = np.nan if iteration == 0 else -600 - 50 * shrink + rng.normal()
                rows.append(row)
            final = {**_labels(cell), "replicate": replicate}
            final |= {name: CENTRE[name] * (1 + 0.01 * replicate) for name in PARAMETERS}
            final |= {"log_likelihood": -598.0 if replicate == 1 else -599.0 - replicate, "log_likelihood_se": 0.05}
            finals.append(final)
    return pd.DataFrame(rows), pd.DataFrame(finals)


def write_folder(path, tables=("chains", "posterior", "priors", "if2", "maximum_likelihood"), seed=0):
    """A finished result folder holding the named tables; returns its path."""
    rng = np.random.default_rng(seed)
    path.mkdir(parents=True, exist_ok=True)
    chains = chains_table(rng)
    if2, maximum_likelihood = if2_tables(rng)
    every = {"chains": chains, "posterior": posterior_table(chains), "priors": priors_table(),
             "if2": if2, "maximum_likelihood": maximum_likelihood}
    for name in tables:
        write_csv(every[name], path / f"{name}.csv")
    (path / "manifest.json").write_text(json.dumps(_manifest(FIGURE_NAMES), indent=2))
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_folder(tmp_path_factory.mktemp("estimation") / "run")


def _lines(axes):
    """The data lines of a panel (not the shaded warm-up, the grid, nor the reference lines)."""
    return [line for line in axes.get_lines() if line.get_linestyle() == "-" and len(line.get_xdata()) > 2]


# -- the tables' parameters ------------------------------------------------------------------------

def test_parameters_are_the_columns_between_the_bookkeeping_and_the_log_likelihood(folder):
    result = ResultFolder(folder)
    assert parameter_columns(result.table("chains"), "warm_up") == PARAMETERS
    assert parameter_columns(result.table("if2"), "iteration") == PARAMETERS
    assert parameter_columns(result.table("priors"), "iteration") == []


def test_thinning_keeps_at_most_the_limit_evenly_from_first_to_last():
    assert evenly_thinned(5).tolist() == [0, 1, 2, 3, 4]
    kept = evenly_thinned(10_000)
    assert len(kept) == MOST_POINTS_PER_CELL and kept[0] == 0 and kept[-1] == 9_999
    assert set(np.diff(kept)) == {5, 6}                  # 9999 / 1999 = 5.002: every fifth draw, or sixth


# -- chain_traces ------------------------------------------------------------------------------------

def test_chain_traces_a_row_per_parameter_and_the_log_likelihood_a_column_per_cell(folder):
    figure = chain_traces(ResultFolder(folder))
    assert isinstance(figure, matplotlib.figure.Figure)
    assert len(figure.axes) == (len(PARAMETERS) + 1) * len(CELLS)
    grid = np.array(figure.axes).reshape(len(PARAMETERS) + 1, len(CELLS))
    chains = ResultFolder(folder).table("chains")
    for column, cell in enumerate(CELLS):
        assert grid[0, column].get_title().startswith(CELLS[cell])
        for row, name in enumerate([*PARAMETERS, "log_likelihood"]):
            lines = _lines(grid[row, column])
            assert len(lines) == CHAINS
            expected = chains[(chains["cell"] == cell) & (chains["chain"] == 1)].sort_values("iteration")
            np.testing.assert_allclose(lines[1].get_ydata(), expected[name])
            np.testing.assert_allclose(lines[1].get_xdata(), np.arange(ITERATIONS + 1))
            shaded = [patch for patch in grid[row, column].patches]
            assert len(shaded) == 1
            x_low, x_high = shaded[0].get_window_extent().x0, shaded[0].get_window_extent().x1
            to_data = grid[row, column].transData.inverted()
            assert to_data.transform((x_low, 0))[0] == pytest.approx(0, abs=1e-6)
            assert to_data.transform((x_high, 0))[0] == pytest.approx(WARM_UP, abs=1e-6)
    assert grid[0, 0].get_ylabel() == "mu" and grid[1, 0].get_ylabel() == "measurement_noise.\nvariance"
    assert f"{CHAINS} chains" in figure._suptitle.get_text()
    assert f"{ITERATIONS} iterations" in figure._suptitle.get_text()
    assert f"first {WARM_UP} warm-up" in figure._suptitle.get_text()


def test_chain_traces_title_gives_the_acceptance_rate_after_warm_up(folder):
    figure = chain_traces(ResultFolder(folder))
    chains = ResultFolder(folder).table("chains")
    for axes, cell in zip(figure.axes[:len(CELLS)], CELLS):
        after = chains[(chains["cell"] == cell) & ~chains["warm_up"]]
        assert f"acceptance after warm-up {after['accepted'].mean():.0%}" in axes.get_title()


def test_one_cell_is_one_column_and_the_title_gives_its_acceptance(tmp_path):
    path = write_folder(tmp_path / "one", tables=())
    one = chains_table(np.random.default_rng(1), cells=["a1b2c3d4e5f6"])
    write_csv(one, path / "chains.csv")
    figure = chain_traces(ResultFolder(path))
    assert len(figure.axes) == len(PARAMETERS) + 1
    assert "acceptance after warm-up" in figure._suptitle.get_text()
    assert figure.legends == []


def test_an_infinite_log_likelihood_is_a_gap_not_a_point(tmp_path):
    path = write_folder(tmp_path / "inf", tables=())
    chains = chains_table(np.random.default_rng(2))
    chains.loc[3, "log_likelihood"] = -np.inf
    write_csv(chains, path / "chains.csv")
    figure = chain_traces(ResultFolder(path))
    first = _lines(figure.axes[len(PARAMETERS) * len(CELLS)])[0]
    assert np.isnan(first.get_ydata()[3]) and np.isfinite(np.delete(first.get_ydata(), 3)).all()


# -- posterior_marginals ---------------------------------------------------------------------------

def test_marginals_are_densities_of_the_draws_after_warm_up(folder):
    result = ResultFolder(folder)
    figure = posterior_marginals(result)
    assert isinstance(figure, matplotlib.figure.Figure)
    assert len(figure.axes) == len(PARAMETERS)
    chains = result.table("chains")
    after = chains[~chains["warm_up"]]
    for axes, name in zip(figure.axes, PARAMETERS):
        assert axes.get_xlabel() == name
        histograms = axes.patches
        assert len(histograms) == len(CELLS)
        for histogram, cell in zip(histograms, CELLS):
            assert histogram.get_label() == CELLS[cell]
            x = histogram.get_path().vertices[:, 0]
            draws = after.loc[after["cell"] == cell, name]
            # only the draws after warm-up (the warm-up ones sit at 10x the centre)
            assert x.min() == pytest.approx(draws.min()) and x.max() == pytest.approx(draws.max())
            assert _area(histogram.get_path().vertices) == pytest.approx(1.0)      # a density


def _area(vertices: np.ndarray) -> float:
    """The area of a polygon (the shoelace formula): a density histogram's outline encloses 1."""
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def test_marginals_draw_the_prior_dashed_and_each_cells_posterior_mean(folder):
    result = ResultFolder(folder)
    figure = posterior_marginals(result)
    priors = result.table("priors")
    posterior = result.table("posterior")
    for axes, name in zip(figure.axes, PARAMETERS):
        prior, = [line for line in axes.get_lines() if line.get_linestyle() == "--"]
        assert prior.get_color() == "black"
        np.testing.assert_allclose(prior.get_ydata(), priors.loc[priors["parameter"] == name, "density"])
        means = [line.get_xdata()[0] for line in axes.get_lines() if line.get_linestyle() == "-"]
        expected = [posterior.loc[(posterior["cell"] == cell) & (posterior["parameter"] == name), "mean"].item()
                    for cell in CELLS]
        np.testing.assert_allclose(means, expected)
    labels = [text.get_text() for text in figure.legends[0].get_texts()]
    assert labels == [*CELLS.values(), "posterior mean", "prior"]


def test_marginals_titles_give_r_hat_and_bulk_ess_per_cell(folder):
    figure = posterior_marginals(ResultFolder(folder))
    assert figure.axes[0].get_title() == "bootstrap: R-hat 1.001, bulk ESS 123\nguided: R-hat 1.001, bulk ESS 123"
    assert "R-hat 1.011, bulk ESS 124" in figure.axes[1].get_title()


def test_marginals_without_posterior_or_priors_still_draw_the_draws(tmp_path):
    path = write_folder(tmp_path / "bare", tables=("chains",))
    figure = posterior_marginals(ResultFolder(path))
    assert len(figure.axes) == len(PARAMETERS)
    assert all(axes.get_title() == "" for axes in figure.axes)
    assert not any(line.get_linestyle() == "--" for axes in figure.axes for line in axes.get_lines())
    chains = ResultFolder(path).table("chains")
    after = chains[~chains["warm_up"] & (chains["cell"] == next(iter(CELLS)))]
    assert figure.axes[0].get_lines()[0].get_xdata()[0] == pytest.approx(after["mu"].mean())


# -- posterior_pairs -------------------------------------------------------------------------------

def test_pairs_scatter_below_histograms_on_the_diagonal_correlations_above(folder):
    result = ResultFolder(folder)
    figure = posterior_pairs(result)
    count = len(PARAMETERS)
    assert isinstance(figure, matplotlib.figure.Figure)
    assert len(figure.axes) == count * count
    grid = np.array(figure.axes).reshape(count, count)
    after = result.table("chains")
    after = after[~after["warm_up"]]
    for row in range(count):
        assert len(grid[row, row].patches) == len(CELLS)
        assert grid[row, row].get_title() == PARAMETERS[row]
    scatters = grid[1, 0].collections
    assert len(scatters) == len(CELLS)
    for scatter, cell in zip(scatters, CELLS):
        draws = after[after["cell"] == cell]
        np.testing.assert_allclose(scatter.get_offsets(), draws[[PARAMETERS[0], PARAMETERS[1]]].to_numpy())
    texts = [text.get_text() for text in grid[0, 1].texts]
    expected = [f"corr {np.corrcoef(after.loc[after['cell'] == cell, PARAMETERS].to_numpy().T)[0, 1]:.2f}"
                for cell in CELLS]
    assert texts == expected
    assert grid[1, 0].get_xlabel() == PARAMETERS[0] and grid[1, 0].get_ylabel() == "measurement_noise.\nvariance"
    assert [text.get_text() for text in figure.legends[0].get_texts()] == list(CELLS.values())


def test_pairs_thin_a_long_run_to_at_most_the_limit_per_cell(tmp_path):
    path = write_folder(tmp_path / "long", tables=())
    long = chains_table(np.random.default_rng(3), chains=4, iterations=700, warm_up=100)   # 2400 draws a cell
    write_csv(long, path / "chains.csv")
    figure = posterior_pairs(ResultFolder(path))
    scatter_panel = figure.axes[len(PARAMETERS)]           # row 1, column 0
    for scatter in scatter_panel.collections:
        assert len(scatter.get_offsets()) == MOST_POINTS_PER_CELL
    assert "2400 per cell" in figure._suptitle.get_text()


# -- if2_convergence -------------------------------------------------------------------------------

def test_if2_a_panel_per_parameter_and_the_log_likelihood_a_line_per_replicate(folder):
    result = ResultFolder(folder)
    figure = if2_convergence(result)
    assert isinstance(figure, matplotlib.figure.Figure)
    assert len(figure.axes) == len(PARAMETERS) + 1
    if2 = result.table("if2")
    for axes, name in zip(figure.axes, [*PARAMETERS, "log_likelihood"]):
        lines = _lines(axes)
        assert len(lines) == REPLICATES * len(CELLS)
        assert [line.get_color() for line in lines] == ["C0"] * REPLICATES + ["C1"] * REPLICATES
        first = if2[(if2["cell"] == next(iter(CELLS))) & (if2["replicate"] == 0)].sort_values("iteration")
        np.testing.assert_allclose(lines[0].get_ydata(), first[name])
        assert axes.get_xlabel() == "IF2 iteration"
    assert np.isnan(_lines(figure.axes[-1])[0].get_ydata()[0])          # iteration 0 has no likelihood
    assert figure.axes[0].get_yscale() == "log"        # starts at 0.1, 1 and 10 times the centre
    assert f"{REPLICATES} replicates x {IF2_ITERATIONS} iterations" in figure._suptitle.get_text()


def test_if2_dashes_the_best_replicates_estimate_not_the_last(folder):
    result = ResultFolder(folder)
    figure = if2_convergence(result)
    maximum_likelihood = result.table("maximum_likelihood")
    for axes, name in zip(figure.axes, [*PARAMETERS, "log_likelihood"]):
        dashed = [line for line in axes.get_lines() if line.get_linestyle() == "--"]
        assert len(dashed) == len(CELLS)
        for line, cell in zip(dashed, CELLS):
            best = maximum_likelihood[(maximum_likelihood["cell"] == cell) & (maximum_likelihood["replicate"] == 1)]
            assert line.get_ydata()[0] == pytest.approx(best[name].item())
    assert figure.axes[-1].get_title() == "best -598.00 (se 0.05) (bootstrap)\nbest -598.00 (se 0.05) (guided)"
    labels = [text.get_text() for text in figure.legends[0].get_texts()]
    assert labels == [*CELLS.values(), "best replicate's estimate (highest log-likelihood)"]


def test_if2_without_maximum_likelihood_draws_the_paths_alone(tmp_path):
    path = write_folder(tmp_path / "paths", tables=("if2",))
    figure = if2_convergence(ResultFolder(path))
    assert not any(line.get_linestyle() == "--" for axes in figure.axes for line in axes.get_lines())


# -- nothing to draw, and the registry -------------------------------------------------------------

@pytest.mark.parametrize("name, table", [("chain_traces", "chains"), ("posterior_marginals", "chains"),
                                         ("posterior_pairs", "chains"), ("if2_convergence", "if2")])
def test_a_folder_without_the_table_has_nothing_to_draw(tmp_path, name, table):
    others = tuple(t for t in ("chains", "posterior", "priors", "if2", "maximum_likelihood") if t != table)
    path = write_folder(tmp_path / "without", tables=others)
    assert FIGURES[name](ResultFolder(path)) is None
    (path / f"{table}.csv").write_text("")                       # an empty file
    assert FIGURES[name](ResultFolder(path)) is None


def test_chains_still_in_warm_up_have_traces_but_no_posterior(tmp_path):
    path = write_folder(tmp_path / "warming", tables=())
    write_csv(chains_table(np.random.default_rng(4), warm_up=ITERATIONS), path / "chains.csv")
    result = ResultFolder(path)
    assert chain_traces(result) is not None
    assert posterior_marginals(result) is None and posterior_pairs(result) is None


def test_render_figures_writes_the_four(tmp_path):
    path = write_folder(tmp_path / "render")
    written = render_figures(path)
    assert sorted(target.name for target in written) == sorted(f"{name}.png" for name in FIGURE_NAMES)
    assert all(target.stat().st_size > 10_000 for target in written)


def test_marginals_keep_the_posteriors_scale_under_a_flat_prior(tmp_path):
    """A flat prior on (0, inf) writes density 1 into priors.csv whatever the units: the axes keep
    the histograms' scale (their densities, about 0.08 here, stay visible) and say where the prior is."""
    path = write_folder(tmp_path / "flat")
    priors = priors_table()
    flat = priors["parameter"] == "measurement_noise.variance"
    priors.loc[flat, "density"] = 1.0
    priors.loc[flat.idxmax(), "density"] = 0.0             # the support's open edge, as priors.csv has it
    write_csv(priors, path / "priors.csv")
    figure = posterior_marginals(ResultFolder(path))
    axes = figure.axes[PARAMETERS.index("measurement_noise.variance")]
    top = axes.get_ylim()[1]
    bars = max(patch.get_path().vertices[:, 1].max() for patch in axes.patches)
    assert bars <= top < 1.0 and bars > 0.5 * top
    assert any("prior above the axes" in text.get_text() for text in axes.texts)
    assert not any("prior above the axes" in text.get_text() for text in figure.axes[PARAMETERS.index("mu")].texts)
