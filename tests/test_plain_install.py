"""A plain install (``pip install .``, no extras) runs everything that needs no extra.

JAX and Dask are optional extras (docs/backends.md, docs/dask.md): pfx imports them only when a
run asks for them, and where one is missing it says so in one line naming the extra. The main
environment of ``make test`` has every extra installed, so it cannot see a module-level import
of one; these tests therefore build a second environment, ``.venv-plain``, with ``pip install .``
and nothing more, and run pfx there as a user who installed it that way would:

* every module of the package imports, except the few that *are* a backend or an executor of an
  extra (:data:`NEEDS_AN_EXTRA`): a new module-level import of JAX or Dask elsewhere fails here;
* every config of ``configs/examples/`` runs (filter configs at two trials, the figures of one of
  them drawn, the PMMH and IF2 configs at a few iterations: the code paths, not the numbers, are
  what is checked);
* ``backend: jax`` and ``--executor dask-local`` are refused in one line naming the extra.

The environment is made once (about half a minute: pfx's dependencies from PyPI, not compiled to
bytecode, as Python compiles what it imports) and kept; each test
session reinstalls pfx itself into it (``pip install --no-deps --no-build-isolation .``, with the
build requirements installed there once), so the code tested is the working tree's, built and
installed as ``pip install .`` builds it (package data included).

They run apart from ``make test`` (marker ``plain_install``): ``make check-plain-install`` runs them,
and CI's ``.ci/run`` runs that after the suite, so every change is still checked on a plain install.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import venv
from pathlib import Path

import pytest

# `make test` leaves these out; `make check-plain-install` runs them, and CI runs that after it.
pytestmark = pytest.mark.plain_install

ROOT = Path(__file__).resolve().parent.parent
PLAIN = ROOT / ".venv-plain"
EXTRAS = ("jax", "jaxlib", "dask", "distributed")

# The modules that are a backend or an executor of an optional extra: they import it at their top,
# and only a run that asks for the extra imports them.
NEEDS_AN_EXTRA = {
    "pfx.bench.jax_reference": "jax",
    "pfx.estimation.compiled_if2": "jax",
    "pfx.filters.particle.jax_engine": "jax",
    "pfx.filters.particle.jax_resampling": "jax",
    "pfx.run.executors.dask": "dask",
}

FILTER_CONFIGS = sorted(path for path in (ROOT / "configs" / "examples").glob("*.yaml")
                        if "estimation:" not in path.read_text())
ESTIMATION_CONFIGS = sorted(path for path in (ROOT / "configs" / "examples").glob("*.yaml")
                            if "estimation:" in path.read_text())


def _pyproject() -> dict:
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())


# pyproject's build requirements (setuptools), installed into the environment once, so that each
# session rebuilds pfx there without fetching them again (pip's build isolation would)
BUILD_REQUIREMENTS = _pyproject()["build-system"]["requires"]


def _dependencies_stamp() -> str:
    """What decides the environment's third-party packages: pyproject's dependencies and build
    requirements."""
    pyproject = _pyproject()
    return hashlib.sha256(json.dumps([pyproject["project"]["dependencies"], BUILD_REQUIREMENTS]).encode()).hexdigest()


def _pip(python: Path, *arguments: str) -> None:
    result = subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                             *arguments], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, f"pip install {' '.join(arguments)} failed:\n{result.stdout}\n{result.stderr}"


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> dict:
    """``.venv-plain`` with pfx installed as ``pip install .`` installs it (no extras)."""
    python = PLAIN / "bin" / "python"
    stamp_file = PLAIN / ".dependencies"
    stamp = _dependencies_stamp()
    if not python.exists() or not stamp_file.exists() or stamp_file.read_text() != stamp:
        venv.create(PLAIN, with_pip=True, clear=True)
        _pip(python, "--no-compile", ".")                    # pfx and its dependencies, no extra
        _pip(python, "--no-compile", *BUILD_REQUIREMENTS)    # to rebuild pfx here, without a download
        stamp_file.write_text(stamp)
    else:                                                    # the working tree's pfx, as pip builds it
        # setuptools copies into build/lib and never deletes there: a module removed from the
        # tree would stay in the wheel
        shutil.rmtree(ROOT / "build", ignore_errors=True)
        _pip(python, "--no-deps", "--force-reinstall", "--no-build-isolation", "--no-compile", ".")
    present = subprocess.run([str(python), "-c", "import importlib.util as u; "
                              f"print([m for m in {EXTRAS!r} if u.find_spec(m)])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    assert present == "[]", f"the plain environment has an extra installed: {present}"
    home = tmp_path_factory.mktemp("plain-home")
    environment = {key: value for key, value in os.environ.items() if not key.startswith(("PYTHON", "VIRTUAL_ENV"))}
    environment.update(MPLBACKEND="Agg", HOME=str(home), NUMBA_CACHE_DIR=str(PLAIN / "numba-cache"))
    return {"python": python, "pfx": PLAIN / "bin" / "pfx", "env": environment, "cwd": home}


def _name(config: Path) -> str:
    return next(line.split(":", 1)[1].strip() for line in config.read_text().splitlines() if line.startswith("name:"))


def _run(plain: dict, *arguments: str) -> subprocess.CompletedProcess:
    # run outside the repository, so that the installed package is imported, not the working tree
    return subprocess.run([str(plain["pfx"]), *arguments], cwd=plain["cwd"], env=plain["env"],
                          capture_output=True, text=True, timeout=900)


def test_every_module_imports_but_the_backends_of_an_extra(plain):
    script = """
import importlib, json, pkgutil, pfx
failed = {}
for module in pkgutil.walk_packages(pfx.__path__, "pfx."):
    try:
        importlib.import_module(module.name)
    except ModuleNotFoundError as error:
        failed[module.name] = error.name.split(".")[0]
print(json.dumps(failed))
"""
    result = subprocess.run([str(plain["python"]), "-c", script], cwd=plain["cwd"], env=plain["env"],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    failed = json.loads(result.stdout.strip().splitlines()[-1])
    assert failed == NEEDS_AN_EXTRA, (
        "modules that need an optional extra changed; a module that a plain run imports must import "
        f"JAX or Dask only inside the function that asks for it: {failed}")


def test_every_example_filter_config_runs(plain, tmp_path):
    # figures only for the first: matplotlib is no extra, and drawing them all would double the time
    result = _run(plain, "run", *map(str, FILTER_CONFIGS[1:]), "--trials", "2", "--out", str(tmp_path), "--quiet",
                  "--set", "outputs.figures=[]")
    assert result.returncode == 0, result.stderr[-3000:]
    drawn = _run(plain, "run", str(FILTER_CONFIGS[0]), "--trials", "2", "--out", str(tmp_path / "drawn"), "--quiet")
    assert drawn.returncode == 0, drawn.stderr[-3000:]
    assert list((tmp_path / "drawn" / "figures").glob("*.png")), f"{FILTER_CONFIGS[0].name}: no figure drawn"
    for config in FILTER_CONFIGS[1:]:
        folder = tmp_path / _name(config)
        assert (folder / "trials.csv").is_file() and (folder / "summary.csv").is_file(), config.name


def test_one_estimation_of_each_method_runs(plain, tmp_path):
    methods = {config.name: next(line.split(":")[1].strip() for line in config.read_text().splitlines()
                                 if line.strip().startswith("method:"))
               for config in ESTIMATION_CONFIGS}
    assert {"pmmh", "if2"} <= set(methods.values()), methods
    for config in ESTIMATION_CONFIGS:        # warm_up is PMMH's (an IF2 config refuses it)
        shorter = ["--set", "estimation.warm_up=2"] if methods[config.name] == "pmmh" else []
        result = _run(plain, "run", str(config), "--out", str(tmp_path / _name(config)), "--quiet",
                      "--set", "estimation.iterations=6", *shorter)
        assert result.returncode == 0, result.stderr[-3000:]
    table = {"pmmh": "posterior.csv", "if2": "maximum_likelihood.csv", "profile": "profile.csv"}
    for config, method in methods.items():
        folder = tmp_path / _name(ROOT / "configs" / "examples" / config)
        assert (folder / table[method]).is_file(), f"{config}: no {table[method]}"


def test_the_jax_backend_is_refused_naming_the_extra(plain, tmp_path):
    config = ROOT / "configs" / "examples" / "linear-gaussian.yaml"
    result = _run(plain, "run", str(config), "--set", "filter.backend=jax", "--out", str(tmp_path / "out"))
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "pfx[jax]" in lines[0] and "backend" in lines[0], result.stderr
    assert not (tmp_path / "out").exists()


def test_dask_is_refused_naming_the_extra(plain, tmp_path):
    config = ROOT / "configs" / "examples" / "linear-gaussian.yaml"
    result = _run(plain, "run", str(config), "--executor", "dask-local", "--out", str(tmp_path / "out"))
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "pfx[dask]" in lines[0], result.stderr
    assert not (tmp_path / "out").exists()
