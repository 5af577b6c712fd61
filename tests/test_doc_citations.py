"""Docstrings and comments cite the docs by section: ``docs/method.md, "Tracker"``. Every such
citation in the package and the benchmarks names a heading the cited file has today, so a docs
rewrite that renames a section shows here instead of leaving the code pointing nowhere.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: ``docs/NAME.md`` then ``, `` / `` `` / ``'s `` / ``, section `` / `` (`` and one or more quoted
#: section names (``"A", "B"`` or ``"A" and "B"``); a quote right after ``.md`` closes a string.
CITATION = re.compile(
    r"(docs/[\w/.-]+?\.md)(?:'s)?(?:,\s*|\s+)(?:sections?\s+|\(\s*)?"
    r'("[^"\n]{1,80}"(?:\s*(?:,|and)\s*"[^"\n]{1,80}")*)'
)


def headings(path: Path) -> set[str]:
    """The text of every Markdown heading of ``path``, outside fenced code, each also without a
    closing parenthetical (``Predictions (JSON lines)`` may be cited as ``Predictions``)."""
    found, fenced = set(), False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and (m := re.match(r"#+ (.*)", line)):
            heading = m.group(1).strip()
            found |= {heading, re.sub(r"\s*\([^()]*\)$", "", heading)}
    return found


def citations(text: str) -> list[tuple[str, str]]:
    """(``docs/...md``, section) for every section citation in ``text`` (Python source; a
    citation may run over a line break, in a docstring or a comment)."""
    flat = re.sub(r"\n\s*(?:#\s*)?", " ", text)
    return [(m.group(1), name) for m in CITATION.finditer(flat) for name in re.findall(r'"([^"]+)"', m.group(2))]


def test_a_heading_is_cited_with_or_without_its_closing_parenthetical(tmp_path):
    doc = tmp_path / "d.md"
    doc.write_text("# D\n\n## Predictions (JSON lines)\n\n```sh\n# not a heading\n```\n")
    assert headings(doc) == {"D", "Predictions (JSON lines)", "Predictions"}


def test_the_pattern_finds_citations_and_skips_a_closing_quote():
    text = '''"""x (docs/method.md, "Tracker"; docs/performance.md,
    "Runtime latency") and docs/dataset.md's "Predictions (JSON lines)" section;
    docs/method.md, "Markers", "Resting".
    """
    help="see docs/accuracy.md",
    '''
    assert citations(text) == [
        ("docs/method.md", "Tracker"),
        ("docs/performance.md", "Runtime latency"),
        ("docs/dataset.md", "Predictions (JSON lines)"),
        ("docs/method.md", "Markers"),
        ("docs/method.md", "Resting"),
    ]


SOURCES = sorted((ROOT / "neurotouch_hid").rglob("*.py")) + sorted((ROOT / "benchmarks").rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_section_citation_names_a_heading_of_the_cited_doc(path):
    broken = []
    for doc, section in citations(path.read_text(encoding="utf-8")):
        target = ROOT / doc
        if not target.is_file():
            broken.append(f"{doc} (no such file)")
        elif section not in headings(target):
            broken.append(f'{doc}, "{section}"')
    assert broken == [], f"{path.relative_to(ROOT)} cites sections that do not exist: {broken}"


def test_the_code_cites_sections():
    """The check reads real citations (not an empty scan): the stages cite docs/method.md's."""
    cited = {c for path in SOURCES for c in citations(path.read_text(encoding="utf-8"))}
    assert ("docs/method.md", "Tracker") in cited and len(cited) > 20
