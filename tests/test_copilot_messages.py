"""What the user is told about the copilot's devices: which are plugged in and which waited for
(presence, doctor, the live view, ``devices --json``, ``profile show``), and the note on hiding
them."""

from __future__ import annotations

import os

from copilot_helpers import HELPER, SHORT_FORM

from neurotouch_hid.inputs.match import InputInfo
from neurotouch_hid.mapping.profile import load_profile, parse_profile


# --- what the user is told ------------------------------------------------------------------------
def test_presence_names_what_is_plugged_in_and_what_is_waited_for():
    from neurotouch_hid.inputs.match import presence, presence_line

    box = InputInfo("/dev/input/event8", "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    assert presence_line(["Helper Pad", "Switch Box", "045e:028e"], [HELPER]) == (
        "present: Helper Pad (/dev/input/event7); missing: Switch Box, 045e:028e"
    )
    # one device is taken by the first rule naming it, as the running driver takes it
    assert presence(["045e:02ea", "Helper Pad", "Switch Box"], [HELPER, box]) == [
        ("045e:02ea", HELPER),
        ("Helper Pad", None),
        ("Switch Box", box),
    ]


def test_doctor_says_which_copilot_devices_are_there_and_which_are_waited_for(tmp_path, monkeypatch):
    from neurotouch_hid.service.doctor import FAIL, OK, SKIP, WARN, check_copilot

    node = tmp_path / "event7"
    node.write_text("")
    helper = InputInfo(str(node), "Helper Pad", "usb-2/input0", 0x045E, 0x02EA)
    profile = parse_profile(SHORT_FORM, "p.yaml")
    waiting = check_copilot({"mine": profile}, [helper], hiding=True)
    assert waiting.status == WARN
    assert waiting.detail.startswith(f"mine: Helper Pad at {node}, Switch Box missing")
    box = InputInfo(str(node), "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    assert check_copilot({"mine": profile}, [helper, box], hiding=True).status == OK
    # not root: grabbed but not hidden, so a game may list the helper's pad; how to avoid it
    unhidden = check_copilot({"mine": profile}, [helper, box], hiding=False)
    assert unhidden.status == WARN and "SDL_GAMECONTROLLER_IGNORE_DEVICES=0x045e/0x02ea" in unhidden.fix
    closed = InputInfo("/nonexistent/event9", "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    denied = check_copilot({"mine": profile}, [helper, closed])
    assert denied.status == FAIL and "sudo usermod -aG input $USER" in denied.fix
    assert "not readable by this user" in denied.detail
    import neurotouch_hid.service.doctor as doctor

    readable = InputInfo(str(node), "Switch Box", "usb-3/input0", 0x1234, 0x5678)
    # a node this user may read but not write (root may write anything: the test says which)
    monkeypatch.setattr(doctor.os, "access", lambda path, mode: mode == os.R_OK)
    read_only = check_copilot({"mine": profile}, [helper, readable], hiding=True)
    monkeypatch.undo()
    assert read_only.status == WARN and "merged, but a game's rumble is not played on them" in read_only.detail
    assert check_copilot({"default": load_profile("default")}, []).status == SKIP


def test_the_live_view_says_what_is_merged_and_what_is_missing():
    from neurotouch_hid.views.live import copilot_line

    assert copilot_line(("Helper Pad",), ("Switch Box",)).plain == "merged: Helper Pad; missing: Switch Box"
    assert copilot_line((), ()).plain == "merged: none; missing: none"


def test_devices_json_lists_the_input_devices_a_copilot_can_merge():
    import json

    from helpers import run_cli

    from neurotouch_hid.inputs.match import mergeable_devices, to_json

    data = json.loads(run_cli("devices", "--json").stdout)
    assert data["inputs"] == [to_json(info) for info in mergeable_devices()]
    assert to_json(HELPER) == {
        "node": "/dev/input/event7",
        "name": "Helper Pad",
        "ids": "045e:02ea",
        "phys": "usb-0000:00:14.0-2/input0",
        "links": ["/dev/input/by-id/usb-Helper-event-joystick"],
    }


def test_profile_show_says_which_copilot_devices_are_plugged_in(cli, tmp_path):
    path = tmp_path / "helped.yaml"
    path.write_text(SHORT_FORM)
    done = cli("show", str(path))
    assert done.returncode == 0, done.stderr
    assert done.stdout == SHORT_FORM  # a pipe gets the file's exact bytes
    assert "# copilot: present: none; missing: Helper Pad, Switch Box" in done.stderr


def test_the_unhidden_note_says_needs_root_only_to_a_user_who_is_not(monkeypatch):
    """As root, doctor said hiding merged devices 'needs root': where root cannot hide them,
    /dev/input is what is not writable."""
    import os

    from neurotouch_hid.inputs.copilot import unhidden_note

    monkeypatch.setattr(os, "geteuid", lambda: 0)
    as_root = unhidden_note()
    assert "needs root" not in as_root and "/dev/input is not writable here" in as_root
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    assert "(that needs root)" in unhidden_note() and "run the driver as root" in unhidden_note()
