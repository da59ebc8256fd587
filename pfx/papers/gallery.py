"""The gallery ``results/README.md``: every reproduced paper's figures, tables and verdicts.

Each paper has a **report** (:mod:`pfx.papers`): a function that reads the paper's result
folders (CSV and figure files only, never rerunning anything) and the document's own numbers
(``paper.yaml``, copied from ``configs/papers/<paper>/`` by ``pfx reproduce``), and returns a
:class:`Section`: captioned figures, Markdown tables with the document's numbers beside ours,
and one :class:`Verdict` per claim, whose wording is computed from our numbers.
``pfx reproduce`` rewrites the gallery after every run, with a section for each paper that
has results.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Literal, Optional, Union

import yaml

from pfx.registry import Registry
from pfx.result_folder import ResultFolder, write_text

VERDICTS = ("reproduced", "partly reproduced", "not reproduced", "not comparable")


@dataclass
class Figure:
    """A figure file of one of the paper's result folders, with its caption."""

    experiment: str
    name: str                      # file name in figures/, with its extension
    caption: str


@dataclass
class Table:
    """A Markdown table (see :func:`markdown_table`) with a title and a note under it."""

    title: str
    markdown: str
    note: str = ""


@dataclass
class Text:
    markdown: str


@dataclass
class Verdict:
    """One claim of the document and what our runs say of it."""

    claim: str
    verdict: Literal["reproduced", "partly reproduced", "not reproduced", "not comparable"]
    evidence: str                  # one sentence with our numbers: why this verdict


@dataclass
class Section:
    paper: str
    title: str
    summary: str
    items: list[Union[Figure, Table, Text]] = field(default_factory=list)
    verdicts: list[Verdict] = field(default_factory=list)


class PaperResults:
    """A paper's result folder ``results/<paper>/`` as its report sees it."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.paper = self.path.name

    def folder(self, experiment: str) -> ResultFolder:
        return ResultFolder(self.path / experiment)

    def has(self, experiment: str) -> bool:
        return (self.path / experiment / "manifest.json").exists()

    @property
    def numbers(self) -> dict:
        """The document's own numbers and facts (``paper.yaml``)."""
        path = self.path / "paper.yaml"
        return yaml.safe_load(path.read_text()) if path.exists() else {}

    def figures(self, experiment: str) -> list[str]:
        folder = self.path / experiment / "figures"
        return sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []


REPORTS: Registry[Callable[[PaperResults], Section]] = Registry("paper report")


def format_number(value, digits: int = 3) -> str:
    """A number for a table: ``digits`` significant digits, thousands as 12,345; blanks for NaN."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "yes" if value else "no"
    value = float(value)
    if math.isnan(value):
        return ""
    if math.isinf(value):
        return "∞" if value > 0 else "-∞"
    if value != 0 and (abs(value) >= 1e6 or abs(value) < 1e-3):
        return f"{value:.{digits - 1}e}"
    if abs(value) >= 10 ** digits:
        return f"{value:,.0f}"
    return f"{value:.{digits}g}"


def markdown_table(frame, digits: int = 3, formats: Optional[dict[str, Callable]] = None) -> str:
    """A pandas DataFrame as a Markdown table (no extra dependency), numbers via format_number."""
    formats = formats or {}
    header = "| " + " | ".join(str(c).replace("|", "\\|") for c in frame.columns) + " |"
    rule = "| " + " | ".join("---" for _ in frame.columns) + " |"
    lines = [header, rule]
    for _, row in frame.iterrows():
        cells = [formats[c](row[c]) if c in formats else format_number(row[c], digits) for c in frame.columns]
        lines.append("| " + " | ".join(str(cell).replace("|", "\\|") for cell in cells) + " |")
    return "\n".join(lines)


def render_section(section: Section, results: PaperResults, root: Path) -> str:
    lines = [f"## {section.title}", "", section.summary.strip(), ""]
    if section.verdicts:
        lines += ["**Verdicts**", ""]
        for verdict in section.verdicts:
            lines.append(f"- *{verdict.claim}* — **{verdict.verdict}**: {verdict.evidence}")
        lines.append("")
    for item in section.items:
        if isinstance(item, Figure):
            path = results.path / item.experiment / "figures" / item.name
            if not path.exists():
                lines += [f"*(figure {item.experiment}/{item.name} missing: run `make reproduce-papers`)*", ""]
                continue
            relative = path.relative_to(root).as_posix()
            lines += [f"![{item.caption}]({relative})", "", f"*{item.caption}*", ""]
        elif isinstance(item, Table):
            lines += [f"**{item.title}**", "", item.markdown, ""]
            if item.note:
                lines += [item.note.strip(), ""]
        else:
            lines += [item.markdown.strip(), ""]
    return "\n".join(lines)


def write_gallery(results_dir: str | Path) -> Path:
    """Rewrite ``results/README.md`` from every paper folder that has a report and results."""
    root = Path(results_dir)
    from pfx.papers import GALLERY_ORDER  # importing the package registers the reports

    unordered = [paper for paper in REPORTS if paper not in GALLERY_ORDER]
    if unordered:
        raise ValueError(f"reports missing from pfx.papers.GALLERY_ORDER: {', '.join(unordered)}")
    sections = []
    for paper in GALLERY_ORDER:
        folder = root / paper
        if not folder.is_dir():
            continue
        results = PaperResults(folder)
        section = REPORTS[paper](results)
        for verdict in section.verdicts:
            if verdict.verdict not in VERDICTS:
                raise ValueError(f"{paper}: unknown verdict {verdict.verdict!r}")
        sections.append(render_section(section, results, root))
    header = ["# Reproduced results", "",
              "Generated by `make reproduce-papers` (`pfx reproduce`) from the CSV files in this folder; "
              "do not edit by hand. Each section shows the document's own numbers beside ours and "
              "says, claim by claim, whether our runs reproduce it. Every figure here is re-rendered "
              "from its folder's CSV files by `pfx figures results/<paper>/<experiment>`.", ""]
    if sections:
        header += ["Contents: " + " · ".join(f"[{s.split(chr(10))[0][3:]}](#{_anchor(s.split(chr(10))[0][3:])})"
                                             for s in sections), ""]
    target = root / "README.md"
    write_text("\n".join(header + sections), target)
    return target


def _anchor(title: str) -> str:
    text = "".join(c for c in title.lower() if c.isalnum() or c in " -").replace(" ", "-")
    return text
