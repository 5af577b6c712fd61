"""Who an output device says it is: every device the driver makes for one camera carries an
identity derived from that camera's serial, so two gels give two controllers that games, SDL
and Steam tell apart and remember from one run to the next.

:func:`identity_for` maps a serial (as read from the camera, or the simulator's ``--serial``) to
an :class:`Identity`: the uinput ``phys``, the UHID ``uniq`` (a MAC address, the format of
hid-playstation's ``uniq``), the MAC a DualSense reports in its pairing-info feature report and
the USB gadget's iSerialNumber. The MAC is a stable hash of the serial (BLAKE2b, hashlib), made
a locally administered unicast address (IEEE 802, the two low bits of the first octet: bit 0
clear = unicast, bit 1 set = locally administered), so it never claims a vendor's block.

Lengths: uinput and UHID keep ``phys`` and ``uniq`` in 64-byte fields (``struct
uhid_create2_req``, include/uapi/linux/uhid.h; ``struct hid_device``), so a serial is at most
:data:`MAX_SERIAL_CHARS` ASCII characters, and the gadget's serial string stays far under the
126 UTF-16 characters of a USB string descriptor (USB 2.0 section 9.6.7). A serial is also a
device link (``/dev/neurotouch-SERIAL``), a systemd instance name and a folder name, so it is
made of letters, digits and ``_`` only (:func:`neurotouch_hid.service.serials.check_serial`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

from neurotouch_hid.service.serials import MAX_SERIAL_CHARS, check_serial

__all__ = ["MAX_SERIAL_CHARS", "Identity", "check_serial", "identity_for", "mac_for"]

#: Prefix of every ``phys`` the driver sets (the udev rule's ``neurotouch-hid/*`` tags them
#: ID_NEUROTOUCH_VIRTUAL=1, and the remapper never grabs them).
PHYS_PREFIX = "neurotouch-hid/"
#: The gadget's iSerialNumber when no serial is known (the one every board had before serials).
DEFAULT_USB_SERIAL = "00000001"
#: ``phys`` when no serial is known (the driver's outputs then keep each their own phys:
#: ``neurotouch-hid/gamepad``, ``neurotouch-hid/uhid``, as they always had).
DEFAULT_PHYS = PHYS_PREFIX + "default"
#: Salt of the MAC hash: changing it changes every MAC, and hosts would forget paired pads.
_MAC_SALT = b"neurotouch-hid mac v1\0"


@dataclass(frozen=True)
class Identity:
    """The identity of the output devices made for one camera.

    Attributes:
        serial: the camera's serial as read from the camera (or the simulator's ``--serial``);
            ``""`` when none is known.
        mac: 6 bytes in the order written ``aa:bb:...`` (``mac[0]`` first), locally administered
            unicast (``mac[0] & 0x03 == 0x02``), the same for the same serial on every machine.
            A DualSense's feature report 0x09 carries it reversed (hid-playstation reads bytes
            1..6 and prints them with ``%pMR``).
        uniq: the MAC as ``"aa:bb:cc:dd:ee:ff"`` (lower case): a UHID device's ``uniq``.
        phys: ``"neurotouch-hid/<serial>"`` (``DEFAULT_PHYS`` without a serial): a uinput
            device's ``phys``; a second device of the same camera adds ``/<what>``.
        usb_serial: the USB gadget's iSerialNumber: the serial itself (``DEFAULT_USB_SERIAL``
            without one), at most :data:`MAX_SERIAL_CHARS` characters.
    """

    serial: str
    mac: bytes
    uniq: str
    phys: str
    usb_serial: str


def mac_for(serial: str) -> bytes:
    """The 6-byte MAC of ``serial``: BLAKE2b (hashlib, 6-byte digest) of a fixed salt and the
    serial's UTF-8, the first octet made locally administered unicast (``& 0xFC | 0x02``).

    Args:
        serial: any text (``""`` for the default identity).

    Returns:
        6 bytes, ``mac[0] & 0x03 == 0x02``.
    """
    digest = bytearray(hashlib.blake2b(_MAC_SALT + serial.encode(), digest_size=6).digest())
    digest[0] = (digest[0] & 0xFC) | 0x02
    return bytes(digest)


def identity_for(serial: str | None) -> Identity:
    """The identity of the outputs of the camera with ``serial``.

    Args:
        serial: the camera's serial, or None when none is known (a recording, the simulator
            without ``--serial``): then a fixed default identity (``DEFAULT_PHYS``,
            ``DEFAULT_USB_SERIAL``, the MAC of ``""``).

    Returns:
        An :class:`Identity`; the same serial gives the same identity, two serials two
        different ones (``phys`` and ``usb_serial`` hold the serial; the MACs differ unless
        48-bit hashes collide).

    Raises:
        ValueError: ``serial`` is not a valid serial (:func:`check_serial`).
    """
    if serial is None:
        mac = mac_for("")
        return Identity("", mac, _colons(mac), DEFAULT_PHYS, DEFAULT_USB_SERIAL)
    check_serial(serial)
    mac = mac_for(serial)
    return Identity(serial, mac, _colons(mac), PHYS_PREFIX + serial, serial)


def _colons(mac: bytes) -> str:
    return ":".join(f"{b:02x}" for b in mac)
