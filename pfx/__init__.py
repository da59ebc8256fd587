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
