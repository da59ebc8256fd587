"""Shared fixtures: run the ``pfx`` command line, share a Dask cluster, write small valid configs.

The suite runs in parallel (``make test``: pytest-xdist, ``-n logical --dist loadfile``), so a test
writes only below its own ``tmp_path`` (or ``tmp_path_factory``), never into the repository, and
depends on no other test. One worker runs all of a module's tests, so a module fixture runs once.
``@pytest.mark.slow`` marks the few tests that need a full-size run (``make test`` runs them too;
``pytest -m "not slow"`` leaves them out).

* ``pfx_in_process(*args, cwd=..., timeout=...)`` calls the command line's entry point
  (:func:`pfx.cli.main`) in the test's own process, as ``python -m pfx ARGS`` would run it:
  ``sys.argv``, the working folder, ``CI=1``, a fresh process's warning filters and plugin
  registries; stdout and stderr captured; the exit status from ``SystemExit``, and an uncaught exception printed as a
  traceback with status 1, as Python does. It returns a :class:`PfxResult` like ``run_pfx`` and
  costs no interpreter start (1.5 to 2 s of CPU each, most of it imports). Use it wherever a subprocess proves
  nothing more: messages, exit statuses, what is written.
* ``run_pfx(*args, cwd=..., timeout=...)`` runs ``python -m pfx ARGS`` in a real subprocess and
  returns a :class:`PfxResult` (``returncode, stdout, stderr = result`` also works). Keep it for
  what only a process shows: signals, locks between processes, the environment (PYTHONPATH
  shims), worker processes, and a few checks of the process's exit status itself.
  ``run_pfx.many({key: (args, cwd)})`` runs several invocations concurrently (one per CPU);
  ``pfx_in_process.many`` takes the same jobs and runs them one after the other.
* ``dask_cluster`` (session scope: one per xdist worker process that asks for it, so keep the
  tests that use it in one module, tests/test_dask.py): a Dask ``LocalCluster`` of 2
  single-threaded worker processes with nannies (a killed worker is restarted), on loopback, and
  a ``Client`` to it: ``cluster, client = dask_cluster``; ``cluster.scheduler_address`` is what
  ``pfx run --executor dask --scheduler`` takes. Skipped without the ``dask`` extra. A test that
  kills a worker waits for 2 workers first (``client.wait_for_workers(2)``).
* ``fresh_plugins``: every plugin the test loaded in this process (``pfx.load_plugin``, a
  ``pfx.run`` of a config with plugins) is unloaded after it, so that the worker's next test, of
  any module, sees pfx's own registries (a test module that loads plugins in process sets
  ``pytestmark = pytest.mark.usefixtures("fresh_plugins")``).
* ``backend`` runs a test once per backend of the particle filter, ``"numpy"`` then ``"jax"``
  (ids ``numpy``, ``jax``); the jax run is skipped, saying why, without the ``jax`` extra. An
  algorithm's check (the likelihood's unbiasedness, agreement with the Kalman filter, missing
  measurements, lost particles, a feature's own property) takes it and passes it on
  (``pfx.filter(..., backend=backend)``). A module fixture per backend reuses the list:
  ``@pytest.fixture(scope="module", params=BACKENDS)``. A check of the NumPy backend's own
  numbers or draws, bit for bit, is marked ``@pytest.mark.numpy_only`` instead.
* ``tiny_config_dict()`` is a fresh dict of a tiny, fast, valid experiment (1-D linear-Gaussian
  model, 5 steps, 20 particles, 4 trials); ``write_config(data, name)`` writes a dict (as YAML),
  text or bytes into ``tmp_path``; ``tiny_config`` is the tiny config written to a file.
"""

from __future__ import annotations

import contextlib
import copy
import importlib.metadata
import importlib.util
import io
import logging
import os
import signal
import subprocess
import sys
import traceback
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Iterator, NamedTuple, Optional

import pytest
import yaml

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TIMEOUT_S = 180      # a safety net against hangs, not a timing assertion

# JAX compiles each filter, PMMH and IF2 program it meets; the suite meets many of them more than
# once (a rerun, an extended run, the same config in another file). Its persistent compilation
# cache, shared by the workers and kept between sessions (a compiled program is keyed by its
# whole computation, the XLA flags and JAX's version, so a stale entry is never used), compiles
# each once. It changes no number. A first run in a clone compiles about 900 programs, a third of
# its CPU time, so the cache lives in the user's cache folder, not in the clone: a developer's
# next clone, or a worktree, starts warm. It is capped (JAX evicts the least recently used
# entries); ``JAX_COMPILATION_CACHE_DIR`` chooses another folder. Set here, before anything
# imports JAX; the subprocesses inherit it.
def _compilation_cache_folder() -> Path:
    user_cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    folder = Path(user_cache) / "pfx" / "jax-compilation-cache"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:                   # no writable home (a sandboxed build): the clone's own folder
        folder = REPO_ROOT / ".jax-cache"
    return folder


os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_compilation_cache_folder()))
os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(2 * 1024**3))     # bytes: 2 GiB
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
# Much of a JAX test's time is XLA compiling a program it runs once on a few particles (435 of
# the suite's 1,620 test-seconds from a fresh clone). Two code-generation settings cut it:
# - LLVM at optimisation level 1 compiles 10-30 % faster than at XLA's default 2, and runs the
#   few tests that run long (PMMH's 16 x 500 iterations) as fast (level 0 runs them 1.5-3 times
#   slower);
# - XLA:CPU's older fusion emitters instead of its MLIR ones: 8-25 % less time per test file.
# XLA's own passes, which decide what is computed and in what order, are unchanged (no fast-math):
# the same numbers, checked array for array on float64 and float32 runs (dacca-jax's cholera,
# the ekf proposal, the regularising move). `pfx bench` and `make gpu-check` measure the programs
# users get (gpu-check sets XLA_FLAGS, empty, for its tests too).
# XLA stops the process, without a Python traceback, at a flag it does not know, and jaxlib 0.11
# dropped the fusion-emitter switch (its MLIR emitters are the only ones): the switch is given only
# to the jaxlib versions that have it.
def _xla_flags() -> str:
    try:
        version = tuple(int(part) for part in importlib.metadata.version("jaxlib").split(".")[:2])
    except (importlib.metadata.PackageNotFoundError, ValueError):
        version = (0, 0)
    flags = ["--xla_backend_optimization_level=1"]
    if version < (0, 11):
        flags.append("--xla_cpu_use_fusion_emitters=false")
    return " ".join(flags)


if "XLA_FLAGS" not in os.environ:
    os.environ["XLA_FLAGS"] = _xla_flags()

# The particle filter's backends, for ``@pytest.fixture(params=BACKENDS)``: the jax one is
# skipped without the extra (found, not imported: a test imports JAX only when it runs on it).
BACKENDS = [
    pytest.param("numpy", id="numpy"),
    pytest.param("jax", id="jax", marks=pytest.mark.skipif(
        importlib.util.find_spec("jax") is None, reason="the jax backend needs the 'jax' extra (pip install 'pfx[jax]')")),
]


@pytest.fixture(params=BACKENDS)
def backend(request) -> str:
    """The particle filter's backend, ``"numpy"`` or ``"jax"``: the test runs once on each."""
    return request.param


TINY_CONFIG: dict[str, Any] = {
    "name": "tiny",
    "description": "a tiny experiment for the tests",
    "seed": 7,
    "trials": 4,
    "model": {
        "kind": "linear_gaussian",
        "steps": 5,
        "transition_matrix": [[1.0]],
        "measurement_matrix": [[1.0]],
    },
    "filter": {"particles": 20, "resampler": "systematic"},
    "outputs": {"trace_trials": 2},
}


class PfxResult(NamedTuple):
    returncode: int
    stdout: str
    stderr: str

    @property
    def output(self) -> str:
        return self.stdout + self.stderr


def _environment() -> dict[str, str]:
    env = dict(os.environ)
    env["CI"] = "1"                          # no progress bar
    # The suite runs several CLI processes side by side: one BLAS thread each avoids
    # oversubscribing the CPUs (results must not depend on it).
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(variable, "1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


class PfxRunner:
    """Callable that runs the real CLI as a subprocess (see the module docstring)."""

    def __init__(self, default_cwd: Path):
        self.default_cwd = Path(default_cwd)

    def __call__(self, *args: Any, cwd: Optional[Path] = None, timeout: float = DEFAULT_TIMEOUT_S) -> PfxResult:
        completed = subprocess.run(
            [sys.executable, "-m", "pfx", *[str(a) for a in args]],
            cwd=str(cwd or self.default_cwd), env=_environment(), capture_output=True, text=True,
            timeout=timeout, stdin=subprocess.DEVNULL)
        return PfxResult(completed.returncode, completed.stdout, completed.stderr)

    def many(self, jobs: dict[Any, tuple], timeout: float = DEFAULT_TIMEOUT_S) -> dict[Any, PfxResult]:
        """Run ``{key: (args, cwd)}`` concurrently; return ``{key: PfxResult}``."""
        workers = max(1, min(len(jobs), os.cpu_count() or 1))
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {key: pool.submit(self, *args, cwd=cwd, timeout=timeout)
                       for key, (args, cwd) in jobs.items()}
            return {key: future.result() for key, future in futures.items()}


@pytest.fixture(scope="session")
def run_pfx(tmp_path_factory) -> PfxRunner:
    """Run ``python -m pfx``; the default working folder is an empty temporary folder."""
    return PfxRunner(tmp_path_factory.mktemp("pfx-cwd"))


# The warning filters of a fresh `python -m pfx` process (Python's defaults), so that a warning
# the command line would print on stderr is printed by the in-process runner too.
FRESH_PROCESS_WARNING_FILTERS = (
    ("default", DeprecationWarning, "__main__"),
    ("ignore", DeprecationWarning, ""),
    ("ignore", PendingDeprecationWarning, ""),
    ("ignore", ImportWarning, ""),
    ("ignore", ResourceWarning, ""),
)


class InProcessPfx:
    """Callable with ``run_pfx``'s signature that runs :func:`pfx.cli.main` in this process
    (see the module docstring). What ``main`` may change for its process is put back after
    each call: ``sys.argv``, the environment, the working folder, the signal handlers, and the
    plugins it loaded (a plugin file registering the same names as another test's, from another
    folder, would otherwise be refused as taken)."""

    def __init__(self, default_cwd: Path):
        self.default_cwd = Path(default_cwd)

    def __call__(self, *args: Any, cwd: Optional[Path] = None, timeout: float = DEFAULT_TIMEOUT_S) -> PfxResult:
        from pfx.cli import main
        from pfx.config.plugins import loaded_plugins, unload_plugin

        plugins_before = {plugin.origin for plugin in loaded_plugins()}
        stdout, stderr = io.StringIO(), io.StringIO()
        saved_argv, saved_environment, saved_cwd = sys.argv, dict(os.environ), os.getcwd()
        saved_handlers = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
        status = 0
        try:
            os.environ["CI"] = "1"                      # no progress bar, as for run_pfx
            os.chdir(cwd or self.default_cwd)
            sys.argv = ["pfx", *[str(a) for a in args]]
            with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr), \
                    warnings.catch_warnings(record=True) as caught:
                warnings.resetwarnings()
                for action, category, module in reversed(FRESH_PROCESS_WARNING_FILTERS):
                    warnings.filterwarnings(action, category=category, module=module)
                try:
                    main()
                except SystemExit as exit:
                    status = _exit_status(exit.code, stderr)
                except Exception:                   # what Python does with an uncaught exception
                    traceback.print_exc(file=stderr)
                    status = 1
                for warning in caught:              # where a process would have printed them
                    stderr.write(warnings.formatwarning(warning.message, warning.category, warning.filename,
                                                        warning.lineno, warning.line))
        finally:
            sys.argv = saved_argv
            os.environ.clear()
            os.environ.update(saved_environment)
            os.chdir(saved_cwd)
            for number, handler in saved_handlers.items():
                signal.signal(number, handler)
            for plugin in loaded_plugins():             # a process's plugins end with it
                if plugin.origin not in plugins_before:
                    unload_plugin(plugin)
        return PfxResult(status, stdout.getvalue(), stderr.getvalue())

    def many(self, jobs: dict[Any, tuple], timeout: float = DEFAULT_TIMEOUT_S) -> dict[Any, PfxResult]:
        """Run ``{key: (args, cwd)}`` one after the other (one process has one working folder)."""
        return {key: self(*args, cwd=cwd, timeout=timeout) for key, (args, cwd) in jobs.items()}


def _exit_status(code: Any, stderr: io.StringIO) -> int:
    """The process exit status ``sys.exit(code)`` gives: None is 0, a message is printed and 1."""
    if code is None or isinstance(code, int):
        return code or 0
    print(code, file=stderr)
    return 1


@pytest.fixture
def fresh_plugins():
    """Unload, after the test, every plugin it loaded in this process (``pfx.load_plugin``,
    ``pfx.run`` of a config with plugins): the next test in this worker sees pfx's own
    registries, as a fresh process would (``pytestmark = pytest.mark.usefixtures("fresh_plugins")``)."""
    from pfx.config.plugins import loaded_plugins, unload_plugin

    before = {plugin.origin for plugin in loaded_plugins()}
    yield
    for plugin in loaded_plugins():
        if plugin.origin not in before:
            unload_plugin(plugin)


@pytest.fixture(scope="session")
def pfx_in_process(tmp_path_factory) -> InProcessPfx:
    """Call ``pfx.cli.main`` in this process; the default working folder is an empty temporary folder."""
    return InProcessPfx(tmp_path_factory.mktemp("pfx-in-process-cwd"))


@pytest.fixture(scope="session")
def dask_cluster():
    """One Dask cluster for the session (per xdist worker): ``(LocalCluster, Client)``."""
    distributed = pytest.importorskip("distributed", reason="the Dask tests need the 'dask' extra (in '.[test]')")
    import dask.config

    from pfx.run.executors.dask import WORKER_SETTINGS

    # as docs/dask.md advises for one's own workers; in force while it lives (a nanny restarting a
    # killed worker reads them again)
    with dask.config.set(WORKER_SETTINGS):
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                           dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL)
        client = distributed.Client(cluster, set_as_default=False)
        yield cluster, client
        client.close()
        cluster.close()


def tiny_config_dict(**changes: Any) -> dict:
    """A fresh copy of the tiny config, with top-level keys replaced by ``changes``."""
    data = copy.deepcopy(TINY_CONFIG)
    data.update(copy.deepcopy(changes))
    return data


@pytest.fixture(name="tiny_config_dict")
def tiny_config_dict_fixture():
    return tiny_config_dict


def write_config_file(folder: Path, data: Any, name: str = "config.yaml") -> Path:
    """Write a dict (as YAML), a str or bytes to ``folder/name``; return the path."""
    path = Path(folder) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, bytes):
        path.write_bytes(data)
    elif isinstance(data, str):
        path.write_text(data, encoding="utf-8")
    else:
        path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


@pytest.fixture
def write_config(tmp_path):
    """``write_config(data, name='config.yaml')`` writes into ``tmp_path``."""
    def write(data: Any, name: str = "config.yaml") -> Path:
        return write_config_file(tmp_path, data, name)
    return write


@pytest.fixture
def tiny_config(tmp_path) -> Path:
    """The tiny valid config, written to ``tmp_path/tiny.yaml``."""
    return write_config_file(tmp_path, tiny_config_dict(), "tiny.yaml")


def csv_fields(text: str) -> Iterator[str]:
    """Every comma-separated field of a CSV text (the tests' files hold no quoted commas)."""
    for line in text.splitlines():
        yield from line.split(",")
