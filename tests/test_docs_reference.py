"""The reference docs say what is true today, each figure with the command that made it.

docs/accuracy.md and docs/performance.md are short reference pages (today's figure per topic and
its command); their history lives in docs/lab/ (append-only, linked from the docs, never from
code); docs/method.md has one section per stage, whose headings code docstrings cite.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
REFERENCE = ("accuracy.md", "performance.md")
MAX_REFERENCE_LINES = 300
METHOD_SECTIONS = [
    "Overview",
    "Noise filter",
    "Markers",
    "Tracker",
    "Frame correction",
    "Contacts",
    "Gel motion",
    "Gesture",
    "Episode vote",
    "Creep",
    "Resting",
    "Camera model",
    "Adaptation",
    "The paper's method",
]
#: A command that makes a figure: a benchmark script, the CLI, or the CLI under /usr/bin/time.
COMMAND = re.compile(r"python3\s+benchmarks/\w+\.py|neurotouch-hid\s+(eval|track|simulate|calibrate)\b")
#: Diary wording that belongs in docs/lab/, not in a reference page.
DIARY = re.compile(r"\b(round|issue)\s+[0-9]|\b20[0-9]{2}-[01][0-9]-[0-3][0-9]\b", re.IGNORECASE)


def _prose_lines(text: str) -> list[str]:
    """The lines outside fenced code blocks."""
    out, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            out.append(line)
    return out


def _sections(text: str, level: int) -> dict[str, str]:
    """Heading text -> the section's text (its subsections included), for headings of ``level``
    (fenced code is kept in the body: it holds commands)."""
    sections: dict[str, list[str]] = {}
    current = None
    fenced = False
    marker = "#" * level + " "
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith(marker):
            current = line[len(marker) :].strip()
            sections[current] = []
        elif not fenced and re.match(r"#{1,%d} " % (level - 1), line):
            current = None
        elif current is not None:
            sections[current].append(line)
    return {name: "\n".join(body) for name, body in sections.items()}


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    anchors = set()
    for line in _prose_lines(path.read_text(encoding="utf-8")):
        m = re.match(r"#+ (.*)", line)
        if m:
            slug = _slug(m.group(1))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            anchors.add(slug if n == 0 else f"{slug}-{n}")
    return anchors


@pytest.mark.parametrize("name", REFERENCE)
def test_a_reference_doc_is_short(name):
    lines = (DOCS / name).read_text(encoding="utf-8").splitlines()
    assert len(lines) < MAX_REFERENCE_LINES, f"docs/{name}: {len(lines)} lines; history goes to docs/lab/"


@pytest.mark.parametrize("name", REFERENCE)
def test_a_reference_doc_has_no_diary_sections(name):
    hits = [line for line in (DOCS / name).read_text(encoding="utf-8").splitlines() if DIARY.search(line)]
    assert hits == [], f"docs/{name}: rounds, issues or dates belong in docs/lab/: {hits}"


@pytest.mark.parametrize("name", REFERENCE)
def test_every_table_of_figures_names_the_command_that_made_it(name):
    text = (DOCS / name).read_text(encoding="utf-8")
    sections = _sections(text, 2)
    assert sections, f"docs/{name} has no sections"
    missing = []
    for heading, body in sections.items():
        has_figures = any(line.startswith("|") and re.search(r"\d", line) for line in _prose_lines(body))
        if has_figures and not COMMAND.search(body):
            missing.append(heading)
    assert missing == [], f"docs/{name}: sections with figures and no command: {missing}"


@pytest.mark.parametrize("name", REFERENCE)
def test_a_reference_doc_links_its_history_in_the_lab(name):
    assert f"lab/{Path(name).stem}-history.md" in (DOCS / name).read_text(encoding="utf-8")
    assert (DOCS / "lab" / f"{Path(name).stem}-history.md").is_file()


def test_method_has_one_section_per_stage_in_order():
    text = (DOCS / "method.md").read_text(encoding="utf-8")
    headings = [line[3:].strip() for line in _prose_lines(text) if line.startswith("## ")]
    assert headings == METHOD_SECTIONS


@pytest.mark.parametrize("stage", METHOD_SECTIONS[1:-1])
def test_each_stage_says_where_it_departs_from_the_paper_and_what_decided_it(stage):
    body = _sections((DOCS / "method.md").read_text(encoding="utf-8"), 2)[stage]
    assert "**Departure.**" in body and "**Decided by**" in body
    assert "paper" in body.split("**Departure.**", 1)[1]
    decided = body.split("**Decided by**", 1)[1]
    assert COMMAND.search(decided) or "lab/" in decided or "test_" in decided, (
        f"method.md, {stage}: the decision names no command, lab entry or test"
    )


def test_relative_links_in_the_docs_resolve_to_files_and_headings():
    broken = []
    for doc in sorted(DOCS.glob("*.md")) + sorted((DOCS / "lab").glob("*.md")):
        prose = "\n".join(_prose_lines(doc.read_text(encoding="utf-8")))
        for target in re.findall(r"\]\(([^)\s]+)\)", prose):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            resolved = (doc.parent / path).resolve() if path else doc
            if not resolved.exists():
                broken.append(f"{doc.relative_to(ROOT)}: {target}")
            elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
                broken.append(f"{doc.relative_to(ROOT)}: {target} (no such heading)")
    assert broken == []


def test_code_never_links_into_the_lab():
    hits = [
        f"{path.relative_to(ROOT)}:{n}"
        for path in sorted((ROOT / "neurotouch_hid").rglob("*.py"))
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if "docs/lab" in line
    ]
    assert hits == [], f"code cites docs/method.md, never docs/lab/: {hits}"


#: Citing the history from code: a round or an issue by number.
CODE_DIARY = re.compile(r"\b(round|issue)\s+#?[0-9]", re.IGNORECASE)


def test_code_cites_the_docs_never_rounds_or_issues():
    """Docstrings and comments point at docs/ (method, accuracy, performance); how a choice was
    found, round by round or issue by issue, is docs/lab/'s."""
    hits = []
    for folder in ("neurotouch_hid", "benchmarks", "tests", "packaging", ".ci"):
        for path in sorted((ROOT / folder).rglob("*")):
            if path.suffix not in (".py", ".sh", ".yaml", ".toml", "") or not path.is_file():
                continue
            text = path.read_text(encoding="utf-8", errors="replace")
            lines = enumerate(text.splitlines(), 1)
            hits += [f"{path.relative_to(ROOT)}:{n}" for n, line in lines if CODE_DIARY.search(line)]
    assert hits == [], f"rounds or issues cited from code (say it in docs/lab/): {hits}"


def test_the_code_check_sees_a_citation():
    """The pattern catches what it is for, and not the word in ordinary use."""
    assert CODE_DIARY.search("(round" + " 5: contrast)") and CODE_DIARY.search("fast (issue" + " 11, docs)")
    assert not CODE_DIARY.search("a round flat top") and not CODE_DIARY.search("the issue's tolerance")
