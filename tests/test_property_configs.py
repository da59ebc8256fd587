"""Property tests: random mutations of valid configs never produce a traceback.

Starting points are the example configs (``configs/examples/*.yaml``) shrunk to a few particles,
steps and trials. A mutation deletes or renames a key, replaces a value at a random path with a
random value of another type (int, float incl. huge / negative / NaN / inf, string, list, dict,
None, bool), or adds an unknown key. The contract: validation either succeeds or raises
:class:`pfx.errors.ConfigError`, whose text is one line naming the file; through the command
line, exit status 0 or 2 and never a traceback.

Examples are generated deterministically (``derandomize=True``) so CI is reproducible.
"""

from __future__ import annotations

import copy
import functools
import math
import sys
from pathlib import Path
from typing import Any

import pytest
import typer.main
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pfx.config.plan import build_plan
from pfx.errors import ConfigError
from pfx.safe_yaml import load_config_file

EXAMPLES = Path(__file__).resolve().parents[1] / "configs" / "examples"
FILE = "mutated.yaml"


def _shrink(data: dict) -> dict:
    """The config with tiny particle counts, steps and trials (as `--set` would do)."""
    data = copy.deepcopy(data)
    data["trials"] = 2
    data["model"]["steps"] = 3
    if "kidnap" in data["model"]:                 # a kidnapping within the shrunk steps
        data["model"]["kidnap"]["step"] = min(data["model"]["kidnap"]["step"], 3)
    data.setdefault("filter", {})["particles"] = 5
    if "filter.particles" in data.get("sweep", {}):
        data["sweep"]["filter.particles"] = [4, 6]
    data.setdefault("outputs", {})["trace_trials"] = 1
    return data


# Configs on recorded data (`data:`) are left out: their steps come from their files, which a
# mutated config in another folder cannot reach (tests/test_recorded_data.py covers them).
BASES = {path.stem: _shrink(config) for path in sorted(EXAMPLES.glob("*.yaml"))
         if "data" not in (config := load_config_file(path))}

# Names a mutation may use: real keys and names (so that mutations reach deep validation) and junk.
KNOWN_WORDS = sorted({
    "kind", "steps", "dt", "variance", "family", "df", "particles", "resampler", "ess_threshold",
    "weighting", "diffusion", "initial", "model", "filter", "arms", "sweep", "metrics", "outputs",
    "convergence", "radius", "fraction", "hold", "criterion", "mean", "covariance", "low", "high",
    "state", "form", "scale", "factor", "std", "beacons", "path", "region", "motion", "variant",
    "units", "transition_matrix", "measurement_matrix", "trace_trials", "figures", "formats",
    "gaussian", "uniform", "student_t", "systematic", "multinomial", "han_lee_iv", "mahalanobis",
    "sis", "particle", "roughening", "none", "point", "spread", "truth", "lissajous", "waypoints",
    "filter.particles", "model.steps", "filter.resampler", "metrics.convergence.radius",
    "linear_gaussian", "falling_body", "range_beacons", "error_over_time", "png",
})

WORDS = st.one_of(st.sampled_from(KNOWN_WORDS), st.text(max_size=8))
NUMBERS = st.one_of(
    st.integers(min_value=-10, max_value=10),
    st.integers(min_value=-(2 ** 70), max_value=2 ** 70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-320, 1e308, -1e308, math.inf, -math.inf, math.nan, 10 ** 12, -1]),
)
SCALARS = st.one_of(NUMBERS, WORDS, st.none(), st.booleans())
VALUES = st.one_of(
    SCALARS,
    st.lists(SCALARS, max_size=3),
    st.lists(st.lists(NUMBERS, min_size=1, max_size=3), min_size=1, max_size=3),   # matrix-like
    st.dictionaries(WORDS, SCALARS, max_size=3),
)


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path to a value inside nested dicts and lists (keys and list indices)."""
    found = []
    if isinstance(node, dict):
        for key, value in node.items():
            found.append(prefix + (key,))
            found += _paths(value, prefix + (key,))
    elif isinstance(node, list):
        for index, value in enumerate(node):
            found.append(prefix + (index,))
            found += _paths(value, prefix + (index,))
    return found


def _containers(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path to a dict (the root included)."""
    found = [prefix] if isinstance(node, dict) else []
    if isinstance(node, dict):
        for key, value in node.items():
            found += _containers(value, prefix + (key,))
    elif isinstance(node, list):
        for index, value in enumerate(node):
            found += _containers(value, prefix + (index,))
    return found


def _get(node: Any, path: tuple) -> Any:
    for part in path:
        node = node[part]
    return node


def _mutate_once(data: dict, draw) -> None:
    operation = draw(st.sampled_from(["delete", "rename", "replace", "replace", "add"]))
    if operation == "add":
        container = _get(data, draw(st.sampled_from(_containers(data))))
        container[draw(WORDS)] = draw(VALUES)
        return
    paths = _paths(data)
    if not paths:
        return
    path = draw(st.sampled_from(paths))
    parent = _get(data, path[:-1])
    last = path[-1]
    if operation == "delete":
        del parent[last]
    elif operation == "replace":
        parent[last] = draw(VALUES)
    elif isinstance(parent, dict):                        # rename a key, keeping its value
        value = parent.pop(last)
        parent[draw(WORDS)] = value
    else:
        parent[last] = draw(VALUES)


@st.composite
def mutated_configs(draw) -> dict:
    """A shrunk example config with 1 to 3 random mutations."""
    data = copy.deepcopy(BASES[draw(st.sampled_from(sorted(BASES)))])
    for _ in range(draw(st.integers(min_value=1, max_value=3))):
        _mutate_once(data, draw)
    return data


def test_bases_are_valid():
    """The shrunk starting points are valid configs (otherwise the properties test nothing)."""
    assert len(BASES) >= 3
    for name, data in BASES.items():
        plan = build_plan(data, f"{name}.yaml")
        assert plan.cells and plan.experiment.trials == 2


LINE_BREAKS = "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"    # what str.splitlines splits on


def _check_error_text(text: str, data: Any) -> None:
    assert FILE in text.splitlines()[0], text
    assert not any(c in LINE_BREAKS for c in text), f"multi-line error:\n{text}"


@settings(max_examples=4000, deadline=None, derandomize=True, database=None)
@given(mutated_configs())
def test_mutated_config_validates_or_raises_config_error(data):
    """build_plan on a mutated config succeeds or raises ConfigError (never another exception);
    the error names the file and is one line."""
    try:
        build_plan(data, FILE)
    except ConfigError as error:
        _check_error_text(str(error), data)


def _gaussian_law_config() -> dict:
    data = copy.deepcopy(BASES["linear-gaussian"])
    data["filter"]["initial"] = {"kind": "gaussian", "mean": [0.0, 0.0], "covariance": [-1.0, 1.0]}
    return data


def test_gaussian_law_covariance_error_is_one_line():
    """A negative prior covariance gives one line naming filter.initial.covariance."""
    with pytest.raises(ConfigError) as raised:
        build_plan(_gaussian_law_config(), FILE)
    assert "\n" not in str(raised.value), str(raised.value)
    assert "filter.initial.covariance" in str(raised.value)


def test_newline_in_unknown_key_is_escaped():
    """An unknown key 'a\\nb' gives a one-line error."""
    data = copy.deepcopy(BASES["linear-gaussian"])
    data["filter"]["a\nb"] = 1
    with pytest.raises(ConfigError) as raised:
        build_plan(data, FILE)
    assert "\n" not in str(raised.value), str(raised.value)


def _yaml_text(data: dict) -> str:
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True)


@st.composite
def mutated_texts(draw) -> tuple[dict, str]:
    """YAML text of a mutated config, sometimes with a textual edit on top (syntax errors,
    tabs, anchors, tags, duplicated lines)."""
    data = draw(mutated_configs())
    text = _yaml_text(data)
    if draw(st.booleans()):
        lines = text.splitlines(keepends=True)
        index = draw(st.integers(min_value=0, max_value=len(lines) - 1))
        edit = draw(st.sampled_from(["duplicate", "insert", "delete"]))
        if edit == "duplicate":
            lines.insert(index, lines[index])
        elif edit == "delete":
            del lines[index]
        else:
            junk = draw(st.sampled_from(["\t", ":", "{", "]", "&a ", "*a", "!!python/name:os.system ",
                                         "- ", "? ", "'", "%YAML 1.1\n", "---\n", "\x00"]))
            column = draw(st.integers(min_value=0, max_value=len(lines[index])))
            lines[index] = lines[index][:column] + junk + lines[index][column:]
        text = "".join(lines)
    return data, text


_BUILD_COMMAND = typer.main.get_command


@functools.lru_cache(maxsize=None)
def _command_built_once(app: typer.Typer):
    return _BUILD_COMMAND(app)


@pytest.fixture(autouse=True)
def _typer_command_built_once(monkeypatch):
    """Typer builds pfx's click command from the app's functions at every call of ``main``, always
    the same command: built once here, the 600 calls below take a third less time. (A fixture, not
    a line in the test: Hypothesis derives the test's examples from the test's source.)"""
    monkeypatch.setattr(typer.main, "get_command", _command_built_once)


@settings(max_examples=600, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=mutated_texts())
def test_cli_validate_on_mutated_files_never_tracebacks(case, tmp_path, capsys, monkeypatch):
    """`pfx validate FILE` (the real entry point, in-process) on a mutated YAML file exits 0 or 2;
    stderr never holds a traceback and, on exit 2, is one 'pfx: error: FILE...' line."""
    from pfx.cli import main

    data, text = case
    path = tmp_path / FILE
    path.write_text(text, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["pfx", "validate", FILE])
    capsys.readouterr()
    with pytest.raises(SystemExit) as exited:
        main()
    out, err = capsys.readouterr()
    code = exited.value.code
    assert code in (0, 2), (code, err)
    assert "Traceback" not in err
    if code == 2:
        assert err.startswith(f"pfx: error: {FILE}"), err
        _check_error_text(err.removesuffix("\n"), data)
    else:
        assert out.startswith(f"# {FILE}: valid"), out
    assert sorted(p.name for p in tmp_path.iterdir()) == [FILE], "validate wrote something"
