"""Configs: YAML in, validated plan of cells out.

* :mod:`pfx.safe_yaml` reads YAML safely (no object construction, no duplicate keys,
  no alias bombs) and applies ``--set`` overrides.
* :mod:`pfx.config.schema` declares every section as pydantic models: validation, the JSON
  Schema of ``pfx schema`` and the config reference in ``docs/configuration.md`` all come from them.
* :mod:`pfx.config.validation` turns pydantic errors into one-line :class:`~pfx.errors.ConfigError`.
* :mod:`pfx.config.plan` expands arms x sweep into cells and validates every one before any run.
* :mod:`pfx.config.plugins` imports the plugins a config names (user models and components)
  before its validation, and hashes their code for the record; the ``register_*`` decorators
  they call, and who owns each registration, are :mod:`pfx.config.plugin_registration`.
* :mod:`pfx.config.data` attaches recorded data (``data:``) to the plan: measurements, truth
  and controls from CSV files, each read and checked by :mod:`pfx.config.data_files`.
* :mod:`pfx.config.overrides` applies ``--set``; :mod:`pfx.config.reference` generates the
  config reference pages.
"""
