"""The output identity derived from a camera serial (neurotouch_hid/targets/identity.py)."""

import struct

import pytest

from neurotouch_hid.targets.identity import (
    DEFAULT_PHYS,
    DEFAULT_USB_SERIAL,
    MAX_SERIAL_CHARS,
    Identity,
    check_serial,
    identity_for,
    mac_for,
)

#: Field sizes of struct uhid_create2_req (include/uapi/linux/uhid.h): phys[64], uniq[64].
UHID_PHYS_BYTES = UHID_UNIQ_BYTES = 64
#: A USB string descriptor holds at most (255 - 2) / 2 UTF-16 code units (USB 2.0 9.6.7).
USB_STRING_CHARS = 126


def test_same_serial_gives_the_same_identity_every_time():
    assert identity_for("00000499") == identity_for("00000499")
    # pinned: a change of the hash would make every host forget the pads it knows
    assert identity_for("00000499").uniq == "ee:1f:7d:11:63:c5"
    assert identity_for(None).uniq == "0a:c4:17:80:4f:f6"
    assert identity_for("00000499").mac == mac_for("00000499") == bytes.fromhex("ee1f7d1163c5")


def test_two_serials_give_distinct_identities():
    a, b = identity_for("00000499"), identity_for("00000500")
    assert a.serial == "00000499" and b.serial == "00000500"
    assert a.mac != b.mac and a.uniq != b.uniq
    assert a.phys == "neurotouch-hid/00000499" and b.phys == "neurotouch-hid/00000500"
    assert a.usb_serial != b.usb_serial
    macs = {identity_for(f"SIM{i:04d}").mac for i in range(2000)}
    assert len(macs) == 2000


@pytest.mark.parametrize("serial", [None, "0", "00000499", "sim_left", "A" * MAX_SERIAL_CHARS])
def test_mac_is_locally_administered_unicast_and_uniq_is_its_text(serial):
    ident = identity_for(serial)
    assert isinstance(ident, Identity)
    assert len(ident.mac) == 6
    assert ident.mac[0] & 0x01 == 0, "multicast bit set"
    assert ident.mac[0] & 0x02 == 0x02, "not locally administered"
    parts = ident.uniq.split(":")
    assert len(parts) == 6 and bytes(int(p, 16) for p in parts) == ident.mac
    assert ident.uniq == ident.uniq.lower()


@pytest.mark.parametrize("serial", [None, "00000499", "Z" * MAX_SERIAL_CHARS])
def test_lengths_fit_the_kernel_and_usb_fields(serial):
    ident = identity_for(serial)
    # NUL-terminated in 64-byte fields; a second device of the camera adds "/keyboard"
    assert len((ident.phys + "/keyboard").encode()) < UHID_PHYS_BYTES
    assert len(ident.uniq.encode()) < UHID_UNIQ_BYTES
    struct.pack("<64s64s", ident.phys.encode(), ident.uniq.encode())
    assert 0 < len(ident.usb_serial) <= 32 < USB_STRING_CHARS
    assert ident.usb_serial.isascii()


def test_no_serial_gives_the_fixed_default():
    ident = identity_for(None)
    assert ident == identity_for(None)
    assert ident.serial == ""
    assert ident.phys == DEFAULT_PHYS
    assert ident.usb_serial == DEFAULT_USB_SERIAL
    assert ident.mac != identity_for("00000001").mac


@pytest.mark.parametrize(
    ("serial", "said"),
    [
        ("", "empty"),
        ("A" * (MAX_SERIAL_CHARS + 1), "at most 32"),
        ("../etc", "character other than"),
        ("a b", "character other than"),
        ("-x", "character other than"),
        ("A-1", "character other than"),
        ("sé", "character other than"),
        ("a\nb", "character other than"),
    ],
)
def test_bad_serials_are_refused_with_what_was_expected(serial, said):
    with pytest.raises(ValueError, match=said.replace("(", r"\(")):
        identity_for(serial)
    with pytest.raises(ValueError):
        check_serial(serial)


def test_a_valid_serial_is_returned_unchanged():
    assert check_serial("00000499") == "00000499"
    assert check_serial("_x_1") == "_x_1"
