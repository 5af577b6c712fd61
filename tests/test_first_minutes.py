"""What a new user meets in the first minutes: the piped terminal view keeps every output change,
the profile commands undo what they did, doctor's fixes can be copied, the help is readable, and
the README's commands are the ones that work."""

from __future__ import annotations

import io
import subprocess
import sys
import textwrap

import pytest
from rich.console import Console

from neurotouch_hid.controller import ControllerState
from neurotouch_hid.mapping.profile import shipped_profiles_dir
from neurotouch_hid.output.jsonl import StateJsonlWriter
from neurotouch_hid.output.term import TermView


def plain_console() -> Console:
    return Console(file=io.StringIO(), force_terminal=False, width=10_000, color_system=None)


# --- the piped view ------------------------------------------------------------------------------
def test_piped_view_prints_a_key_press_and_its_release_however_short():
    console = plain_console()
    view = TermView(console, line_period_s=3600)  # no line is ever due by time
    view.write(ControllerState.neutral(0))  # the first line
    down = ControllerState.neutral(10_000)
    down.keys = frozenset({"KEY_SPACE"})
    view.write(down)
    view.write(ControllerState.neutral(20_000))
    view.close()
    lines = console.file.getvalue().splitlines()
    assert [("KEY_SPACE" in line) for line in lines] == [False, True, False]


def test_piped_view_prints_the_last_analogue_state_and_the_whole_mouse_motion():
    console = plain_console()
    view = TermView(console, line_period_s=3600)
    view.write(ControllerState.neutral(0))
    for i in range(1, 4):  # three steps within one period: not printed when written
        moved = ControllerState.neutral(i * 10_000)
        moved.axes["ABS_X"] = 32767
        moved.rel = {"REL_X": 5}
        view.write(moved)
    assert len(console.file.getvalue().splitlines()) == 1
    view.close()  # the stretch's last state is printed, with the motion of all three steps
    last = console.file.getvalue().splitlines()[-1]
    assert "L(+1.00,+0.00)" in last and "REL_X +15" in last


class Both:
    """The piped terminal view and the JSON lines of one and the same run."""

    accepts_estimate = True

    def __init__(self, term: TermView, jsonl: StateJsonlWriter):
        self.term, self.jsonl = term, jsonl

    def write(self, state, estimate=None):
        self.term.write(state, estimate)
        self.jsonl.write(state, estimate)

    def prepare(self, profile):
        pass

    def neutralise(self):
        self.term.neutralise()
        self.jsonl.neutralise()


def key_changes(keys_per_line: list[frozenset]) -> list[frozenset]:
    changes = [keys_per_line[0]]
    for keys in keys_per_line[1:]:
        if keys != changes[-1]:
            changes.append(keys)
    return changes


def test_piped_switch_access_run_shows_every_key_press_the_json_lines_show():
    import json

    from neurotouch_hid.driver import run_driver

    console, stream = plain_console(), io.StringIO()
    term = TermView(console)
    jsonl = StateJsonlWriter(stream)
    run_driver("sim", "switch-access", "term", seconds=8, fast=True, output_obj=Both(term, jsonl))
    term.close()
    from_json = [frozenset(json.loads(line)["keys"]) for line in stream.getvalue().splitlines()]
    from_term = []
    for line in console.file.getvalue().splitlines():
        keys = line.split(" keys ")[1].split()[0] if " keys " in line else "-"
        from_term.append(frozenset() if keys == "-" else frozenset(keys.split(",")))
    presses = [k for k in key_changes(from_json) if k]
    assert len(presses) >= 2  # the simulated hand's first gestures press keys within 8 s
    assert key_changes(from_term) == key_changes(from_json)


# --- the profile commands ------------------------------------------------------------------------
@pytest.fixture()
def cli(tmp_path, monkeypatch, capsys):
    """``neurotouch-hid ARGS`` in this process (cli.main: errors -> exit 2), config in tmp;
    ``stdin``: what the user types."""
    from neurotouch_hid.cli import main

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("VISUAL", raising=False)

    def run(*args: str, stdin: str = "") -> subprocess.CompletedProcess:
        monkeypatch.setattr(sys, "argv", ["neurotouch-hid", *args])
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
        capsys.readouterr()
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = exc.code or 0
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(args, code, out, err)

    run.user_dir = tmp_path / "config" / "neurotouch-hid" / "profiles"
    return run


def test_setting_a_shipped_profile_says_it_made_a_shadowing_copy_and_reset_undoes_it(cli):
    changed = cli("profile", "set", "default", "mappings.push.deadzone_mm", "1.0")
    assert changed.returncode == 0, changed.stderr
    copy = cli.user_dir / "default.yaml"
    assert "shipped profile" in changed.stderr and str(copy) in changed.stderr
    assert "neurotouch-hid profile reset default" in changed.stderr
    again = cli("profile", "set", "default", "mappings.push.deadzone_mm", "1.1")
    assert again.returncode == 0 and "shipped profile" not in again.stderr  # said once, when made
    reset = cli("profile", "reset", "default")
    assert reset.returncode == 0 and "shipped one again" in reset.stdout
    assert not copy.exists()
    assert cli("profile", "path", "default").stdout.strip() == str(shipped_profiles_dir() / "default.yaml")
    assert "already the shipped one" in cli("profile", "reset", "default").stdout
    mine = cli("profile", "reset", "mine")
    assert mine.returncode == 2 and "not a shipped profile" in mine.stderr and "profile delete mine" in mine.stderr


def test_delete_removes_a_user_profile_and_refuses_a_shipped_one(cli):
    assert cli("profile", "new", "mine").returncode == 0
    deleted = cli("profile", "delete", "mine")
    assert deleted.returncode == 0 and not (cli.user_dir / "mine.yaml").exists()
    assert cli("profile", "path", "mine").returncode == 2
    shipped = cli("profile", "delete", "default")
    assert shipped.returncode == 2 and "shipped profile" in shipped.stderr
    assert (shipped_profiles_dir() / "default.yaml").is_file()
    assert cli("profile", "set", "default", "mappings.push.deadzone_mm", "1.0").returncode == 0
    shadow = cli("profile", "delete", "default")  # deleting the copy brings the shipped one back
    assert shadow.returncode == 0 and "applies again" in shadow.stdout


def test_unset_on_a_copy_of_a_shipped_profile_goes_back_to_the_shipped_value(cli):
    from ruamel.yaml import YAML

    assert cli("profile", "new", "mine", "--from", "default").returncode == 0
    assert cli("profile", "set", "mine", "mappings.push.deadzone_mm", "2.0").returncode == 0
    undone = cli("profile", "unset", "mine", "mappings.push.deadzone_mm")
    assert undone.returncode == 0, undone.stderr
    shipped = YAML().load((shipped_profiles_dir() / "default.yaml").read_text())["mappings"]["push"]["deadzone_mm"]
    assert shipped != 0.5  # the schema's default, which unset used to leave
    mine = YAML().load((cli.user_dir / "mine.yaml").read_text())
    assert mine["mappings"]["push"]["deadzone_mm"] == shipped and f"shipped value {shipped}" in undone.stdout


def test_a_key_of_a_mapping_the_profile_lacks_names_the_mappings_it_has(cli):
    assert cli("profile", "new", "mine", "--from", "accessibility").returncode == 0
    before = (cli.user_dir / "mine.yaml").read_text()
    wrong = cli("profile", "set", "mine", "mappings.push.deadzone_mm", "1.0")
    assert wrong.returncode == 2
    assert "has no mapping 'push'" in wrong.stderr and "up, down, left, right, confirm, back, move" in wrong.stderr
    assert "input: missing" not in wrong.stderr
    assert (cli.user_dir / "mine.yaml").read_text() == before
    unset = cli("profile", "unset", "mine", "mappings.push.deadzone_mm")
    assert unset.returncode == 2 and "it has: up, down" in unset.stderr


@pytest.fixture()
def scripted_editor(tmp_path, monkeypatch):
    """$EDITOR: a script that breaks the profile on its first call and fixes it on the next ones,
    counting its calls in ``calls``."""
    calls = tmp_path / "calls"
    script = tmp_path / "editor.sh"
    script.write_text(
        textwrap.dedent(
            f"""\
            #!/bin/sh
            echo x >> {calls}
            if [ "$(wc -l < {calls})" -eq 1 ]; then
                sed -i 's/deadzone_mm: 0.8 /deadzone_mm: -2 /' "$1"
            else
                sed -i 's/deadzone_mm: -2 /deadzone_mm: 1.5 /' "$1"
            fi
            """
        )
    )
    script.chmod(0o755)
    monkeypatch.setenv("EDITOR", str(script))
    return calls


def test_edit_reopens_the_editor_on_an_invalid_save_like_crontab(cli, scripted_editor):
    edited = cli("profile", "edit", "default", stdin="y\n")
    assert edited.returncode == 0, edited.stderr
    assert len(scripted_editor.read_text().split()) == 2  # opened again after the invalid save
    assert "deadzone_mm" in edited.stderr and "edit it again?" in edited.stderr
    assert "deadzone_mm: 1.5 " in (cli.user_dir / "default.yaml").read_text()


def test_edit_answered_no_keeps_the_profile_and_the_rejected_edit(cli, scripted_editor):
    assert cli("profile", "set", "default", "mappings.push.exponent", "1.0").returncode == 0
    copy = cli.user_dir / "default.yaml"
    before = copy.read_text()
    given_up = cli("profile", "edit", "default", stdin="n\n")
    assert given_up.returncode == 2 and "Traceback" not in given_up.stderr
    assert copy.read_text() == before  # the profile the driver loads is still valid
    assert "deadzone_mm: -2 " in (cli.user_dir / "default.yaml.rejected").read_text()
    assert "default.yaml.rejected" in given_up.stderr
    unchanged = cli("profile", "edit", "default")  # the script's second call changes nothing here
    assert unchanged.returncode == 0 and "unchanged" in unchanged.stdout and copy.read_text() == before
