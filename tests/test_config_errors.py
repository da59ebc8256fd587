"""Every class of config error, through the real command line.

Each case is a bad input given to ``pfx validate`` (and, for a representative subset, to
``pfx run --out out``). The contract (SPEC, Reliability): exit status 2, stderr exactly one line
``pfx: error: <file>[:line:col]: [<key path>: ]<reason>``, no traceback, nothing written.

All invocations are real subprocesses; a module fixture starts them concurrently (one per CPU)
and each test checks its own.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Union

import pytest
import yaml

from conftest import tiny_config_dict, write_config_file

FILE = "exp.yaml"


def _config(**sections: Any) -> str:
    """The tiny config with sections replaced (value None removes a section), as YAML text."""
    data = tiny_config_dict()
    for key, value in sections.items():
        if value is None:
            data.pop(key, None)
        else:
            data[key] = value
    return yaml.safe_dump(data, sort_keys=False)


def _filter(**changes: Any) -> str:
    return _config(filter={**tiny_config_dict()["filter"], **changes})


def _model(**changes: Any) -> str:
    return _config(model={**tiny_config_dict()["model"], **changes})


def _model_2d(**changes: Any) -> str:
    """A 2-D state, 2-D measurement linear model (for covariance matrices)."""
    return _config(model={"kind": "linear_gaussian", "steps": 5,
                          "transition_matrix": [[1.0, 0.0], [0.0, 1.0]],
                          "measurement_matrix": [[1.0, 0.0], [0.0, 1.0]], **changes})


_BILLION_LAUGHS = "\n".join(
    ['name: lol', 'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    + [f"{c}: &{c} [{','.join(['*' + p] * 9)}]" for p, c in zip("abcdefgh", "bcdefghi")]) + "\n"


@dataclass
class Case:
    id: str
    content: Union[str, bytes, None]          # None: no file is written
    key: Optional[str]                        # key path the message must name (None: no key)
    reason: tuple[str, ...]                   # substrings of the reason (case-insensitive)
    extra_args: tuple[str, ...] = ()
    target: str = FILE                        # what is passed on the command line
    location: Optional[str] = None            # regex for 'file:line:col' where YAML positions apply
    run: bool = False                         # also check `pfx run --out out`
    xfail: Optional[str] = None               # reason, for a known pfx defect
    check: Optional[Callable[[Path, Any], None]] = None   # extra check (case folder, result)


def _nothing_executed(folder: Path, result) -> None:
    assert not (folder / "pwned.txt").exists(), "the YAML tag ran os.system"
    assert "hi" not in result.stdout


CASES = [
    # --- the file itself -------------------------------------------------------------------
    Case("yaml-syntax", "name: tiny\nmodel:\n  kind: linear_gaussian\n    steps: 5\n", None,
         ("yaml syntax error",), location=r"exp\.yaml:4:10: ", run=True),
    Case("tab-indentation", "name: tiny\nmodel:\n\tkind: linear_gaussian\n", None,
         ("yaml syntax error", "\\t"), location=r"exp\.yaml:3:1: "),
    Case("top-level-list", "- name: tiny\n- seed: 7\n", None, ("top level must be a mapping", "list")),
    Case("top-level-scalar", "just some words\n", None, ("top level must be a mapping",)),
    Case("empty-file", "", None, ("empty",)),
    Case("binary-file", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x01", None, ("binary",)),
    Case("missing-file", None, None, ("no such file",), target="absent.yaml"),
    Case("directory", None, None, ("directory",), target="a-folder"),
    Case("duplicate-key", "name: tiny\nmodel: {kind: linear_gaussian, transition_matrix: [[1]], "
         "measurement_matrix: [[1]]}\nfilter:\n  particles: 10\n  particles: 20\n",
         "filter.particles", ("duplicate key",), location=r"exp\.yaml:5:3: "),
    Case("python-tag", "name: tiny\ndescription: !!python/object/apply:os.system ['echo hi > pwned.txt']\n"
         "model: {kind: linear_gaussian, transition_matrix: [[1]], measurement_matrix: [[1]]}\n",
         None, ("tag",), location=r"exp\.yaml:2:14: ", run=True, check=_nothing_executed),
    # refused by counting nodes before anything is expanded (9^9 strings if it were expanded)
    Case("alias-bomb", _BILLION_LAUGHS, None, ("alias", "refused", "more than")),
    # --- unknown keys, with the closest valid name --------------------------------------------
    Case("unknown-top-level", _config(seeds=3), "seeds", ("unknown key", "did you mean 'seed'")),
    Case("unknown-filter", _filter(particels=50), "filter.particels",
         ("unknown key", "did you mean 'particles'"), run=True),
    Case("unknown-model", _model(stpes=5), "model.stpes", ("unknown key", "did you mean 'steps'")),
    Case("unknown-convergence", _config(metrics={"convergence": {"radus": 2.0}}), "metrics.convergence.radus",
         ("unknown key", "did you mean 'radius'")),
    Case("unknown-outputs", _config(outputs={"trace_trial": 2}), "outputs.trace_trial",
         ("unknown key", "did you mean 'trace_trials'")),
    # --- wrong types and out-of-range values ---------------------------------------------------
    Case("particles-not-int", _filter(particles="many"), "filter.particles", ("integer", "many")),
    Case("particles-zero", _filter(particles=0), "filter.particles", ("greater than or equal to 1",)),
    Case("trials-negative", _config(trials=-3), "trials", ("greater than or equal to 1",)),
    Case("ess-threshold-above-1", _filter(ess_threshold=1.5), "filter.ess_threshold", ("less than or equal to 1",)),
    Case("ess-threshold-negative", _filter(ess_threshold=-0.1), "filter.ess_threshold",
         ("greater than or equal to 0",)),
    Case("variance-negative", _model(process_noise={"variance": -1.0}), "model.process_noise.variance",
         (">= 0",)),
    Case("covariance-not-definite", _model_2d(measurement_noise={"variance": [[1.0, 2.0], [2.0, 1.0]]}),
         "model.measurement_noise.variance", ("positive",)),
    Case("covariance-singular", _model_2d(measurement_noise={"variance": [[1.0, 1.0], [1.0, 1.0]]}),
         "model.measurement_noise.variance", ("positive definite",)),
    Case("covariance-not-symmetric", _model_2d(measurement_noise={"variance": [[1.0, 0.5], [0.0, 1.0]]}),
         "model.measurement_noise.variance", ("symmetric",)),
    Case("variance-wrong-size", _model(measurement_noise={"variance": [1.0, 2.0]}),
         "model.measurement_noise.variance", ("expected 1 component", "got 2")),
    # --- unknown names, with a suggestion ------------------------------------------------------
    Case("unknown-model-kind", _model(kind="linear_gausian"), "model.kind",
         ("unknown", "did you mean 'linear_gaussian'")),
    Case("unknown-resampler", _filter(resampler="systemtic"), "filter.resampler",
         ("unknown", "did you mean 'systematic'")),
    Case("unknown-weighting", _filter(weighting="mahalanobs"), "filter.weighting.kind",
         ("unknown", "did you mean 'mahalanobis'")),
    Case("unknown-noise-family", _model(measurement_noise={"family": "gausian"}),
         "model.measurement_noise.family", ("unknown", "did you mean 'gaussian'")),
    Case("unknown-figure", _config(outputs={"figures": ["error_over_tim"]}), "outputs.figures[0]",
         ("unknown", "did you mean 'error_over_time'")),
    Case("model-without-kind", _config(model={"steps": 5, "transition_matrix": [[1.0]],
                                              "measurement_matrix": [[1.0]]}),
         "model.kind", ("missing", "linear_gaussian")),
    Case("student-t-without-df", _model(measurement_noise={"family": "student_t", "variance": 1.0}),
         "model.measurement_noise.df", ("df",)),
    # --- sweeps and arms ---------------------------------------------------------------------------
    Case("sweep-empty-list", _config(sweep={"filter.particles": []}), "sweep.filter.particles",
         ("at least 1",)),
    Case("sweep-bad-key", _config(sweep={"trials": [1, 2]}), "sweep.trials", ("model.", "filter.", "metrics.")),
    Case("sweep-bad-value", _config(sweep={"filter.particles": [10, -1]}), "sweep.filter.particles[1]",
         ("greater than or equal to 1",), run=True),
    Case("arm-bad-value", _config(arms={"fast": {"particles": 10}, "broken": {"resampler": "systemtic"}}),
         "arms.broken.resampler", ("unknown", "did you mean 'systematic'")),
    Case("arm-bad-name", _config(arms={"bad name": {"particles": 10}}), "arms.bad name", ("match",)),
    # --- command-line overrides ------------------------------------------------------------------
    Case("set-without-equals", _config(), None, ("--set", "key.path=value"),
         extra_args=("--set", "filter.particles")),
    Case("set-unknown-key", _config(), "filter.particels", ("unknown key", "did you mean 'particles'"),
         extra_args=("--set", "filter.particels=50"), run=True),
]

MODES = [(case, mode) for case in CASES for mode in (("validate", "run") if case.run else ("validate",))]
GOOD = "good.yaml"      # `pfx run` gets a valid config first: it must not run either (all are checked first)


def _prepare(folder: Path, case: Case, mode: str) -> None:
    folder.mkdir(parents=True)
    if case.content is not None:
        write_config_file(folder, case.content, FILE)
    if case.target == "a-folder":
        (folder / "a-folder").mkdir()
    if mode == "run" and not case.extra_args:
        write_config_file(folder, tiny_config_dict(), GOOD)


def _arguments(case: Case, mode: str) -> list[str]:
    if mode == "validate":
        return ["validate", case.target, *case.extra_args]
    configs = [case.target] if case.extra_args else [GOOD, case.target]
    return ["run", *configs, "--out", "out", *case.extra_args]


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory, run_pfx):
    """Run every (case, mode) once, concurrently; {(case id, mode): (folder, result, files before)}."""
    root = tmp_path_factory.mktemp("config-errors")
    jobs, folders = {}, {}
    for case, mode in MODES:
        folder = root / f"{case.id}-{mode}"
        _prepare(folder, case, mode)
        folders[(case.id, mode)] = (folder, sorted(p.name for p in folder.iterdir()))
        jobs[(case.id, mode)] = (_arguments(case, mode), folder)
    results = run_pfx.many(jobs, timeout=120)     # the timeout is a safety net (alias bomb), not a check
    return {key: (*folders[key], results[key]) for key in jobs}


PARAMS = [pytest.param(case, mode, id=f"{case.id}-{mode}",
                       marks=[pytest.mark.xfail(reason=case.xfail, strict=True)] if case.xfail else [])
          for case, mode in MODES]


@pytest.mark.parametrize("case, mode", PARAMS)
def test_config_error_is_one_clear_line(case: Case, mode: str, outcomes):
    folder, files_before, result = outcomes[(case.id, mode)]
    assert "Traceback" not in result.output
    assert result.returncode == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got:\n{result.stderr}"
    line = lines[0]
    assert line.startswith("pfx: error: "), line
    message = line[len("pfx: error: "):]
    assert message.startswith(case.target + ":"), f"the message must start with the file name: {line}"
    if case.location:
        assert re.match(case.location, message), f"expected position {case.location!r}: {line}"
    if case.key:
        assert f": {case.key}: " in message, f"key path {case.key!r} not named: {line}"
    for fragment in case.reason:
        assert fragment.lower() in message.lower(), f"reason lacks {fragment!r}: {line}"
    assert message.rstrip().rsplit(": ", 1)[-1].strip(), f"no reason: {line}"
    assert sorted(p.name for p in folder.iterdir()) == files_before, "the command wrote something"
    if mode == "run":
        assert result.stdout == ""
    if case.check:
        case.check(folder, result)
