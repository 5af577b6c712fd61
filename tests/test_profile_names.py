"""The names the live view and the docs show (A, LB, RT, Start, "SPACE key", "d-pad up") are the
names a profile takes, and a mistyped name gets a suggestion that makes sense."""

from __future__ import annotations

import pytest
from ruamel.yaml import YAML

from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.mapping.profile import (
    AxisMapping,
    ButtonMapping,
    StickMapping,
    parse_profile,
)
from neurotouch_hid.views.live import mapping_lines
from neurotouch_hid.views.term import BUTTON_LABELS, PAD_NAMES, pad_name


def one(output: str, input: str = "pinch"):
    return parse_profile(f"mappings:\n  m:\n    input: {input}\n    output: {output}\n", "q.yaml").mappings["m"]


@pytest.mark.parametrize("code, shown", sorted(PAD_NAMES.items()))
def test_every_name_the_view_shows_is_taken_and_shown_back(code, shown):
    """Each pad, mouse and d-pad name of the view, as a profile's output, drives the output the
    view gives that name, and the view shows it back as written."""
    vector = code in ("left_stick", "right_stick", "pointer")
    mapping = one(f"'{shown}'", "push" if vector else "pinch")
    expected = {"A": "BTN_SOUTH", "B": "BTN_EAST", "X": "BTN_NORTH", "Y": "BTN_WEST"}.get(shown, code)
    assert mapping.output == expected
    given = "push" if vector else "pinch"
    profile = parse_profile(f"mappings:\n  {given}:\n    input: {given}\n    output: '{shown}'\n", "q.yaml")
    assert mapping_lines(profile) == [(given, shown)]


@pytest.mark.parametrize(
    "written, kind, output, shown",
    [
        ("LB", ButtonMapping, "BTN_TL", "LB"),
        ("RT", AxisMapping, "ABS_RZ", "RT"),
        ("right_trigger", AxisMapping, "ABS_RZ", "RT"),
        ("left_trigger", AxisMapping, "ABS_Z", "LT"),
        ("start", ButtonMapping, "BTN_START", "Start"),
        ("SPACE", ButtonMapping, "KEY_SPACE", "SPACE key"),
        ("space", ButtonMapping, "KEY_SPACE", "SPACE key"),
        ("SPACE key", ButtonMapping, "KEY_SPACE", "SPACE key"),
        ("LEFTSHIFT+TAB key", ButtonMapping, "KEY_LEFTSHIFT+KEY_TAB", "LEFTSHIFT+TAB key"),
        ("Shift+Tab", ButtonMapping, "KEY_LEFTSHIFT+KEY_TAB", "LEFTSHIFT+TAB key"),
        ("L stick", StickMapping, "left_stick", "L stick"),
    ],
)
def test_names_as_written_by_players(written, kind, output, shown):
    mapping = one(f"'{written}'", "push" if kind is StickMapping else "zoom")
    assert isinstance(mapping, kind) and mapping.output == output
    assert pad_name(mapping.output) == shown


def test_the_view_labels_are_the_ones_accepted():
    assert set(BUTTON_LABELS.values()) >= {"A", "LB", "Start", "Back", "Guide"}


@pytest.mark.parametrize(
    "written, field, suggestion, not_suggested",
    [
        ("right_triger", "output", "did you mean 'right_trigger'?", "right_stick"),
        ("KEY_SPCE", "output", "did you mean 'KEY_SPACE'?", None),
        ("SPCE", "output", "did you mean 'SPACE'?", None),
        ("Strat", "output", "did you mean 'Start'?", None),
    ],
)
def test_a_mistyped_output_gets_a_suggestion_that_makes_sense(written, field, suggestion, not_suggested):
    with pytest.raises(ProfileError) as err:
        one(written)
    message = str(err.value)
    assert f"mappings.m.{field}: found '{written}'" in message and suggestion in message, message
    if not_suggested:
        assert f"did you mean '{not_suggested}'" not in message


def test_a_mistyped_input_gets_a_suggestion():
    with pytest.raises(ProfileError) as err:
        one("RT", "twirl")
    assert "q.yaml:3: mappings.m.input: found 'twirl'" in str(err.value)
    assert "did you mean 'twist'?" in str(err.value)


def test_turning_an_axis_into_a_button_says_the_one_line_fix(cli):
    """``profile set default mappings.zoom.output A``: the trigger's dead zone and curve are no
    button's fields; nothing changes, and the one command printed makes the change."""
    result = cli("set", "default", "mappings.zoom.output", "A")
    assert result.returncode == 2
    assert "a button output takes no deadzone_mm" in result.stderr, result.stderr
    assert not (cli.user_dir / "default.yaml").exists()
    line = next(ln.strip() for ln in result.stderr.splitlines() if ln.strip().startswith("neurotouch-hid profile set"))
    args = line.split(" ", 5)[3:]  # profile set NAME KEY 'VALUE'
    done = cli("set", args[0], args[1], args[2].strip("'"))
    assert done.returncode == 0, done.stderr
    zoom = YAML().load((cli.user_dir / "default.yaml").read_text())["mappings"]["zoom"]
    assert zoom["output"] == "A" and zoom["input"] == "zoom" and "deadzone_mm" not in zoom


def test_the_one_line_fix_is_printed_only_when_it_would_work(cli):
    """A push made a button cannot work whatever its fields (a direction drives no button), and a
    mistyped key stays mistyped in the command printed: the fix printed was refused when run. Now
    the refusal says what is wrong with the change itself, and no command that fails is offered."""
    result = cli("set", "default", "mappings.push.output", "A")
    assert result.returncode == 2
    assert "mappings.push.input: found 'push'" in result.stderr, result.stderr
    assert "neurotouch-hid profile set default mappings.push '" not in result.stderr, result.stderr
    typo = cli("set", "default", "mappings.zoom.output", "KEY_SPCE")
    assert typo.returncode == 2
    assert "did you mean 'KEY_SPACE'?" in typo.stderr, typo.stderr
    assert "KEY_SPCE, " not in typo.stderr and "profile set default mappings.zoom '" not in typo.stderr, typo.stderr
    assert not (cli.user_dir / "default.yaml").exists()


@pytest.mark.parametrize("parts", [40, 400])
def test_a_key_deeper_than_any_profiles_is_one_line(cli, parts):
    """``profile set mine a.a.(x400).x 1`` ended in a RecursionError traceback, and a 40-part key
    was said to be "nested more than 32 levels" at a line the file does not have."""
    key = ".".join(["a"] * parts)
    result = cli("set", "default", key, "1")
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert f"{parts} parts; a profile's keys have at most 8" in result.stderr, result.stderr
    assert not (cli.user_dir / "default.yaml").exists()


def test_delete_and_reset_keep_a_backup_and_warn_about_games_pointing_at_the_profile(cli):
    """``profile delete`` and ``reset`` acted at once, with no backup and no word about the games
    mapped to the profile (``profile auto list`` showed them as fine)."""
    assert cli("new", "racing").returncode == 0
    mine = cli.user_dir / "racing.yaml"
    text = mine.read_text()
    assert cli("auto", "add", "4242", "racing").returncode == 0
    assert cli("auto", "add", "supertuxkart", "default").returncode == 0
    deleted = cli("delete", "racing")
    assert deleted.returncode == 0, deleted.stderr
    backup = cli.user_dir / "racing.yaml.bak"
    assert not mine.exists() and backup.read_text() == text and f"kept as {backup}" in deleted.stdout
    assert "Steam app 4242 -> racing, which no longer exists" in deleted.stderr
    assert "profile auto remove 4242" in deleted.stderr
    assert "racing" not in cli("list").stdout  # the backup is no profile
    listed = cli("auto", "list")
    assert "Steam app 4242 -> racing  NO SUCH PROFILE" in listed.stdout
    assert "supertuxkart -> default\n" in listed.stdout
    assert cli("set", "default", "mappings.push.deadzone_mm", "1.0").returncode == 0
    copy = (cli.user_dir / "default.yaml").read_text()
    reset = cli("reset", "default")
    assert reset.returncode == 0 and (cli.user_dir / "default.yaml.bak").read_text() == copy
    assert "supertuxkart -> default: that game now gets the shipped 'default'" in reset.stderr


@pytest.mark.parametrize(
    "text, line",
    [
        ("mappings:\n  m:\n    input pinch\n    output: KEY_A\n", 3),  # the mapping's first key
        ("mappings\n  m:\n    input: pinch\n    output: KEY_A\n", 1),
        ("mappings:\n  m:\n    # the trigger\n    input pinch\n\n    output: KEY_A\n", 4),
        ("mappings:\n  m:\n    input: pinch\n    output KEY_A\n    mode: hold\n", 4),  # already right
    ],
)
def test_a_key_without_its_colon_is_reported_on_its_own_line(text, line):
    with pytest.raises(ProfileError) as err:
        parse_profile(text, "q.yaml")
    assert str(err.value).startswith(f"q.yaml:{line}: not valid YAML: could not find expected ':'"), str(err.value)


def test_ctrl_alt_delete_is_refused_in_a_sentence_not_a_dict():
    text = (
        "mappings:\n  a: {input: pinch, output: KEY_LEFTCTRL}\n  b: {input: zoom, output: KEY_LEFTALT}\n"
        "  c: {input: push_intensity, output: KEY_DELETE}\n"
    )
    with pytest.raises(ProfileError) as err:
        parse_profile(text, "q.yaml")
    problem = str(err.value).splitlines()[1].strip()
    assert problem == (
        "q.yaml:1: This profile could hold Ctrl, Alt and Delete at once (it presses KEY_DELETE, KEY_LEFTALT, "
        "KEY_LEFTCTRL), and the console reboots the machine on Ctrl+Alt+Delete: map one of them to another key"
    )
    assert "{" not in problem
