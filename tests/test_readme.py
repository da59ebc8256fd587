"""The README's config reference is generated from the config declarations: keep it current."""

from pathlib import Path

from pfx.config.reference import markdown_reference

README = Path(__file__).resolve().parents[1] / "README.md"
START, END = "<!-- config-reference:start -->", "<!-- config-reference:end -->"


def test_readme_config_reference_is_current():
    """Regenerate with: python -m pfx.config.reference --update-readme"""
    text = README.read_text()
    section = text.split(START, 1)[1].split(END, 1)[0]
    assert section.strip() == markdown_reference().strip()


def test_readme_starts_with_the_two_commands():
    text = README.read_text()
    first_block = text.split("```sh", 1)[1].split("```", 1)[0]
    assert "make reproduce-papers" in first_block and "make test" in first_block
