"""pfx from Python: run a config and read its results as pandas tables (for notebooks).

Three names, the same machinery as the command line, nothing of its own::

    import pfx

    result = pfx.run("configs/examples/falling-body.yaml", overrides={"trials": 10})
    result.summary                          # summary.csv as a DataFrame
    result.compare("rmse_altitude")         # the table `pfx compare ... --metric rmse_altitude` prints
    later = pfx.load("runs/falling-body")   # the same Result, read back from the folder

* :func:`run` is ``pfx run CONFIG [--out OUT] [--set KEY=VALUE ...] [--quiet]``: the config is
  read and checked by the functions the command line uses (:func:`pfx.safe_yaml.load_config_file`,
  :func:`pfx.config.overrides.apply_overrides`, :func:`pfx.config.plan.build_plan`), the folder
  is checked and written by :func:`pfx.run.runner.run_plan` (studies too), on this process. A
  config may also be a dict, checked exactly like a YAML file holding the same data; its
  messages name the file ``<dict>``, and relative file names in it (a wall map) are read from
  the working directory.
* :func:`load` reads a finished result folder; :class:`Result` holds its tables, read by the
  folder's one reader (:mod:`pfx.result_folder`).
* :meth:`Result.compare` is ``pfx compare``: the same checks, the same function
  (:func:`pfx.analysis.compare.paired_comparison`), the same table, returned instead of
  written (a notebook call should not add files to a result folder; ``table.to_csv`` or the
  command writes it when wanted).

A user's mistake raises :class:`~pfx.errors.ConfigError` (or its subclass
:class:`~pfx.errors.UsageError`) whose ``str()`` is the very line the command line prints after
``pfx: error:``, and nothing is written. Unlike the command line, a call changes nothing in
the Python process around it: it installs no signal handlers (Ctrl-C, or a notebook's
interrupt, stops a run as a ``KeyboardInterrupt`` that keeps the finished cells, with a note
saying so) and leaves the C allocator alone (:func:`pfx.run.memory.keep_freed_memory`, which
makes the command faster for large particle counts, would keep a notebook's peak memory for
the life of its kernel).

This module is imported by ``import pfx``, so it imports nothing heavy until a function is
called: ``pfx --help`` stays fast.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Optional, Union

from pfx.errors import ConfigError, UsageError

if TYPE_CHECKING:          # pandas is imported where a table is read
    import pandas as pd

    from pfx.config.plan import Plan, StudyPlan

DICT_CONFIG_FILE = "<dict>"       # what messages and the manifest call a config given as a dict

ConfigSource = Union[str, "os.PathLike[str]", Mapping]
Overrides = Union[Mapping[str, Any], Sequence[str], None]


def run(config: ConfigSource, *, out: Optional[Union[str, os.PathLike]] = None, overrides: Overrides = None,
        quiet: bool = True, fresh: bool = False) -> Result:
    """Run a config as ``pfx run`` does and return its :class:`Result`.

    ``config``: a config file's path, or the config itself as a dict. ``out``: the result
    folder (default ``runs/<name>``, relative to the working directory). ``overrides``: a dict
    ``{"dotted.path": value}`` or a list of ``"dotted.path=value"`` texts, applied in order as
    ``--set`` applies them. ``quiet=False`` shows what the command shows: its messages and
    progress bar on stderr (the bar only on a terminal), the end-of-run table on stdout.
    ``fresh=True`` is ``--fresh``: recompute into a folder that holds other results. As with
    the command, running the same config again finds the folder up to date and only reads it.
    """
    from pfx.run.executors import make_executor
    from pfx.run.memory import check_fits, default_budget
    from pfx.run.progress_bar import show_progress
    from pfx.run.runner import check_folder, run_plan

    report = (lambda message: None) if quiet else _print_error_stream
    plan = _plan(config, overrides, report)
    target = Path("runs") / plan.experiment.name if out is None else Path(out)
    budget = default_budget()
    # The command's order of checks (folder, then memory), so that a config failing both gets
    # the same message from both; run_plan repeats them, harmlessly.
    check_folder(plan, target, fresh=fresh)
    check_fits(plan, budget)
    with make_executor("local", None, None) as executor:       # this process, as `pfx run` with no options
        where = executor.describe()
        if where:
            report(f"running on {where}")
        run_plan(plan, target, executor=executor, fresh=fresh, report=report,
                 progress=show_progress(quiet),
                 memory_budget=budget)
    if not quiet:
        print(f"{plan.experiment.name}: {plan.size_text} -> {target}")
        _print_run_summary(plan, target)
    return load(target)


def load(folder: Union[str, os.PathLike]) -> Result:
    """The :class:`Result` of a finished result folder (a filter run's or a study's).

    A folder that is missing, unfinished (an interrupted run) or not made by pfx raises
    :class:`~pfx.errors.ConfigError` naming it, as ``pfx compare`` and ``pfx figures`` do.
    """
    from pfx.result_folder import finished_manifest

    path = Path(folder)
    return Result(path, finished_manifest(path))


class Result:
    """A finished result folder, its tables as pandas DataFrames (read when first asked for).

    * ``folder`` (a Path), ``name``, ``manifest`` (manifest.json as a dict) and ``config`` (the
      resolved config as recorded in config.yaml: rerunning it gives the same tables).
    * ``trials``, ``summary``, ``steps_summary``, ``steps``, ``particles``, ``scene``: the
      tables of a filter run (docs/output-files.md); each is ``None`` when the folder has no such
      file (a run that kept no particle clouds, a model without a scene, a study).
    * ``tables``: every table the folder holds, by file name without ``.csv``: the filter
      run's tables above, the tables a study wrote (its manifest lists them), or an estimation
      run's (``chains``, ``posterior``, ``priors``; ``if2``, ``maximum_likelihood``). Each is also
      an attribute (``result.offspring``; ``tables`` has them all, whatever their names);
      another name is an AttributeError that lists them.
    * :meth:`compare`: ``pfx compare`` on this folder.
    """

    def __init__(self, folder: Path, manifest: dict):
        from pfx.result_folder import ResultFolder

        self.folder = Path(folder)
        self.manifest = manifest
        self._reader = ResultFolder(self.folder)
        self._read: dict[str, pd.DataFrame] = {}

    @property
    def name(self) -> str:
        return self.manifest.get("name", self.folder.name)

    @cached_property
    def config(self) -> dict:
        import yaml

        path = self.folder / "config.yaml"
        return yaml.safe_load(path.read_text(encoding="utf-8")) if path.is_file() else {}

    @property
    def is_study(self) -> bool:
        return "study" in self.manifest

    @property
    def table_names(self) -> list[str]:
        """The tables this folder holds, in the order the run (or the study) writes them."""
        if self.is_study:
            candidates = list(self.manifest.get("tables", []))
        elif "estimation" in self.manifest:
            from pfx.run.estimation import TABLES

            candidates = [name.removesuffix(".csv") for name in TABLES]
        else:
            from pfx.run.runner import OUTPUT_FILES

            candidates = [name.removesuffix(".csv") for name in OUTPUT_FILES if name.endswith(".csv")]
        return [name for name in candidates if (self.folder / f"{name}.csv").is_file()]

    def table(self, name: str) -> pd.DataFrame:
        """One table by name (``"trials"``, a study's ``"offspring"``, ...), read once."""
        if name not in self.table_names:
            raise KeyError(f"{self.folder} has no table {name!r}; it has: {', '.join(self.table_names) or 'none'}")
        if name not in self._read:
            self._read[name] = self._reader.table(name)
        return self._read[name]

    @property
    def tables(self) -> dict[str, pd.DataFrame]:
        """Every table of the folder by name (each read on this first access, then kept)."""
        return {name: self.table(name) for name in self.table_names}

    @property
    def trials(self) -> Optional[pd.DataFrame]:
        return self._run_table("trials")

    @property
    def summary(self) -> Optional[pd.DataFrame]:
        return self._run_table("summary")

    @property
    def steps_summary(self) -> Optional[pd.DataFrame]:
        return self._run_table("steps_summary")

    @property
    def steps(self) -> Optional[pd.DataFrame]:
        return self._run_table("steps")

    @property
    def particles(self) -> Optional[pd.DataFrame]:
        return self._run_table("particles")

    @property
    def scene(self) -> Optional[pd.DataFrame]:
        return self._run_table("scene")

    def _run_table(self, name: str) -> Optional[pd.DataFrame]:
        return self.table(name) if name in self.table_names else None

    def __getattr__(self, name: str) -> pd.DataFrame:
        # Called only for names that are not ordinary attributes: a study's tables. Private
        # names, and any name before __init__ has set the manifest (copy, pickle), are not tables.
        if name.startswith("_") or "manifest" not in self.__dict__:
            raise AttributeError(name)
        if name in self.table_names:
            return self.table(name)
        raise AttributeError(f"{type(self).__name__} of {self.folder} has no attribute or table {name!r}; "
                             f"its tables: {', '.join(self.table_names) or 'none'}")

    def __dir__(self):
        return sorted({*super().__dir__(), *self.table_names})

    def compare(self, metric: str, by: str = "arm", baseline: Any = None, higher_is_better: bool = False,
                bootstrap: Optional[int] = None, versus: Iterable[str] = ()) -> pd.DataFrame:
        """``pfx compare FOLDER --metric METRIC --by BY ...``: paired differences trial by trial.

        Returns the table the command prints and writes (see docs/comparing.md), without writing
        it. ``baseline`` may be the value itself (``50``) or its text (``"50"``), as on the command line.
        ``versus`` (``--versus``): other metric columns compared with ``metric`` within each cell.
        """
        from pfx.analysis.compare import paired_comparison
        from pfx.result_folder import finished_manifest

        # The command's checks and messages, in its order (pfx/cli.py `compare`).
        finished_manifest(self.folder, needs=("trials.csv",))
        try:
            trials = self.table("trials")
        except (ValueError, UnicodeDecodeError, OSError) as error:     # pandas' ParserError is a ValueError
            raise ConfigError(f"unreadable trials.csv: {error}", file=str(self.folder)) from None
        try:
            return paired_comparison(trials, metric, by, baseline, self._reader.label_columns,
                                     higher_is_better=higher_is_better, bootstrap=bootstrap,
                                     versus=[versus] if isinstance(versus, str) else versus)
        except ConfigError as error:
            raise error.located(file=str(self.folder / "trials.csv")) from None

    def __repr__(self) -> str:
        if self.is_study:
            size = f"study={self.manifest['study']!r}"
        elif "estimation" in self.manifest:
            estimation = self.manifest["estimation"]
            size = (f"cells={len(self.manifest.get('cells', []))}, {estimation['method']}: "
                    f"chains={estimation['chains']}, iterations={estimation['iterations']}")
        else:
            size = f"cells={len(self.manifest.get('cells', []))}, trials={self.manifest.get('trials')}"
        return (f"Result(name={self.name!r}, folder={str(self.folder)!r}, {size}, "
                f"tables=[{', '.join(self.table_names)}])")


# -- reading the config, as the command line does ---------------------------------------------------

def _plan(config: ConfigSource, overrides: Overrides, report: Callable[[str], None]) -> Plan | StudyPlan:
    """The validated plan of a config file or dict with the overrides applied (pfx/cli.py
    `_load_plan`: the same three steps), or the ConfigError the command would print; each arm
    value or sweep axis an override replaced is reported, as ``--set`` reports it."""
    from pfx.config.overrides import apply_overrides, blame_override
    from pfx.config.plan import build_plan
    from pfx.safe_yaml import load_config_file

    if isinstance(config, Mapping):
        file = DICT_CONFIG_FILE
        raw = _plain_data(config, file, "")
    elif isinstance(config, (str, os.PathLike)):
        file = str(config)
        raw = load_config_file(config)
    else:
        raise UsageError(f"expected a config file's path or a dict, not {type(config).__name__}", key="config")
    assignments = _assignments(overrides, file)
    changed, notes = apply_overrides(raw, assignments, file)
    try:
        plan = build_plan(changed, file)
    except ConfigError as error:            # a typo in an override is the override's, not the config's
        raise blame_override(error, raw, assignments, file, label="overrides") from None
    for note in notes:
        report(f"{file}: {note}")
    return plan


def _assignments(overrides: Overrides, file: str) -> list[str]:
    """``--set`` texts from the overrides: a dict's values written as YAML, which ``--set``
    reads back, so that a value means the same in both forms (``float("inf")`` is ``.inf``)."""
    import yaml

    if overrides is None:
        return []
    if isinstance(overrides, str):
        return [overrides]
    if isinstance(overrides, Mapping):
        assignments = []
        for dotted, value in overrides.items():
            if not isinstance(dotted, str) or "=" in dotted:
                raise UsageError(f"a key must be a dotted path without '=', not {dotted!r}", key="overrides")
            text = yaml.safe_dump(_plain_data(value, file, dotted), default_flow_style=True, width=float("inf"))
            assignments.append(f"{dotted}={text}")
        return assignments
    if isinstance(overrides, Sequence) and all(isinstance(item, str) for item in overrides):
        return list(overrides)
    raise UsageError("expected a dict {'dotted.path': value} or a list of 'dotted.path=value' texts, "
                     f"not {type(overrides).__name__}", key="overrides")


def _plain_data(value: Any, file: str, key: str) -> Any:
    """A copy of ``value`` as the plain data a YAML file holds (mappings, lists, text, numbers,
    booleans, null), so that a dict config is checked, hashed and recorded exactly like the file
    it could have been; a tuple becomes a list and a NumPy number or array plain numbers."""
    if isinstance(value, Mapping):
        return {name: _plain_data(item, file, f"{key}.{name}" if key else str(name)) for name, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain_data(item, file, f"{key}[{index}]") for index, item in enumerate(value)]
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    if hasattr(value, "tolist") and type(value).__module__ == "numpy":
        return _plain_data(value.tolist(), file, key)
    raise ConfigError(f"{type(value).__name__} is not config data (use mappings, lists, text, numbers, "
                      "booleans or None)", file=file, key=key or None)


# -- what `pfx run` shows when not quiet --------------------------------------------------------------

def _print_error_stream(message: str) -> None:
    print(message, file=sys.stderr)


def _print_run_summary(plan: Plan | StudyPlan, target: Path) -> None:
    """The end-of-run table and next command, as pfx/cli.py `_print_summary` (a study: none)."""
    from pfx.analysis.run_summary import print_run_summary
    from pfx.result_folder import read_manifest

    manifest = read_manifest(target)
    if manifest and "estimation" in manifest:
        from pfx.analysis.run_summary import print_estimation_summary

        print_estimation_summary(target, manifest, print)
    elif plan.cells and manifest and (target / "summary.csv").is_file():
        print_run_summary(target, manifest, print, rich_console=sys.stdout.isatty() and not os.environ.get("CI"))
