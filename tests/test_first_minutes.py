"""What a new user meets in the first minutes: the piped terminal view keeps every output change,
the profile commands undo what they did, doctor's fixes can be copied, the help is readable, and
the README's commands are the ones that work."""

from __future__ import annotations

import importlib.metadata
import io
import os
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest
from helpers import run_cli
from rich.console import Console

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.mapping.profile import shipped_profiles_dir
from neurotouch_hid.views.jsonl import StateJsonlWriter
from neurotouch_hid.views.term import TermView


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

    wants_markers = False

    def __init__(self, term: TermView, jsonl: StateJsonlWriter):
        self.term, self.jsonl = term, jsonl

    def publish(self, record):
        self.term.publish(record)
        self.jsonl.publish(record)

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

    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    console, stream = plain_console(), io.StringIO()
    term = TermView(console)
    jsonl = StateJsonlWriter(stream)
    run_driver("sim", "switch-access", "term", DriverOptions(seconds=8, fast=True, outputs=[Both(term, jsonl)]))
    term.close()
    from_json = [frozenset(json.loads(line)["keys"]) for line in stream.getvalue().splitlines()]
    from_term = []
    for line in console.file.getvalue().splitlines():
        keys = line.split(" keys ")[1].split()[0] if " keys " in line else "-"
        from_term.append(frozenset() if keys == "-" else frozenset(keys.split(",")))
    presses = [k for k in key_changes(from_json) if k]
    assert len(presses) >= 2  # the simulated hand's first gestures press keys within 8 s
    assert key_changes(from_term) == key_changes(from_json)


# --- the profile commands (test_cli's fixture) ----------
def test_setting_a_shipped_profile_says_it_made_a_shadowing_copy_and_reset_undoes_it(cli):
    changed = cli("set", "default", "mappings.push.deadzone_mm", "1.0")
    assert changed.returncode == 0, changed.stderr
    copy = cli.user_dir / "default.yaml"
    assert "shipped profile" in changed.stderr and str(copy) in changed.stderr
    assert "neurotouch-hid profile reset default" in changed.stderr
    again = cli("set", "default", "mappings.push.deadzone_mm", "1.1")
    assert again.returncode == 0 and "shipped profile" not in again.stderr  # said once, when made
    reset = cli("reset", "default")
    assert reset.returncode == 0 and "shipped one again" in reset.stdout
    assert not copy.exists()
    assert cli("path", "default").stdout.strip() == str(shipped_profiles_dir() / "default.yaml")
    assert "already the shipped one" in cli("reset", "default").stdout
    assert cli("new", "mine").returncode == 0
    mine = cli("reset", "mine")
    assert mine.returncode == 2 and "not a shipped profile" in mine.stderr and "profile delete mine" in mine.stderr


def test_delete_removes_a_user_profile_and_refuses_a_shipped_one(cli):
    assert cli("new", "mine").returncode == 0
    deleted = cli("delete", "mine")
    assert deleted.returncode == 0 and not (cli.user_dir / "mine.yaml").exists()
    assert cli("path", "mine").returncode == 2
    shipped = cli("delete", "default")
    assert shipped.returncode == 2 and "shipped profile" in shipped.stderr
    assert (shipped_profiles_dir() / "default.yaml").is_file()
    assert cli("set", "default", "mappings.push.deadzone_mm", "1.0").returncode == 0
    shadow = cli("delete", "default")  # deleting the copy brings the shipped one back
    assert shadow.returncode == 0 and "applies again" in shadow.stdout


def test_unset_on_a_copy_of_a_shipped_profile_goes_back_to_the_shipped_value(cli):
    from ruamel.yaml import YAML

    assert cli("new", "mine", "--from", "default").returncode == 0
    assert cli("set", "mine", "mappings.push.deadzone_mm", "2.0").returncode == 0
    undone = cli("unset", "mine", "mappings.push.deadzone_mm")
    assert undone.returncode == 0, undone.stderr
    shipped = YAML().load((shipped_profiles_dir() / "default.yaml").read_text())["mappings"]["push"]["deadzone_mm"]
    assert shipped != 0.5  # the schema's default, which unset used to leave
    mine = YAML().load((cli.user_dir / "mine.yaml").read_text())
    assert mine["mappings"]["push"]["deadzone_mm"] == shipped and f"shipped value {shipped}" in undone.stdout


def test_a_copys_mapping_and_key_can_be_removed_from_the_command_line(cli):
    """unset on a copy put the shipped value back and, when it was there already, changed nothing
    ('300 -> back to the shipped value 300'): the second unset removes the key, and set ... null
    points at unset and edit."""
    from ruamel.yaml import YAML

    assert cli("new", "mine", "--from", "default").returncode == 0
    key = "mappings.push.deadzone_mm"
    first = cli("unset", "mine", key)  # the shipped value already: removed
    assert first.returncode == 0 and "it was the shipped value already: removed" in first.stdout, first.stdout
    assert "deadzone_mm" not in YAML().load((cli.user_dir / "mine.yaml").read_text())["mappings"]["push"]
    gone = cli("unset", "mine", "mappings.zoom")
    assert gone.returncode == 0 and "removed" in gone.stdout
    assert "zoom" not in YAML().load((cli.user_dir / "mine.yaml").read_text())["mappings"]
    null = cli("set", "mine", "mappings.pinch", "null")
    assert null.returncode == 2
    assert "`neurotouch-hid profile unset mine mappings.pinch`" in null.stderr, null.stderr
    assert "`neurotouch-hid profile edit mine`" in null.stderr


def test_text_that_yaml_reads_as_a_mapping_gets_the_quoted_command(cli):
    assert cli("new", "mine", "--from", "default").returncode == 0
    before = (cli.user_dir / "mine.yaml").read_text()
    refused = cli("set", "mine", "description", "Client A: push = Space")
    assert refused.returncode == 2 and (cli.user_dir / "mine.yaml").read_text() == before
    hint = "read as YAML, as a mapping; for text, quote it"
    assert hint in refused.stderr and "profile set mine description \"'Client A: push = Space'\"" in refused.stderr
    done = cli("set", "mine", "description", "'Client A: push = Space'")  # what the hint gives the shell
    assert done.returncode == 0 and "description: 'Client A: push = Space'" in (cli.user_dir / "mine.yaml").read_text()
    number = cli("set", "mine", "mappings.push.deadzone_mm", "-1")  # a number where a number goes: no quoting hint
    assert number.returncode == 2 and "quote it" not in number.stderr


def test_a_key_of_a_mapping_the_profile_lacks_names_the_mappings_it_has(cli):
    assert cli("new", "mine", "--from", "accessibility").returncode == 0
    before = (cli.user_dir / "mine.yaml").read_text()
    wrong = cli("set", "mine", "mappings.push.deadzone_mm", "1.0")
    assert wrong.returncode == 2
    assert "has no mapping 'push'" in wrong.stderr and "up, down, left, right, confirm, back, move" in wrong.stderr
    assert "input: missing" not in wrong.stderr
    assert (cli.user_dir / "mine.yaml").read_text() == before
    unset = cli("unset", "mine", "mappings.push.deadzone_mm")
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


def test_edit_reopens_the_editor_on_an_invalid_save_like_crontab(cli, scripted_editor, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO("y\n"))  # the user answers yes
    edited = cli("edit", "default")
    assert edited.returncode == 0, edited.stderr
    assert len(scripted_editor.read_text().split()) == 2  # opened again after the invalid save
    assert "deadzone_mm" in edited.stderr and "edit it again?" in edited.stderr
    assert "deadzone_mm: 1.5 " in (cli.user_dir / "default.yaml").read_text()


def test_edit_answered_no_keeps_the_profile_and_the_rejected_edit(cli, scripted_editor, monkeypatch):
    assert cli("set", "default", "mappings.push.exponent", "1.0").returncode == 0
    copy = cli.user_dir / "default.yaml"
    before = copy.read_text()
    monkeypatch.setattr(sys, "stdin", io.StringIO("n\n"))
    given_up = cli("edit", "default")
    assert given_up.returncode == 2 and "Traceback" not in given_up.stderr
    assert copy.read_text() == before  # the profile the driver loads is still valid
    assert "deadzone_mm: -2 " in (cli.user_dir / "default.yaml.rejected").read_text()
    assert "default.yaml.rejected" in given_up.stderr
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    again = cli("edit", "default")  # starts from the rejected edit, which the script's second call fixes
    assert again.returncode == 0 and "deadzone_mm: 1.5 " in copy.read_text()
    assert not (cli.user_dir / "default.yaml.rejected").exists()


# --- install, doctor, --version, --help ----------------------------------------------------------
ROOT = Path(__file__).resolve().parents[1]


def test_the_rule_and_the_install_script_ship_inside_the_package():
    from neurotouch_hid.service.udev import INSTALL_SCRIPT, RULES_FILE

    for path in (RULES_FILE, INSTALL_SCRIPT, INSTALL_SCRIPT.with_name("neurotouch-hid.service")):
        assert path.is_absolute() and path.is_file()
    package = ROOT / "neurotouch_hid"
    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    shipped = {p for g in globs["neurotouch_hid"] for p in package.glob(g)}
    assert {package / "data/udev/60-neurotouch.rules", package / "data/packaging/install.sh"} <= shipped
    assert (package / "data/udev/60-neurotouch.rules").read_bytes() == (ROOT / "udev/60-neurotouch.rules").read_bytes()


def test_doctor_piped_is_plain_lines_with_each_fix_whole_on_its_own_line(tmp_path):
    from neurotouch_hid.service.udev import INSTALL_SCRIPT, RULES_INSTALL

    config = tmp_path / "xdg"
    proc = run_cli("doctor", env={"XDG_CONFIG_HOME": str(config), "COLUMNS": "40"})
    assert proc.returncode == 1  # no camera here: a report with problems, not a usage error
    lines = proc.stdout.splitlines()
    assert not any(ch in proc.stdout for ch in "│┃━─╭╰") and "\x1b[" not in proc.stdout
    assert f"sh {INSTALL_SCRIPT} --user" in " ".join(line.strip() for line in lines)
    assert not any(line.strip().startswith(("packaging/", "udev/")) for line in lines)
    if not os.path.exists("/dev/uinput"):
        assert RULES_INSTALL in [line.strip() for line in lines]  # whole, alone: copyable
    # the unit install.sh writes under $XDG_CONFIG_HOME is the one doctor finds
    shim = tmp_path / "bin" / "neurotouch-hid"
    shim.parent.mkdir()
    shim.write_text("#!/bin/sh\nexit 0\n")
    shim.chmod(0o755)
    env = {"HOME": str(tmp_path / "home"), "XDG_CONFIG_HOME": str(config)}
    installed = subprocess.run(
        ["sh", str(INSTALL_SCRIPT), "--user", "--bin", str(shim)],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=60,
    )
    assert installed.returncode == 0, installed.stderr
    unit = config / "systemd/user/neurotouch-hid.service"
    assert unit.is_file()
    again = run_cli("doctor", env={"XDG_CONFIG_HOME": str(config)})
    rows = again.stdout.replace("\n" + " " * 37, " ").splitlines()  # a detail's wrapped lines joined
    service = [line for line in rows if "plug-and-play service" in line]
    assert service and service[0].startswith("ok") and str(unit) in service[0].replace(" ", ""), again.stdout


def test_doctor_piped_keeps_to_100_columns_but_for_a_whole_command(tmp_path):
    """The gadget row was a 244-column line: details wrap under themselves, comments as comments;
    only a command (copied whole) may be longer."""
    proc = run_cli("doctor", env={"XDG_CONFIG_HOME": str(tmp_path / "xdg")})
    long = [line for line in proc.stdout.splitlines() if len(line) > 100]
    assert all(line.startswith("      ") and not line.strip().startswith("#") for line in long), long


def test_install_script_finds_pipx_command_off_path(tmp_path):
    from neurotouch_hid.service.udev import INSTALL_SCRIPT

    home = tmp_path / "home"
    pipx_bin = home / ".local/bin/neurotouch-hid"
    pipx_bin.parent.mkdir(parents=True)
    pipx_bin.write_text("#!/bin/sh\nexit 0\n")
    pipx_bin.chmod(0o755)
    env = {**os.environ, "HOME": str(home), "XDG_CONFIG_HOME": "", "PATH": "/usr/bin:/bin"}
    proc = subprocess.run(["sh", str(INSTALL_SCRIPT), "--user"], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert f"ExecStart={pipx_bin} run" in (home / ".config/systemd/user/neurotouch-hid.service").read_text()


def test_install_script_help_is_its_usage_not_its_code():
    from neurotouch_hid.service.udev import INSTALL_SCRIPT

    proc = subprocess.run(["sh", str(INSTALL_SCRIPT), "--help"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "usage: install.sh" in proc.stdout
    assert "--system" in proc.stdout and "--user" in proc.stdout and "DESTDIR" in proc.stdout
    code = [line for line in INSTALL_SCRIPT.read_text().splitlines() if line and not line.startswith("#")]
    assert not any(line.strip() and line in code for line in proc.stdout.splitlines())
    assert not any(line.startswith("#") for line in proc.stdout.splitlines())


def test_version():
    proc = run_cli("--version")
    assert proc.returncode == 0
    assert proc.stdout == f"neurotouch-hid {importlib.metadata.version('neurotouch-hid')}\n"


def test_help_has_no_bool_placeholders_and_whole_sentences():
    run = run_cli("run", "--help")
    assert run.returncode == 0 and "<bool>" not in run.stdout and "╭" not in run.stdout
    fast = [line for line in run.stdout.splitlines() if line.strip().startswith("--fast")]
    assert fast and "do not pace recordings in real time" in fast[0]  # flag and help on one line
    # piped, a paragraph of the docstring stays one line, never broken where the source broke it
    assert any(
        line.strip().startswith("Stops at the end of the source") and line.rstrip().endswith("back.")
        for line in run.stdout.splitlines()
    )
    profile = run_cli("profile", "--help")
    commands = profile.stdout.split("Commands:")[1].splitlines()
    assert any(line.split()[:1] == ["delete"] for line in commands if line.strip())
    assert not any(line.rstrip().endswith("...") for line in commands)  # no summary cut short


def test_no_uinput_is_a_few_short_lines_with_the_command_alone(tmp_path):
    from neurotouch_hid.core.errors import DeviceError
    from neurotouch_hid.service.udev import RULES_INSTALL
    from neurotouch_hid.targets.uinput.gamepad import create_uinput

    with pytest.raises(DeviceError) as info:
        create_uinput("gamepad", {}, devnode=str(tmp_path / "uinput"))
    lines = str(info.value).replace(str(tmp_path / "uinput"), "/dev/uinput").splitlines()
    assert 2 <= len(lines) <= 5 and RULES_INSTALL in lines
    assert all(len(line) <= 100 for line in lines if line != RULES_INSTALL)


# --- the README and the docs ---------------------------------------------------------------------
def sh_blocks(text: str) -> list[str]:
    return re.findall(r"^```sh\n(.*?)^```$", text, flags=re.S | re.M)


def test_readme_first_command_needs_no_pip_into_the_system_python():
    readme = (ROOT / "README.md").read_text()
    first, second = sh_blocks(readme)[:2]
    assert "pipx install ." in first and "pip install" not in first.replace("pipx install", "")
    before = readme[: readme.index("```sh")]
    apt = re.search(r"`sudo apt install ([^`]*)`", before)  # said before the command
    assert apt and apt.group(1).split() == ["pipx"]  # no compiler, no headers: evdev comes as a wheel
    started = sh_blocks((ROOT / "docs/getting-started.md").read_text())[0].splitlines()
    assert started[:2] == ["sudo apt install pipx", "pipx install ."]
    # the test command .ci/run runs stays as it was
    assert second.strip() == (
        "python3 -m venv .venv && .venv/bin/python -m pip install -q --upgrade --upgrade-strategy eager "
        "-e '.[test]' && .venv/bin/python -m pytest -q"
    )
    packaging = (ROOT / "packaging/README.md").read_text()
    assert "pip install --user" not in packaging and "pipx install ." in packaging


def test_every_option_the_readme_shows_exists():
    import typer.main

    from neurotouch_hid.cli import app

    root = typer.main.get_command(app)
    readme = (ROOT / "README.md").read_text()
    spans = re.findall(r"`(neurotouch-hid [^`]+)`", readme)
    assert len(spans) > 10
    for span in spans:
        words = span.replace("\\|", "|").split()[1:]
        command = root
        while words and hasattr(command, "commands") and words[0] in command.commands:
            command = command.commands[words.pop(0)]
        known = {opt for p in command.params for opt in (*p.opts, *p.secondary_opts)}
        for word in words:
            flag = word.strip("[]").split("=")[0]
            if flag.startswith("--"):
                assert flag in known, f"README: `{span}`: {command.name} has no {flag}"
    assert "--set noise_filter=none` turns it off for `track`" not in readme
    assert "What was and was not tested" not in readme
    # the exit codes README promises are the ones the commands give (test_doctor: doctor exits 1)
    assert "exits with\ncode 2; `doctor` and `devices` are reports, and exit 1" in readme
    assert "What was and was not tested on hardware" in (ROOT / "tests/README.md").read_text()


def test_troubleshooting_lists_the_messages_the_driver_prints(tmp_path):
    from neurotouch_hid.service.udev import uinput_problem
    from neurotouch_hid.sources.discovery import explain, merge

    text = (ROOT / "docs/troubleshooting.md").read_text()
    missing = uinput_problem(str(tmp_path / "uinput")).replace(str(tmp_path / "uinput"), "/dev/uinput")
    assert f"`{missing}`" in text
    plain = tmp_path / "plain"
    plain.write_text("")
    assert uinput_problem(str(plain)).replace(str(plain), "/dev/uinput") in text
    assert explain(merge([], [])).split(":")[0] in text
    for message in ("has no mapping", "is a shipped profile: it cannot be deleted", "not saved:", "(stalled)"):
        assert message in text
    assert (ROOT / "docs/getting-started.md").is_file()


def test_pip_fixes_name_this_installation_python_not_the_distribution_one():
    from neurotouch_hid.service import doctor

    fix = doctor.check_library("neurotouch_no_such_module", "no-such-dist").fix
    assert fix == f"{sys.executable} -m pip install --upgrade no-such-dist"  # python3 -m pip: PEP 668


def test_profile_test_names_outputs_as_the_profile_writes_them(cli, tmp_path):
    """A switch user's profile says ``space``; profile test said only ``KEY_SPACE``."""
    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType

    assert cli("new", "sw", "--from", "accessibility").returncode == 0
    assert cli("set", "sw", "mappings.confirm.output", "space").returncode == 0
    preds = tmp_path / "p.jsonl"
    write_predictions(preds, [GestureEstimate(t_us=10_000 * i, gesture=GestureType.NONE) for i in range(5)])
    done = cli("test", "sw", "--source", str(preds))
    assert done.returncode == 0, done.stderr
    assert "space (KEY_SPACE)" in done.stdout and "B (BTN_EAST)" in done.stdout, done.stdout
