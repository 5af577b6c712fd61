"""The copilot in a REAL Linux kernel (Debian's, booted under qemu by tests/kernel/vm.py): a
helper's pad and a switch box (python-evdev UInput devices) merged into the gel's pad by
``neurotouch-hid run``; the guest check is tests/kernel/checks_copilot.py. Skips, with the
reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel

CHECK = "checks_copilot.check_copilot_merges_grabs_rejoins_and_rumbles"


def test_the_mouse_profile_makes_no_joystick_node_and_profile_use_default_makes_one(guest):
    details = passed(guest, CHECK)
    assert details["pads_with_mouse_profile"] == []
    assert details["use_default"].startswith("switched to profile default")
    assert details["pads"] == 1 and details["ID_INPUT_JOYSTICK"] == "1"


def test_the_helpers_buttons_and_stick_arrive_on_the_one_pad_by_the_axis_policies(guest):
    details = passed(guest, CHECK)
    gel = details["gel_alone"]
    assert gel["ABS_X"] > 30000 and gel["buttons"] == []
    # ABS_X "further": the helper's -20000 loses to the gel's push, its -32768 wins; ABS_Y "sum"
    assert details["helper_small"]["ABS_X"] == gel["ABS_X"]
    assert details["helper_small"]["ABS_Y"] == gel["ABS_Y"] + 8000
    assert details["helper_full"]["ABS_X"] == -32768 and details["helper_full"]["buttons"] == ["BTN_SOUTH"]
    assert details["sdl_held"]["a"] and details["sdl_held"]["leftx"] <= -32767


def test_a_grabbed_helper_reaches_no_other_reader_until_the_run_ends_neutral(guest):
    details = passed(guest, CHECK)
    assert details["helper_reader_while_grabbed"] == 0 and details["helper_reader_while_grabbed_again"] == 0
    assert details["helper_reader_after_stop"]
    assert details["windows"] > 0 and details["pad_last"] == {"ABS_X": 0, "ABS_Y": 0, "buttons": []}


def test_an_unplugged_helper_lets_go_at_once_and_a_new_one_of_the_same_name_rejoins(guest):
    details = passed(guest, CHECK)
    gel = details["gel_alone"]
    assert details["after_unplug"] == {"ABS_X": gel["ABS_X"], "ABS_Y": gel["ABS_Y"], "buttons": []}
    assert details["rejoined"]["buttons"] == ["BTN_NORTH"]


def test_a_profile_without_the_copilot_releases_the_grab_and_switching_back_grabs_it_again(guest):
    details = passed(guest, CHECK)
    assert details["use_plain"].startswith("switched to profile default")
    assert details["helper_reader_after_switch"] >= 2
    assert details["merged_again"]["buttons"] == ["BTN_NORTH"]


def test_the_copilot_costs_nothing_at_rest(guest):
    details = passed(guest, CHECK)
    # no thread of its own: the merged devices, the pad's feedback, the control socket and the games
    # watcher wait on the run's one loop, in its main thread
    run_threads = {name for name in details["threads"] if name.startswith("nt-")}
    assert run_threads <= {"nt-source", "nt-pipeline", "nt-resting"}, details["threads"]
    assert sum("merged Helper Pad" in line for line in details["said"]) == 3  # at start, rejoined, switched back


def test_an_sdl_rumble_on_the_pad_is_played_on_the_helpers_device(guest):
    details = passed(guest, CHECK)
    assert details["sdl_rumble"]["rumble"]
    assert any(entry[0] == "upload" for entry in details["helper_ff"])
    assert any(entry[0] == "play" and entry[2] > 0 for entry in details["helper_ff"])


def test_merged_as_root_the_helpers_nodes_are_hidden_so_a_game_started_then_lists_one_pad(guest):
    details = passed(guest, CHECK)
    hidden = details["hidden"]
    # the helper pad's event and joystick nodes and the switch box's event node left /dev/input
    assert sum(n.startswith("input/event") for n in hidden) == 2 and sum(n.startswith("input/js") for n in hidden) == 1
    assert not details["helper_node_in_dev_while_merged"] and not details["helper_node_in_dev_after_udev_change"]
    assert details["late_sdl"]["count"] == 1 and len(details["late_sdl"]["guids"]) == 1
    assert details["late_sdl"]["guids"][0][16:20] == "8e02"  # the gel's pad (product 028e)
    # released by a profile switch, and by SIGTERM: back in /dev/input, readable, nothing left hidden
    assert details["helper_node_in_dev_after_switch"]
    assert details["hidden_after_stop"] == [] and details["helper_node_readable_after_stop"]
    assert details["box_node_as_before"]  # the switch box's node: the same number, mode, owner and ACL


def test_a_driver_killed_while_it_hides_the_helpers_pad_leaves_the_pad_listed_and_readable(guest):
    details = passed(guest, "checks_copilot.check_a_killed_driver_leaves_no_device_hidden")
    assert details["hid"].startswith("['input/event") and not details["in_dev_while_hidden"]
    assert details["guard_ready"]  # its put-back prepared before the kill
    assert details["in_dev_after_kill"] and details["node_as_before"] and not details["left_hidden"]
    assert details["reader_after_kill"] == [["BTN_SOUTH", 1], ["BTN_SOUTH", 0]]
    said = "the driver died with merged devices hidden; put back /dev/input/event"
    assert details["said"] and said in details["said"][0]
