"""pfx: an experiment runner for particle filters.

Data flows one way through the package::

    YAML config --config/--> plan of cells x trials --run/--> batches in the filters/ engine
        --analysis/--> trials.csv, steps_summary.csv, summary.csv --figures/, papers/--> PNG, gallery

The folders, by role, from the top of the layering down (``pyproject.toml`` holds the
import-linter contract: a lower layer never imports a higher one; ``make test`` checks it):

* :mod:`pfx.cli` the command line; :mod:`pfx.bench` the benchmark; :mod:`pfx.papers` the
  reproductions' reports and gallery.
* :mod:`pfx.run` runs a plan: batches of trials, executors (local, Dask), the memory budget.
* :mod:`pfx.config` reads and validates the YAML file and expands it into cells.
* :mod:`pfx.figures` draws figures from a result folder's CSV only; :mod:`pfx.studies` are
  experiments that are computations rather than filter runs.
* :mod:`pfx.result_folder` writes and reads the result folder (and knows its state).
* :mod:`pfx.analysis` turns traces and tables into numbers: metrics, summaries, comparisons.
* :mod:`pfx.filters` holds the filter kinds (the particle filter's engine and components in
  :mod:`pfx.filters.particle`; Kalman filters; the grid filter); :mod:`pfx.models` one
  state-space model per file (initial law, transition, measurement), used both to simulate the
  truth and inside the filter; :mod:`pfx.motion` Probabilistic Robotics' motion models.
* :mod:`pfx.laws` the noise families and initial laws; :mod:`pfx.safe_yaml` safe YAML reading.
* :mod:`pfx.numerics` random streams and seeding, compiled loops, angles, hashing.
* :mod:`pfx.registry` and :mod:`pfx.errors`, which every layer may use.
"""

__version__ = "0.1.0"

# -- the public Python API, imported lazily ------------------------------------------------------
# ``import pfx`` stays cheap (``pfx --help`` imports it): each name below is imported from its
# module on first use, through the module ``__getattr__`` (PEP 562). ``importlib`` keeps these
# imports out of the import-linter's static graph: ``pfx`` itself is no layer.
#
# Writing plugins (docs/plugins.md): the model base class, whose method names and array shapes
# are a public contract, and the decorators that register components under their names.
_LAZY_NAMES = {
    "Model": "pfx.models.base",
    "register_model": "pfx.config.plugin_registration",
    "register_resampler": "pfx.config.plugin_registration",
    "register_weighting": "pfx.config.plugin_registration",
    "register_filter_kind": "pfx.config.plugin_registration",
    "register_proposal": "pfx.config.plugin_registration",
    # a plugin's proposal subclasses this (filter.proposal; docs/plugins.md)
    "Proposal": ("pfx.filters.particle.proposals", "ProposalBase"),
    # the laws a model's presets() and default_prior() return
    "Noise": "pfx.laws.noise",
    "PointLaw": "pfx.laws.initial",
    "GaussianLaw": "pfx.laws.initial",
    "UniformLaw": "pfx.laws.initial",
    # a model's methods written once for the numpy and jax backends (docs/plugins.md)
    "namespace": "pfx.numerics.arrays",
    "with_values": "pfx.numerics.arrays",
    "special_functions": "pfx.numerics.arrays",
    "repeat": "pfx.numerics.arrays",
    # count-valued transitions, drawn from the trial's streams on either backend (docs/plugins.md)
    "multinomial": "pfx.laws.count_transitions",
    "euler_multinomial": "pfx.laws.count_transitions",
    "gamma_white_noise": "pfx.laws.count_transitions",
    # one filter from Python, on arrays (pfx/filtering.py; docs/python-api.md)
    "model": "pfx.filtering",
    "particle_filter": "pfx.filtering",
    "filter": "pfx.filtering",
    "simulate": "pfx.filtering",
    "Simulation": "pfx.filtering",
    "FilterResult": "pfx.filtering",
    "choose_particles": "pfx.filtering",
    # a plugin loaded from Python, as a config's plugins: entry loads it (docs/python-api.md)
    "load_plugin": "pfx.filtering",
}

# Running configs and reading results from Python (pfx/api.py, which imports nothing heavy until
# called): ``pfx.run``, ``pfx.load``, ``pfx.Result``, and ``pfx.ConfigError``, what they raise.
# ``pfx.run`` names both the function and the subpackage pfx/run/: Python binds a subpackage's
# name on this package when the subpackage is first imported, which would replace the function.
# So the subpackage (an empty __init__) is imported first, and the function then keeps the name;
# code reaches the subpackage by its imports (``from pfx.run.runner import run_plan``).
import pfx.run as _run_subpackage  # noqa: E402,F401
from pfx.api import Result, load, run  # noqa: E402
from pfx.errors import ConfigError  # noqa: E402

del _run_subpackage


def __getattr__(name: str):
    if name in _LAZY_NAMES:
        import importlib

        module, attribute = _LAZY_NAMES[name] if isinstance(_LAZY_NAMES[name], tuple) else (_LAZY_NAMES[name], name)
        value = getattr(importlib.import_module(module), attribute)
        globals()[name] = value              # once imported, an ordinary attribute
        return value
    raise AttributeError(f"module 'pfx' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY_NAMES])


__all__ = ["ConfigError", "Result", "load", "run", "__version__", *_LAZY_NAMES]
