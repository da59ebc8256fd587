"""Small command-line conventions: --version, -h, completion, `pfx list`, compare's hints and
relative change, where a YAML syntax error is reported, and the benchmark's goal lines.

The exit statuses and the one-line errors come from ``pfx.cli.main``: the top-level invocations
are checked through real subprocesses (``run_pfx``), the others through ``main`` in the test's
process (``pfx_in_process``); help texts are checked in process with typer's
``CliRunner``; the pure functions (``paired_comparison``, ``relative_change_interval``,
``parse_yaml``, the bench report) directly.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import typer
from conftest import tiny_config_dict, write_config_file
from typer.testing import CliRunner

import pfx
from pfx.analysis.compare import format_table, output_name, paired_comparison
from pfx.analysis.paired_statistics import relative_change_interval
from pfx.cli import LISTABLE, _registries, app
from pfx.errors import ConfigError
from pfx.safe_yaml import parse_yaml

COMMANDS = list(typer.main.get_command(app).commands)


def _one_error_line(result) -> str:
    """The single 'pfx: error: ...' line on stderr of a failed command (exit 2, nothing on stdout)."""
    assert result.returncode == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("pfx: error: "), result.stderr
    assert "Traceback" not in result.output and result.stdout == ""
    return lines[0]


# -- 1. --version, -h, completion, usage errors -----------------------------------------------------

@pytest.fixture(scope="module")
def top_level(run_pfx, tmp_path_factory):
    """The top-level invocations, run concurrently as real subprocesses: {name: PfxResult}."""
    folder = tmp_path_factory.mktemp("conventions")
    jobs = {
        "version": (["--version"], folder),
        "no-arguments": ([], folder),
        "unknown-option": (["--bogus"], folder),
        "unknown-command": (["frobnicate"], folder),
        "missing-argument": (["run"], folder),
        "bad-subcommand-option": (["list", "--nonsense"], folder),
    }
    return run_pfx.many(jobs)


def test_version_prints_the_package_version(top_level):
    result = top_level["version"]
    assert result.returncode == 0, result.output
    assert result.stdout == f"pfx {pfx.__version__}\n"
    assert result.stderr == ""


def test_no_arguments_shows_the_help_and_exits_0(top_level):
    result = top_level["no-arguments"]
    assert result.returncode == 0, result.output
    assert "Usage: pfx" in result.stdout
    for command in COMMANDS:
        assert re.search(rf"\b{command}\b", result.stdout), command
    assert "--version" in result.stdout and "--install-completion" in result.stdout


@pytest.mark.parametrize("name", ["unknown-option", "unknown-command", "missing-argument",
                                  "bad-subcommand-option"])
def test_usage_errors_are_one_line_and_exit_2(top_level, name):
    line = _one_error_line(top_level[name])
    assert "Usage" not in line and "│" not in line         # no help panel squeezed into the line


def test_shell_completion_script_is_offered(tmp_path):
    # typer finds the shell by walking up the process tree, so run pfx from bash itself (under a
    # runner whose parents are not shells it would print "Shell  not supported").
    # (a second command keeps bash from replacing itself with its only command)
    command = f"{shlex.quote(sys.executable)} -m pfx --show-completion; exit $?"
    result = subprocess.run(["bash", "-c", command], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "_PFX_COMPLETE" in result.stdout                # the variable typer's completion reads


@pytest.mark.parametrize("arguments", [[]] + [[command] for command in COMMANDS],
                         ids=["app"] + COMMANDS)
def test_h_is_the_same_as_help(arguments):
    runner = CliRunner()
    short = runner.invoke(app, [*arguments, "-h"], prog_name="pfx")
    long = runner.invoke(app, [*arguments, "--help"], prog_name="pfx")
    assert short.exit_code == 0 and long.exit_code == 0, short.output
    assert " ".join(["Usage: pfx", *arguments]) in short.output
    assert short.output == long.output


def test_commands_are_the_expected_set():
    """-h is checked on each of these (a new command is covered automatically; this guards the list)."""
    assert {"run", "validate", "list", "schema", "figures", "reproduce", "compare", "bench"} <= set(COMMANDS)


# -- 2. pfx list ------------------------------------------------------------------------------------

def test_listable_names_are_the_registries():
    assert LISTABLE == tuple(_registries())
    assert "studies" in LISTABLE


def test_list_shows_every_registry_including_studies():
    result = CliRunner().invoke(app, ["list"], prog_name="pfx")
    assert result.exit_code == 0, result.output
    sections = re.findall(r"^(\w+):$", result.output, re.M)
    assert sections == list(LISTABLE)
    after = result.output.split("studies:\n", 1)[1].split("\n")
    studies = after[:next(i for i, line in enumerate(after) if not line.startswith("  "))]
    assert any(line.startswith("  offspring_counts ") for line in studies)    # a registered study, with its description


def _first_paragraph_of(text: str) -> str:
    """The first paragraph of a docstring, its lines joined by single spaces (written here, not
    taken from pfx, so the test does not check pfx against itself)."""
    paragraph = []
    for line in (text or "").strip().splitlines():
        if not line.strip():
            break
        paragraph.append(" ".join(line.split()))
    return " ".join(paragraph)


def test_no_listed_description_stops_mid_sentence():
    """`pfx list` printed the first line of a docstring, so a summary wrapped onto a second line
    was cut mid-sentence ("... (particles_mean: N, or the mean"). Every description is now a
    docstring's whole first paragraph, or one written for the listing, and complete."""
    for name, registry in _registries().items():
        for item, description in registry.describe().items():
            summary = _first_paragraph_of(getattr(registry[item], "__doc__", None))
            # The docstring's whole summary, or a description written for the listing (a noise
            # family's, a resampler's), never the start of the summary cut short.
            assert description == summary or not summary.startswith(description), (name, item, description)
            # every bracket closed (counted together: a half-open interval "[0, 1)" is closed)
            opened = sum(description.count(bracket) for bracket in "([")
            assert description and opened == sum(description.count(bracket) for bracket in ")]"), (name, item)
            assert not description.rstrip().endswith((",", ":", ";", "(", " the", " of", " and", " or")), (name, item)
    output = CliRunner().invoke(app, ["list", "metrics"], prog_name="pfx").output
    assert "the mean particle count and the mean number injected per step." in output


def test_list_of_a_misspelt_registry_suggests_it(pfx_in_process):
    line = _one_error_line(pfx_in_process("list", "studys"))
    assert "did you mean 'studies'?" in line


# -- 3 and 4. pfx compare: hints, and relative change against a negative baseline -------------------

def _one_arm_sweep() -> pd.DataFrame:
    """trials.csv of a run without arms: arm 'default' everywhere, particles and resampler swept."""
    rows = []
    for particles in (10, 20):
        for resampler in ("systematic", "multinomial"):
            for trial in range(3):
                rows.append({"cell": f"{particles}-{resampler}", "arm": "default", "model": "linear_gaussian",
                             "n_particles": particles, "resampler": resampler, "trial": trial,
                             "rmse": 1.0 + trial + particles / 100})
    return pd.DataFrame(rows)


LABELS = ["arm", "model", "n_particles", "resampler"]


def test_a_single_arm_error_names_the_columns_that_vary():
    with pytest.raises(ConfigError) as caught:
        paired_comparison(_one_arm_sweep(), "rmse", "arm", None, LABELS)
    message = str(caught.value)
    assert caught.value.key == "--by"
    assert "single value ('default')" in message
    assert "label columns that vary: n_particles, resampler (try --by n_particles)" in message
    assert "model" not in message.split("vary:", 1)[1]       # one value everywhere: not suggested


def test_a_single_cell_error_says_nothing_varies():
    one_cell = _one_arm_sweep().query("n_particles == 10 and resampler == 'systematic'")
    with pytest.raises(ConfigError, match=r"single value .*no label column varies"):
        paired_comparison(one_cell, "rmse", "arm", None, LABELS)


LOG_LIKELIHOODS = np.array([-130.0, -128.0, -135.0, -131.0, -129.0, -133.0])
WORSE_BY = np.array([-2.0, -1.0, -3.0, 0.5, -2.5, -1.0])       # mostly lower: worse, mean -1.5


def _log_likelihood_arms() -> pd.DataFrame:
    n = len(LOG_LIKELIHOODS)
    return pd.DataFrame({"cell": ["a"] * n + ["b"] * n, "arm": ["A"] * n + ["B"] * n,
                         "trial": list(range(n)) * 2,
                         "log_likelihood": np.concatenate([LOG_LIKELIHOODS, LOG_LIKELIHOODS + WORSE_BY])})


@pytest.mark.parametrize("higher_is_better", [True, False])
def test_relative_change_has_the_sign_of_the_difference_for_a_negative_baseline(higher_is_better):
    row = paired_comparison(_log_likelihood_arms(), "log_likelihood", "arm", None, ["arm"],
                            higher_is_better=higher_is_better).iloc[0]
    assert row["baseline_mean"] < 0 and row["mean_difference"] == pytest.approx(WORSE_BY.mean())
    assert row["relative_change"] < 0                       # lower than the baseline: a negative change
    assert row["relative_change"] == pytest.approx(WORSE_BY.mean() / abs(LOG_LIKELIHOODS.mean()))
    wins, losses = (1, 5) if higher_is_better else (5, 1)  # the flag only decides what a win is
    assert (row["wins"], row["losses"]) == (wins, losses)
    printed = format_table(pd.DataFrame([row]), "arm").splitlines()[-1]
    assert f"{100 * row['relative_change']:+.1f}%" in printed and "-1.1%" in printed


def test_relative_change_interval_of_a_negative_baseline_mirrors_the_positive_one():
    """Negating both sides negates the change and mirrors its interval: the same rule, |b|."""
    random = np.random.default_rng(7)
    base = random.normal(100.0, 5.0, 12)
    value = 0.9 * base + random.normal(0.0, 2.0, 12)
    estimate, low, high = relative_change_interval(base, value)
    assert low < estimate < high < 0                          # value below base: a negative change
    negated = relative_change_interval(-base, -value)         # value above base (less negative)
    assert negated == pytest.approx((-estimate, -high, -low))
    assert negated[0] == pytest.approx((-value.mean() + base.mean()) / abs(-base.mean()))


@pytest.fixture(scope="module")
def one_arm_run(pfx_in_process, tmp_path_factory):
    """A real run without arms (a particles x resampler sweep), then compare invocations on it."""
    root = tmp_path_factory.mktemp("one-arm")
    config = tiny_config_dict(name="one-arm", trials=4,
                              sweep={"filter.particles": [10, 40], "filter.resampler": ["systematic", "multinomial"]},
                              outputs={"trace_trials": 1, "figures": []})
    write_config_file(root, config, "one-arm.yaml")
    ran = pfx_in_process("run", "one-arm.yaml", "--out", "one-arm", "--quiet", cwd=root)
    assert ran.returncode == 0, ran.output
    jobs = {
        "default-by": (["compare", "one-arm", "--metric", "rmse_position"], root),
        "misspelt-metric": (["compare", "one-arm", "--metric", "rmse_postion", "--by", "n_particles"], root),
        "suggested-by": (["compare", "one-arm", "--metric", "log_likelihood", "--by", "n_particles",
                          "--higher-is-better"], root),
    }
    results = pfx_in_process.many(jobs)
    results["root"] = root
    return results


def test_compare_on_a_run_without_arms_suggests_a_column_to_compare_by(one_arm_run):
    line = _one_error_line(one_arm_run["default-by"])
    assert "--by: column 'arm' has a single value ('default')" in line
    assert "label columns that vary: n_particles, resampler (try --by n_particles)" in line
    assert not list((one_arm_run["root"] / "one-arm").glob("compare_*_by_arm.csv"))


def test_compare_of_a_misspelt_metric_suggests_the_closest(one_arm_run):
    assert "no metric 'rmse_postion' in trials.csv (did you mean 'rmse_position'?)" in \
        _one_error_line(one_arm_run["misspelt-metric"])


def test_compare_by_the_suggested_column_works_and_log_likelihood_changes_keep_their_sign(one_arm_run):
    result = one_arm_run["suggested-by"]
    assert result.returncode == 0, result.output
    table = pd.read_csv(one_arm_run["root"] / "one-arm" / output_name("log_likelihood", "n_particles"))
    assert len(table) == 2 and (table["baseline_mean"] < 0).all()
    assert (np.sign(table["relative_change"]) == np.sign(table["mean_difference"])).all()
    assert table["relative_change"].to_numpy() == pytest.approx(
        (table["mean_difference"] / table["baseline_mean"].abs()).to_numpy())


# -- 5. where a YAML syntax error is reported ---------------------------------------------------------

FIVE_LINES = ("name: tiny\nseed: 7\nmodel:\n  kind: linear_gaussian\n"
              "filter: {particles: 20, resampler: systematic\n")


@pytest.mark.parametrize("text, line, column", [
    # noticed at the next token (or the end of the file): reported after the last content before it
    pytest.param(FIVE_LINES, 5, 46, id="unclosed-flow-mapping-on-the-last-line"),
    pytest.param(FIVE_LINES + "\n# the end\n\n", 5, 46, id="unclosed-flow-mapping-then-blank-and-comment"),
    pytest.param("name: tiny\nmatrix: [[1.0], [2.0]\nseed: 3\n", 2, 22, id="unclosed-flow-sequence-then-a-key"),
    pytest.param("name: tiny\nfilter: {particles: 20   # it's 20\n\n# more\nseed: 4\n", 2, 23,
                 id="unclosed-flow-mapping-with-a-comment"),
    pytest.param('filter: {name: "run #1", particles: 20\n', 1, 39, id="a-hash-inside-quotes-is-no-comment"),
    pytest.param("name: tiny\nmodel\nseed: 3\n", 2, 6, id="key-without-colon"),
    pytest.param("model:\n  kind: a  # note\n  # more\nsteps\n", 4, 6, id="key-without-colon-at-the-end"),
    pytest.param("a: [1,\n\n", 1, 7, id="trailing-comma-at-the-end"),
    pytest.param("name: tiny\r\nfilter: {a: 1\r\n", 2, 14, id="crlf-line-breaks"),
    # a quote never closed runs to the end: reported at the opening quote
    pytest.param('name: "tiny\nseed: 3\ntrials: 2\n', 1, 7, id="unclosed-quote"),
    # the problem mark points at the offending character: kept
    pytest.param("name: x\nmodel:\n\tkind: a\n", 3, 1, id="tab-at-column-1"),
    pytest.param("name: x\n- a\n", 2, 1, id="list-item-in-a-mapping"),
    pytest.param("name: tiny\nmodel:\n  kind: linear_gaussian\n    steps: 5\n", 4, 10, id="over-indented-key"),
    pytest.param('name: "a\\qb"\n', 1, 10, id="bad-escape-in-a-quote"),
])
def test_yaml_syntax_error_is_reported_where_the_user_sees_it(text, line, column):
    with pytest.raises(ConfigError) as caught:
        parse_yaml(text, "config.yaml")
    error = caught.value
    assert (error.line, error.column) == (line, column), str(error)
    assert "YAML syntax error" in str(error)


def test_a_flow_mapping_error_names_the_line_of_its_opening_brace():
    text = "name: tiny\nfilter: {particles: 20\n         resampler: systematic}\n"   # a missing comma
    with pytest.raises(ConfigError) as caught:
        parse_yaml(text, "config.yaml")
    assert (caught.value.line, caught.value.column) == (3, 19)
    assert "(in the flow mapping opened at line 2, column 9)" in str(caught.value)


def test_validate_reports_the_unclosed_brace_on_its_own_line(pfx_in_process, tmp_path):
    write_config_file(tmp_path, FIVE_LINES, "five.yaml")
    line = _one_error_line(pfx_in_process("validate", "five.yaml", cwd=tmp_path))
    assert line.startswith("pfx: error: five.yaml:5:46: YAML syntax error: expected ',' or '}'"), line


# -- 6. the benchmark report speaks of goals ----------------------------------------------------------

def _timing(particles: int, trials: int, implementation: str, seconds: float):
    return SimpleNamespace(case=SimpleNamespace(particles=particles, trials=trials), implementation=implementation,
                           seconds=seconds, runs=1, error=None)


def test_bench_goals_say_met_or_not_met_with_the_numbers():
    from pfx.bench.report import format_goals

    timings = [_timing(100_000, 1, "pfx", 1.0), _timing(100_000, 1, "numpy", 1.6),       # 0.62: not <= 0.5
               _timing(100, 1000, "pfx", 1.0), _timing(100, 1000, "numpy", 4.0)]         # 4.00: >= 3
    lines = format_goals(timings, None, {"particles": 1_000_000, "peak_rss": 0.5 * 1024 ** 3}).splitlines()
    assert lines[0] == "goals (ratios of best wall times on this machine):"
    assert lines[1] == "  N=1e3, 1 trial: pfx time / numpy reference time: not measured (case not run; goal <= 1)"
    assert lines[2] == "  N=1e5, 1 trial: pfx time / numpy reference time: goal not met (0.62 vs <= 0.5)"
    assert lines[5] == "  1000 x N=100: numpy reference loop time / pfx time: goal met (4.00 vs >= 3)"
    assert lines[6].endswith("speed-up: not measured (skipped; goal >= 1.8)")
    assert lines[7].endswith("(GiB): goal met (0.50 vs <= 1)")
    assert not any("target" in line or "NOT MET" in line for line in lines)
