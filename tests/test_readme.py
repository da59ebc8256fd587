"""The front page and the docs: the README starts with the two commands, the config reference in
docs/configuration.md and the figure table of docs/figures.md are generated and kept current, and every
relative link of the README and of docs/ resolves inside the repository."""

import re
from pathlib import Path

import pytest

from pfx.config.reference import markdown_reference
from pfx.figures.registry import figure_table

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CONFIGURATION = ROOT / "docs" / "configuration.md"
START, END = "<!-- config-reference:start -->", "<!-- config-reference:end -->"
PAGES = [README, *sorted((ROOT / "docs").rglob("*.md"))]


def test_config_reference_is_current():
    """Regenerate with:
    python -m pfx.config.reference --update"""
    text = CONFIGURATION.read_text()
    section = text.split(START, 1)[1].split(END, 1)[0]
    assert section.strip() == markdown_reference().strip()


def test_figure_table_is_current():
    """The figure table of docs/figures.md is generated from the registry; regenerate with:
    python -m pfx.config.reference --update"""
    text = (ROOT / "docs" / "figures.md").read_text()
    section = text.split("<!-- figure-table:start -->", 1)[1].split("<!-- figure-table:end -->", 1)[0]
    assert section.strip() == figure_table().strip()
    from pfx.figures import FIGURES
    assert all(f"| `{name}` |" in section for name in FIGURES)


def test_readme_starts_with_the_two_commands():
    text = README.read_text()
    first_block = text.split("```sh", 1)[1].split("```", 1)[0]
    assert "make reproduce-papers" in first_block and "make test" in first_block


def _anchors(page: Path) -> set[str]:
    """GitHub's heading anchors of a Markdown page (lower case, punctuation dropped, spaces to
    hyphens, repeats numbered)."""
    anchors: set[str] = set()
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    for heading in re.findall(r"^#{1,6} +(.+?) *#*$", text, flags=re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        candidate, n = slug, 0
        while candidate in anchors:
            n += 1
            candidate = f"{slug}-{n}"
        anchors.add(candidate)
    return anchors


def _links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    return re.findall(r"\]\(([^)\s]+)\)", text)


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_relative_links_resolve(page):
    """Every relative link (and its #anchor, for Markdown targets) points inside the repository."""
    broken = []
    for link in _links(page):
        if re.match(r"^[a-z]+:", link):
            continue                                   # https:, mailto:
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        if ROOT not in target.parents and target != ROOT:
            broken.append(f"{link} (outside the repository)")
        elif not target.exists():
            broken.append(f"{link} (no such file)")
        elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
            broken.append(f"{link} (no such heading)")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)
