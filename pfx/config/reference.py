"""The config reference in Markdown, generated from the same declarations as validation
(for pfx's own components, plus those of plugins given to ``pfx schema --plugin``)."""

from __future__ import annotations

import types
import typing
from typing import Any, Collection

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from pfx.analysis.metrics import ConvergenceCriterion
from pfx.config.components import REGISTRIES, registry
from pfx.config.schema import ParticleSnapshots, config_schema
from pfx.config.validation import _union_members, _unwrap
from pfx.laws.initial import GaussianLaw, PointLaw, UniformLaw
from pfx.laws.noise import Noise
from pfx.models import MODELS
from pfx.studies import STUDIES


def _type_name(annotation: Any) -> str:
    annotation = _unwrap(annotation)
    origin = typing.get_origin(annotation)
    if origin is typing.Literal and len(typing.get_args(annotation)) > 8:
        return "name"              # long registries (figures): the description says where to look
    if origin is typing.Literal:
        return " \\| ".join(repr(a).replace("'", "") for a in typing.get_args(annotation))
    if origin in (typing.Union, types.UnionType):
        members = _union_members(annotation)
        kinds = [m.model_fields["kind"].default for m in members
                 if isinstance(m, type) and issubclass(m, BaseModel) and "kind" in m.model_fields]
        if kinds and len(kinds) == len(members):
            return "{kind: " + " \\| ".join(kinds) + ", ...}"
        return " or ".join(_type_name(a) for a in members)
    if origin in (list, tuple, dict):
        arguments = ", ".join(_type_name(a) for a in typing.get_args(annotation) if a is not Ellipsis)
        return f"{origin.__name__}[{arguments}]"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "mapping"
    return getattr(annotation, "__name__", str(annotation)).replace("typing.", "")


def _default(field) -> str:
    if field.default is not PydanticUndefined:
        value = field.default
    elif field.default_factory is not None:
        value = field.default_factory()
    else:
        return "**required**"
    if isinstance(value, BaseModel):
        value = value.model_dump(exclude_defaults=False) if "kind" not in type(value).model_fields else value.kind
    if value is None:
        return "(preset)" if field.description and "default" not in field.description else "none"
    return f"`{value}`"


def model_table(model: type[BaseModel], skip: tuple[str, ...] = ()) -> str:
    lines = ["| key | type | default | meaning |", "| --- | --- | --- | --- |"]
    for name, field in model.model_fields.items():
        if name in skip:
            continue
        key = field.alias or name
        description = (field.description or "").replace("|", "\\|")
        lines.append(f"| `{key}` | {_type_name(field.annotation)} | {_default(field)} | {description} |")
    return "\n".join(lines)


def markdown_reference(plugins: Collection[str] = ()) -> str:
    """The whole config reference, section by section (with the components of ``plugins``)."""
    classes = config_schema(plugins)
    Experiment, StudyExperiment = classes.Experiment, classes.StudyExperiment
    parts = ["### Top level", "", (Experiment.__doc__ or "").strip(), "", model_table(Experiment), ""]
    parts += ["### `filter` (and each entry of `arms`)", "", model_table(classes.FilterConfig), ""]
    parts += ["### `model`", "",
              "`kind` picks the model; fields left empty take the model's presets "
              "(`pfx validate` prints the resolved values).", ""]
    for name, model in MODELS.visible(plugins).items():
        parts += [f"#### `kind: {name}`", "", (model.__doc__ or "").strip(), "", model_table(model, ("kind",)), ""]
    parts += ["### Noise (`process_noise`, `measurement_noise`)", "", model_table(Noise), ""]
    parts += ["### Initial laws (`model.initial`, `filter.initial`)", ""]
    for law in (PointLaw, GaussianLaw, UniformLaw):
        parts += [f"- `kind: {law.model_fields['kind'].default}`: {law.__doc__.strip()} Keys: "
                  + ", ".join(f"`{f.alias or n}`" for n, f in law.model_fields.items() if n != "kind")]
    for title, name in (("Weightings", "weightings"), ("Diffusion", "diffusions"),
                        ("Moves after resampling", "moves"), ("Proposals", "proposals")):
        source = next(source for source in REGISTRIES if source.name == name)
        parts += ["", f"### {title} (`{source.config_key}`)", ""]
        for kind, component in registry(name).visible(plugins).items():
            keys = [f"`{n}`" for n in component.model_fields if n != "kind"]
            parts.append(f"- `{kind}`: {component.__doc__.strip()}" + (f" Keys: {', '.join(keys)}." if keys else ""))
    parts += ["", "### `metrics.convergence`", "", model_table(ConvergenceCriterion), ""]
    parts += ["### `outputs`", "", model_table(classes.OutputsConfig), ""]
    parts += ["### `outputs.particles`", "", model_table(ParticleSnapshots), ""]
    parts += ["### Studies", "", (StudyExperiment.__doc__ or "").strip()
              + ". A config with a `study` section has these top-level keys instead of `model`, "
              "`filter`, `arms`, `sweep`, `trials` and `metrics`:", "", model_table(StudyExperiment), ""]
    for name, study in STUDIES.visible(plugins).items():
        parts += [f"#### `study: {{kind: {name}}}`", "", (study.__doc__ or "").strip(), "",
                  model_table(study, ("kind",)), ""]
    return "\n".join(parts)


REFERENCE_PAGE = "docs/configuration.md"
FIGURES_PAGE = "docs/figures.md"


def update_generated_pages(reference: str = REFERENCE_PAGE, figures: str = FIGURES_PAGE) -> None:
    """Rewrite the generated parts of the docs between their markers: the config reference in
    ``docs/configuration.md`` and the figure table in ``docs/figures.md``
    (``python -m pfx.config.reference --update``; a test keeps both current)."""
    from pfx.figures.registry import figure_table

    _replace_between(reference, "config-reference", markdown_reference())
    _replace_between(figures, "figure-table", figure_table())


def _replace_between(path: str, marker: str, generated: str) -> None:
    from pathlib import Path

    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    page = Path(path)
    before, rest = page.read_text().split(start, 1)
    _, after = rest.split(end, 1)
    page.write_text(f"{before}{start}\n{generated}\n{end}{after}")


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["--update"]:
        update_generated_pages()
    else:
        print(markdown_reference())
