"""The JSON Schema ``pfx schema`` publishes for editors describes the configs pfx accepts.

A standard validator (the ``jsonschema`` library, as editors and check-jsonschema use it)
accepts every shipped config, shorthands and studies included, and rejects what pfx rejects
for its shape: unknown keys, wrong types, unknown kinds. A shipped config that names plugins
(the benchmarks' models) is checked against the schema with those plugins' components, the one
``pfx schema --plugin FILE`` prints for editors.
"""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
from conftest import REPO_ROOT, tiny_config_dict

from pfx.config.plugins import load_plugin
from pfx.config.schema import config_json_schema
from pfx.safe_yaml import load_config_file

SHIPPED = sorted(path for path in (REPO_ROOT / "configs").rglob("*.yaml") if path.name != "paper.yaml")
SCHEMA_FILE = REPO_ROOT / "docs" / "config.schema.json"


@pytest.fixture(scope="module")
def validator():
    schema = config_json_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


@pytest.mark.parametrize("config", SHIPPED, ids=lambda path: str(path.relative_to(REPO_ROOT / "configs")))
def test_every_shipped_config_is_valid_under_the_schema(config, validator):
    data = load_config_file(config)
    if data.get("plugins"):
        origins = [load_plugin(entry, config.parent, config_file=str(config)).origin for entry in data["plugins"]]
        validator = jsonschema.Draft202012Validator(config_json_schema(origins))
    errors = sorted(validator.iter_errors(data), key=lambda error: error.path)
    assert not errors, f"{config}: {errors[0].message[:300]}"


@pytest.mark.parametrize("change, where", [
    ({"filter": {"particles": "many"}}, "particles"),
    ({"filter": {"weighting": "cosine"}}, "weighting"),
    ({"filter": {"resampler": "sytematic"}}, "resampler"),
    ({"colour": "blue"}, "colour"),
    ({"model": {"kind": "linear_gaussian", "transition_matrix": [[1.0]], "measurement_matrix": [[1.0]],
                "steps": 0}}, "steps"),
])
def test_the_schema_rejects_what_pfx_rejects_for_its_shape(change, where, validator):
    config = {**tiny_config_dict(), **change}
    errors = list(validator.iter_errors(config))
    assert errors and any(where in json.dumps(list(error.absolute_path) + [error.message])
                          for error in [*errors, *[c for e in errors for c in e.context]])


def test_the_schema_file_for_editors_is_current():
    """docs/config.schema.json is what `pfx schema` prints (configs point editors at it)."""
    assert json.loads(SCHEMA_FILE.read_text()) == config_json_schema(), \
        "regenerate it: pfx schema > docs/config.schema.json"


def test_every_shipped_config_points_editors_at_the_schema():
    for config in SHIPPED:
        first = config.read_text().splitlines()[0]
        relative = Path("../" * (len(config.relative_to(REPO_ROOT).parts) - 1)) / "docs" / "config.schema.json"
        assert first == f"# yaml-language-server: $schema={relative.as_posix()}", config
