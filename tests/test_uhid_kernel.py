"""``neurotouch-hid run --output hid`` in a REAL Linux kernel (Debian's, booted under qemu once per
session by tests/kernel/vm.py): the UHID joystick read as a host reads it, through sysfs, hidapi
on hidraw, evdev and SDL; the guest check is tests/kernel/checks_uhid.py. Skips, with the reason,
only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
from neurotouch_hid.targets.uhid import HID_DEFAULT

pytestmark = pytest.mark.kernel


@pytest.fixture(scope="module")
def details(guest):
    return passed(guest, "checks_uhid.check_run_output_hid")


def test_uhid_loads_and_hid_generic_binds_the_joystick(details):
    assert details["modprobe"]["uhid"]
    assert details["driver"] == "hid-generic"
    assert details["hid_device"].startswith(f"0003:{HID_DEFAULT.vendor:04X}:{HID_DEFAULT.product:04X}.")


def test_hidapi_opens_it_by_its_ids_and_reads_the_documented_descriptor_and_reports(details):
    assert details["hidapi"]["path"].startswith("/dev/hidraw")
    assert (details["hidapi"]["usage_page"], details["hidapi"]["usage"]) == (0x01, 0x04)  # a Joystick
    assert details["descriptor_bytes"] == len(HID_JOYSTICK.descriptor)
    held = bytes.fromhex(details["held_report"])
    assert int.from_bytes(held[0:2], "little", signed=True) > 0 and held[11] & 1  # pushed right, A
    assert details["reports"] >= 2  # the push and the neutral report after SIGTERM (at least)


def test_evdev_and_sdl_read_the_push_to_the_right(details):
    assert details["ID_INPUT_JOYSTICK"] == "1"
    assert details["evdev_abs_x_max"] == 32767
    opened = details["sdl_opened"]
    assert opened["axes"] == 6 and opened["hats"] == 1 and opened["buttons"] == 16
    assert details["sdl_held_axes"][0] > 0.99
