"""docs/extending.md, performed: each "add a ..." story of the page, done to a copy of pfx.

Every story copies the package (and the generated doc pages) into a temporary folder, makes there
exactly the edits the page asks for -- a new module, an import line, a registration, a list entry
-- and nothing else (checked: the files that differ from the fresh copy are exactly the ones the
story edited). Then one subprocess with the copy on ``PYTHONPATH`` drives the real command line
(``pfx.cli.main``, several commands in one process to save start-up time): ``pfx list`` shows the
new component with its description, the JSON Schema ``pfx schema`` prints accepts a config naming
it while the unmodified copy's schema refuses that config, a tiny config using it runs with
``pfx run CONFIG --out DIR``, its result folder shows it, and ``python -m pfx.config.reference
--update`` and ``pfx schema > docs/config.schema.json`` bring the generated pages along.

The stories run concurrently (a module fixture starts them all); each test waits for its own.
Each copies the same copy of the package, compiled to bytecode once (:func:`compiled_package`).
"""

from __future__ import annotations

import ast
import compileall
import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

import jsonschema
import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import REPO_ROOT, tiny_config_dict, write_config_file

PACKAGE = REPO_ROOT / "pfx"
# The pages `python -m pfx.config.reference --update` and `pfx schema > ...` regenerate.
GENERATED_PAGES = ("docs/configuration.md", "docs/figures.md", "docs/config.schema.json")
TIMEOUT_S = 300          # a safety net against hangs, not a timing assertion
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

# Runs in the subprocess: each step is a command line of `pfx` (through pfx.cli.main, the
# console script's entry point), a module run as `python -m`, or a snippet of Python; what each
# printed and its exit status go to a JSON file.
DRIVER = r'''
import contextlib, io, json, runpy, sys, traceback
from pathlib import Path

steps = json.loads(Path(sys.argv[1]).read_text())
target = Path(sys.argv[2])
import pfx
from pfx.cli import main

results = {"pfx": pfx.__file__, "steps": {}}
for name, step in steps.items():
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            if "cli" in step:
                sys.argv = ["pfx", *step["cli"]]
                main()
            elif "module" in step:
                sys.argv = [step["module"], *step.get("argv", [])]
                runpy.run_module(step["module"], run_name="__main__", alter_sys=True)
            else:
                exec(step["code"], {"__name__": "__step__"})
            code = 0
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else int(stop.code is not None)
        except BaseException:
            traceback.print_exc()
            code = "exception"
    if step.get("stdout_to"):
        Path(step["stdout_to"]).write_text(out.getvalue())
    results["steps"][name] = {"code": code, "stdout": out.getvalue(), "stderr": err.getvalue()}
target.write_text(json.dumps(results))
'''


# -- the copy and its edits -----------------------------------------------------------------------

class PackageCopy:
    """``root/src/pfx``: a copy of the package to edit as docs/extending.md says, plus copies of
    the generated doc pages under ``root/docs``; every edit is recorded in :attr:`touched`."""

    def __init__(self, root: Path, package: Path = PACKAGE):
        self.root = root
        self.src = root / "src"
        # With the bytecode (``package``: the repository's, or :func:`compiled_package`'s copy of
        # it): copytree keeps each file's time, so Python (and numba's cache) take a compiled
        # module for the same source as valid, and a module a story edits is compiled again.
        # Without it, every process of every copy compiles each module it imports, again.
        shutil.copytree(package, self.src / "pfx")
        for page in GENERATED_PAGES:
            (root / page).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO_ROOT / page, root / page)
        self.touched: dict[str, str] = {}        # path (pfx/..., tests/..., configs/...) -> new | edited
        # the fresh copy's contents, to tell what the story changed (the repository may change meanwhile)
        self.fresh = {relative: path.read_bytes() for relative, path in self._files()}

    def path(self, relative: str) -> Path:
        return (self.src if relative.startswith("pfx/") else self.root) / relative

    def new_file(self, relative: str, text: str) -> None:
        path = self.path(relative)
        assert not path.exists(), f"{relative} exists already"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        self.touched[relative] = "new"

    def copy_test(self, name: str) -> None:
        """A test module of the repository, to edit in the copy (``tests/<name>``)."""
        (self.root / "tests").mkdir(exist_ok=True)
        shutil.copy2(REPO_ROOT / "tests" / name, self.root / "tests" / name)
        self.fresh[f"tests/{name}"] = (self.root / "tests" / name).read_bytes()

    def replace(self, relative: str, old: str, new: str) -> None:
        """Replace the one occurrence of ``old``."""
        path = self.path(relative)
        text = path.read_text()
        assert text.count(old) == 1, f"{relative}: expected {old!r} once, found it {text.count(old)} times"
        path.write_text(text.replace(old, new))
        self.touched.setdefault(relative, "edited")

    def insert(self, relative: str, text: str, *, before: str) -> None:
        """Insert ``text`` just before the one occurrence of ``before``."""
        self.replace(relative, before, text + before)

    def append(self, relative: str, text: str) -> None:
        path = self.path(relative)
        assert path.read_text().endswith("\n")
        with path.open("a") as file:
            file.write(text)
        self.touched.setdefault(relative, "edited")

    def _files(self):
        """(path, file) of every file of the copy's package, tests and configs, caches aside."""
        for part in ("pfx", "tests", "configs"):
            base = self.src if part == "pfx" else self.root
            for path in sorted((base / part).rglob("*")):
                if path.is_file() and "__pycache__" not in path.parts:
                    yield path.relative_to(base).as_posix(), path

    def changed_files(self) -> dict[str, str]:
        """What differs from the fresh copy, file by file: path -> new | edited."""
        return {relative: "new" if relative not in self.fresh else "edited"
                for relative, path in self._files() if self.fresh.get(relative) != path.read_bytes()}


def compiled_package(folder: Path) -> Path:
    """A copy of the package in ``folder``, every module compiled to bytecode, for the stories to
    copy. A fresh clone has no bytecode, and with PYTHONDONTWRITEBYTECODE set no process writes
    any: each of the file's dozen processes would compile the modules it imports (about half a
    second each); compiled once here (about as long), they load them."""
    package = folder / "pfx"
    shutil.copytree(PACKAGE, package)
    compileall.compile_dir(package, quiet=1)        # writes the bytecode whatever PYTHONDONTWRITEBYTECODE says
    return package


def block(source: str) -> str:
    """A top-level definition to insert before another one: dedented, two blank lines after."""
    return textwrap.dedent(source).strip("\n") + "\n\n\n"


def module(source: str) -> str:
    return textwrap.dedent(source).lstrip("\n")


# -- running the copy -----------------------------------------------------------------------------

def _environment(copy: PackageCopy, jit: bool = False) -> dict[str, str]:
    env = dict(os.environ)
    env.update(PYTHONPATH=str(copy.src), CI="1", MPLBACKEND="Agg")       # the copy, never the repository
    if not jit:
        # The compiled loops run as the plain Python they are written in: compiling them in every
        # fresh copy costs more than these tiny runs (tests/test_compiled.py checks they agree).
        env["NUMBA_DISABLE_JIT"] = "1"
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(variable, "1")
    return env


def cli(*args: Any, stdout_to: str | None = None) -> dict:
    step: dict[str, Any] = {"cli": [str(a) for a in args]}
    if stdout_to:
        step["stdout_to"] = stdout_to
    return step


# `python -m pfx.config.reference --update`, then `pfx schema > docs/config.schema.json` (whose
# output is also the schema the story's configs are validated against).
REGENERATE = {"reference": {"module": "pfx.config.reference", "argv": ["--update"]},
              "schema": cli("schema", stdout_to="docs/config.schema.json")}


class Steps(dict):
    """Step name -> {code, stdout, stderr} of one driver run."""

    def ok(self, name: str) -> str:
        """The stdout of a step that must have succeeded."""
        step = self[name]
        assert step["code"] == 0, f"{name}: exit {step['code']}\n{step['stdout'][-2000:]}\n{step['stderr'][-3000:]}"
        return step["stdout"]


def drive(copy: PackageCopy, steps: dict[str, dict], label: str = "steps", jit: bool = False) -> Steps:
    """Run the steps in one subprocess on the copy (working folder: the copy's root)."""
    driver = copy.root / "driver.py"
    driver.write_text(DRIVER)
    (copy.root / f"{label}.json").write_text(json.dumps(steps))
    completed = subprocess.run(
        [sys.executable, str(driver), f"{label}.json", f"{label}-results.json"], cwd=copy.root,
        env=_environment(copy, jit), capture_output=True, text=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL)
    assert completed.returncode == 0, completed.stderr[-3000:]
    results = json.loads((copy.root / f"{label}-results.json").read_text())
    assert Path(results["pfx"]).is_relative_to(copy.src), f"imported {results['pfx']}, not the copy"
    return Steps(results["steps"])


def listed(output: str, what: str, name: str) -> str | None:
    """The description `pfx list` prints for ``name`` under ``what:`` (models, noises, ...), or None."""
    section = None
    for line in output.splitlines():
        if re.fullmatch(r"\w+:", line):
            section = line[:-1]
        match = re.fullmatch(r"  (\S+) +(.*)", line)
        if section == what and match and match.group(1) == name:
            return match.group(2)
    return None


def schema_errors(schema_text: str, config: dict) -> list[str]:
    validator = jsonschema.Draft202012Validator(json.loads(schema_text))
    return [error.message for error in validator.iter_errors(config)]


def tiny(name: str, **changes: Any) -> dict:
    """conftest's tiny config (1-D linear-Gaussian, 5 steps, 20 particles), 2 trials, no figures."""
    return tiny_config_dict(**{"name": name, "trials": 2, "outputs": {"trace_trials": 1, "figures": []}, **changes})


class Story:
    """What a story's checks need: the copy, its driver steps, and the unmodified copy's."""

    def __init__(self, copy: PackageCopy, steps: Steps, baseline: Steps):
        self.copy, self.steps, self.baseline = copy, steps, baseline

    def assert_listed(self, what: str, name: str, description: str) -> None:
        """`pfx list <what>` shows the name with its description; the unmodified copy does not."""
        assert listed(self.steps.ok("list"), what, name) == description, self.steps["list"]["stdout"]
        assert listed(self.baseline.ok("list"), what, name) is None

    def assert_schema_accepts(self, config: dict) -> None:
        """The copy's `pfx schema` accepts the config; the unmodified copy's refuses it."""
        assert schema_errors(self.steps.ok("schema"), config) == []
        assert schema_errors(self.baseline.ok("schema"), config), "the unmodified schema accepted it too"

    def assert_regenerated(self, page: str, text: str) -> None:
        """A page regenerated in the copy shows ``text``, which the repository's page does not."""
        assert text in (self.copy.root / page).read_text(), f"{page} lacks {text!r}"
        assert text not in (REPO_ROOT / page).read_text()

    def assert_touched(self, expected: dict[str, str]) -> None:
        """The story edited exactly these files, and nothing else differs from the fresh copy."""
        assert self.copy.touched == expected
        assert self.copy.changed_files() == expected

    def result(self, folder: str = "out") -> Path:
        return self.copy.root / folder


# -- the stories ----------------------------------------------------------------------------------

STORIES: dict[str, Callable[[PackageCopy, Callable[[], Steps]], None]] = {}


def story(function):
    STORIES[function.__name__.removeprefix("add_")] = function
    return function


DRIFT_WALK = module(r'''
    """A random walk with drift on a line, observed directly (added by tests/test_extending.py).

    x_k = x_{k-1} + drift dt + w_k, z_k = x_k + v_k.
    """

    from __future__ import annotations

    from typing import Literal

    import numpy as np
    from pydantic import Field, StrictFloat

    from pfx.laws.initial import GaussianLaw
    from pfx.laws.noise import Noise
    from pfx.models.base import MODELS, Model


    @MODELS.register_kind
    class DriftWalk(Model):
        """Random walk with drift on a line, x' = x + drift dt + w, observed as z = x + v."""

        kind: Literal["drift_walk"] = "drift_walk"
        drift: StrictFloat = Field(0.0, description="velocity added at every step (m/s)")

        def presets(self):
            return {"steps": 20, "dt": 1.0, "process_noise": Noise(variance=0.25),
                    "measurement_noise": Noise(variance=1.0), "initial": GaussianLaw(mean=[0.0], covariance=1.0)}

        @property
        def state_names(self):
            return ("x",)

        @property
        def state_units(self):
            return ("m",)

        @property
        def measurement_dimension(self):
            return 1

        def propagate(self, state, control, noise):
            moved = np.empty_like(noise)
            np.add(state, noise, out=moved)
            moved += self.drift * self.dt
            return moved

        def measurement_mean(self, state):
            return state.copy()
''')


@story
def add_model(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.new_file("pfx/models/drift_walk.py", DRIFT_WALK)                        # step 1
    copy.insert("pfx/models/__init__.py", "    drift_walk,\n", before="    falling_body,\n")     # step 2
    config = tiny("walk", model={"kind": "drift_walk", "steps": 8, "drift": 0.5}, filter={"particles": 50})
    write_config_file(copy.root, config)
    write_config_file(copy.root, {**config, "model": {"kind": "drift_wlak"}}, "typo.yaml")
    steps = drive(copy, {"list": cli("list", "models"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out"), "typo": cli("validate", "typo.yaml")})
    story = Story(copy, steps, baseline())
    story.assert_listed("models", "drift_walk",
                        "Random walk with drift on a line, x' = x + drift dt + w, observed as z = x + v.")
    story.assert_schema_accepts(config)
    steps.ok("run")
    trials = pd.read_csv(story.result() / "trials.csv")
    assert len(trials) == 2 and set(trials["model"]) == {"drift_walk"}
    assert trials["rmse_x"].between(0, 3).all(), trials["rmse_x"]         # the filter follows the walk
    assert yaml.safe_load((story.result() / "config.yaml").read_text())["model"]["drift"] == 0.5
    assert steps["typo"]["code"] == 2 and "did you mean 'drift_walk'?" in steps["typo"]["stderr"], steps["typo"]
    story.assert_regenerated("docs/configuration.md", "#### `kind: drift_walk`")
    story.assert_regenerated("docs/configuration.md", "velocity added at every step (m/s)")
    story.assert_regenerated("docs/config.schema.json", '"drift_walk"')
    story.assert_touched({"pfx/models/drift_walk.py": "new", "pfx/models/__init__.py": "edited"})


RESAMPLING = "pfx/filters/particle/resampling.py"
NEW_RESAMPLERS = block(r'''
    def antithetic(weights: np.ndarray, random: TrialStreams) -> np.ndarray:
        """Antithetic multinomial resampling: N/2 sorted uniforms and their mirror images 1 - u."""
        n = weights.shape[-1]
        half = sorted_uniforms(random, (n + 1) // 2)
        points = np.sort(np.concatenate([half, 1.0 - half[:, : n // 2]], axis=-1), axis=-1)
        return inverse_cdf(weights, points)


    def reflected(weights: np.ndarray, random: TrialStreams) -> np.ndarray:
        """Reflected multinomial resampling: the order statistics of N uniforms, mirrored (1 - u)."""
        return inverse_cdf(weights, 1.0 - sorted_uniforms(random, weights.shape[-1])[:, ::-1])
''')


RESAMPLER_TESTS = """
import sys, pytest
sys.exit(pytest.main(["-q", "-p", "no:cacheprovider", "tests/test_resampling.py", "tests/test_extremes.py",
                      "-k", "antithetic or reflected"]))
"""


@story
def add_resampler(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    # step 1: the functions (every point is a uniform, so E[N_j] = N w_j: unbiased)
    copy.insert(RESAMPLING, NEW_RESAMPLERS, before="def han_lee_iv(weights")
    # step 2, both ways the page gives: RESAMPLERS.add at the bottom, and the tuple of the loop
    copy.append(RESAMPLING, 'RESAMPLERS.add("antithetic", Resampler(antithetic, unbiased=True),\n'
                            '               "antithetic multinomial: N/2 order statistics and their mirrors 1 - u")\n')
    copy.replace(RESAMPLING, "(multinomial, stratified, systematic, residual):",
                 "(multinomial, stratified, systematic, residual, reflected):")
    # step 3: the lists the tests run over
    copy.copy_test("test_resampling.py")
    copy.copy_test("test_extremes.py")
    copy.replace("tests/test_resampling.py", 'UNBIASED = ["multinomial", "stratified", "systematic", "residual"]',
                 'UNBIASED = ["multinomial", "stratified", "systematic", "residual", "antithetic", "reflected"]')
    copy.replace("tests/test_extremes.py", '"residual", "han_lee_iv"]', '"residual", "han_lee_iv", "antithetic", "reflected"]')

    config = tiny("resamplers", model={**tiny_config_dict()["model"], "steps": 6},
                  arms={"antithetic": {"resampler": "antithetic"}, "reflected": {"resampler": "reflected"}})
    write_config_file(copy.root, config)
    # compiled, as in use: the new functions feed the compiled inverse_cdf. The repository's own
    # tests over those lists ("tests") run on the copy by pytest in the driver's process, which
    # has imported the copy's pfx already: one interpreter start and one import of pfx fewer.
    steps = drive(copy, {"list": cli("list", "resamplers"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out"), "tests": {"code": RESAMPLER_TESTS}},
                  jit=True)
    story = Story(copy, steps, baseline())
    story.assert_listed("resamplers", "antithetic",
                        "antithetic multinomial: N/2 order statistics and their mirrors 1 - u")   # add's line
    story.assert_listed("resamplers", "reflected",      # the loop's: the docstring's first line
                        "Reflected multinomial resampling: the order statistics of N uniforms, mirrored (1 - u).")
    story.assert_schema_accepts(config)
    steps.ok("run")
    trials = pd.read_csv(story.result() / "trials.csv")
    assert sorted(trials["resampler"]) == ["antithetic", "antithetic", "reflected", "reflected"]
    assert (trials["resample_count"] == 6).all()          # ess_threshold 1: every step
    story.assert_regenerated("docs/configuration.md", "residual \\| reflected \\| han_lee_iv \\| antithetic")
    story.assert_regenerated("docs/config.schema.json", '"antithetic"')

    # The repository's own tests over those lists, run on the copy: E[N_j] = N w_j and the
    # extremes (every weight underflowing, one or two particles) for both new schemes.
    tests = steps.ok("tests")
    # per scheme: test_unbiased_mean_offspring, test_shape_range_and_zero_weights (test_resampling);
    # 6 of test_engine_every_weight_underflows and 2 of test_engine_one_or_two_particles_one_step
    assert re.search(r"\b22 passed\b", tests), tests[-2000:]
    extremes = ast.parse((copy.root / "tests" / "test_extremes.py").read_text())
    names = next(ast.literal_eval(node.value) for node in extremes.body if isinstance(node, ast.Assign)
                 and getattr(node.targets[0], "id", None) == "RESAMPLER_NAMES")
    assert {"antithetic", "reflected"} <= set(names)
    story.assert_touched({RESAMPLING: "edited", "tests/test_resampling.py": "edited",
                          "tests/test_extremes.py": "edited"})


WEIGHTING = "pfx/filters/particle/weighting.py"
TEMPERED = block(r'''
    @WEIGHTINGS.register_kind
    class TemperedWeighting(_Weighting):
        """The likelihood raised to a power 0 < exponent <= 1 (tempered: flatter weights)."""

        kind: Literal["tempered"] = "tempered"
        exponent: StrictFloat = Field(0.5, gt=0, le=1, description="power of the likelihood (1: the Bayesian weight)")

        def label(self):
            return f"tempered-{self.exponent:g}"

        def log_weights(self, model, measurement, particles, weights):
            return self.exponent * model.log_likelihood(measurement, particles)
''')


@story
def add_weighting(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.insert(WEIGHTING, TEMPERED, before="Weighting = WEIGHTINGS.kind_union()")
    config = tiny("tempering", filter={"particles": 50},
                  arms={"bayes": {"weighting": "gaussian"},
                        "tempered": {"weighting": {"kind": "tempered", "exponent": 0.25}},
                        "shorthand": {"weighting": "tempered"}})             # {kind: tempered}, its defaults
    write_config_file(copy.root, config)
    steps = drive(copy, {"list": cli("list", "weightings"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out")})
    story = Story(copy, steps, baseline())
    story.assert_listed("weightings", "tempered",
                        "The likelihood raised to a power 0 < exponent <= 1 (tempered: flatter weights).")
    story.assert_schema_accepts(config)
    steps.ok("run")
    trials = pd.read_csv(story.result() / "trials.csv")
    labels = trials.groupby("arm")["weighting"].agg(set).to_dict()
    assert labels == {"bayes": {"gaussian"}, "tempered": {"tempered-0.25"}, "shorthand": {"tempered-0.5"}}
    ess = trials.groupby("arm")["ess_mean"].mean()
    assert ess["tempered"] > ess["shorthand"] > ess["bayes"], ess          # ever flatter weights were used
    story.assert_regenerated("docs/configuration.md", "- `tempered`: The likelihood raised to a power")
    story.assert_regenerated("docs/config.schema.json", '"tempered"')
    story.assert_touched({WEIGHTING: "edited"})


DIFFUSION = "pfx/filters/particle/diffusion.py"
UNIFORM_DIFFUSION = block(r'''
    @DIFFUSIONS.register_kind
    class UniformDiffusion(_Diffusion):
        """Add U(-half_width, half_width) to every component after resampling."""

        kind: Literal["uniform"] = "uniform"
        half_width: Union[Annotated[StrictFloat, Field(gt=0)], list[Annotated[StrictFloat, Field(gt=0)]]] = Field(
            description="half the width of the jitter (one, or one per component)")

        def check(self, dimension):
            if isinstance(self.half_width, list) and len(self.half_width) != dimension:
                raise ValueError(f"@half_width: give one value or one per state component ({dimension}), "
                                 f"got {len(self.half_width)}")

        def apply(self, particles, random):
            half_width = np.asarray(self.half_width, dtype=float)
            return particles + half_width * (2.0 * random.uniform(particles.shape[1:]) - 1.0)
''')


@story
def add_diffusion(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.insert(DIFFUSION, UNIFORM_DIFFUSION, before="Diffusion = DIFFUSIONS.kind_union()")
    config = tiny("jitter", filter={"particles": 50},
                  arms={"plain": {"diffusion": "none"}, "jitter": {"diffusion": {"kind": "uniform", "half_width": 0.3}}},
                  outputs={"trace_trials": 1, "figures": [], "particles": {"steps": [3], "stages": ["resampled"]}})
    write_config_file(copy.root, config)
    wrong = tiny("wrong-jitter", filter={"diffusion": {"kind": "uniform", "half_width": [0.1, 0.2]}})
    write_config_file(copy.root, wrong, "wrong.yaml")
    steps = drive(copy, {"list": cli("list", "diffusions"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out"), "wrong": cli("validate", "wrong.yaml")})
    story = Story(copy, steps, baseline())
    story.assert_listed("diffusions", "uniform", "Add U(-half_width, half_width) to every component after resampling.")
    story.assert_schema_accepts(config)
    steps.ok("run")
    trials = pd.read_csv(story.result() / "trials.csv")
    assert trials.groupby("arm")["diffusion"].agg(set).to_dict() == {"plain": {"none"}, "jitter": {"uniform"}}
    # the resampled cloud: copies of few particles without diffusion, all distinct with it
    cloud = pd.read_csv(story.result() / "particles.csv")
    distinct = cloud.groupby("arm")["x1"].nunique()
    assert distinct["jitter"] == 50 and distinct["plain"] < 50, distinct
    # check(dimension) refuses a half-width per component that does not fit, before anything runs
    assert steps["wrong"]["code"] == 2, steps["wrong"]
    assert "filter.diffusion.half_width: give one value or one per state component (1), got 2" in steps["wrong"]["stderr"]
    story.assert_regenerated("docs/configuration.md", "- `uniform`: Add U(-half_width, half_width)")
    story.assert_regenerated("docs/config.schema.json", "half the width of the jitter")
    story.assert_touched({DIFFUSION: "edited"})


NOISE = "pfx/laws/noise.py"
LOGISTIC_FUNCTIONS = block(r'''
    _LOGISTIC_SCALE = math.sqrt(3.0) / math.pi        # unit variance: s^2 pi^2 / 3 = 1


    def _logistic_sample(random, shape, df=None):
        # the log of the ratio of two independent Exp(1) draws is standard logistic
        return _LOGISTIC_SCALE * np.log(random.standard_exponential(shape) / random.standard_exponential(shape))


    def _logistic_log_density(z, df=None):
        t = np.abs(z) / _LOGISTIC_SCALE
        return -t - 2.0 * np.log1p(np.exp(-t)) - math.log(_LOGISTIC_SCALE)


    def _logistic_log_tail(c, df=None):
        return -np.logaddexp(0.0, c / _LOGISTIC_SCALE)
''')
LOGISTIC_ENTRY = ('    "logistic": NoiseFamily(_logistic_sample, _logistic_log_density,\n'
                  '                            "logistic (tails between gaussian and laplace)", _logistic_log_tail),\n')
# In the copy: the new family's standard form has zero mean, unit variance and a log-tail equal
# to its integrated density (as tests/test_sonar_mcl.py checks for every family); Noise scales it.
LOGISTIC_CHECK = r'''
import json, math
import numpy as np
from scipy import integrate
from pfx.laws.noise import NOISE_FAMILIES, Noise
from pfx.numerics.seeding import TrialStreams

family = NOISE_FAMILIES["logistic"]
density = lambda z: math.exp(family.log_density_standard(np.array(z)))
moments = [integrate.quad(lambda z: z ** k * density(z), -np.inf, np.inf)[0] for k in (0, 1, 2)]
tails = [(math.exp(family.log_tail_standard(np.array(c))), integrate.quad(density, c, np.inf)[0])
         for c in (-3.0, -0.3, 0.0, 1.7, 4.0)]
draws = Noise(family="logistic", variance=[2.0, 0.5]).bind(2).sample(TrialStreams.from_seeds([3]), (200_000,))
print(json.dumps({"moments": moments, "tails": tails, "means": draws[0].mean(axis=0).tolist(),
                  "variances": draws[0].var(axis=0).tolist()}))
'''


@story
def add_noise_family(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.insert(NOISE, LOGISTIC_FUNCTIONS, before="for _name, _family in {")
    copy.insert(NOISE, LOGISTIC_ENTRY, before="}.items():\n    NOISE_FAMILIES.add(")
    noises = {"process_noise": {"family": "logistic", "variance": 0.5},
              "measurement_noise": {"family": "logistic", "variance": 1.0}}
    config = tiny("logistic", model={**tiny_config_dict()["model"], **noises})
    write_config_file(copy.root, config)
    steps = drive(copy, {"list": cli("list", "noises"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out"), "check": {"code": LOGISTIC_CHECK}})
    story = Story(copy, steps, baseline())
    story.assert_listed("noises", "logistic", "logistic (tails between gaussian and laplace)")
    story.assert_schema_accepts(config)
    steps.ok("run")
    resolved = yaml.safe_load((story.result() / "config.yaml").read_text())["model"]
    assert {key: resolved[key] for key in noises} == {key: {**value, "df": None} for key, value in noises.items()}
    trials = pd.read_csv(story.result() / "trials.csv")
    assert len(trials) == 2 and np.isfinite(trials["log_likelihood"]).all()
    numbers = json.loads(steps.ok("check"))
    np.testing.assert_allclose(numbers["moments"], [1.0, 0.0, 1.0], atol=1e-8)     # a unit-variance law
    for tail, integrated in numbers["tails"]:
        assert tail == pytest.approx(integrated, abs=1e-8)
    np.testing.assert_allclose(numbers["means"], [0.0, 0.0], atol=0.02)
    np.testing.assert_allclose(numbers["variances"], [2.0, 0.5], rtol=0.03)       # the variance is the config's
    story.assert_regenerated("docs/configuration.md", "student_t \\| logistic")
    story.assert_regenerated("docs/config.schema.json", '"logistic"')
    story.assert_touched({NOISE: "edited"})


METRICS = "pfx/analysis/metrics.py"
MAX_ERROR = block(r'''
    @METRICS.register("max_error")
    def max_error_metrics(inputs: MetricInputs) -> dict[str, np.ndarray]:
        """Largest position error distance over the steps (max_error_distance)."""
        return {"max_error_distance": _distance(inputs).max(axis=1)}
''')


@story
def add_metric(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.insert(METRICS, MAX_ERROR, before="def compute_metrics(")
    write_config_file(copy.root, tiny("max-error", trials=3))
    steps = drive(copy, {"list": cli("list", "metrics"), "run": cli("run", "config.yaml", "--out", "out")})
    story = Story(copy, steps, baseline())
    story.assert_listed("metrics", "max_error", "Largest position error distance over the steps (max_error_distance).")
    steps.ok("run")
    trials = pd.read_csv(story.result() / "trials.csv")
    assert len(trials) == 3
    assert (trials["max_error_distance"] >= trials["error_distance_final"]).all()
    assert (trials["max_error_distance"] >= trials["error_distance_mean"]).all()
    summary = pd.read_csv(story.result() / "summary.csv")
    assert summary["max_error_distance_mean"].iloc[0] == pytest.approx(trials["max_error_distance"].mean())
    assert {"max_error_distance_ci95_low", "max_error_distance_median"} <= set(summary.columns)
    story.assert_touched({METRICS: "edited"})


FIGURE = module(r'''
    """The trials' final error distances as a histogram (added by tests/test_extending.py)."""

    from __future__ import annotations

    from pfx.figures.registry import FIGURES
    from pfx.result_folder import ResultFolder


    @FIGURES.register("final_error_histogram")
    def final_error_histogram(result: ResultFolder):
        """Histogram of the final position error distance over the trials, one colour per arm.

        Reads trials.csv's `error_distance_final`; nothing to draw for a study.
        """
        import matplotlib.pyplot as plt

        if not (result.path / "trials.csv").exists():
            return None
        trials = result.trials
        figure, axes = plt.subplots(figsize=(6, 4))
        for arm, group in trials.groupby("arm", sort=False):
            axes.hist(group["error_distance_final"], bins=5, alpha=0.6, label=str(arm))
        axes.set_xlabel("final error distance")
        axes.set_ylabel("trials")
        axes.legend()
        return figure
''')


FIXED_GAIN = module(r'''
    """A fixed-gain (alpha) filter (added by tests/test_extending.py).

    x_k^- = f(x_{k-1}, u_k, 0), x_k = x_k^- + g (z_k - h(x_k^-)), for measurements of the whole state.
    """

    from __future__ import annotations

    import numpy as np
    from pydantic import BaseModel, ConfigDict, Field, StrictFloat

    from pfx.filters.base import FILTERS, FilterKind
    from pfx.filters.trace import FilterTrace


    class FixedGainSettings(BaseModel):
        model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
        gain: StrictFloat = Field(0.5, gt=0.0, le=1.0, description="share of the innovation taken (0 < g <= 1)")


    @FILTERS.register_kind
    class FixedGain(FilterKind):
        """Fixed-gain filter: move the prediction a fixed share of the way to the measurement."""

        kind = "fixed_gain"
        settings = {"fixed_gain": (FixedGainSettings, "kind fixed_gain: its gain")}

        def __init__(self, gain: float = 0.5):
            self.gain = gain

        @classmethod
        def plan(cls, model, settings, prior):
            cls.check_model_needs(model)
            if model.measurement_dimension != model.state_dimension:
                raise ValueError("@kind: the fixed_gain filter needs a measurement of the whole state")
            return cls(settings.fixed_gain.gain)

        def run(self, model, measurements, random, *, settings, prior, spread_criterion=None,
                consistency=False, snapshot=None):
            trials, steps, _ = measurements.shape
            estimate = np.broadcast_to(np.asarray(prior.mean_vector(), dtype=float),
                                       (trials, model.state_dimension)).copy()
            estimates = np.empty((trials, steps, model.state_dimension))
            for k in range(1, steps + 1):
                predicted = model.propagate(estimate, model.control(k), np.zeros_like(estimate))
                estimate = predicted + self.gain * (measurements[:, k - 1] - model.measurement_mean(predicted))
                estimates[:, k - 1] = estimate
            nothing = np.full((trials, steps), np.nan)
            return FilterTrace(estimates=estimates, ess=nothing, resampled=np.zeros((trials, steps), dtype=bool),
                               degenerate=np.zeros((trials, steps), dtype=bool), spread=nothing.copy(),
                               log_likelihood=np.full(trials, np.nan),
                               lost_particles=np.zeros(trials, dtype=np.int64))
''')


@story
def add_filter_kind(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.new_file("pfx/filters/fixed_gain.py", FIXED_GAIN)                                     # step 1
    copy.insert("pfx/filters/__init__.py", "    fixed_gain,  # noqa: F401  (registers fixed_gain)\n",
                before="    histogram,  # noqa: F401")                                         # step 2
    config = tiny("gain", filter={"kind": "fixed_gain", "fixed_gain": {"gain": 0.6}},
                  arms={"PF": {"kind": "particle", "particles": 50}, "alpha": {}})
    write_config_file(copy.root, config)
    write_config_file(copy.root, tiny("particles-only"), "particles.yaml")
    write_config_file(copy.root, tiny("bad", filter={"kind": "fixed_gain", "fixed_gain": {"gain": 1.5}}), "bad.yaml")
    partial = tiny("partial", filter={"kind": "fixed_gain"},
                   model={"kind": "linear_gaussian", "steps": 5, "transition_matrix": [[1.0, 1.0], [0.0, 1.0]],
                          "measurement_matrix": [[1.0, 0.0]], "process_noise": {"variance": [0.1, 0.1]},
                          "initial": {"kind": "gaussian", "mean": [0.0, 0.0], "covariance": [1.0, 1.0]}})
    write_config_file(copy.root, partial, "partial.yaml")
    steps = drive(copy, {"list": cli("list", "filters"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out"),
                         "validate": cli("validate", "config.yaml"), "particles": cli("validate", "particles.yaml"),
                         "bad": cli("validate", "bad.yaml"), "partial": cli("validate", "partial.yaml")})
    story = Story(copy, steps, baseline())
    story.assert_listed("filters", "fixed_gain",
                        "Fixed-gain filter: move the prediction a fixed share of the way to the measurement.")
    story.assert_schema_accepts(config)
    steps.ok("run")
    trials = pd.read_csv(story.result() / "trials.csv")
    assert sorted(set(zip(trials["arm"], trials["filter"]))) == [("PF", "particle"), ("alpha", "fixed_gain")]
    assert trials["rmse_x1"].notna().all() and (trials["rmse_x1"] < 5).all(), trials["rmse_x1"]
    assert trials.loc[trials["filter"] == "fixed_gain", "n_particles"].isna().all()   # not a particle kind
    # its settings block is a key of filter:, kept where a kind reads it and left out elsewhere
    assert yaml.safe_load(steps.ok("validate"))["filter"]["fixed_gain"] == {"gain": 0.6}
    assert "fixed_gain" not in yaml.safe_load(steps.ok("particles"))["filter"]
    # refusals, before anything runs: a setting out of its bounds, and the plan's own check
    assert steps["bad"]["code"] == 2 and "filter.fixed_gain.gain" in steps["bad"]["stderr"], steps["bad"]
    assert steps["partial"]["code"] == 2, steps["partial"]
    assert "filter.kind: the fixed_gain filter needs a measurement of the whole state" in steps["partial"]["stderr"]
    story.assert_regenerated("docs/configuration.md", "kind fixed_gain: its gain")
    story.assert_regenerated("docs/config.schema.json", '"fixed_gain"')
    story.assert_touched({"pfx/filters/fixed_gain.py": "new", "pfx/filters/__init__.py": "edited"})



@story
def add_figure(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.new_file("pfx/figures/final_errors.py", FIGURE)
    copy.insert("pfx/figures/__init__.py", "    final_errors,  # noqa: F401\n", before="    mahalanobis,  # noqa: F401\n")
    config = tiny("histogram", trials=4, outputs={"trace_trials": 1, "figures": ["final_error_histogram"]})
    write_config_file(copy.root, config)
    steps = drive(copy, {"list": cli("list", "figures"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out")})
    story = Story(copy, steps, baseline())
    story.assert_listed("figures", "final_error_histogram",
                        "Histogram of the final position error distance over the trials, one colour per arm.")
    story.assert_schema_accepts(config)
    steps.ok("run")
    assert (story.result() / "figures" / "final_error_histogram.png").read_bytes().startswith(PNG_SIGNATURE)
    assert json.loads((story.result() / "manifest.json").read_text())["figures"] == ["final_error_histogram"]
    story.assert_regenerated("docs/figures.md", "| `final_error_histogram` | Histogram of the final position error "
                             "distance over the trials, one colour per arm. Reads trials.csv's `error_distance_final`; "
                             "nothing to draw for a study. |")
    story.assert_regenerated("docs/config.schema.json", '"final_error_histogram"')
    story.assert_touched({"pfx/figures/final_errors.py": "new", "pfx/figures/__init__.py": "edited"})


STUDY = module(r'''
    """Means of uniform samples, repeated (added by tests/test_extending.py).

    Table ``means``: one row per repetition, ``repeat``, the sample size ``samples`` and the mean
    ``mean`` of that many U(0, width) draws. Table ``spread``: the standard deviation ``std`` of
    those means beside the theory, width / sqrt(12 n).
    """

    from __future__ import annotations

    from typing import ClassVar, Literal

    import numpy as np
    import pandas as pd
    from pydantic import Field, StrictFloat, StrictInt

    from pfx.studies.base import STUDIES, Study


    @STUDIES.register_kind
    class SampleMeans(Study):
        """Means of n uniform draws, repeated: their spread against width / sqrt(12 n)."""

        kind: Literal["sample_means"] = "sample_means"
        samples: StrictInt = Field(100, ge=1, le=1_000_000, description="draws n per mean")
        repeats: StrictInt = Field(200, ge=2, le=100_000, description="how many means")
        width: StrictFloat = Field(1.0, gt=0, description="the uniform law's interval [0, width) (m)")
        units: ClassVar[dict[str, str]] = {"mean": "m", "std": "m", "theory": "m"}

        def tables(self, random):
            means = self.width * random.random((self.repeats, self.samples)).mean(axis=1)
            table = pd.DataFrame({"repeat": np.arange(1, self.repeats + 1), "samples": self.samples, "mean": means})
            spread = pd.DataFrame([{"samples": self.samples, "std": means.std(ddof=1),
                                    "theory": self.width / np.sqrt(12.0 * self.samples)}])
            return {"means": table, "spread": spread}
''')


@story
def add_study(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.new_file("pfx/studies/sample_means.py", STUDY)
    copy.insert("pfx/studies/__init__.py", "    sample_means,\n", before="    velocity_motion,\n")
    config = {"name": "means", "seed": 4, "study": {"kind": "sample_means", "samples": 30, "repeats": 400, "width": 2.0}}
    write_config_file(copy.root, config)
    steps = drive(copy, {"list": cli("list", "studies"), **REGENERATE,
                         "run": cli("run", "config.yaml", "--out", "out")})
    story = Story(copy, steps, baseline())
    story.assert_listed("studies", "sample_means",
                        "Means of n uniform draws, repeated: their spread against width / sqrt(12 n).")
    story.assert_schema_accepts(config)
    steps.ok("run")
    means = pd.read_csv(story.result() / "means.csv")
    assert list(means.columns) == ["repeat", "samples", "mean"] and len(means) == 400
    assert means["mean"].mean() == pytest.approx(1.0, abs=0.03)
    spread = pd.read_csv(story.result() / "spread.csv").iloc[0]
    assert spread["std"] == pytest.approx(spread["theory"], rel=0.15)
    manifest = json.loads((story.result() / "manifest.json").read_text())
    assert manifest["study"] == "sample_means" and manifest["units"] == {"mean": "m", "std": "m", "theory": "m"}
    story.assert_regenerated("docs/configuration.md", "#### `study: {kind: sample_means}`")
    story.assert_regenerated("docs/config.schema.json", '"sample_means"')
    story.assert_touched({"pfx/studies/sample_means.py": "new", "pfx/studies/__init__.py": "edited"})


REPORT = module(r'''
    """tiny-paper: a made-up document with one claim (added by tests/test_extending.py).

    Experiment ``tracking``: a 1-D linear-Gaussian system, 20 particles. ``paper.yaml`` holds the
    document's position RMSE.
    """

    from __future__ import annotations

    import pandas as pd

    from pfx.papers.base import (
        REPORTS,
        Figure,
        PaperResults,
        Part,
        Section,
        Table,
        Verdict,
        assemble,
        format_number,
        markdown_table,
        verdict_from_checks,
    )

    PAPER = "tiny-paper"
    TITLE = "Tiny paper: one filter, one claim"


    def tracking_part(results: PaperResults) -> Part:
        """The tracking experiment: our position RMSE beside the document's."""
        if not results.has("tracking"):
            return Part()
        ours = float(results.folder("tracking").trials["rmse_position"].mean())
        theirs = float(results.numbers["rmse_position"])
        table = pd.DataFrame({"quantity": ["position RMSE"], "document": [theirs], "pfx": [ours]})
        verdict = Verdict("The position RMSE is at most twice the document's", verdict_from_checks([ours <= 2 * theirs]),
                          f"our mean position RMSE is {format_number(ours)}, the document's {format_number(theirs)}")
        return Part([Figure("tracking", "error_over_time.png", "Position error over time"),
                     Table("Position RMSE, the document's and ours", markdown_table(table))], [verdict])


    PARTS = (tracking_part,)


    @REPORTS.register(PAPER)
    def report(results: PaperResults) -> Section:
        items, verdicts = assemble(results, PARTS)
        return Section(PAPER, TITLE, "A made-up document, reproduced by a test.", list(items), list(verdicts))
''')
GALLERY_REFUSES = r'''
from pathlib import Path
from pfx.papers import REPORTS
from pfx.papers.gallery import write_gallery

assert "tiny-paper" in REPORTS
write_gallery(Path("no-results"))
'''


@story
def add_paper(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    # step 1: the configs, one experiment per file, and paper.yaml
    copy.new_file("configs/papers/tiny-paper/tracking.yaml", yaml.safe_dump(
        tiny("tracking", outputs={"trace_trials": 1, "figures": ["error_over_time"]}), sort_keys=False))
    copy.new_file("configs/papers/tiny-paper/paper.yaml", "rmse_position: 1.0\n")
    # step 2: the report, imported in pfx/papers/__init__.py ...
    copy.new_file("pfx/papers/tiny_paper.py", REPORT)
    copy.replace("pfx/papers/__init__.py", "    prob_robotics,\n", "    prob_robotics,\n    tiny_paper,\n")
    refused = drive(copy, {"gallery": {"code": GALLERY_REFUSES}}, label="before-order")
    assert refused["gallery"]["code"] == "exception"
    assert "ValueError: reports missing from pfx.papers.GALLERY_ORDER: tiny-paper" in refused["gallery"]["stderr"], \
        refused["gallery"]
    # ... and its short name in GALLERY_ORDER
    copy.replace("pfx/papers/__init__.py", '"beyond-the-papers")', '"beyond-the-papers", "tiny-paper")')
    # step 4: `pfx reproduce <short-name>` (default folders: configs/papers, results)
    steps = drive(copy, {"reproduce": cli("reproduce", "tiny-paper")})
    steps.ok("reproduce")
    results = copy.root / "results"
    assert yaml.safe_load((results / "tiny-paper" / "paper.yaml").read_text()) == {"rmse_position": 1.0}
    assert (results / "tiny-paper" / "tracking" / "figures" / "error_over_time.png").is_file()
    gallery = (results / "README.md").read_text()
    assert "## Tiny paper: one filter, one claim" in gallery
    assert "- *The position RMSE is at most twice the document's* — **reproduced**: our mean position RMSE is" in gallery
    assert "![Position error over time](tiny-paper/tracking/figures/error_over_time.png)" in gallery
    assert "| quantity | document | pfx |" in gallery
    assert copy.touched == copy.changed_files() == {
        "configs/papers/tiny-paper/tracking.yaml": "new", "configs/papers/tiny-paper/paper.yaml": "new",
        "pfx/papers/tiny_paper.py": "new", "pfx/papers/__init__.py": "edited"}


NEW_COMPONENTS = [("models", "drift_walk"), ("resamplers", "antithetic"), ("resamplers", "reflected"),
                  ("weightings", "tempered"), ("diffusions", "uniform"), ("noises", "logistic"),
                  ("metrics", "max_error"), ("figures", "final_error_histogram"), ("studies", "sample_means"),
                  ("filters", "fixed_gain")]


# -- the tests ------------------------------------------------------------------------------------

EXACT_PROPOSAL_PLUGIN = module(r'''
    """The exact proposal of a linear-Gaussian model, p(x_k | x_k-1, z_k), from a plugin (tests/test_extending.py)."""

    from typing import Literal

    import numpy as np

    import pfx


    @pfx.register_proposal
    class ExactLinear(pfx.Proposal):
        """The exact p(x_k | x_k-1, z_k) of a linear-Gaussian model, from a plugin."""

        kind: Literal["exact_linear"] = "exact_linear"

        def check(self, model):
            if getattr(model, "matrices", None) is None:
                raise ValueError("@proposal: exact_linear needs a model with matrices (linear_gaussian)")

        def propose(self, model, previous, step, measurement, observed, random):
            H = model.matrices[1]
            Q = model.process_noise.covariance()
            R = model.measurement_noise.covariance()
            predicted = model.propagate(previous, model.control(step), np.zeros(previous.shape[:-1] + (model.process_noise_dimension,)))
            gain = np.linalg.solve(H @ Q @ H.T + R, H @ Q).T
            covariance = (np.eye(len(Q)) - gain @ H) @ Q
            if observed is not None:
                measurement = np.where(observed[:, None], measurement, 0.0)
            mean = predicted + (measurement[:, None, :] - predicted @ H.T) @ gain.T
            factor = np.linalg.cholesky(covariance)
            standard = random.standard_normal(previous.shape[1:])
            state = mean + standard @ factor.T
            log_proposal = (-0.5 * np.sum(standard * standard, axis=-1) - np.sum(np.log(np.diag(factor)))
                            - 0.5 * len(Q) * np.log(2 * np.pi))
            adjustment = model.transition_log_density(state, previous, step) - log_proposal
            if observed is not None:       # a missing measurement: draw from the transition instead
                noise = model.process_noise.sample(random, previous.shape[1:-1])
                state = np.where(observed[:, None, None], state, predicted + noise)
                adjustment = np.where(observed[:, None], adjustment, 0.0)
            return state, adjustment
''')


@story
def add_proposal_from_a_plugin(copy: PackageCopy, baseline: Callable[[], Steps]) -> None:
    copy.root.joinpath("exact_proposal.py").write_text(EXACT_PROPOSAL_PLUGIN)      # a file beside the config
    config = tiny("proposals", plugins=["exact_proposal.py"], filter={"particles": 50},
                  arms={"bootstrap": {}, "exact": {"proposal": "exact_linear"}})
    write_config_file(copy.root, config)
    # The same filter seeds for the built-in locally optimal proposal and the plugin's: the same
    # draws, so the same numbers (to rounding: the two compute the same Gaussian differently).
    same_draws = textwrap.dedent("""
        import numpy as np
        import pfx
        from pfx.config.plugins import load_plugin
        load_plugin("exact_proposal.py")
        model = pfx.model("linear_gaussian", steps=30, transition_matrix=[[0.9]], measurement_matrix=[[1.0]])
        measurements = np.random.default_rng(3).normal(size=(30, 1))
        runs = [pfx.filter(model, measurements, seeds=[11, 12], particles=200, proposal=name)
                for name in ("locally_optimal", "exact_linear")]
        print(float(np.max(np.abs(runs[0].estimates - runs[1].estimates))),
              float(np.max(np.abs(runs[0].log_likelihood - runs[1].log_likelihood))))
    """)
    steps = drive(copy, {"list": cli("list", "proposals", "--plugin", "exact_proposal.py"),
                         "run": cli("run", "config.yaml", "--out", "out"), "same": {"code": same_draws}})
    story = Story(copy, steps, baseline())
    story.assert_listed("proposals", "exact_linear",
                        "The exact p(x_k | x_k-1, z_k) of a linear-Gaussian model, from a plugin. [plugin exact_proposal.py]")
    steps.ok("run")
    trials = pd.read_csv(story.result() / "trials.csv")
    assert set(trials["arm"]) == {"bootstrap", "exact"} and np.isfinite(trials["log_likelihood"]).all()
    recorded = yaml.safe_load((story.result() / "config.yaml").read_text())
    assert recorded["arms"]["exact"]["proposal"] == {"kind": "exact_linear"}
    estimate_gap, likelihood_gap = map(float, steps.ok("same").split())
    assert estimate_gap < 1e-9 and likelihood_gap < 1e-9, (estimate_gap, likelihood_gap)
    story.assert_touched({})                                                       # pfx itself unchanged


def _baseline(copy: PackageCopy) -> Steps:
    """The unmodified copy: what it lists and the schema it prints."""
    steps = drive(copy, {"list": cli("list"), "schema": cli("schema")})
    assert copy.changed_files() == {}
    return steps


@pytest.fixture(scope="module")
def stories(tmp_path_factory):
    """Every story started at once (each in its own copy); story name -> its future."""
    package = compiled_package(tmp_path_factory.mktemp("compiled"))
    with ThreadPoolExecutor(max_workers=max(2, 2 * (os.cpu_count() or 1))) as pool:
        baseline = pool.submit(_baseline, PackageCopy(tmp_path_factory.mktemp("unmodified"), package))
        futures = {name: pool.submit(perform, PackageCopy(tmp_path_factory.mktemp(name), package), baseline.result)
                   for name, perform in STORIES.items()}
        yield {"baseline": baseline, **futures}


def test_the_unmodified_copy_has_none_of_the_new_components(stories):
    listing = stories["baseline"].result().ok("list")
    for what, name in NEW_COMPONENTS:
        assert listed(listing, what, name) is None
    assert listed(listing, "models", "linear_gaussian") and listed(listing, "noises", "uniform")  # parsed


@pytest.mark.parametrize("name", list(STORIES))
def test_a_story_of_extending_md(name, stories):
    stories[name].result()


# What the stories above do, in the words of docs/extending.md (whitespace aside): when the page
# changes an instruction, this fails until the story that performs it changes too.
PAGE_SAYS = {
    "": ["`python -m pfx.config.reference --update`", "`pfx schema > docs/config.schema.json`"],
    "A model": ["`pfx/models/<name>.py`", "`@MODELS.register_kind` (`from pfx.models.base import MODELS, Model`)",
                '`kind: Literal["<name>"] = "<name>"`', "`np.empty_like(noise)`",
                "Add the module to the import list of `pfx/models/__init__.py`"],
    "A resampler": ["`inverse_cdf(weights, points)`", "`sorted_uniforms(random, n)`",
                    '`RESAMPLERS.add("<name>", Resampler(<function>, unbiased=True), "<one line>")`',
                    "add an unbiased function to the tuple the loop there registers by function name",
                    "`UNBIASED` in `tests/test_resampling.py`", "`RESAMPLER_NAMES` in `tests/test_extremes.py`"],
    "A weighting": ["`log_weights(model, measurement, particles, weights) -> (trials, N)`", "override `label()`",
                    "`@WEIGHTINGS.register_kind`", "above the line `Weighting = WEIGHTINGS.kind_union()`"],
    "A diffusion": ["`apply(particles, random)`", "`check(dimension)`", "`@DIFFUSIONS.register_kind`",
                    "above `Diffusion = DIFFUSIONS.kind_union()`"],
    "A proposal": ["`propose(model, previous, step, measurement, observed, random)`", "`guided: ClassVar[bool] = True`",
                   "log p(x_k | x_{k-1}) - log q(x_k | x_{k-1}, z_k)", "`@PROPOSALS.register_kind`",
                   "`Proposal = PROPOSALS.kind_union()`"],
    "A proposal from a plugin": ["`@pfx.register_proposal`", "`pfx.Proposal`",
                                 "`model.transition_log_density(state, previous, step)`",
                                 "`plugins: [my_proposal.py]`", "`filter.proposal: <name>`"],
    "A move": ["`apply(context, random)`", "`needs_parents = True`", "`reports_acceptance = True`",
               "`@MOVES.register_kind`", "`Move = MOVES.kind_union()`"],
    "A noise family": ["added to the dict the module registers into `NOISE_FAMILIES`",
                       "`sample_standard(random, shape, df)`", "`log_density_standard(z, df)`",
                       "`log_tail_standard(c, df)`", "`family: <name>`"],
    "A metric": ['decorated `@METRICS.register("<name>")`', "its columns go to trials.csv, and summary.csv gets "
                 "their statistics"],
    "A filter kind": ["`@FILTERS.register_kind`", "`from pfx.filters.base import FILTERS, FilterKind`",
                      "Import its module in `pfx/filters/__init__.py` (one import line registers it)",
                      "`plan` checks that the kind can run on the cell's model"],
    "A figure": ['`@FIGURES.register("<name>")` (from `pfx.figures.registry`)',
                 "A new module needs one import line in `pfx/figures/__init__.py`", "`outputs.figures`"],
    "A study": ["`pfx/studies/<name>.py`", "`units: ClassVar[dict[str, str]]`", "`tables(random) -> {name: DataFrame}`",
                "`@STUDIES.register_kind`", "Add the module to the import list of `pfx/studies/__init__.py`"],
    "A paper": ["`configs/papers/<short-name>/`", "`paper.yaml`", "`items, verdicts = assemble(results, PARTS)`",
                '`@REPORTS.register("<short-name>")`', "Import the module in `pfx/papers/__init__.py` and add the "
                "short name to `GALLERY_ORDER` (the gallery refuses a report missing from it)",
                "`pfx reproduce <short-name>` runs it and rewrites `results/README.md`"],
}


def test_the_page_says_what_the_stories_do():
    page = (REPO_ROOT / "docs" / "extending.md").read_text()
    intro, *chunks = re.split(r"^## ", page, flags=re.MULTILINE)
    sections = {"": intro}
    for chunk in chunks:
        title, _, body = chunk.partition("\n")
        sections[title.strip()] = body
    for title, phrases in PAGE_SAYS.items():
        text = " ".join(sections[title].split())
        missing = [phrase for phrase in phrases if phrase not in text]
        assert not missing, f"docs/extending.md, {title or 'introduction'}: no longer says {missing}"
