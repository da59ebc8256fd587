"""The ``pfx`` command line (Typer).

Every command turns a user's mistake (:class:`~pfx.errors.ConfigError`) into one line on
stderr and exit status 2, with no traceback and nothing written.
"""

from __future__ import annotations

import functools
import json
import os
import sys
from pathlib import Path
from typing import List, Optional

import typer
import yaml

from pfx.config.components import NAMES as COMPONENT_NAMES
from pfx.errors import ConfigError, ExecutorError, ModelContractError, ModelNumericalError, PluginFault
from pfx.run.interrupts import Interrupted, stop_on_signals

app = typer.Typer(add_completion=True, no_args_is_help=True, pretty_exceptions_enable=False,
                  context_settings={"help_option_names": ["-h", "--help"]},     # inherited by every command
                  help="pfx: run, compare and reproduce particle-filter experiments from YAML configs.")


def _print_version(requested: bool) -> None:
    if requested:
        from pfx import __version__

        typer.echo(f"pfx {__version__}")
        raise typer.Exit(0)


@app.callback()
def _global_options(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                 help="print the version and exit"),
    show_traceback: bool = typer.Option(False, "--traceback",
                                        help="errors show the Python traceback above their one line (for "
                                             "plugin developers; also PFX_TRACEBACK=1; allowed after the "
                                             "command too)"),
):
    """Options before any command: --version, and typer's shell-completion options.

    (The app's help text is the ``help`` given to ``typer.Typer`` above, not this docstring.)
    """
    if show_traceback:
        os.environ[TRACEBACK_VARIABLE] = "1"


# What `pfx list` can show, in the order it shows them: the one list of registries
# (pfx/config/components.py), whose modules are imported only when a listing is asked for.
LISTABLE = COMPONENT_NAMES


TRACEBACK_VARIABLE = "PFX_TRACEBACK"     # set to 1 (or pass --traceback): errors show their traceback too


def _fail(message: str, status: int = 2, error: Optional[BaseException] = None) -> None:
    if error is not None and os.environ.get(TRACEBACK_VARIABLE, "") not in ("", "0"):
        _print_traceback(error)
    typer.echo(f"pfx: error: {message}", err=True)
    raise typer.Exit(status)


def _print_traceback(error: BaseException) -> None:
    """For a plugin's developer: where an error came from (a worker's traceback travels as text)."""
    import traceback

    if isinstance(error, PluginFault) and error.details:
        typer.echo(error.details.rstrip(), err=True)
    elif error.__cause__ is not None:
        typer.echo("".join(traceback.format_exception(error.__cause__)).rstrip(), err=True)
    else:
        typer.echo("".join(traceback.format_exception(error)).rstrip(), err=True)


def _guarded(command):
    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except ConfigError as error:         # one found while running also says what the run kept
            _fail(_with_outcome(str(error), error), error=error)
        except (ModelNumericalError, ModelContractError, PluginFault, ExecutorError) as error:
            _fail(_with_outcome(str(error), error), status=1, error=error)
        except Interrupted as error:
            _fail(_with_outcome(f"interrupted by {error.signal_name}", error), status=128 + error.signal_number)
        except KeyboardInterrupt as error:
            _fail(_with_outcome("interrupted by SIGINT", error), status=130)
        except Exception as error:       # a plugin's exception that no stage turned into one line
            from pfx.config.plugin_faults import locate

            fault = locate(error)
            if fault is None:
                raise                    # pfx's own bug: its traceback is the report
            _fail(fault.one_line(), status=2, error=error)
    return wrapper


def _with_outcome(message: str, error: BaseException) -> str:
    """The error and what the run kept (the runner's note on the exception), in one line."""
    notes = getattr(error, "__notes__", None)
    return f"{message}; {notes[-1]}" if notes else message


def _show_progress(quiet: bool) -> bool:
    from pfx.run.progress_bar import show_progress

    return show_progress(quiet)


def _load_plan(path: Path, assignments: list[str], trials: Optional[int], report=None):
    from pfx.config.overrides import apply_overrides, blame_override
    from pfx.config.plan import build_plan
    from pfx.safe_yaml import load_config_file

    original = load_config_file(path)
    raw, notes = apply_overrides(original, assignments, str(path))
    try:
        plan = build_plan(raw, str(path), trials=trials)
    except ConfigError as error:            # a --set typo is the command line's, not the file's
        raise blame_override(error, original, assignments, str(path)) from None
    for note in notes if report else []:
        report(f"{path}: {note}")
    return plan


@app.command()
@_guarded
def run(
    configs: List[Path] = typer.Argument(..., help="config file(s)", show_default=False),
    out: Optional[Path] = typer.Option(None, "--out", help="result folder (default runs/<name>; "
                                       "with several configs, their parent)"),
    assignments: List[str] = typer.Option([], "--set", help="override a key: dotted.path=value"),
    trials: Optional[int] = typer.Option(None, "--trials", min=1, help="override the trial count"),
    workers: Optional[int] = typer.Option(None, "--workers", min=1, show_default=False,
                                          help="local worker processes (default 1), or the dask-local "
                                               "cluster's worker processes (default: one per CPU)"),
    executor_name: str = typer.Option("local", "--executor", metavar="local|dask|dask-local",
                                      help="where batches run: here, a Dask cluster at --scheduler, "
                                           "or a Dask cluster started here"),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", metavar="ADDRESS",
                                            help="the Dask scheduler, e.g. tcp://host:8786 (--executor dask)"),
    resume: bool = typer.Option(True, "--resume/--fresh", help="resume an interrupted run, or recompute"),
    quiet: bool = typer.Option(False, "--quiet", help="no progress bar or messages"),
    max_memory: Optional[str] = typer.Option(None, "--max-memory",
                                             help="memory for particle arrays, e.g. 4G (default: half the available)"),
):
    """Run every cell and trial of the config(s); write CSV tables and figures."""
    from pfx.run.executors import make_executor
    from pfx.run.memory import budget_from_option, check_fits, keep_freed_memory
    from pfx.run.runner import run_plan

    stop_on_signals()
    keep_freed_memory()
    executor = make_executor(executor_name, workers, scheduler)    # options checked, Dask imported
    budget = budget_from_option(max_memory)
    from pfx.run.runner import check_folder

    report = (lambda message: None) if quiet else (lambda message: typer.echo(message, err=True))
    plans = [_load_plan(path, assignments, trials, report) for path in configs]   # validate all first
    if out is None:
        targets = [Path("runs") / plan.experiment.name for plan in plans]
    else:
        targets = [out / plan.experiment.name for plan in plans] if len(plans) > 1 else [out]
    for index, target in enumerate(targets):
        if target in targets[:index]:
            raise ConfigError(f"two configs named {plans[index].experiment.name!r} would share the result "
                              f"folder {target}; rename one", file=plans[index].file, key="name")
        check_folder(plans[index], target, fresh=not resume)
        check_fits(plans[index], budget)
    with executor:                  # a Dask scheduler is reached (or a local cluster started) here
        where = executor.describe()
        if where:
            report(f"running on {where}")
        for plan, target in zip(plans, targets):
            run_plan(plan, target, executor=executor, fresh=not resume, report=report,
                     progress=_show_progress(quiet), memory_budget=budget)
            if not quiet:
                typer.echo(f"{plan.experiment.name}: {plan.size_text} -> {target}")
                _print_summary(plan, target)


def _print_summary(plan, target: Path) -> None:
    """The end-of-run table and next command (a study writes its own tables: none)."""
    from pfx.analysis.run_summary import print_run_summary
    from pfx.result_folder import read_manifest

    manifest = read_manifest(target)
    if manifest and "estimation" in manifest:
        from pfx.analysis.run_summary import print_estimation_summary

        print_estimation_summary(target, manifest, typer.echo)
    elif plan.cells and manifest and (target / "summary.csv").is_file():
        print_run_summary(target, manifest, typer.echo,
                          rich_console=sys.stdout.isatty() and not os.environ.get("CI"))


@app.command()
@_guarded
def validate(
    configs: List[Path] = typer.Argument(..., help="config file(s)", show_default=False),
    assignments: List[str] = typer.Option([], "--set", help="override a key: dotted.path=value"),
):
    """Check configs and print each fully resolved config (exit 0, or 2 on the first error)."""
    plans = [_load_plan(path, assignments, None, lambda message: typer.echo(message, err=True))
             for path in configs]
    for plan in plans:
        typer.echo(f"# {plan.file}: valid; {plan.size_text}; "
                   f"config hash {plan.config_hash}")
        typer.echo(yaml.safe_dump(plan.resolved, sort_keys=False).rstrip())


def _plugin_option(help_text: str):
    return typer.Option([], "--plugin", metavar="FILE|MODULE",
                        help=f"{help_text} (runs its code: docs/plugins.md)")


def _load_command_line_plugins(entries: List[str], installed: bool = False) -> list:
    """Import the plugins given with --plugin (files relative to the working folder) and, with
    ``installed``, those installed packages offer (entry-point group ``pfx.plugins``)."""
    from pfx.config.plugins import load_installed_plugins, load_plugins

    plugins = load_installed_plugins() if installed else []
    return plugins + load_plugins(entries)


@app.command(name="list")
@_guarded
def list_components(
    what: Optional[str] = typer.Argument(None, help=f"one of: {', '.join(LISTABLE)}"),
    plugins: List[str] = _plugin_option("also list the components of this plugin"),
):
    """List what a config can name, with a one-line description each (installed plugins'
    components too, marked with their plugin)."""
    from pfx.registry import closest_name

    if what is not None and what not in LISTABLE:
        hint = closest_name(what, LISTABLE)
        _fail(f"nothing called {what!r} to list" + (f" (did you mean {hint!r}?)" if hint else
                                                   f"; choose from {', '.join(LISTABLE)}"))
    registries = _registries()
    loaded = {plugin.origin: plugin.name for plugin in _load_command_line_plugins(plugins, installed=True)}
    for name in [what] if what else LISTABLE:
        typer.echo(f"{name}:")
        registry = registries[name]
        descriptions = registry.describe()
        width = max([18, *(len(item) for item in descriptions)])     # names aligned, however long
        for item, description in descriptions.items():
            origin = registry.origin(item)
            if origin is not None and origin not in loaded:
                continue          # registered by a plugin this command did not load (a Python session)
            marker = f" [plugin {loaded[origin]}]" if origin is not None else ""
            typer.echo(f"  {item:<{width}} {description}{marker}")


def _registries() -> dict:
    """Every listable registry by name, in LISTABLE's order (imports the registries' modules)."""
    from pfx.config.components import all_registries

    return all_registries()


@app.command()
@_guarded
def schema(
    output_format: str = typer.Option("json", "--format", help="json (JSON Schema) or markdown"),
    plugins: List[str] = _plugin_option("also document the components of this plugin"),
):
    """Print the JSON Schema of the config format (or the Markdown config reference)."""
    from pfx.config.schema import config_json_schema

    if output_format not in ("json", "markdown"):
        _fail(f"--format: unknown format {output_format!r} (json or markdown)")
    origins = [plugin.origin for plugin in _load_command_line_plugins(plugins)]
    if output_format == "json":
        typer.echo(json.dumps(config_json_schema(origins), indent=2))
    else:
        from pfx.config.reference import markdown_reference

        typer.echo(markdown_reference(origins))


@app.command()
@_guarded
def figures(
    result_dir: Path = typer.Argument(..., help="a result folder written by pfx run"),
    add: List[str] = typer.Option([], "--figure", metavar="NAME",
                                  help="add this figure (`pfx list figures`) to the folder and render it"),
):
    """Re-render a result folder's figures from its CSV files alone (or add one with --figure)."""
    from pfx.figures import FIGURES, render_figures
    from pfx.result_folder import FIGURES_PENDING, check_writable, finished_manifest, record_figures, write_manifest

    manifest = finished_manifest(result_dir)
    formats = tuple(manifest.get("formats", ["png"]))
    for name in add:
        if name not in FIGURES:
            raise ConfigError(f"--figure: {FIGURES.unknown_message(name)}", file=str(result_dir))
    if add:                               # the figures are added to the folder's record
        check_writable(result_dir)
    check_writable(result_dir / "figures", "figures folder")
    try:
        written = render_figures(result_dir, add or None, formats)
        drawn = {path.stem for path in written}
        for name in add:
            if name not in drawn:
                asked = getattr(FIGURES[name], "asks_for", None)
                needs = f": it draws what {asked} writes, which this folder's config did not ask for" if asked else ""
                typer.echo(f"{name}: nothing to draw from this folder's tables{needs} (not added)", err=True)
        if add:
            record_figures(result_dir, [name for name in add if name in drawn],
                           lambda config: _load_plan(config, [], None).config_hash)
        elif manifest.pop(FIGURES_PENDING, False):       # every figure is drawn now
            write_manifest(manifest, result_dir)
    except OSError as error:          # what the checks cannot see (a read-only file system for root)
        raise ConfigError(f"cannot write {error.filename or 'a figure'}: {error.strerror or error}",
                          file=str(result_dir)) from None
    for path in written:
        typer.echo(str(path))


@app.command()
@_guarded
def simulate(
    config: Path = typer.Argument(..., help="config file", show_default=False),
    out: Path = typer.Option(..., "--out", help="folder for simulations.csv and its figure"),
    paths: int = typer.Option(20, "--paths", help="paths to simulate (1 to 10,000)"),
    assignments: List[str] = typer.Option([], "--set", help="override a key: dotted.path=value"),
):
    """Simulate measurement paths from the config's model (seeded per path), over its recorded data."""
    from pfx.run.simulations import simulate_over_data

    plan = _load_plan(config, assignments, None, lambda message: typer.echo(message, err=True))
    for path in simulate_over_data(plan, out, paths):
        typer.echo(str(path))


@app.command()
@_guarded
def reproduce(
    papers: List[str] = typer.Argument(None, help="paper short names (default: all)"),
    configs_dir: Path = typer.Option(Path("configs/papers"), "--configs", help="folder of per-paper config folders"),
    out: Path = typer.Option(Path("results"), "--out", help="where results/<paper>/<experiment> go"),
    resume: bool = typer.Option(False, "--resume/--fresh", help="keep up-to-date results instead of recomputing"),
    quiet: bool = typer.Option(False, "--quiet", help="no progress bar"),
    plugin_store: Optional[Path] = typer.Option(None, "--plugin-store", show_default=False,
                                                help="where the folders' plugin code is kept, once per content "
                                                     "(default: <out>/plugins)"),
):
    """Regenerate the papers' tables and figures (what `make reproduce-papers` runs)."""
    from pfx.papers.reproduce import reproduce_papers
    from pfx.run.memory import keep_freed_memory

    stop_on_signals()
    keep_freed_memory()
    reproduce_papers(papers or [], configs_dir, out, fresh=not resume, plugin_store=plugin_store,
                     report=lambda message: typer.echo(message, err=True), progress=_show_progress(quiet))


@app.command()
@_guarded
def compare(
    result_dir: Path = typer.Argument(..., help="a result folder written by pfx run"),
    metric: str = typer.Option(..., "--metric", help="metric column of trials.csv (e.g. rmse_position)"),
    by: str = typer.Option("arm", "--by", help="label column whose values are compared"),
    baseline: Optional[str] = typer.Option(None, "--baseline",
                                           help="the value the others are compared with (default: the first)"),
    higher_is_better: bool = typer.Option(False, "--higher-is-better",
                                          help="a win is a higher metric value (default: lower)"),
    bootstrap: Optional[int] = typer.Option(None, "--bootstrap", min=100, metavar="B",
                                            help="percentile-bootstrap interval from B resamples "
                                                 "(default: t-interval)"),
    versus: Optional[list[str]] = typer.Option(None, "--versus", metavar="COLUMN",
                                               help="compare --metric with this other metric of the same "
                                                    "trials, within each cell (repeatable; e.g. a smoother's "
                                                    "rmse_ffbs_position against the filter's rmse_position)"),
):
    """Paired differences between arms (or any label column), trial by trial, with 95% intervals."""
    from pfx.analysis.compare import VERSUS, format_table, output_name, paired_comparison
    from pfx.result_folder import ResultFolder, check_writable, finished_manifest, write_csv

    finished_manifest(result_dir, needs=("trials.csv",))
    check_writable(result_dir)              # the comparison's CSV is written into it
    folder = ResultFolder(result_dir)
    try:
        trials = folder.trials
    except (ValueError, UnicodeDecodeError, OSError) as error:     # pandas' ParserError is a ValueError
        raise ConfigError(f"unreadable trials.csv: {error}", file=str(result_dir)) from None
    try:
        table = paired_comparison(trials, metric, by, baseline, folder.label_columns,
                                  higher_is_better=higher_is_better, bootstrap=bootstrap, versus=versus or ())
    except ConfigError as error:
        raise error.located(file=str(result_dir / "trials.csv")) from None
    target = result_dir / output_name(metric, by, versus or ())
    try:
        write_csv(table, target)
    except OSError as error:
        raise ConfigError(f"cannot write {target.name}: {error.strerror or error}", file=str(result_dir)) from None
    typer.echo(format_table(table, VERSUS if versus else by))
    typer.echo(f"wrote {target}", err=True)


@app.command()
@_guarded
def bench(
    quick: bool = typer.Option(False, "--quick", help="small sizes only (seconds, for tests)"),
    repeats: int = typer.Option(3, "--repeats", min=1, help="runs per implementation and case (best counts)"),
    budget: float = typer.Option(20.0, "--budget", min=0.0,
                                 help="seconds after which an implementation is not repeated in a case"),
    peers: bool = typer.Option(True, "--peers/--no-peers", help="time particles, filterpy, pfilter if installed"),
    workers: bool = typer.Option(True, "--workers/--no-workers", help="measure --workers 2 against 1"),
    memory: bool = typer.Option(True, "--memory/--no-memory", help="measure memory per particle"),
    algorithms: bool = typer.Option(True, "--algorithms/--no-algorithms",
                                    help="time the proposals, APF, moves, KLD and injection against the bootstrap"),
    pmmh: bool = typer.Option(True, "--pmmh/--no-pmmh",
                              help="time a PMMH iteration (1 and 16 chains) against particles' PMMH"),
    quiet: bool = typer.Option(False, "--quiet", help="no progress lines on stderr"),
    backend: str = typer.Option("numpy", "--backend",
                                help="numpy: the benchmark above; jax: pfx's numpy and jax backends beside a plain JAX "
                                     "filter, particle-steps/s and the fraction of the memory-bandwidth limit (of the "
                                     "other options only --quick, --repeats, --budget, --bandwidth, --quiet apply)"),
    bandwidth: Optional[float] = typer.Option(None, "--bandwidth", min=0.0,
                                              help="--backend jax: the device's memory bandwidth in bytes/s (default: "
                                                   "the maker's figure for a known GPU, else the column is blank)"),
):
    """Benchmark: ns per particle-step of pfx, a plain NumPy filter, the Python peers, and pfx's algorithms;
    a PMMH iteration against particles'. With --backend jax: pfx's jax backend beside a plain JAX filter."""
    from pfx.bench import run_bench, run_jax_bench

    if backend not in ("numpy", "jax"):
        _fail(f"--backend: numpy or jax, not {backend!r}")
    if backend == "jax":
        from pfx.bench.jax_bench import jax_missing

        if jax_missing():
            _fail(jax_missing())

    # A full benchmark takes minutes: say what is being timed, one plain line per case and
    # implementation, on a terminal and in a redirected log alike; not in CI, where logs are
    # read after the fact and the report says it all.
    def show(message: str) -> None:
        typer.echo(f"  ... {message}", err=True)

    def hide(message: str) -> None:
        pass

    progress = hide if quiet or os.environ.get("CI") else show
    if backend == "jax":
        run_jax_bench(quick=quick, repeats=repeats, budget=budget, bandwidth=bandwidth, echo=typer.echo,
                      progress=progress)
        return
    run_bench(quick=quick, repeats=repeats, budget=budget, peers=peers, workers=workers, memory=memory,
              algorithms=algorithms, pmmh=pmmh, echo=typer.echo, progress=progress)


def _one_thread_per_process() -> None:
    """One BLAS/OpenMP thread per process unless the user chose otherwise.

    pfx runs in parallel by processes (``--workers``); BLAS threads would compete with them
    for the same cores, and OpenBLAS's idle threads spin. Must run before numpy is imported.
    """
    for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(variable, "1")


def main() -> None:
    """Entry point: command-line usage errors, too, are one line and exit status 2."""
    _one_thread_per_process()
    if "--traceback" in sys.argv[1:]:     # anywhere on the line: `pfx run x.yaml --traceback` too
        sys.argv = [sys.argv[0], *(argument for argument in sys.argv[1:] if argument != "--traceback")]
        os.environ[TRACEBACK_VARIABLE] = "1"
    try:
        result = app(prog_name="pfx", standalone_mode=False)
    except Exception as error:  # typer's (or click's) UsageError family, whichever package provides it
        if not hasattr(error, "format_message") or getattr(error, "exit_code", None) != 2:
            raise
        if type(error).__name__ == "NoArgsIsHelpError":
            typer.echo(error.format_message())
            sys.exit(0)
        typer.echo(f"pfx: error: {' '.join(error.format_message().split())}", err=True)
        sys.exit(2)
    sys.exit(result if isinstance(result, int) else 0)


if __name__ == "__main__":
    main()
