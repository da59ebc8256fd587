"""What a paper report is made of, and the one way a report is put together.

A **report** (one module per source document: ``han_lee.py``, ``park_mpf.py``, ...) reads a
paper's result folders ``results/<paper>/`` -- CSV and figure files, never rerunning anything --
and the document's own numbers (``paper.yaml``), and returns the paper's gallery
:class:`Section`: captioned figures, Markdown tables with the document's numbers beside ours,
and one :class:`Verdict` per claim, whose wording is computed from our numbers.

Every report has the same shape. It is an ordered tuple of **part functions**; each takes the
:class:`PaperResults` and returns a :class:`Part` -- the items (figures, tables, texts) and the
verdicts it adds -- or an empty ``Part()`` when the experiment it reads has no results yet, so
that a partial ``pfx reproduce`` still gives a gallery::

    PARTS = (concept_part, tracking_part, degeneracy_part)        # the section's order

    @REPORTS.register("han-lee")
    def report(results: PaperResults) -> Section:
        items, verdicts = assemble(results, PARTS)
        return Section(PAPER, TITLE, summary, items, verdicts)

A report that computes its numbers from a file the repository leaves out (``.gitignore``: a
run's draws too large to commit) registers in :data:`KEPT_TABLES` what to keep of them instead:
``pfx reproduce`` writes those small tables into the folder, and the report reads them back
where the large file is absent, or says the results are missing -- never a verdict silently
dropped.

A part may itself be an assembly of parts (``prob_robotics_motion.motion_sections``). Turning
sections into Markdown is :mod:`pfx.papers.gallery`'s job: this module imports neither it nor
the reports, so the reports depend on this module only.

Also here, written once for every report: the verdict words and the rule that turns a claim's
checks into a verdict (:func:`verdict_from_checks`), and the number formats of the gallery
(:func:`format_number`, :func:`markdown_table`, :func:`interval`, :func:`percent`,
:func:`p_value`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path
from typing import Callable, Iterable, Literal, NamedTuple, Optional, Sequence, Union, get_args

import yaml

from pfx.registry import Registry
from pfx.result_folder import ResultFolder

# -- verdicts ----------------------------------------------------------------------------------

VerdictWord = Literal["reproduced", "partly reproduced", "not reproduced", "not comparable"]
VERDICTS: tuple[str, ...] = get_args(VerdictWord)


def verdict_from_checks(checks: Iterable[bool]) -> VerdictWord:
    """The verdict on a claim tested by several checks: all pass, some pass, or none.

    "reproduced" when every check passes, "partly reproduced" when some do, "not reproduced"
    when none does -- or when there is no check at all: a claim that nothing tested was not
    reproduced.
    """
    passed = [bool(check) for check in checks]
    if passed and all(passed):
        return "reproduced"
    return "partly reproduced" if any(passed) else "not reproduced"


@dataclass
class Verdict:
    """One claim of the document and what our runs say of it."""

    claim: str
    verdict: VerdictWord
    evidence: str                  # one sentence with our numbers: why this verdict


# -- the items of a section --------------------------------------------------------------------

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
    """A paragraph of Markdown: an explanation that is neither a caption nor a table note."""

    markdown: str


Item = Union[Figure, Table, Text]


@dataclass
class Section:
    """A paper's section of the gallery: what its report returns."""

    paper: str                     # the short name, as in results/<paper>/
    title: str
    summary: str
    items: list[Item] = field(default_factory=list)
    verdicts: list[Verdict] = field(default_factory=list)


# -- the one way a report is assembled ---------------------------------------------------------

class Part(NamedTuple):
    """What one part function adds to its section: items and verdicts, each in section order.

    A tuple, so that ``items, verdicts = part`` works; its defaults are empty tuples (never a
    shared list), and ``Part()`` is what a part returns when its experiment has no results.
    """

    items: Sequence[Item] = ()
    verdicts: Sequence[Verdict] = ()


def assemble(results: PaperResults, parts: Iterable[Callable[[PaperResults], Part]]) -> Part:
    """Run a report's part functions in order; their items and their verdicts, concatenated."""
    items: list[Item] = []
    verdicts: list[Verdict] = []
    for part in parts:
        new_items, new_verdicts = part(results)
        items += new_items
        verdicts += new_verdicts
    return Part(items, verdicts)


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

    def config(self, experiment: str) -> dict:
        """An experiment's resolved ``config.yaml`` (our settings, not results); {} when absent."""
        path = self.path / experiment / "config.yaml"
        return yaml.safe_load(path.read_text()) if path.exists() else {}

    def figures(self, experiment: str) -> list[str]:
        folder = self.path / experiment / "figures"
        return sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []


# Paper short name -> its report. Importing pfx.papers registers all five; the gallery's order
# is pfx.papers.GALLERY_ORDER, not the order of registration.
REPORTS: Registry[Callable[[PaperResults], Section]] = Registry("paper report")

# Paper short name -> what its report keeps of files the repository leaves out (.gitignore): a
# function (experiment name, freshly computed result folder) that writes into the folder the small
# tables the report would otherwise compute from those files, or nothing for an experiment that
# needs none. `pfx reproduce` calls it before the folder is compared with the committed one
# (pfx.papers.record), so the tables are committed, compared and kept like any other, and the
# report gives the same verdict from a checkout that lacks the large files.
KEPT_TABLES: Registry[Callable[[str, Path], None]] = Registry("kept tables")


# -- numbers as the gallery writes them --------------------------------------------------------

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
        return f"{shown(value, digits):.{digits - 1}e}"
    if abs(value) >= 10 ** digits:
        return f"{shown(value, len(str(int(abs(value))))):,.0f}"
    return f"{shown(value, digits):.{digits}g}"


def shown(value: float, digits: int) -> float:
    """``value`` rounded to ``digits`` significant digits, half up, from its 12-digit decimal form:
    the last bits two machines differ by (1.1649999999999998 on one, 1.1650000000000000 on the
    other) then show the same digits (1.17), where formatting the binary value directly would
    show 1.16 on one and 1.17 on the other."""
    decimal = Decimal(f"{value:.12g}")
    if decimal == 0:
        return 0.0
    return float(decimal.quantize(Decimal(1).scaleb(decimal.adjusted() - digits + 1), rounding=ROUND_HALF_UP))


def flag_text(row) -> str:
    """A posterior.csv row's ``flag`` for a gallery table: the checks it fails, or "none" (an
    empty field, which pandas reads as NaN; a folder written before the column had none either)."""
    flag = row.get("flag") if hasattr(row, "get") else None
    return flag if isinstance(flag, str) and flag else "none"


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


def _is_finite(value) -> bool:
    return value is not None and math.isfinite(float(value))


def interval(low: float, high: float, *, number: Callable[[float], str] = format_number,
             brackets: str = "[]", separator: str = ", ") -> str:
    """A confidence interval, "[0.12, 0.34]"; blank when either end is not a finite number.

    ``number`` writes each end (e.g. :func:`percent`); ``brackets`` and ``separator`` give other
    shapes, as kim-mcl's "(0.12–0.34)".
    """
    if not (_is_finite(low) and _is_finite(high)):
        return ""
    return f"{brackets[0]}{number(low)}{separator}{number(high)}{brackets[1]}"


def percent(fraction: float, *, decimals: int = 1, significant: Optional[int] = None, suffix: str = "%") -> str:
    """A signed percentage of a fraction, 0.123 -> "+12.3%"; blank when not a finite number.

    ``decimals`` fixes the digits after the point. With ``significant`` instead, small changes
    keep that many significant digits and larger ones are whole percents (significant=2:
    "+0.34", "+3.4", "+45", "+120", never an exponent). ``suffix`` may be " %" (a space first).
    """
    if not _is_finite(fraction):
        return ""
    value = 100 * float(fraction)
    if significant is None:
        return f"{value:+.{decimals}f}{suffix}"
    if abs(fraction) < 10 ** (significant - 1) / 100:
        return f"{value:+.{significant}g}{suffix}"
    return f"{value:+.0f}{suffix}"


UNDERFLOW = 1e-300      # p-values below this are written "< 1e-300": a survival function's tail underflows


def p_value(p: float, *, in_words: bool = False, number: Optional[Callable[[float], str]] = None) -> str:
    """A p-value, "0.032" or "2.6e-49", and "< 1e-300" where the computation underflowed.

    ``in_words`` writes it for a sentence: "p = 0.032", "p < 1e-300". ``number`` writes the
    value; by default :func:`format_number` with two significant digits ("2.6e-49"), while
    prob-robotics' Fig. 4.3 keeps Python's ``"{:.2g}".format`` ("6e-135" and "0.00012" where
    format_number writes "6.0e-135" and "1.2e-04"). Blank when not a number.
    """
    if p is None or math.isnan(float(p)):
        return ""
    if p < UNDERFLOW:
        return "p < 1e-300" if in_words else "< 1e-300"
    text = number(p) if number else format_number(p, 2)
    return f"p = {text}" if in_words else text
