"""pfx: an experiment runner for particle filters.

Data flows one way through the package::

    YAML config  --config/-->  plan of cells x trials  --engine-->  per-trial traces
         --metrics-->  trials.csv / steps.csv / summary.csv  --figures/-->  PNG

* :mod:`pfx.config` reads and validates the YAML file and expands it into cells.
* :mod:`pfx.models` holds one state-space model per file (initial law, transition,
  measurement), used both to simulate the truth and inside the filter.
* :mod:`pfx.filters.particle.engine` advances many independent trials of a particle filter at once.
* :mod:`pfx.filters.particle.resampling`, :mod:`pfx.filters.particle.weighting`, :mod:`pfx.laws.noise` and :mod:`pfx.filters.particle.diffusion`
  are registries of interchangeable components, each selected by name in a config.
* :mod:`pfx.analysis.metrics` turns traces into per-trial numbers; :mod:`pfx.result_folder` writes CSV;
  :mod:`pfx.figures` draws figures from that CSV only.
"""

__version__ = "0.1.0"
