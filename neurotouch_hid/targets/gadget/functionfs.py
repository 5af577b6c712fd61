"""The few FunctionFS structures the XInput pad needs, per the kernel's documentation.

FunctionFS (Documentation/usb/functionfs.rst; the structs are include/uapi/linux/usb/functionfs.h)
is a file system: its ``ep0`` takes the function's descriptors and strings (one write each,
before anything else), and then gives the function's events (12 bytes each); ``ep1``, ``ep2``, ...
appear for the endpoints in the order the descriptors declare them. Written here rather than
taken from the ``functionfs`` package (GPL-3.0+, and this project is MIT).

Descriptors are USB 2.0 (chapter 9.6): interface, then a class descriptor where the class has one
(HID's, HID 1.11 section 6.2.1: FunctionFS takes a class descriptor after an interface of the HID,
CCID or DFU class only, ``ffs_do_single_desc``), then endpoints; the same set for full and high
speed.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

#: FUNCTIONFS_DESCRIPTORS_MAGIC_V2, FUNCTIONFS_STRINGS_MAGIC.
DESCRIPTORS_MAGIC_V2, STRINGS_MAGIC = 3, 2
#: FUNCTIONFS_HAS_FS_DESC | FUNCTIONFS_HAS_HS_DESC: full- and high-speed descriptors follow.
HAS_FS_DESC, HAS_HS_DESC = 1, 2
#: ``struct usb_functionfs_event``: an 8-byte setup packet, the type, 3 bytes of padding.
EVENT = struct.Struct("<BBHHHB3x")
#: Event types (``enum usb_functionfs_event_type``).
BIND, UNBIND, ENABLE, DISABLE, SETUP, SUSPEND, RESUME = range(7)
EVENT_NAMES = ("bind", "unbind", "enable", "disable", "setup", "suspend", "resume")
#: US English, the only language of the strings.
LANG_EN_US = 0x0409


@dataclass(frozen=True)
class Endpoint:
    """One endpoint: its address (bit 7 set: IN), transfer type (3: interrupt), packet size
    (bytes) and interval (frames at full speed; 2^(n-1) microframes at high speed)."""

    address: int
    attributes: int = 0x03
    max_packet: int = 32
    interval: int = 4

    def descriptor(self, high_speed: bool) -> bytes:
        """The 7-byte endpoint descriptor (USB 2.0, 9.6.6)."""
        interval = self.interval
        if high_speed:  # full speed counts 1 ms frames; high speed 2^(n-1) x 125 us
            interval = max(1, (self.interval * 8).bit_length())
        return struct.pack("<BBBBHB", 7, 0x05, self.address, self.attributes, self.max_packet, interval)


def interface_descriptor(klass: tuple[int, int, int], endpoints: int, string_index: int = 1) -> bytes:
    """The 9-byte interface descriptor (USB 2.0, 9.6.5): interface 0, ``klass`` = (class,
    subclass, protocol), ``endpoints`` endpoints, its name the string ``string_index``."""
    return struct.pack("<BBBBBBBBB", 9, 0x04, 0, 0, endpoints, *klass, string_index)


#: HID class: interface class 3 (HID 1.11, 4.1); descriptor types HID 0x21 and Report 0x22 (7.1).
HID_CLASS = (0x03, 0x00, 0x00)
HID_DESCRIPTOR_TYPE, REPORT_DESCRIPTOR_TYPE = 0x21, 0x22
#: bcdHID of the HID descriptor: HID 1.11.
BCD_HID = 0x0111


def hid_descriptor(report_descriptor_length: int) -> bytes:
    """The 9-byte HID descriptor (HID 1.11, 6.2.1): bcdHID 1.11, no country code, one class
    descriptor, the report descriptor of ``report_descriptor_length`` bytes."""
    return struct.pack(
        "<BBHBBBH", 9, HID_DESCRIPTOR_TYPE, BCD_HID, 0, 1, REPORT_DESCRIPTOR_TYPE, report_descriptor_length
    )


def descriptors(klass: tuple[int, int, int], endpoints: tuple[Endpoint, ...], class_descriptor: bytes = b"") -> bytes:
    """What is written first to ``ep0``: ``usb_functionfs_descs_head_v2`` (magic, length, flags),
    the full- and high-speed counts, then each speed's interface, its ``class_descriptor`` (one
    descriptor, e.g. :func:`hid_descriptor`; none when empty) and endpoint descriptors."""
    speeds = []
    for high in (False, True):
        head = interface_descriptor(klass, len(endpoints)) + class_descriptor
        speeds.append(head + b"".join(e.descriptor(high) for e in endpoints))
    count = 1 + bool(class_descriptor) + len(endpoints)
    body = struct.pack("<II", count, count) + b"".join(speeds)
    return struct.pack("<III", DESCRIPTORS_MAGIC_V2, 12 + len(body), HAS_FS_DESC | HAS_HS_DESC) + body


def strings(*texts: str) -> bytes:
    """What is written second to ``ep0``: ``usb_functionfs_strings_head`` (magic, length, string
    count, language count) and, for US English, its code and the NUL-terminated ``texts``."""
    body = struct.pack("<H", LANG_EN_US) + b"".join(t.encode() + b"\0" for t in texts)
    return struct.pack("<IIII", STRINGS_MAGIC, 16 + len(body), len(texts), 1) + body


@dataclass(frozen=True)
class Event:
    """One ``ep0`` event: its type (:data:`BIND` ...) and, for :data:`SETUP`, the request
    (bmRequestType, bRequest, wValue, wIndex, wLength)."""

    type: int
    request_type: int = 0
    request: int = 0
    value: int = 0
    index: int = 0
    length: int = 0

    @property
    def name(self) -> str:
        """``bind``, ``enable``, ... (``unknown N`` for a type this kernel added later)."""
        return EVENT_NAMES[self.type] if self.type < len(EVENT_NAMES) else f"unknown {self.type}"


def parse_events(data: bytes) -> list[Event]:
    """The events in one read of ``ep0`` (a multiple of 12 bytes; a trailing part is ignored)."""
    usable = len(data) - len(data) % EVENT.size
    return [Event(t, rt, r, v, i, n) for rt, r, v, i, n, t in EVENT.iter_unpack(bytes(data[:usable]))]
