"""Two hostile inputs probed in a REAL Linux kernel (Debian's, booted under qemu by
tests/kernel/vm.py; the guest checks are tests/kernel/checks_hostile.py): a hidraw reader
flooding the UHID joystick, and hiding a merged interface of a USB device that also has a
keyboard. Skips, with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import json

import pytest
from conftest import passed

pytestmark = pytest.mark.kernel

FLOOD = "checks_hostile.check_a_flooding_hidraw_reader_costs_the_driver_a_bounded_share"
HIDE = "checks_hostile.check_hiding_a_merged_interface_leaves_the_same_usb_devices_keyboard"


def test_a_hidraw_reader_flooding_the_uhid_joystick_costs_the_driver_a_bounded_share_and_no_window(guest):
    """Output reports written as fast as another process can: the driver handles them within its
    bounds (events a second, a share of a core), so the flood costs it a bounded share of a core on
    top of the run's own, and the run drops no window. With the bounds lifted in the same run (what
    it did before them) the same flood costs it more than that. In the emulated kernel an event
    cost ~0.6 ms: with the events' bound alone (1000 a second) the flood took +0.64 of a core,
    which fails here; with the share's too, +0.29 (the boots of 2026-11-29, load 5-11)."""
    details = passed(guest, FLOOD)
    said = json.dumps(details)
    quiet, flood, unbounded = details["quiet"], details["flood"], details["flood_unbounded"]
    assert flood["writes"] > 1000 and unbounded["writes"] > 1000, said  # a flood, each time
    assert flood["dropped_items"] == 0 and flood["windows"] >= 0.8 * quiet["windows"], said
    assert flood["share"] - quiet["share"] <= 0.4, said
    assert unbounded["share"] > flood["share"], said  # the bounds are what held the cost back


def test_hiding_a_merged_joystick_interface_leaves_the_same_usb_devices_keyboard(guest):
    """A USB device with a joystick and a keyboard interface (the hid gadget with its keyboard,
    on dummy_hcd): merging the joystick hides its event node, its joystick node and its own
    HID device's hidraw; the keyboard's hidraw and event node stay where games and the desktop
    read them. What hiding took before (every interface's hidraw of the USB device) includes the
    keyboard's: the probe tells the two apart."""
    details = passed(guest, HIDE)
    said = json.dumps(details)
    joystick, keyboard = details["joystick_hidraw"], details["keyboard_hidraw"]
    assert len(joystick) == 1 and len(keyboard) == 1 and joystick != keyboard, said
    event, js = details["nodes"]["joystick"].rsplit("/", 1)[1], [n for n in details["hidden"] if "/js" in n]
    assert sorted(details["hidden"]) == sorted([f"input/{event}", *js, *joystick]) and js, said
    assert set(keyboard) <= set(details["every_interfaces_hidraw"]), said  # before: the keyboard's went too
    kept = details["in_dev_while_hidden"]
    assert kept[keyboard[0]] and kept[f"input/{details['nodes']['keyboard'].rsplit('/', 1)[1]}"], said
    assert not kept[joystick[0]], said
    assert sorted(details["put_back"]) == sorted(details["hidden"]) and all(details["in_dev_after"].values()), said
