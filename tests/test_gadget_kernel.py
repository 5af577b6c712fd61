"""``neurotouch-hid run --output usb`` in a REAL Linux kernel (Debian's, booted under qemu by
tests/kernel/vm.py): the USB gadget on dummy_hcd's controller, read on the same kernel's host side
as a host reads it (hid-generic and hidapi, xpad, evdev, SDL); the guest checks are
tests/kernel/checks_gadget.py. Skips, with the reason, only where qemu cannot be installed at all."""

from __future__ import annotations

import pytest
from conftest import passed

from neurotouch_hid.targets.protocols import PROTOCOLS
from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
from neurotouch_hid.targets.reports.switch import SWITCH

HID_IDS = (PROTOCOLS["hid"].vendor, PROTOCOLS["hid"].product)
pytestmark = pytest.mark.kernel


def test_hid_gadget_is_bound_by_hid_generic_and_read_by_hidapi(guest):
    details = passed(guest, "checks_gadget.check_usb_hid")
    assert all(details["modprobe"][m] for m in ("dummy_hcd", "libcomposite", "usb_f_hid", "usb_f_fs"))
    assert details["driver"] == "hid-generic"
    assert details["hid_device"].startswith(f"0003:{HID_IDS[0]:04X}:{HID_IDS[1]:04X}.")
    assert (details["hidapi"]["usage_page"], details["hidapi"]["usage"]) == (0x01, 0x04)  # a Joystick
    assert details["descriptor_bytes"] == len(HID_JOYSTICK.descriptor)
    held = bytes.fromhex(details["held_report"])
    assert int.from_bytes(held[0:2], "little", signed=True) > 0 and held[11] & 1  # pushed right, button 1


def test_hid_gadget_reaches_sdl_survives_a_replug_and_ends_neutral(guest):
    details = passed(guest, "checks_gadget.check_usb_hid")
    opened = details["sdl_opened"]
    assert opened["axes"] == 6 and opened["hats"] == 1 and opened["buttons"] == 16
    assert details["sdl_held_axes"][0] > 0.99
    assert details["last_report"] == HID_JOYSTICK.neutral().hex()


def test_switch_gadget_report_decodes_field_by_field(guest):
    details = passed(guest, "checks_gadget.check_usb_switch")
    assert details["hid_device"].startswith(f"0003:{SWITCH.vendor:04X}:{SWITCH.product:04X}.")
    assert details["descriptor_bytes"] == len(SWITCH.descriptor)
    # docs/reports.md, "switch": B and ZR pressed, nothing else; hat right (2); left stick right
    assert details["decoded"] == {
        "B": True,
        "ZR": True,
        "others": 0,
        "hat": 2,
        "padding": 0,
        "LX": 255,
        "LY": 128,
        "RX": 128,
        "RY": 128,
        "vendor": 0,
    }
    assert details["last_report"] == SWITCH.neutral().hex()


def test_xinput_gadget_is_bound_by_xpad_read_by_sdl_and_hears_its_rumble(guest):
    details = passed(guest, "checks_gadget.check_usb_xinput")
    assert details["interface_class"] == ["ff", "5d", "01"]
    assert details["sdl_opened"]["controller_name"]
    assert details["sdl_held"]["leftx"] > 32000
    assert details["sdl_rumble"]["rumble"] is True
    assert details["rumble_lines"]


def test_an_xinput_run_on_gadgetfs_has_at_most_5_threads(guest):
    """The pad's events are answered on the run's loop (its main thread), not a thread of their
    own: the main thread, the source's, the pipeline's, the OUT endpoint's reader and the report
    writer (GadgetFS's endpoint files cannot be polled: inode.c has no poll for them)."""
    threads = passed(guest, "checks_gadget.check_usb_xinput")["threads"]
    assert len(threads) <= 5, threads
    assert not [name for name in threads if name.endswith(": events")], threads


def test_xinput_pad_on_gadgetfs_carries_the_wired_pads_0x21_descriptor(guest):
    """What Windows' XInput driver reads and FunctionFS cannot carry: the host read the 17-byte
    descriptor right after the FF/5D/01 interface, naming the endpoints it has (0x81, 0x02)."""
    from test_gadgetfs import WIRED_PAD, WIRED_PAD_DEVICE

    from neurotouch_hid.targets.gadget.gadgetfs import XINPUT_CLASS_DESCRIPTOR

    usb = passed(guest, "checks_gadget.check_usb_xinput")["usb"]
    read = bytes.fromhex(usb["raw_configuration"])  # byte for byte a wired pad's but for remote wake-up
    assert read[:7] + read[8:] == WIRED_PAD[:7] + WIRED_PAD[8:] and (read[7], WIRED_PAD[7]) == (0x80, 0xA0)
    device = bytes.fromhex(usb["raw_device"])  # but for ep0's packet size, which GadgetFS sets to the UDC's
    assert device[:7] + device[8:] == WIRED_PAD_DEVICE[:7] + WIRED_PAD_DEVICE[8:]
    assert usb["interfaces"] == [["ff", "5d", "01"]]
    assert usb["class_descriptors"] == [XINPUT_CLASS_DESCRIPTOR.hex()]
    assert [e["address"] for e in usb["endpoints"]] == ["81", "02"]
    assert usb["configuration"]["bmAttributes"] == "80"  # a real pad's 0xA0 asks for remote wake-up: refused


def test_switch_access_profile_types_on_a_usb_keyboard(guest):
    details = passed(guest, "checks_gadget.check_usb_switch_access_keyboard")
    assert details["ID_INPUT_KEYBOARD"] == "1"


def test_a_run_killed_by_sigkill_leaves_the_host_the_neutral_report(guest):
    """Nothing in a process catches SIGKILL (or the OOM killer, or a crash in native code): the
    host, whose device stays, still reads the neutral report last (the gadget's guard)."""
    details = passed(guest, "checks_gadget.check_usb_killed")
    assert details["last_report"] == HID_JOYSTICK.neutral().hex() != details["held_report"]


def test_an_xinput_run_killed_by_sigkill_unplugs_the_pad(guest):
    """The XInput pad needs no guard: the kernel unbinds the gadget when its GadgetFS (or
    FunctionFS) files close."""
    passed(guest, "checks_gadget.check_usb_killed_xinput")  # the guest asserts the pad went away


def test_latency_from_decision_to_host_event_is_measured(guest):
    """The figures docs/performance.md gives ("USB gadget latency"); every move arrived."""
    details = passed(guest, "checks_gadget.check_usb_latency")
    assert details["samples"] == 100 and details["p50_ms"] <= details["p99_ms"]


def test_the_packaged_user_unit_runs_the_usb_output_in_its_sandbox(guest):
    """NEUROTOUCH_OUTPUT=usb in service.env, the unit under a real systemd --user (the guest check
    says what it changes for this guest: no camera, no journald)."""
    details = passed(guest, "checks_gadget.check_usb_from_the_user_unit")
    assert "DeviceAllow=char-hidg rw" in details["sandbox"] and "DevicePolicy=closed" in details["sandbox"]
    assert "SystemCallFilter=@system-service" in details["sandbox"]
    assert f"--output usb --profile {details['profile']}" in details["cmdline"]  # service.env's choices
    assert sorted(details["result"]) == ["ExecMainStatus=0", "Result=success"]  # stopped in order
    assert details["last_report"] != details["held_report"]  # the guest checks it is the neutral one


def test_switch_gadget_has_64_byte_endpoints_as_a_wired_hori_pad(guest):
    """wMaxPacketSize 64 on both endpoints, as GP2040-CE's copy of HORI's descriptors has; the
    rest of what the host read is recorded beside it (docs/any-host.md compares it)."""
    usb = passed(guest, "checks_gadget.check_usb_switch")["usb"]
    assert [e["wMaxPacketSize"] for e in usb["endpoints"]] == [64, 64]
    assert usb["interfaces"] == [["03", "00", "00"]] and usb["configuration"]["bmAttributes"] == "80"


def test_xac_gadget_is_one_joystick_function_read_as_the_documented_report(guest):
    from neurotouch_hid.targets.reports.xac import XAC

    details = passed(guest, "checks_gadget.check_usb_xac")
    assert details["functions"] == ["hid.usb0"] and len(details["usb"]["interfaces"]) == 1
    held = bytes.fromhex(details["held_report"])
    assert held[0] == 255 and held[5] & 1  # X full right, button 1
    assert details["last_report"] == XAC.neutral().hex()
    # Debian 12's 6.1 has no interval attribute: doctor's note says so
    assert details["interval"] is None and "cannot set its polling interval" in details["notes"][0]
    # and which interface for a whole configuration descriptor it has (the test kernel: gadgetfs.ko)
    assert details["notes"][1].startswith("xinput: gadgetfs available"), details["notes"]


def test_two_cameras_on_one_board_give_one_host_two_pads_each_driven_by_its_own_gel(guest):
    """``gadget setup --serial LEFT1 --serial RIGHT1``: one gadget, a pad function per camera;
    the two runs each write their own; stopping one leaves the other's pad moving."""
    details = passed(guest, "checks_gadget_pads.check_usb_two_cameras_two_pads")
    assert details["functions"] == ["hid.padLEFT1", "hid.padRIGHT1"]
    left, right = details["LEFT1"], details["RIGHT1"]
    assert left["phys"].endswith("/input0") and right["phys"].endswith("/input1")
    assert left["uniq"] == right["uniq"] == "LEFT1-RIGHT1"  # one USB device: its serial names both cameras
    assert details["left_after_stop"] == details["right_after_stop"] == {"x": 0, "keys": []}
    assert details["right_pushes_after_left_stopped"] >= 2 and details["right_running_after_left_exited"]
    assert details["left_result"]["exit"] == details["right_result"]["exit"] == 0
