"""Two sensors on one machine in a REAL Linux kernel (Debian's, booted under qemu once per session
by tests/kernel/vm.py): two drivers, one per camera serial, run at once; their pads carry
distinct identities from the serials, each is driven by its own gel, the camera with a config
folder of its own gets its own profile, `devices` lists both drivers, and stopping one leaves the
other running. The guest check is tests/kernel/checks_sensors.py (what stands in for each camera
is said there). Skips, with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel

CHECK = "checks_sensors.check_two_sensors_two_pads_each_its_own"
BTN_SOUTH, ABS_X, ABS_Y = 304, 0, 1


def test_two_serials_give_two_pads_with_distinct_identities_and_their_own_config(guest):
    details = passed(guest, CHECK)
    left, right = details["LEFT1"], details["RIGHT1"]
    assert left["phys"] == "neurotouch-hid/LEFT1" and right["phys"] == "neurotouch-hid/RIGHT1"
    assert left["path"] != right["path"]
    assert left["name"] == "NeuroTouch LEFT1"  # sensors/LEFT1/profile.yaml
    assert right["name"] == "Microsoft X-Box 360 pad"  # no folder: the shared default
    assert left["ids"] == right["ids"] == [0x045E, 0x028E]  # the same model, told apart by phys


def test_each_pad_is_driven_by_its_own_gel_only(guest):
    details = passed(guest, CHECK)
    assert details["left_axes"] == {}  # LEFT1's own profile presses A and moves no stick
    assert BTN_SOUTH not in details["right_pressed_ever"]  # RIGHT1's push moves its stick only


def test_devices_lists_a_driver_for_each_serial(guest):
    details = passed(guest, CHECK)
    drivers = {row["serial"]: row for row in details["devices"]["drivers"]}
    assert set(drivers) == {"LEFT1", "RIGHT1"}, details["devices"]
    for serial in ("LEFT1", "RIGHT1"):
        assert drivers[serial]["driver"]["pid"] == details["pids"][serial]
        assert drivers[serial]["camera"] is None  # no camera on the guest's bus: not on the bus
    assert drivers["LEFT1"]["config"] == ["profile.yaml"] and drivers["RIGHT1"]["config"] == []
    assert drivers["LEFT1"]["driver"]["status"].startswith("profile ")


def test_stopping_one_driver_leaves_the_other_running(guest):
    details = passed(guest, CHECK)
    assert details["left_result"]["ok"] and details["left_result"]["exit"] == 0, details["left_result"]
    assert details["left_gone"] and details["left_pressed_at_end"] == []
    assert details["right_alive_after_left_stopped"]
    assert details["right_events_after_left_stopped"] > 20
    assert details["right_result"]["ok"] and details["right_result"]["exit"] == 0, details["right_result"]
    assert details["right_gone"] and details["right_axes_at_end"] == {}


UNITS = "checks_sensor_units.check_a_camera_with_its_own_folder_starts_its_own_instance"


def test_a_camera_with_its_own_folder_starts_its_own_instance_not_the_single_unit(guest):
    seen = passed(guest, UNITS)
    assert seen["link"], seen  # /dev/neurotouch-00000001 -> the camera's node
    assert "neurotouch-hid@00000001.service" in seen["wants"].split() and "neurotouch-hid.service" in seen["wants"]
    assert seen["device"] and seen["instance_started"], seen
    assert "--serial 00000001" in seen["instance_exec"], seen
    assert seen["single"]["invocation"] == "", seen  # it stepped aside: ConditionPathExists=!
    assert seen["instance_stopped"] and seen["link_gone"], seen
