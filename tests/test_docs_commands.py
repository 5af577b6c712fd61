"""The docs lead into no errors: every ``neurotouch-hid ...`` command in README.md and docs/*.md
runs as written, page by page in a new user's home, and every message docs/troubleshooting.md
lists is one the code can print.

A command is run as written, through the shell (``~`` is the sandbox's home), with the
changes a test needs, each listed in :data:`CHANGED`: a live run or a simulated enrolment is cut
short, files under /tmp go to the sandbox, and the files a page assumes the user has (a recording, a predictions file)
are made first (:func:`user_files`). The commands not run are listed in :data:`NOT_RUN`, each
with the reason.
"""

from __future__ import annotations

import ast
import functools
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from neurotouch_hid.enrolment.plan import Plan, make_plan, write_plan

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: Commands not run, first match wins: (pattern, why).
NOT_RUN: list[tuple[str, str]] = [
    (
        r"^neurotouch-hid (?:track|eval|enrol|adapt|simulate|info|view)$",
        "names a command in prose; its arguments are in the text around it",
    ),
    (r"\$\{?\w", "a figure's reproduction with shell variables (docs/accuracy.md): minutes of CPU each"),
    (
        r"[\[\]|<>]|\b(?:KEY|VALUE|NAME|DIR|N|FAMILY|DEG|GAME|PROFILE|DATASET|FILE|PATH)\b",
        "a synopsis: capitals, [optional] parts and a|b stand for what the user fills in",
    ),
    (r"--source davis\b", "needs the DAVIS-346 camera and the gel"),
    (r"^neurotouch-hid (?:run|record|calibrate)\b(?!.*--source)", "needs the DAVIS-346 camera (the default source)"),
    (
        r"--preset (?:paper|quick)",
        "simulates a dataset: minutes of CPU (tests/test_simulator.py simulates the presets)",
    ),
    (r"sim-40s-seed0\.aedat4", "a benchmark's recording (benchmarks/), made by the benchmark"),
    (r"^neurotouch-hid eval ", "needs a labelled dataset (tests/test_through_profile.py runs eval on a simulated one)"),
]
#: How many of its plan's prompts a simulated enrolment follows here (:data:`CHANGED`).
ENROL_PROMPTS = 4
#: What the test changes in a command as written, and why.
CHANGED = {
    "--seconds N of demo and run -> --seconds 2": "the same run, shorter",
    "run --source sim without --seconds -> with --seconds 2": "it runs until Ctrl-C",
    "enrol --source sim -> with --fast": "the same session and dataset, not paced in real time (~2 min)",
    "enrol --source sim -> with --plan of the first ENROL_PROMPTS prompts of its seed's plan": (
        "the same session, shorter (the whole plan: ~20 s of CPU; tests/test_enrolment_session.py runs its paths)"
    ),
    "/tmp/ -> the sandbox's folder": "no file outside the test's folder",
}
#: Commands documented to fail here, with the message troubleshooting.md must list for them.
EXPECTED_ERRORS = {r"^neurotouch-hid profile use ": "no neurotouch-hid driver is running"}


def _join_inline_spans(text: str) -> str:
    """The prose's inline code spans on one line each (a span may wrap in the Markdown)."""
    parts = text.split("`")
    return "`".join(p.replace("\n", " ") if i % 2 else p for i, p in enumerate(parts))


def documented_commands(page: Path) -> list[str]:
    """Every ``neurotouch-hid ...`` command of ``page`` in order: the lines of its code blocks
    (a ``$`` prompt and a trailing ``# comment`` left out, ``\\`` continuations joined) and its
    inline code spans that start with the command."""
    commands: list[str] = []
    prose: list[str] = []
    fenced = False
    pending = ""
    for line in page.read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
            prose.append("")
            continue
        if not fenced:
            prose.append(line)
            continue
        line = pending + line.strip()
        pending = ""
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        line = re.sub(r"^\$ ", "", line)
        if line.startswith("neurotouch-hid "):
            commands.append(re.sub(r"\s+#\s.*$", "", line).strip())
    text = _join_inline_spans("\n".join(prose))
    commands += [span.strip() for span in re.findall(r"`(neurotouch-hid [^`]+)`", text)]
    return commands


def not_run_reason(command: str) -> str | None:
    """Why ``command`` is not run (:data:`NOT_RUN`), or None."""
    return next((why for pattern, why in NOT_RUN if re.search(pattern, command)), None)


def as_run(command: str, sandbox: Path) -> str:
    """``command`` with the changes of :data:`CHANGED`."""
    if re.match(r"neurotouch-hid (?:demo|run)\b", command):
        command = re.sub(r"--seconds \S+", "--seconds 2", command)
        if "--seconds" not in command:
            command += " --seconds 2"
    plan = ""
    if re.match(r"neurotouch-hid enrol\b.*--source sim\b", command):
        if "--fast" not in command:
            command += " --fast"
        if "--plan" not in command:  # the same seed's plan, its first prompts
            seed = re.search(r"--seed (\d+)", command)
            prompts = make_plan(int(seed.group(1)) if seed else 0).prompts[:ENROL_PROMPTS]
            plan = f" --plan {write_plan(Plan(prompts), sandbox / 'first-prompts.json')}"
    return command.replace("/tmp/", f"{sandbox}/") + plan


def user_files(home: Path, recording: Path) -> None:
    """The files the pages assume the user has, in the home they run in: recordings (a short
    simulated one) and a predictions file."""
    for name in ("REC.aedat4", "my-recording.aedat4", "rec.aedat4"):
        shutil.copyfile(recording, home / name)
    predictions = home / "predictions.jsonl"
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType

    rows = []
    for i in range(200):
        pushing = 50 <= i < 120
        e = GestureEstimate(
            t_us=i * 10_000,
            gesture=GestureType.PUSH if pushing else GestureType.NONE,
            resting=not pushing,
            intensity_mm=3.0 if pushing else 0.0,
            translation_mm=[0.0, 1.0] if pushing else [0.0, 0.0],
        )
        rows.append(json.dumps(e.to_json_dict()))
    predictions.write_text("\n".join(rows) + "\n")


def sandbox_env(home: Path) -> dict[str, str]:
    """A new user's environment: HOME, no XDG_CONFIG_HOME (so ``~/.config`` is the config folder,
    as the docs say), a runtime folder, ``neurotouch-hid`` on PATH (this tree's), no editor."""
    bin_dir = home.parent / "bin"
    bin_dir.mkdir(exist_ok=True)
    wrapper = bin_dir / "neurotouch-hid"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m neurotouch_hid.cli "$@"\n')
    wrapper.chmod(0o755)
    runtime = home.parent / "run"
    runtime.mkdir(mode=0o700, exist_ok=True)
    return {
        "PATH": f"{bin_dir}:/usr/bin:/bin",
        "HOME": str(home),
        "XDG_RUNTIME_DIR": str(runtime),
        "PYTHONPATH": str(ROOT),
        "EDITOR": "true",
        "COLUMNS": "120",
        # the compiled pipeline is shared with the other tests: a new cache would compile again
        **{k: v for k, v in os.environ.items() if k.startswith("NUMBA_")},
    }


def test_every_page_has_commands_and_every_one_is_run_or_says_why_not():
    found = {page.name: documented_commands(page) for page in PAGES}
    assert len(found["profiles.md"]) > 10 and len(found["README.md"]) > 10
    ran = [c for commands in found.values() for c in commands if not_run_reason(c) is None]
    assert len(ran) > 30


@pytest.mark.parametrize("page", [p for p in PAGES if documented_commands(p)], ids=lambda p: p.name)
def test_the_commands_of_a_page_run_as_written(page, tmp_path, sim_gel_short_recording):
    home = tmp_path / "home"
    home.mkdir()
    user_files(home, sim_gel_short_recording)
    env = sandbox_env(home)
    troubleshooting = (ROOT / "docs" / "troubleshooting.md").read_text()
    problems = []
    for command in documented_commands(page):
        if not_run_reason(command) is not None:
            continue
        done = subprocess.run(
            ["bash", "-c", as_run(command, tmp_path)],
            cwd=home,
            env=env,
            capture_output=True,
            text=True,
            stdin=subprocess.DEVNULL,
            timeout=600,
        )
        said = done.stdout + done.stderr
        expected = next((m for p, m in EXPECTED_ERRORS.items() if re.search(p, command)), None)
        if "Traceback" in said:
            problems.append(f"{command}: a traceback\n{said[-2000:]}")
        elif expected is not None:
            if done.returncode != 2 or expected not in said or expected not in troubleshooting:
                problems.append(f"{command}: expected the listed error '{expected}', got {done.returncode}: {said}")
        elif done.returncode not in (0, 1) or "error:" in done.stderr:
            problems.append(f"{command}: exit {done.returncode}\n{said[-2000:]}")
        elif done.returncode == 1 and not re.match(r"neurotouch-hid (?:doctor|devices)\b", command):
            problems.append(f"{command}: exit 1 (only the reports, doctor and devices, exit 1)\n{said[-2000:]}")
    assert not problems, "\n\n".join(problems)


def test_readmes_profile_takes_the_settings_profiles_md_shows(tmp_path):
    """A user makes README's profile, then follows docs/profiles.md's set and unset lines."""
    home = tmp_path / "home"
    home.mkdir()
    env = sandbox_env(home)
    made = [c for c in documented_commands(ROOT / "README.md") if c.startswith("neurotouch-hid profile new ")]
    changes = [
        c
        for c in documented_commands(ROOT / "docs" / "profiles.md")
        if re.match(r"neurotouch-hid profile (?:set|unset) mine ", c)
    ]
    assert made and changes
    for command in made[:1] + changes:
        done = subprocess.run(["bash", "-c", command], cwd=home, env=env, capture_output=True, text=True)
        assert done.returncode == 0, f"{command}: {done.stderr}"


# --- troubleshooting.md's messages are the code's -------------------------------------------------
WORD = re.compile(r"[A-Za-z0-9_]+")
#: A value an f-string fills in (it stands for up to this many words of a doc's example).
SLOT = None
SLOT_WORDS = 6
#: The docs' placeholders in a message (FILE, N, ...).
PLACEHOLDERS = {"FILE", "LINE", "FIELD", "VALUE", "NAME", "N", "X", "K", "P", "W", "F", "B", "D", "E", "DEG"}
#: Messages of other programs that troubleshooting.md explains (pip, gcc, the shell).
OTHER_PROGRAMS = (
    "externally-managed-environment",
    "Can not perform a '--user' install",
    "include files are missing",
    "gcc: not found",
    "neurotouch-hid: command not found",
)


@functools.cache
def code_templates() -> list[tuple]:
    """Every string the package (and its shell scripts) can print, as words, an f-string's
    values as :data:`SLOT`."""
    found: set[tuple] = set()
    for path in (ROOT / "neurotouch_hid").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                found.add(tuple(WORD.findall(node.value)))
            elif isinstance(node, ast.JoinedStr):
                words: list = []
                for value in node.values:
                    words += WORD.findall(value.value) if isinstance(value, ast.Constant) else [SLOT]
                found.add(tuple(words))
    for script in (ROOT / "packaging").glob("*.sh"):
        for line in script.read_text().splitlines():
            found.add(tuple(SLOT if w.startswith("$") else w for w in re.findall(r"\$\{?\w+\}?|\w+", line)))
    return [t for t in found if len(t) > 1]


def _literal_words(doc: tuple, template: tuple) -> int:
    """The most words of ``doc`` matched literally when it is read as a stretch of a message made
    from ``template`` (each value standing for up to :data:`SLOT_WORDS` of its words; a placeholder
    only for a value); -1 when it cannot be."""

    @functools.cache
    def match(j: int, i: int, taken: int) -> int:
        if j == len(doc):
            return 0
        if i == len(template):
            return -1
        if template[i] is SLOT:
            within = match(j + 1, i, taken + 1) if taken < SLOT_WORDS else -1
            return max(match(j, i + 1, 0), within)
        if doc[j] != template[i]:
            return -1
        rest = match(j + 1, i + 1, 0)
        return -1 if rest < 0 else rest + 1

    return max((match(0, start, 0) for start in range(len(template))), default=-1)


def listed_messages() -> list[str]:
    """The messages in troubleshooting.md's tables (the first column's code spans)."""
    text = (ROOT / "docs" / "troubleshooting.md").read_text()
    cells = [line.split(" | ")[0].lstrip("| ") for line in text.splitlines() if line.startswith("| `")]
    return [m.replace("\\|", "|") for cell in cells for m in re.findall(r"`([^`]+)`", cell)]


def test_every_message_troubleshooting_lists_is_one_the_code_prints():
    """Each stretch of a listed message between ``...`` reads as part of one string of the code:
    its words in order, the code's values standing for the docs' examples and placeholders."""
    missing = []
    for message in listed_messages():
        if any(other in message for other in OTHER_PROGRAMS):
            continue
        for stretch in message.split("..."):
            doc = tuple(WORD.findall(stretch))
            if len([w for w in doc if w not in PLACEHOLDERS]) < 4:
                continue  # too short to tell one message from another
            if not any(_literal_words(doc, t) >= 2 for t in code_templates()):
                missing.append(f"{stretch.strip()!r} (in `{message}`)")
    assert not missing, "not in the code:\n" + "\n".join(missing)


def test_the_message_check_tells_a_changed_message():
    doc = tuple(WORD.findall("cannot reach the driver at"))
    assert any(_literal_words(doc, t) >= 2 for t in code_templates())
    wrong = tuple(WORD.findall("cannot contact the running driver over"))
    assert not any(_literal_words(wrong, t) >= 2 for t in code_templates())


def test_the_docs_put_the_compiled_code_where_numba_puts_it():
    """Installed with pipx or in a venv, the package's own folders are writable, so numba caches
    there (neurotouch_hid/service/jit_cache.py): a page that names ``~/.cache/neurotouch-hid`` as the
    cache also names the package's ``__pycache__`` folders."""
    from neurotouch_hid.service import jit_cache

    assert jit_cache.chosen().kind == jit_cache.PACKAGE  # this tree, as a pipx or venv install
    for page in PAGES:
        for paragraph in page.read_text().split("\n\n"):
            if "~/.cache/neurotouch-hid" in paragraph:
                assert "__pycache__" in paragraph, f"{page.name}: {paragraph}"
