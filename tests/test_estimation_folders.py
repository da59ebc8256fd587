"""Estimation folders keep the user's chains: an interrupted PMMH or IF2 run resumes to the very
numbers of an uninterrupted one; a refused run (fewer iterations, a damaged progress file, a
start the model refuses) changes nothing; a parameter cannot take a column's name; a damaged
progress file is refused, naming it and its line, never read as data; a likelihood that is zero
everywhere is said, not a crash; a figure asked of a folder it cannot draw is refused.

The configs are tiny (25 simulated steps, 40 particles, 2 chains, a few iterations) and run in
this process (``pfx.run``); one test each goes through the command line where the command's own
behaviour (its exit status and one line, a real SIGTERM) is what is checked.
"""

from __future__ import annotations

import copy
import importlib
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, _environment, tiny_config_dict, write_config_file

import pfx
from pfx.config.estimation_tables import (
    CHAINS,
    IF2,
    MAXIMUM_LIKELIHOOD,
    POSTERIOR_COLUMNS,
    PRIORS_COLUMNS,
    reserved_names,
)
from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.estimation.if2 import IteratedFiltering, log_mean_likelihood
from pfx.estimation.pmmh import ParticleMarginalMetropolisHastings

TABLES = {"pmmh": ("chains.csv", "posterior.csv", "priors.csv"), "if2": ("if2.csv", "maximum_likelihood.csv")}
SAMPLER = {"pmmh": ParticleMarginalMetropolisHastings, "if2": IteratedFiltering}
PROCESS = "model.process_noise.variance"
MEASUREMENT = "model.measurement_noise.variance"


def estimation_config(method: str = "pmmh", **estimation) -> dict:
    """A tiny estimation config: both variances of a simulated local level, 2 chains."""
    config = {
        "name": f"tiny-{method}", "seed": 11,
        "model": {"kind": "linear_gaussian", "steps": 25, "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                  "process_noise": {"variance": 1.0}, "measurement_noise": {"variance": 2.0}},
        "filter": {"particles": 40, "resampler": "systematic"},
        "outputs": {"figures": []},
        "estimation": {"method": method, "chains": 2, "iterations": 6,
                       "parameters": {PROCESS: {"prior": {"law": "flat", "lower": 0.0}, "start": [0.5, 2.0]},
                                      MEASUREMENT: {"prior": {"law": "flat", "lower": 0.0}, "start": 1.5}}}}
    if method == "pmmh":
        config["estimation"]["warm_up"] = 2
    config["estimation"].update(estimation)
    return config


def with_parameter(config: dict, path: str = PROCESS, **settings) -> dict:
    config = copy.deepcopy(config)
    config["estimation"]["parameters"][path].update(settings)
    return config


def snapshot(folder: Path) -> dict:
    """Every file of a folder: its bytes, modification time and inode (a file rewritten, even
    with the same bytes, is a new file)."""
    return {str(path.relative_to(folder)): (path.read_bytes(), path.stat().st_mtime_ns, path.stat().st_ino)
            for path in sorted(folder.rglob("*")) if path.is_file()}


def tables_of(folder: Path, method: str) -> dict[str, bytes]:
    return {name: (folder / name).read_bytes() for name in TABLES[method]}


def progress_path(folder: Path) -> Path:
    (path,) = (folder / "estimation").glob("*.csv")
    return path


def interrupt_at(monkeypatch, method: str, stop: int) -> None:
    """The method's iteration ``stop`` raises KeyboardInterrupt (Ctrl-C, or SIGTERM as the
    command turns it), as if the user stopped the run there."""
    sampler = SAMPLER[method]
    original = sampler.iterate

    def iterate(self, state, iteration):
        if iteration == stop:
            raise KeyboardInterrupt
        return original(self, state, iteration)

    monkeypatch.setattr(sampler, "iterate", iterate)


# -- interrupts ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["pmmh", "if2"])
def test_an_interrupted_run_resumes_to_the_numbers_of_an_uninterrupted_one(method, tmp_path, monkeypatch):
    whole = pfx.run(estimation_config(method), out=tmp_path / "whole")
    with monkeypatch.context() as patch:
        interrupt_at(patch, method, 3)
        with pytest.raises(KeyboardInterrupt) as stopped:
            pfx.run(estimation_config(method), out=tmp_path / "stopped")
    assert "run the same command again to resume" in stopped.value.__notes__[-1]
    kept = pd.read_csv(progress_path(tmp_path / "stopped"))
    assert kept["iteration"].max() == 2           # iterations 1 and 2 are kept: PMMH's at the interrupt itself
    resumed = pfx.run(estimation_config(method), out=tmp_path / "stopped")
    assert tables_of(resumed.folder, method) == tables_of(whole.folder, method)
    assert resumed.manifest["complete"] is True


def test_an_if2_pass_whose_swarm_was_not_saved_is_computed_again(tmp_path, monkeypatch):
    """A run stopped between writing a pass's estimates and its swarm leaves the table one pass
    ahead: the next run computes that pass again, to the same numbers."""
    running = importlib.import_module("pfx.run.estimation")       # pfx.run is also the function pfx.run

    whole = pfx.run(estimation_config("if2"), out=tmp_path / "whole")
    original, calls = running.save_swarm, []

    def save_swarm(swarm, path):
        calls.append(path)
        if len(calls) == 3:
            raise KeyboardInterrupt
        original(swarm, path)

    with monkeypatch.context() as patch:
        patch.setattr(running, "save_swarm", save_swarm)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(estimation_config("if2"), out=tmp_path / "stopped")
    assert pd.read_csv(progress_path(tmp_path / "stopped"))["iteration"].max() == 3
    resumed = pfx.run(estimation_config("if2"), out=tmp_path / "stopped")
    assert tables_of(resumed.folder, "if2") == tables_of(whole.folder, "if2")


def test_a_run_stopped_before_keeping_anything_leaves_no_folder(tmp_path, monkeypatch):
    with monkeypatch.context() as patch:
        interrupt_at(patch, "if2", 1)
        with pytest.raises(KeyboardInterrupt) as stopped:
            pfx.run(estimation_config("if2"), out=tmp_path / "out")
    assert "nothing was kept" in stopped.value.__notes__[-1]
    assert not (tmp_path / "out").exists()
    pfx.run(estimation_config("if2", iterations=2), out=tmp_path / "out")      # another config: no folder in its way


def test_sigterm_stops_a_run_that_the_same_command_resumes(tmp_path, run_pfx):
    """The command line, for real: SIGTERM during the chains keeps them (exit 143, one line),
    and the same command finishes them to the numbers of a run never stopped."""
    config = estimation_config("pmmh", iterations=80, warm_up=20)      # a second or two of chains
    path = write_config_file(tmp_path, config, "long.yaml")
    out = tmp_path / "stopped"
    command = [sys.executable, "-m", "pfx", "run", str(path), "--out", str(out), "--quiet"]
    process = subprocess.Popen(command, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=_environment(), stdin=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not (out / "manifest.json").exists() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)              # the manifest is written once the starts are checked, as the chains begin
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGTERM, stderr
    assert stderr.strip().count("\n") == 0 and "Traceback" not in stderr
    assert "interrupted by SIGTERM" in stderr and "run the same command again to resume" in stderr
    assert pd.read_csv(progress_path(out))["iteration"].max() < 80          # the rows so far, saved at the stop
    again = run_pfx("run", str(path), "--out", str(out), "--quiet")
    assert again.returncode == 0, again.output
    whole = pfx.run(config, out=tmp_path / "whole")
    assert tables_of(out, "pmmh") == tables_of(whole.folder, "pmmh")


@pytest.mark.parametrize("method", ["pmmh", "if2"])
def test_running_a_finished_folder_again_is_up_to_date_and_touches_nothing(method, tmp_path, monkeypatch):
    """The same config on its finished folder recomputes nothing (IF2's final evaluations
    included: a search of an hour would otherwise spend minutes on them again) and rewrites no file."""
    folder = pfx.run(estimation_config(method), out=tmp_path / "out").folder
    before = snapshot(folder)
    monkeypatch.setattr(SAMPLER[method], "__init__", lambda *arguments, **keywords: pytest.fail("recomputed"))
    again = pfx.run(estimation_config(method), out=folder)
    assert snapshot(folder) == before and again.manifest["complete"] is True


# -- a refused run changes nothing -------------------------------------------------------------------------

def test_asking_a_finished_folder_for_fewer_iterations_changes_nothing(tmp_path):
    folder = pfx.run(estimation_config(), out=tmp_path / "out").folder
    before = snapshot(folder)
    with pytest.raises(ConfigError, match="would drop") as refused:
        pfx.run(estimation_config(iterations=4), out=folder)
    assert refused.value.key == "estimation.iterations"
    assert snapshot(folder) == before
    assert pfx.load(folder).manifest["complete"] is True                  # still a finished folder
    longer = pfx.run(estimation_config(iterations=8), out=folder)        # and still extended
    assert len(longer.chains) == 2 * 9


def test_an_interrupted_folder_asked_for_fewer_iterations_than_it_holds_changes_nothing(tmp_path, monkeypatch):
    with monkeypatch.context() as patch:
        interrupt_at(patch, "pmmh", 5)
        with pytest.raises(KeyboardInterrupt):
            pfx.run(estimation_config(), out=tmp_path / "out")
    before = snapshot(tmp_path / "out")
    with pytest.raises(ConfigError, match="holds 4 iterations") as refused:
        pfx.run(estimation_config(iterations=3), out=tmp_path / "out")
    assert refused.value.key == "estimation.iterations"
    assert snapshot(tmp_path / "out") == before


def test_a_bad_start_refused_with_fresh_changes_nothing(tmp_path):
    folder = pfx.run(estimation_config(), out=tmp_path / "out").folder
    before = snapshot(folder)
    bad = with_parameter(estimation_config(), prior={"law": "normal", "mean": 1.0, "sd": 5.0}, transform="none",
                         start=[-1.0, 2.0])
    with pytest.raises(ConfigError, match="chain 0 starts"):
        pfx.run(bad, out=folder, fresh=True)
    assert snapshot(folder) == before


# -- chain starts --------------------------------------------------------------------------------------------

NORMAL = {"prior": {"law": "normal", "mean": 1.0, "sd": 5.0}, "transform": "none"}
STARTS = {
    "a start in a list": ("pmmh", {**NORMAL, "start": [-1.0, 2.0]}, f"estimation.parameters.{PROCESS}.start",
                          "chain 0 starts at process_noise.variance=-1, where the model refuses it"),
    "a start drawn from the prior": ("pmmh", {"prior": {"law": "normal", "mean": -50.0, "sd": 1.0}, "transform": "none",
                                              "start": "prior"},
                                     f"estimation.parameters.{PROCESS}.start", "(drawn from the prior: start: prior)"),
    "an IF2 replicate's start": ("if2", {**NORMAL, "start": [2.0, -3.0]}, f"estimation.parameters.{PROCESS}.start",
                                 "replicate 1 starts at process_noise.variance=-3, where the model refuses it"),
}


@pytest.mark.parametrize("case", list(STARTS))
def test_a_start_the_model_refuses_is_one_config_error_and_leaves_nothing(case, tmp_path):
    method, settings, key, words = STARTS[case]
    with pytest.raises(ConfigError) as refused:
        pfx.run(with_parameter(estimation_config(method), **settings), out=tmp_path / "out")
    assert refused.value.key == key and words in str(refused.value), str(refused.value)
    assert refused.value.file == "<dict>"
    assert not (tmp_path / "out").exists()
    pfx.run(estimation_config(method, iterations=3), out=tmp_path / "out")       # the corrected config runs


@pytest.mark.parametrize("method, chain", [("pmmh", "chain"), ("if2", "replicate")])
def test_a_start_where_the_data_have_zero_likelihood_is_refused(method, chain, tmp_path):
    config = estimation_config(method)
    del config["estimation"]["parameters"][MEASUREMENT]
    config["model"]["measurement_noise"] = {"family": "uniform", "variance": 1e-6}   # no particle can explain a z
    with pytest.raises(ConfigError, match=f"{chain} 0 starts at process_noise.variance=0.5, where the data have "
                                          "zero likelihood") as refused:
        pfx.run(config, out=tmp_path / "out")
    assert refused.value.key == f"estimation.parameters.{PROCESS}.start"
    assert not (tmp_path / "out").exists()


def test_the_command_line_refuses_a_bad_start_in_one_line(tmp_path, run_pfx):
    config = with_parameter(estimation_config(), **STARTS["a start in a list"][1])
    path = write_config_file(tmp_path, config, "bad-start.yaml")
    result = run_pfx("run", str(path), "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert result.stderr.strip() == (f"pfx: error: {path}: estimation.parameters.{PROCESS}.start: chain 0 starts at "
                                     "process_noise.variance=-1, where the model refuses it: model.process_noise."
                                     "variance: variances must be >= 0; give each chain a start the model accepts, "
                                     "or a prior inside the model's range")
    assert not (tmp_path / "out").exists()


# -- column names --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["pmmh", "if2"])
@pytest.mark.parametrize("name", ["log_likelihood", "log_prior", "chain", "iteration", "replicate", "warm_up",
                                  "accepted", "cell", "log_likelihood_se", "parameter", "mean", "r_hat", "density"])
def test_a_parameter_named_like_a_table_column_is_refused(method, name):
    config = with_parameter(estimation_config(method), name=name)
    with pytest.raises(ConfigError, match="give it another `name`") as refused:
        build_plan(config, "names.yaml")
    assert refused.value.key == f"estimation.parameters.{PROCESS}.name"


@pytest.mark.parametrize("name, sweep", [("arm", None), ("n_particles", None), ("model_steps", {"model.steps": [20, 25]})])
def test_a_parameter_named_like_a_cell_label_is_refused(name, sweep):
    config = with_parameter(estimation_config(), name=name)
    if sweep:
        config["sweep"] = sweep
    with pytest.raises(ConfigError, match="label columns") as refused:
        build_plan(config, "names.yaml")
    assert refused.value.key == f"estimation.parameters.{PROCESS}.name"


@pytest.mark.parametrize("method", ["pmmh", "if2"])
def test_the_tables_have_the_columns_of_their_layouts_and_no_other(method, tmp_path):
    """The reserved names are the layouts' columns; a table with a column the layouts lack would
    let a parameter collide with it unseen."""
    config = estimation_config(method, iterations=3)
    config["arms"] = {"small": {"particles": 30}, "large": {}}
    result = pfx.run(config, out=tmp_path / "out")
    labels, parameters = result.manifest["label_columns"], ["process_noise.variance", "measurement_noise.variance"]
    expected = {"chains": CHAINS.columns(labels, parameters), "posterior": ["cell", *labels, *POSTERIOR_COLUMNS],
                "priors": list(PRIORS_COLUMNS), "if2": IF2.columns(labels, parameters),
                "maximum_likelihood": MAXIMUM_LIKELIHOOD.columns(labels, parameters)}
    for name in result.table_names:
        columns = list(result.table(name).columns)
        assert columns == expected[name], name
        assert set(columns) - set(parameters) <= reserved_names() | set(labels)


# -- damaged progress files ----------------------------------------------------------------------------------

def cut(text: str) -> str:
    return text[:-7]


def replace_line(number: int, edit):
    def damage(text: str) -> str:
        lines = text.split("\n")
        lines[number - 1] = edit(lines[number - 1])
        return "\n".join(lines)
    return damage


def drop_line(number: int):
    def damage(text: str) -> str:
        lines = text.split("\n")
        del lines[number - 1]
        return "\n".join(lines)
    return damage


def field(position: int, value: str):
    return replace_line(6, lambda line: ",".join(value if i == position else f for i, f in enumerate(line.split(","))))


# (damage to the 6-iteration PMMH progress file of 2 chains: lines 2..15, words in the message, line named)
DAMAGES = {
    "a cut last row": (cut, "the last row is cut short", 15),
    "a cut within an iteration": (lambda text: "\n".join(text.split("\n")[:12]) + "\n",
                                  "the file ends within iteration 5, with 1 of its 2 rows", 13),
    "a cut between iterations": (lambda text: "\n".join(text.split("\n")[:11]) + "\n",
                                 "holds iterations 0 to 4, and the folder's manifest.json records a finished run of 6",
                                 12),
    "other columns": (replace_line(1, lambda line: line.replace("log_prior", "prior")), "its columns are", 1),
    "a value that is not a number": (field(3, "abc"), "process_noise.variance is 'abc', not a finite number", 6),
    "a missing row": (drop_line(6), "chain 1 of iteration 2 where chain 0 of iteration 2 belongs", 6),
    "a repeated row": (lambda text: text.replace("\n", "\n" + text.split("\n")[1] + "\n", 1),
                       "chain 0 of iteration 0 where chain 1 of iteration 0 belongs", 3),
    "a flag that is not True or False": (field(7, "Tru"), "accepted is 'Tru', not True or False", 6),
    "an extra field": (replace_line(6, lambda line: line + ",1"), "9 fields, not 8", 6),
    "an empty file": (lambda text: "", "is empty", None),
}


@pytest.mark.parametrize("case", list(DAMAGES))
def test_a_damaged_progress_file_is_refused_naming_it_and_its_line(case, tmp_path):
    damage, words, line = DAMAGES[case]
    folder = pfx.run(estimation_config(), out=tmp_path / "out").folder
    path = progress_path(folder)
    path.write_text(damage(path.read_text()))
    before = snapshot(folder)
    with pytest.raises(ConfigError, match="something else") as refused:
        pfx.run(estimation_config(iterations=8), out=folder)
    assert words in refused.value.reason, refused.value.reason
    assert (refused.value.file, refused.value.line) == (str(path), line)
    assert snapshot(folder) == before


def test_a_missing_progress_file_of_a_finished_folder_is_refused(tmp_path):
    folder = pfx.run(estimation_config(), out=tmp_path / "out").folder
    path = progress_path(folder)
    path.unlink()
    with pytest.raises(ConfigError, match="is missing") as refused:
        pfx.run(estimation_config(iterations=8), out=folder)
    assert refused.value.file == str(path)


def damage_swarm(path: Path, how: str) -> None:
    if how == "overwritten":
        path.write_bytes(b"not a swarm")
    elif how == "wrong shape":
        np.save(path, np.zeros((2, 3)))
    elif how == "other values":
        np.save(path, np.load(path) + 0.01)
    else:
        path.unlink()


@pytest.mark.parametrize("how, words", [("overwritten", "is not a NumPy array file"),
                                        ("wrong shape", "not the float64 array of shape (2, 40, 2)"),
                                        ("other values", "whose means are not the estimates of iteration 6"),
                                        ("missing", "is missing")])
def test_a_damaged_if2_swarm_is_refused_naming_it(how, words, tmp_path):
    folder = pfx.run(estimation_config("if2"), out=tmp_path / "out").folder
    (swarm,) = (folder / "estimation").glob("*.swarm.npy")
    damage_swarm(swarm, how)
    before = snapshot(folder)
    with pytest.raises(ConfigError, match="something else") as refused:
        pfx.run(estimation_config("if2", iterations=8), out=folder)
    assert words in refused.value.reason and refused.value.file == str(swarm), refused.value.reason
    assert snapshot(folder) == before


def test_an_if2_table_cut_at_a_start_without_its_log_likelihood_is_refused(tmp_path):
    """IF2's starts have no log-likelihood (an empty last field): a row cut after its last comma
    still lacks the line end pfx writes."""
    folder = pfx.run(estimation_config("if2"), out=tmp_path / "out").folder
    path = progress_path(folder)
    first_rows = path.read_text().split("\n")[:3]
    assert first_rows[1].endswith(",") and first_rows[2].endswith(",")          # iteration 0: empty estimate
    path.write_text("\n".join(first_rows))
    with pytest.raises(ConfigError, match="cut short") as refused:
        pfx.run(estimation_config("if2", iterations=8), out=folder)
    assert refused.value.line == 3


# -- a likelihood that is zero everywhere ------------------------------------------------------------------------

def test_the_log_mean_of_estimates_that_are_all_zero_is_minus_infinity():
    log_mean, standard_error = log_mean_likelihood(np.array([[-np.inf, -np.inf, -np.inf], [-2.0, -3.0, -np.inf]]))
    assert log_mean[0] == -np.inf and np.isnan(standard_error[0])
    assert log_mean[1] == pytest.approx(np.log((np.exp(-2.0) + np.exp(-3.0)) / 3), rel=1e-12)
    assert np.isfinite(standard_error[1])


def test_if2_whose_final_estimates_all_have_zero_likelihood_says_so(tmp_path, monkeypatch, capsys):
    original = IteratedFiltering.evaluate

    def evaluate(self, estimates):            # every final evaluation finds a likelihood of zero
        monkeypatch.setattr(self.target, "log_likelihoods", lambda rows, seeds: np.full(len(rows), -np.inf))
        return original(self, estimates)

    monkeypatch.setattr(IteratedFiltering, "evaluate", evaluate)
    result = pfx.run(estimation_config("if2", iterations=2), out=tmp_path / "out", quiet=False)
    printed = capsys.readouterr()
    assert "every replicate's likelihood is zero at its final estimate" in printed.err
    assert "-inf" in printed.out.split("IF2, the replicate of highest log-likelihood")[1]
    fields = (result.folder / "maximum_likelihood.csv").read_text().split("\n")[1].split(",")
    assert fields[-3:-1] == ["-inf", ""]                      # log_likelihood, and no standard error
    assert fields[-1].startswith("log_likelihood -inf")       # flag


def test_a_posterior_whose_chains_never_moved_still_prints_and_says_why(tmp_path, capsys):
    config = estimation_config(adapt=False)
    for path in (PROCESS, MEASUREMENT):
        config = with_parameter(config, path, proposal_sd=80.0)        # every proposal leaves the likelihood's mass
    result = pfx.run(config, out=tmp_path / "out", quiet=False)
    printed = capsys.readouterr()
    assert "no chain accepted a proposal after the warm-up" in printed.err
    assert "posterior after the warm-up" in printed.out and "process_noise.variance" in printed.out
    draws = result.chains[~result.chains["warm_up"]]
    assert (draws.groupby("chain")[["process_noise.variance", "measurement_noise.variance"]].nunique() == 1).all().all()


# -- figures that do not apply ----------------------------------------------------------------------------------

def test_pfx_figures_refuses_a_filter_run_figure_on_an_estimation_folder(tmp_path, run_pfx):
    folder = pfx.run(estimation_config(iterations=3), out=tmp_path / "out").folder
    before = snapshot(folder)
    result = run_pfx("figures", str(folder), "--figure", "ess_over_time")
    assert result.returncode == 2
    assert result.stderr.strip() == (f"pfx: error: {folder}: figure ess_over_time draws a filter run's (or a study's) "
                                     "tables, and a PMMH estimation folder has chains.csv, posterior.csv, priors.csv "
                                     "instead; `pfx list figures` says what each figure draws")
    assert snapshot(folder) == before


@pytest.mark.parametrize("made_by, figure, words", [
    ("filter run", "chain_traces", "draws chains.csv, which a filter run's folder does not have: it is a PMMH"),
    ("if2", "posterior_pairs", "draws chains.csv, which an IF2 estimation folder does not have"),
    ("pmmh", "if2_convergence", "draws if2.csv, which a PMMH estimation folder does not have"),
    ("filter run", "empirical_cdf", "draws ecdf.csv, which a filter run's folder does not have"),
])
def test_a_figure_asked_of_a_folder_it_cannot_draw_is_refused(made_by, figure, words, tmp_path):
    from pfx.figures import render_figures

    config = tiny_config_dict(outputs={"figures": []}) if made_by == "filter run" else \
        estimation_config(made_by, iterations=3)
    folder = pfx.run(config, out=tmp_path / "out").folder
    before = snapshot(folder)
    with pytest.raises(ConfigError, match=f"figure {figure} {words}"):
        render_figures(folder, [figure])
    assert snapshot(folder) == before


@pytest.mark.parametrize("config, figure", [(estimation_config(), "ess_over_time"),
                                            (estimation_config("if2"), "chain_traces"),
                                            (tiny_config_dict(), "if2_convergence")])
def test_a_config_naming_a_figure_its_folder_cannot_draw_is_refused(config, figure):
    config = copy.deepcopy(config)
    config.setdefault("outputs", {})["figures"] = [figure]
    with pytest.raises(ConfigError, match=f"figure {figure} draws") as refused:
        build_plan(config, "figures.yaml")
    assert refused.value.key == "outputs.figures[0]"


@pytest.mark.parametrize("method", ["pmmh", "if2"])
def test_an_estimation_config_records_the_figures_it_draws(method):
    config = estimation_config(method)
    del config["outputs"]
    plan = build_plan(config, "figures.yaml")
    recorded = yaml.safe_load(yaml.safe_dump(plan.resolved))["outputs"]["figures"]
    assert recorded == {"pmmh": ["chain_traces", "posterior_marginals", "posterior_pairs"],
                        "if2": ["if2_convergence"]}[method]
    assert build_plan(plan.resolved, "again.yaml").resolved == plan.resolved       # the record reruns


def test_if2_whose_random_walk_leaves_the_models_range_names_the_parameter_and_the_transform(tmp_path):
    """A normal prior on a variance with ``transform: none``: IF2's random walk soon carries some
    particle's variance below zero, which the model refuses. One ConfigError naming the parameter's
    transform key and what to use instead, never the model's ValueError from inside the filter."""
    config = with_parameter(estimation_config("if2"), prior={"law": "normal", "mean": 1.0, "sd": 2.0},
                            transform="none", start=[0.5, 1.0], random_walk_sd=0.5)
    with pytest.raises(ConfigError) as caught:
        pfx.run(config, out=tmp_path / "out")
    message = str(caught.value)
    assert message.startswith(f"<dict>: estimation.parameters.{PROCESS}.transform: IF2's random walk (transform: "
                              f"none) moved {PROCESS} to -"), message
    assert "transform: log" in message and len(message.splitlines()) == 1
