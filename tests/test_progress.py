"""What a long run shows while it runs (pfx/run/progress_bar.py), and what `particles: auto`
says the chains will cost before they start (pfx/run/particle_count_pilot.py).

Each kind of long run (a filter run, PMMH with `particles: auto` and so its pilot, IF2) runs
three times through the command line in this process: on a "terminal" (rich's own
``TTY_COMPATIBLE=1``, which also overrides the ``CI=1`` the in-process runner sets, as a
terminal's user who sets it would), on a plain stream (a pipe, CI), and with ``--quiet``. The
bar shows on the first only, the tables are the same bytes in all three, and the pilot's line
with the chains' projected wall time is printed on a terminal and off it, and not with
``--quiet``. The projection's arithmetic and the decision to show a bar are checked directly.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from types import SimpleNamespace

import pandas as pd
import pytest
from conftest import tiny_config_dict, write_config_file
from test_estimation_folders import estimation_config

from pfx.estimation.likelihood_spread import Spread
from pfx.estimation.particle_count import ParticleChoice
from pfx.run.particle_count_pilot import cost_text, duration_text
from pfx.run.progress_bar import show_progress

BAR = "\u2501"            # rich's bar is drawn with this character; no other output of pfx uses it
WAYS = ("terminal", "plain", "quiet")
TIMES = ("run_time_s", "wall_time_s")   # in the columns of a measured time (and its summaries): no two runs share it
COST = re.compile(r"particles auto -> (\d+) \(.*?\); the (\d+) chains x (\d+) iterations will take about "
                  r"([\d.]+) (s|min|h) at ([\d.e-]+) s per filter run \(their starts, (\d+) filter runs at N = (\d+), "
                  r"took ([\d.e-]+) s\)")
UNITS = {"s": 1, "min": 60, "h": 3600}


def pmmh_auto() -> dict:
    """The tiny PMMH config of test_estimation_folders (2 chains x 6 iterations) with `particles: auto`."""
    config = estimation_config("pmmh")
    config["filter"]["particles"] = "auto"
    config["estimation"]["particle_count"] = {"runs": 20, "smallest": 4, "largest": 512, "after_warm_up": False}
    return config


def filter_run() -> dict:
    """conftest's tiny filter config (4 trials), its figures left out as the estimation configs'
    are: the bar and the tables are checked here, and the figures are not compared (drawing them
    three times cost more than the runs)."""
    return tiny_config_dict(outputs={**tiny_config_dict()["outputs"], "figures": []})


CONFIGS = {"filter": filter_run, "pmmh": pmmh_auto, "if2": lambda: estimation_config("if2")}


@pytest.fixture(scope="module")
def runs(pfx_in_process, tmp_path_factory) -> dict:
    """{kind: {way: (PfxResult, folder)}}: every kind of run, each of the three ways."""
    folder = tmp_path_factory.mktemp("progress")
    found = {}
    for kind, config in CONFIGS.items():
        path = write_config_file(folder, config(), f"{kind}.yaml")
        found[kind] = {}
        for way in WAYS:
            out = folder / kind / way
            with pytest.MonkeyPatch.context() as patch:
                if way == "terminal":
                    patch.setenv("TTY_COMPATIBLE", "1")
                else:
                    patch.delenv("TTY_COMPATIBLE", raising=False)
                result = pfx_in_process("run", path, "--out", out, *(["--quiet"] if way == "quiet" else []))
            assert result.returncode == 0, result.output
            found[kind][way] = (result, out)
    return found


def visible(text: str) -> str:
    """The text a terminal shows of ``text``: without its escape codes (colours, cursor moves)."""
    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)


def assert_no_bar(result) -> None:
    assert BAR not in result.stderr and "\x1b[" not in result.stderr and "ETA" not in result.stderr, result.stderr
    assert BAR not in result.stdout


# -- the bar: on a terminal, and only there -------------------------------------------------------------

def test_a_filter_run_shows_its_trials_on_a_terminal_and_nothing_elsewhere(runs):
    terminal = runs["filter"]["terminal"][0]
    shown = visible(terminal.stderr)
    assert BAR in shown and re.search(r"\b4/4 trials\b", shown) and "ETA" in shown
    assert BAR not in terminal.stdout           # stdout keeps its table
    for way in ("plain", "quiet"):
        assert_no_bar(runs["filter"][way][0])


def test_a_pmmh_run_shows_its_iterations_on_a_terminal_and_nothing_elsewhere(runs):
    terminal = runs["pmmh"]["terminal"][0]
    shown = visible(terminal.stderr)
    assert BAR in shown and re.search(r"\b6/6 iterations\b", shown) and "ETA" in shown
    assert re.search(r"[\d.]+/s|[\d.]+ s each", shown), "the bar shows its rate"
    assert BAR not in terminal.stdout
    for way in ("plain", "quiet"):
        assert_no_bar(runs["pmmh"][way][0])


def test_the_pilot_of_particles_auto_shows_the_n_it_measures_on_a_terminal(runs):
    terminal = visible(runs["pmmh"]["terminal"][0].stderr)
    measured = pd.read_csv(runs["pmmh"]["plain"][1] / "particle_count.csv")["particles"]
    shown = {int(n) for n in re.findall(r"particles: auto, N = (\d+)", terminal)}
    assert shown == set(measured)                  # each N, said as it is measured
    assert re.search(r"\d+%", terminal)          # the pilot's work is weighed, shown as a percentage
    for way in ("plain", "quiet"):
        assert "particles: auto, N =" not in runs["pmmh"][way][0].stderr


def test_an_if2_run_shows_its_iterations_on_a_terminal_and_nothing_elsewhere(runs):
    shown = visible(runs["if2"]["terminal"][0].stderr)
    assert BAR in shown and re.search(r"\b6/6 iterations\b", shown) and "ETA" in shown
    for way in ("plain", "quiet"):
        assert_no_bar(runs["if2"][way][0])


def test_on_jax_the_bar_counts_the_iterations_of_each_compiled_block_as_it_returns(pfx_in_process, tmp_path,
                                                                                   monkeypatch):
    """The compiled blocks report their iterations to the host when they end (no callback
    inside them): the bar reaches every iteration, from the blocks' reports. Two blocks, the
    warm-up's 3 iterations and the 3 after it: one block program, compiled once (a block's
    program is compiled per block length); 3 draws a chain are too few for the likelihood's
    spread at the posterior mean, so no program for it either."""
    pytest.importorskip("jax")
    config = estimation_config("pmmh", warm_up=3)
    config["filter"]["backend"] = "jax"
    monkeypatch.setenv("TTY_COMPATIBLE", "1")
    result = pfx_in_process("run", write_config_file(tmp_path, config), "--out", tmp_path / "run")
    assert result.returncode == 0, result.output
    shown = visible(result.stderr)
    assert BAR in shown and re.search(r"\b6/6 iterations\b", shown)


@pytest.mark.parametrize("kind", list(CONFIGS))
def test_the_tables_are_the_same_bytes_with_the_bar_and_without(runs, kind):
    """The bar only counts: every file the run wrote is the same, bar or not, quiet or not
    (the measured times aside: the columns of run_time_s and wall_time_s and their summaries, and the
    manifest)."""
    assert BAR in runs[kind]["terminal"][0].stderr, "the terminal run showed its bar"
    folders = {way: runs[kind][way][1] for way in WAYS}
    files = sorted(path.relative_to(folders["plain"]) for path in folders["plain"].rglob("*")
                   if path.is_file() and path.name != "manifest.json" and path.suffix != ".png")
    assert any(path.suffix == ".csv" for path in files)
    for way in ("terminal", "quiet"):
        assert sorted(path.relative_to(folders[way]) for path in folders[way].rglob("*")
                      if path.is_file() and path.name != "manifest.json" and path.suffix != ".png") == files
        for path in files:
            plain, other = (folders["plain"] / path).read_bytes(), (folders[way] / path).read_bytes()
            if path.suffix == ".csv" and any(time in plain.split(b"\n", 1)[0].decode() for time in TIMES):
                left, right = (pd.read_csv(folder / path) for folder in (folders["plain"], folders[way]))
                timed = [column for column in left.columns if any(time in column for time in TIMES)]
                pd.testing.assert_frame_equal(left.drop(columns=timed), right.drop(columns=timed))
            else:
                assert plain == other, f"{way}: {path} differs"


# -- the pilot's line: what the chains will cost ------------------------------------------------------------

def test_the_pilot_says_what_the_chains_will_cost_from_its_own_measurement(runs):
    """On a plain stream (information, not animation) and on a terminal; not with --quiet. Its
    numbers agree with each other, with particle_count.csv and with the manifest: the chains'
    starts are one iteration's filter runs at the chosen N, so a filter run costs their time / the
    chains, and the projection is that x chains x iterations (each number to two significant
    figures, so within 11 %)."""
    result, folder = runs["pmmh"]["plain"]
    (line,) = [line for line in result.stderr.splitlines() if "particles auto ->" in line]
    found = COST.search(line)
    assert found, line
    chosen, chains, iterations, total, unit, per_run, starts, at, starts_seconds = found.groups()
    table = pd.read_csv(folder / "particle_count.csv")
    row = table[table["chosen"]].iloc[0]
    assert int(chosen) == int(at) == row["particles"]
    assert (int(chains), int(iterations), int(starts)) == (2, 6, 2)
    assert math.isclose(float(per_run), float(starts_seconds) / 2, rel_tol=0.11)
    assert math.isclose(float(total) * UNITS[unit], float(per_run) * 2 * 6, rel_tol=0.11)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert 0 < float(starts_seconds) <= manifest["cell_wall_time_s"][row["cell"]] * 1.05    # the starts are in it
    assert COST.search(visible(runs["pmmh"]["terminal"][0].stderr))
    assert runs["pmmh"]["quiet"][0].stderr == ""


def test_an_extended_run_projects_from_the_pilot_it_reads_back(runs, pfx_in_process, tmp_path):
    """Its starts were computed before: the pilot's runs at the chosen N (particle_count.csv's
    run_time_s) give a filter run's time, a lower bound in one batch."""
    folder = tmp_path / "extended"
    shutil.copytree(runs["pmmh"]["plain"][1], folder)
    longer = pmmh_auto()
    longer["estimation"]["iterations"] = 9
    result = pfx_in_process("run", write_config_file(tmp_path, longer), "--out", folder)
    assert result.returncode == 0, result.output
    found = re.search(r"the 2 chains x 3 iterations left will take at least ([\d.]+) (s|min|h) at ([\d.e-]+) s per "
                      r"filter run \(the pilot's 20 runs at N = (\d+) took ([\d.e-]+) s in one batch, whose fixed "
                      r"cost the chains' batches of 2 share among fewer runs\)", result.stderr)
    assert found, result.stderr
    total, unit, per_run, at, pilot_seconds = found.groups()
    row = pd.read_csv(folder / "particle_count.csv").query("chosen").iloc[0]
    assert int(at) == row["particles"]
    assert math.isclose(float(pilot_seconds), row["run_time_s"], rel_tol=0.06, abs_tol=0.0006)   # 2 figures; ms
    assert math.isclose(float(per_run), float(pilot_seconds) / 20, rel_tol=0.11)
    assert math.isclose(float(total) * UNITS[unit], float(per_run) * 2 * 3, rel_tol=0.11)


def choice(*timed: tuple[int, float], chosen: int, runs: int = 40) -> ParticleChoice:
    return ParticleChoice(chosen, tuple(Spread(n, runs, runs, -100.0, 1.2, seconds) for n, seconds in timed))


def target(chains: int = 4, batched: bool = True, backend: str = "numpy"):
    return SimpleNamespace(estimation=SimpleNamespace(chains=chains), batched=batched,
                           cell=SimpleNamespace(filter=SimpleNamespace(backend=backend)))


def test_the_projection_from_the_run_s_own_filter_runs():
    """From C filter runs timed as an iteration makes them, an iteration costs their time; from
    the pilot's R runs alone, a run costs t / R: about that one by one, at least that in one batch
    (whose fixed cost C rows share, not R); on jax, whose times are mostly compiling, nothing."""
    measured = choice((100, 1.0), (200, 1.8), chosen=200)
    assert cost_text(measured, target(), 2000, timed=("their starts", 0.36)) == (
        "; the 4 chains x 2000 iterations will take about 12 min at 0.09 s per filter run (their starts, 4 filter "
        "runs at N = 200, took 0.36 s)")                    # 0.36 s / 4 chains x 4 x 2000 iterations = 720 s
    assert cost_text(measured, target(batched=False), 2000) == (
        "; the 4 chains x 2000 iterations will take about 6 min at 0.045 s per filter run (the pilot's 40 runs at "
        "N = 200 took 1.8 s)")                              # 1.8 s / 40 runs x 4 x 2000 = 360 s
    assert cost_text(measured, target(), 1500, " left") == (
        "; the 4 chains x 1500 iterations left will take at least 4.5 min at 0.045 s per filter run (the pilot's "
        "40 runs at N = 200 took 1.8 s in one batch, whose fixed cost the chains' batches of 4 share among fewer "
        "runs)")
    assert cost_text(measured, target(), 0) == ""
    assert "do not tell what the chains will take" in cost_text(measured, target(backend="jax"), 2000)


@pytest.mark.parametrize("seconds, text", [(0.004321, "0.0043 s"), (45.2, "45 s"), (3480, "58 min"),
                                           (9000, "2.5 h"), (400 * 3600, "400 h")])
def test_a_wall_time_in_words(seconds, text):
    assert duration_text(seconds) == text


# -- whether a run shows its bar --------------------------------------------------------------------------

class Stream:
    def __init__(self, terminal: bool):
        self.terminal = terminal

    def isatty(self) -> bool:
        return self.terminal


@pytest.mark.parametrize("quiet, terminal, environment, shown", [
    (False, True, {}, True),
    (True, True, {}, False),                                 # --quiet always wins
    (True, False, {"TTY_COMPATIBLE": "1"}, False),
    (False, True, {"CI": "1"}, False),                       # a CI log, not a screen
    (False, False, {}, False),                               # a pipe or a file
    (False, False, {"TTY_COMPATIBLE": "1", "CI": "1"}, True),    # rich's own setting: it is a terminal
    (False, True, {"TTY_COMPATIBLE": "0"}, False),           # ... or it is not
])
def test_a_bar_shows_on_a_terminal_not_in_ci_and_never_with_quiet(monkeypatch, quiet, terminal, environment, shown):
    for name in ("TTY_COMPATIBLE", "CI"):
        monkeypatch.delenv(name, raising=False)
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr("sys.stderr", Stream(terminal))
    assert show_progress(quiet) is shown
