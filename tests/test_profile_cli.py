"""The ``neurotouch-hid profile`` commands, run as a user would (subprocess, XDG_CONFIG_HOME in tmp)."""

from __future__ import annotations

import json
import re
import subprocess
import textwrap

import pytest
from helpers import run_cli
from ruamel.yaml import YAML

from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.mapping.profile import shipped_profiles_dir


@pytest.fixture()
def pushes(tmp_path):
    """A hand-written predictions file: rest, a 3 mm push up for 1 s, rest."""
    path = tmp_path / "pushes.jsonl"
    lines = []
    for i in range(300):
        t = i * 10_000
        pushing = 50 <= i < 150
        e = GestureEstimate(
            t_us=t,
            gesture=GestureType.PUSH if pushing else GestureType.NONE,
            resting=not pushing,
            intensity_mm=3.0 if pushing else 0.0,
            translation_mm=[0.0, 1.2] if pushing else [0.0, 0.0],
        )
        lines.append(json.dumps(e.to_json_dict()))
    path.write_text("\n".join(lines) + "\n")
    return path


def summary(result: subprocess.CompletedProcess) -> dict:
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_new_set_and_test_show_the_effect(cli, pushes):
    assert cli("new", "mine", "--from", "default").returncode == 0
    mine = cli.user_dir / "mine.yaml"
    assert mine.is_file()
    assert cli("path", "mine").stdout.strip() == str(mine)

    before = summary(cli("test", "mine", "--source", str(pushes), "--json"))
    assert before["max_deflection"]["ABS_Y"] > 0.05  # the 3 mm push moves the left stick up
    assert before["max_deflection"]["ABS_RY"] == 0

    result = cli("set", "mine", "mappings.push.output", "right_stick")
    assert result.returncode == 0, result.stderr
    moved = summary(cli("test", "mine", "--source", str(pushes), "--json"))
    assert (
        moved["max_deflection"]["ABS_Y"] == 0 and moved["max_deflection"]["ABS_RY"] == before["max_deflection"]["ABS_Y"]
    )

    assert cli("set", "mine", "mappings.push.deadzone_mm", "3.5").returncode == 0
    dead = summary(cli("test", "mine", "--source", str(pushes), "--json"))
    assert dead["max_deflection"]["ABS_RY"] == 0  # now inside the dead zone

    assert cli("set", "mine", "mappings.push.saturation_mm", "4.0").returncode == 0
    assert cli("unset", "mine", "mappings.push.deadzone_mm").returncode == 0  # back to default's 0.8 mm
    full = summary(cli("test", "mine", "--source", str(pushes), "--json"))
    assert full["max_deflection"]["ABS_RY"] > before["max_deflection"]["ABS_Y"]

    text = mine.read_text()
    assert "# neurotouch-hid profile" in text and "# an 8 mm push gives full deflection" in text  # comments kept
    assert "0x045e" in text  # hex kept
    assert YAML().load(text)["mappings"]["push"]["deadzone_mm"] == 0.8  # the shipped value, not the schema's


def test_set_on_a_shipped_profile_writes_a_user_copy(cli):
    shipped = (shipped_profiles_dir() / "spacecraft.yaml").read_text()
    result = cli("set", "spacecraft", "mappings.roll.gain", "1.5")
    assert result.returncode == 0, result.stderr
    assert (shipped_profiles_dir() / "spacecraft.yaml").read_text() == shipped
    copy = cli.user_dir / "spacecraft.yaml"
    assert YAML().load(copy.read_text())["mappings"]["roll"]["gain"] == 1.5
    assert cli("path", "spacecraft").stdout.strip() == str(copy)
    listing = cli("list").stdout
    assert "user (shadows shipped)" in listing


@pytest.mark.parametrize(
    "key, value, words",
    [
        ("mappings.push.deadzone_mm", "lots", ["mappings.push.deadzone_mm", "found 'lots'", "number"]),
        ("mappings.push.deadzone_mm", "-1", ["found -1", "greater than or equal to 0"]),
        ("mappings.push.output", "ABS_FOO", ["found 'ABS_FOO'", "'left_stick'"]),
        ("mappings.push.wobble", "2", ["mappings.push.wobble", "unknown field"]),
        ("mappings.push.deadzone_mm.x", "2", ["is a value"]),
    ],
)
def test_a_bad_set_changes_nothing(cli, key, value, words):
    assert cli("new", "mine").returncode == 0
    mine = cli.user_dir / "mine.yaml"
    original = mine.read_text()
    result = cli("set", "mine", key, value)
    assert result.returncode == 2
    for w in words:
        assert w in result.stderr, result.stderr
    assert mine.read_text() == original
    assert sorted(p.name for p in cli.user_dir.iterdir()) == ["mine.yaml"]  # no temporary left


def test_a_bad_set_on_a_shipped_profile_creates_no_copy(cli):
    assert cli("set", "default", "mappings.push.exponent", "0").returncode == 2
    assert not (cli.user_dir / "default.yaml").exists()


def test_validate_reports_every_problem_with_file_and_line(cli, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        textwrap.dedent("""\
        device:
          vendor: -3
        mappings:
          push:
            input: push
            output: middle_stick
            gain: "2"
            colour: red
    """)
    )
    result = cli("validate", str(bad))
    assert result.returncode == 2
    err = " ".join(result.stderr.split())  # rich may wrap long lines
    for line, field in [
        (2, "device.vendor"),
        (6, "mappings.push.output"),
        (7, "mappings.push.gain"),
        (8, "mappings.push.colour"),
    ]:
        assert f"{bad}:{line}: {field}:" in err, err
    assert "4 problems" in err
    good = cli("validate", str(shipped_profiles_dir() / "default.yaml"))
    assert good.returncode == 0 and "ok" in good.stdout


def test_new_refuses_an_existing_or_bad_name(cli):
    assert cli("new", "mine").returncode == 0
    again = cli("new", "mine")
    assert again.returncode == 2 and "already exists" in again.stderr
    assert cli("new", "../escape").returncode == 2
    assert cli("new", "x", "--from", "nope").returncode == 2


def test_new_from_a_broken_profile_says_file_line_field_and_writes_nothing(cli, tmp_path):
    """A source that breaks the schema, or is not YAML, gets profile validate's report (file, line,
    field, what was found and expected) and no copy is made; a broken user profile by name too."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("mappings:\n  push:\n    input: push\n    output: left_stick\n    deadzone_mm: -2\n")
    says = cli("validate", str(bad))
    copied = cli("new", "mine", "--from", str(bad))
    assert copied.returncode == 2 and says.returncode == 2
    assert f"{bad}:5: mappings.push.deadzone_mm: found -2" in copied.stderr, copied.stderr
    assert copied.stderr.startswith(says.stderr.rstrip("\n")), (copied.stderr, says.stderr)  # the same report
    assert "nothing written" in copied.stderr and "Traceback" not in copied.stderr
    assert not (cli.user_dir / "mine.yaml").exists()
    tabs = tmp_path / "tabs.yaml"
    tabs.write_text("mappings:\n\tpush: {}\n")
    not_yaml = cli("new", "mine", "--from", str(tabs))
    assert not_yaml.returncode == 2 and f"{tabs}:2: not valid YAML" in not_yaml.stderr, not_yaml.stderr
    assert not (cli.user_dir / "mine.yaml").exists()
    cli.user_dir.mkdir(parents=True, exist_ok=True)  # the edits above locked it: made, empty
    (cli.user_dir / "broken.yaml").write_text(bad.read_text())  # written by hand, never validated
    by_name = cli("new", "mine", "--from", "broken")
    assert by_name.returncode == 2 and "broken.yaml:5: mappings.push.deadzone_mm" in by_name.stderr, by_name.stderr
    assert sorted(p.name for p in cli.user_dir.iterdir()) == ["broken.yaml"]


def test_edit_validates_and_reports_non_interactively(cli, tmp_path):
    fix = cli("edit", "default", editor="sed -i s/deadzone_mm:\\ 0.8/deadzone_mm:\\ 1.2/")
    assert fix.returncode == 0, fix.stderr
    copy = cli.user_dir / "default.yaml"
    assert "deadzone_mm: 1.2" in copy.read_text()
    broken = cli("edit", "default", editor="sed -i s/deadzone_mm:\\ 1.2/deadzone_mm:\\ -2/")
    assert broken.returncode == 2
    assert "not saved" in broken.stderr and "deadzone_mm" in broken.stderr
    assert "deadzone_mm: 1.2" in copy.read_text()  # the profile stays valid
    assert "deadzone_mm: -2" in (cli.user_dir / "default.yaml.rejected").read_text()  # the user's text is kept
    missing = cli("edit", "default", editor="no-such-editor-here")
    assert missing.returncode == 2 and "EDITOR" in missing.stderr


def test_an_edit_saved_as_latin_1_is_kept_for_the_user_not_deleted(cli, tmp_path):
    """An editor that saved the change with a Latin-1 'é' got "not a profile (not UTF-8 text)",
    and the edited file was deleted with the user's change in it: it is kept, byte for byte, in
    the .rejected file the message names, and the next edit says how to go on from it."""
    script = tmp_path / "latin1-editor"
    script.write_text(
        "#!/bin/sh\nsed -i 's/deadzone_mm: 0.8/deadzone_mm: 1.3/' \"$1\"\nprintf '# caf\\351\\n' >> \"$1\"\n"
    )
    script.chmod(0o755)
    result = cli("edit", "default", editor=str(script))
    assert result.returncode == 2, result.stderr
    rejected = cli.user_dir / "default.yaml.rejected"
    assert "not UTF-8" in result.stderr and str(rejected) in " ".join(result.stderr.split()), result.stderr
    kept = rejected.read_bytes()
    assert b"deadzone_mm: 1.3" in kept and kept.endswith(b"# caf\xe9\n")
    assert not (cli.user_dir / "default.yaml").exists()
    again = cli("edit", "default", editor="true")
    assert again.returncode == 2 and str(rejected) in " ".join(again.stderr.split()), again.stderr
    assert "delete it" in again.stderr and rejected.read_bytes() == kept


def test_test_prints_a_timeline_and_plots(cli, pushes, tmp_path):
    png = tmp_path / "t.png"
    result = cli("test", "default", "--source", str(pushes), "--plot", str(png))
    assert result.returncode == 0, result.stderr
    assert "push" in result.stdout and "ABS_Y" in result.stdout and "summary" in result.stdout
    rows = [ln for ln in result.stdout.splitlines() if ln.strip().startswith("│") and ("none" in ln or "push" in ln)]
    assert len(rows) >= 20  # ~30 rows at 100 ms over 3 s
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_test_says_when_the_predictions_give_no_push_direction(cli, pushes, tmp_path):
    """Predictions written without the optional translation_mm (another tool's): the pushes have no
    direction, so the stick stays centred; the replay says why on stderr, the JSON stays whole."""
    bare = tmp_path / "bare.jsonl"
    lines = [json.loads(line) for line in pushes.read_text().splitlines()]
    bare.write_text("".join(json.dumps({k: v for k, v in d.items() if k != "translation_mm"}) + "\n" for d in lines))
    result = run_cli("profile", "test", "default", "--source", str(bare), "--json")
    assert summary(result)["max_deflection"]["ABS_Y"] == 0
    assert f"{bare}: 100 push windows give no translation_mm" in result.stderr
    assert "translation_mm" not in run_cli("profile", "test", "default", "--source", str(pushes), "--json").stderr


def test_tune_sets_saturation_from_what_the_user_reaches(cli, pushes):
    result = cli("tune", "default", "--from", str(pushes))
    assert result.returncode == 0, result.stderr
    assert "push: saturation_mm 8 -> 3" in result.stdout
    tuned = YAML().load((cli.user_dir / "default.yaml").read_text())
    assert tuned["mappings"]["push"]["saturation_mm"] == 3.0
    assert tuned["mappings"]["twist"]["saturation_mm"] == 6.0  # not exercised: unchanged
    after = summary(cli("test", "default", "--source", str(pushes), "--json"))
    assert after["max_deflection"]["ABS_Y"] == 1.0  # the weak push now reaches full travel


@pytest.mark.parametrize("source", ["sim", "davis", "nofile.aedat4"])
def test_tune_takes_only_the_users_own_recording_or_predictions(cli, source):
    """``profile tune mine --from sim`` wrote the simulated hand's reach into the user's profile
    (exit 0), and a missing file was answered about ``--source``, an option tune has not."""
    assert cli("new", "mine").returncode == 0
    before = (cli.user_dir / "mine.yaml").read_text()
    result = cli("tune", "mine", "--from", source)
    assert result.returncode == 2, result.stdout
    assert f"--from {source}" in result.stderr and "--source" not in result.stderr, result.stderr
    assert "recording" in result.stderr and "your own" in result.stderr, result.stderr
    assert (cli.user_dir / "mine.yaml").read_text() == before


def test_bad_predictions_file_names_its_line(cli, tmp_path):
    bad = tmp_path / "bad.jsonl"
    bad.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0}\n{"t_us": 1, "gesture": "wave"}\n'
    )
    result = cli("test", "default", "--source", str(bad))
    assert result.returncode == 2 and f"{bad}:2:" in " ".join(result.stderr.split())


def test_the_installed_command_runs_as_a_user_would(tmp_path, pushes):
    """The console script's module in a fresh process: copy, change, test."""

    def run(*args: str) -> subprocess.CompletedProcess:
        return run_cli("profile", *args, env={"XDG_CONFIG_HOME": str(tmp_path / "config")})

    assert run("new", "mine", "--from", "spacecraft").returncode == 0
    assert run("set", "mine", "mappings.push.output", "right_stick").returncode == 0
    result = run("test", "mine", "--source", str(pushes), "--json")
    assert result.returncode == 0, result.stderr
    moved = json.loads(result.stdout)["max_deflection"]
    assert moved["ABS_RY"] > 0 and moved["ABS_Y"] == 0
    bad = run("set", "mine", "mappings.push.gain", "-1")
    assert bad.returncode == 2 and "mappings.push.gain" in bad.stderr and "nothing was changed" in bad.stderr


# --- end to end: the simulated gel and a real AEDAT4 recording through the pipeline ---------------
def test_test_and_tune_on_a_recording(cli, sim_gel_short_recording):
    # a profile made for much stronger fingers than this (simulated) user's
    assert cli("set", "default", "mappings.push.saturation_mm", "40").returncode == 0
    before = summary(cli("test", "default", "--source", str(sim_gel_short_recording), "--json"))
    assert before["estimates"] >= 100  # 10 ms windows over ~1.5 s
    stick = max(before["max_deflection"]["ABS_X"], before["max_deflection"]["ABS_Y"])
    assert 0 < stick < 0.5  # the push moves the left stick, but only a little
    tuned = cli("tune", "default", "--from", str(sim_gel_short_recording))
    assert tuned.returncode == 0, tuned.stderr
    new = float(re.search(r"push: saturation_mm 40 -> ([0-9.]+)", tuned.stdout).group(1))
    assert 0.8 < new < 40
    assert YAML().load((cli.user_dir / "default.yaml").read_text())["mappings"]["push"]["saturation_mm"] == new
    after = summary(cli("test", "default", "--source", str(sim_gel_short_recording), "--json"))
    # about full travel now (a stick axis sees the push's projection, slightly off-axis, smoothed)
    assert max(after["max_deflection"]["ABS_X"], after["max_deflection"]["ABS_Y"]) > max(0.8, 3 * stick)


def test_test_on_the_simulated_gel(cli):
    result = summary(cli("test", "spacecraft", "--source", "sim", "--seconds", "1.5", "--json"))
    assert result["estimates"] >= 100


def test_list_and_show(cli):
    assert cli("new", "mine").returncode == 0
    (cli.user_dir / "broken.yaml").write_text("mappings: [\n")
    listing = cli("list")
    assert listing.returncode == 0
    rows = {ln.split("│")[1].strip(): ln for ln in listing.stdout.splitlines() if ln.count("│") >= 4}
    assert {"default", "spacecraft", "accessibility", "mine", "broken"} <= set(rows)
    assert "shipped" in rows["default"] and "user" in rows["mine"] and "invalid" in rows["broken"]
    shown = cli("show", "spacecraft")
    assert shown.returncode == 0
    assert str(shipped_profiles_dir() / "spacecraft.yaml") in shown.stderr  # stdout is the file itself
    assert "# pitch (y: push up = nose down" in shown.stdout  # the file, comments included
