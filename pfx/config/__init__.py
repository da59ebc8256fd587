"""Configs: YAML in, validated plan of cells out.

* :mod:`pfx.safe_yaml` reads YAML safely (no object construction, no duplicate keys,
  no alias bombs) and applies ``--set`` overrides.
* :mod:`pfx.config.schema` declares every section as pydantic models: validation, the JSON
  Schema of ``pfx schema`` and the config reference in ``docs/configuration.md`` all come from them.
* :mod:`pfx.config.validation` turns pydantic errors into one-line :class:`~pfx.errors.ConfigError`.
* :mod:`pfx.config.plan` expands arms x sweep into cells and validates every one before any run.
* :mod:`pfx.config.plugins` imports the plugins a config names (user models and components)
  before its validation, and hashes their code for the record.
* :mod:`pfx.config.data` reads and checks recorded data (``data:``): measurements, truth and
  controls from CSV files.
* :mod:`pfx.config.overrides` applies ``--set``; :mod:`pfx.config.reference` generates the
  config reference pages.
"""
