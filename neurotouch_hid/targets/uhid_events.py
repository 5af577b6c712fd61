"""The kernel's ``/dev/uhid`` interface as bytes (Documentation/hid/uhid.rst,
include/uapi/linux/uhid.h): the event types and report types, the packed little-endian
``struct uhid_event`` (a u32 type, then the request; :data:`UHID_EVENT_SIZE` bytes), an event the
kernel sent parsed and bounded (:func:`parse_event`, :func:`read_event`: one read, data fields at
most :data:`UHID_DATA_MAX`) and the ``UHID_CREATE2`` event that makes a device
(:func:`create2_event`). :class:`~neurotouch_hid.targets.uhid.UhidDevice` speaks it.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass

from neurotouch_hid.core.errors import DeviceError

# enum uhid_event_type (include/uapi/linux/uhid.h)
UHID_DESTROY = 1
UHID_START = 2
UHID_STOP = 3
UHID_OPEN = 4
UHID_CLOSE = 5
UHID_OUTPUT = 6
UHID_GET_REPORT = 9
UHID_GET_REPORT_REPLY = 10
UHID_CREATE2 = 11
UHID_INPUT2 = 12
UHID_SET_REPORT = 13
UHID_SET_REPORT_REPLY = 14
#: Names of the event types, for messages.
EVENT_NAMES = {
    UHID_DESTROY: "DESTROY",
    UHID_START: "START",
    UHID_STOP: "STOP",
    UHID_OPEN: "OPEN",
    UHID_CLOSE: "CLOSE",
    UHID_OUTPUT: "OUTPUT",
    UHID_GET_REPORT: "GET_REPORT",
    UHID_SET_REPORT: "SET_REPORT",
}
#: UHID_START's dev_flags: the descriptor numbers its input reports (the report id is byte 0).
UHID_DEV_NUMBERED_INPUT_REPORTS = 1 << 2
# enum uhid_report_type
UHID_FEATURE_REPORT, UHID_OUTPUT_REPORT, UHID_INPUT_REPORT = 0, 1, 2
#: Largest data of one report, and of the report descriptor (UHID_DATA_MAX, HID_MAX_DESCRIPTOR_SIZE).
UHID_DATA_MAX = 4096
#: BUS_USB (include/uapi/linux/input.h).
BUS_USB = 0x03
#: struct uhid_create2_req: name[128] phys[64] uniq[64] rd_size bus vendor product version country
_CREATE2 = struct.Struct("<I128s64s64sHHIIII")
#: sizeof(struct uhid_event): the type and its union of requests, whose largest is uhid_create2_req
#: (its rd_data last, 4372 bytes), padded to the union's 8-byte alignment (uhid_create_req's
#: rd_data pointer): 4 + 4376 = 4380, as gcc gives for linux/uhid.h on x86_64 and aarch64.
UHID_EVENT_SIZE = 4 + -(-(_CREATE2.size - 4 + UHID_DATA_MAX) // 8) * 8
_INPUT2 = struct.Struct("<IH")  # type, size; the data follows
_GET_REPORT = struct.Struct("<IBB")  # id, rnum, rtype
_GET_REPORT_REPLY = struct.Struct("<IIHH")  # type, id, err, size; the data follows
_SET_REPORT = struct.Struct("<IBBH")  # id, rnum, rtype, size; the data follows
_SET_REPORT_REPLY = struct.Struct("<IIH")  # type, id, err
_OUTPUT_TAIL = struct.Struct("<HB")  # after data[UHID_DATA_MAX]: size, rtype
_START = struct.Struct("<Q")  # dev_flags

#: ``phys`` of the UHID devices (the udev rule's ``neurotouch-hid/*`` marks them
#: ID_NEUROTOUCH_VIRTUAL=1, like the uinput pad).
PHYS = "neurotouch-hid/uhid"
#: How long :class:`UhidDevice` waits for a HID driver to bind before its first report (s); past


@dataclass(frozen=True)
class UhidEvent:
    """One event the kernel sent (:func:`read_event`).

    Attributes:
        type: the ``UHID_*`` type.
        id: GET_REPORT/SET_REPORT: the request's id, to copy into the reply.
        rnum: GET_REPORT/SET_REPORT: the report number (0 without report IDs).
        rtype: OUTPUT/GET_REPORT/SET_REPORT: ``UHID_FEATURE_REPORT``, ``UHID_OUTPUT_REPORT`` or
            ``UHID_INPUT_REPORT``.
        data: OUTPUT/SET_REPORT: the report, at most ``UHID_DATA_MAX`` bytes.
        dev_flags: START: the ``UHID_DEV_NUMBERED_*`` flags.
    """

    type: int
    id: int = 0
    rnum: int = 0
    rtype: int = 0
    data: bytes = b""
    dev_flags: int = 0


def parse_event(raw: bytes) -> UhidEvent:
    """The :class:`UhidEvent` in ``raw`` (what one read of /dev/uhid returned). A short event is
    extended with zeros (uhid.h: "If the kernel writes short events, user-space shall extend them
    with 0s"), a longer one cut at ``UHID_EVENT_SIZE``; data sizes are bounded by UHID_DATA_MAX.

    Raises:
        DeviceError: fewer than 4 bytes (no type).
    """
    if len(raw) < 4:
        raise DeviceError(f"/dev/uhid returned {len(raw)} bytes, not an event")
    body = raw[4:UHID_EVENT_SIZE].ljust(UHID_EVENT_SIZE - 4, b"\0")
    kind = int.from_bytes(raw[:4], "little")
    if kind == UHID_START:
        return UhidEvent(kind, dev_flags=_START.unpack_from(body)[0])
    if kind == UHID_OUTPUT:
        size, rtype = _OUTPUT_TAIL.unpack_from(body, UHID_DATA_MAX)
        return UhidEvent(kind, rtype=rtype, data=body[: min(size, UHID_DATA_MAX)])
    if kind == UHID_GET_REPORT:
        request, rnum, rtype = _GET_REPORT.unpack_from(body)
        return UhidEvent(kind, id=request, rnum=rnum, rtype=rtype)
    if kind == UHID_SET_REPORT:
        request, rnum, rtype, size = _SET_REPORT.unpack_from(body)
        start = _SET_REPORT.size
        return UhidEvent(kind, id=request, rnum=rnum, rtype=rtype, data=body[start : start + min(size, UHID_DATA_MAX)])
    return UhidEvent(kind)


def read_event(fd: int) -> UhidEvent:
    """Read one event from the /dev/uhid file descriptor ``fd`` (one read of at most
    ``UHID_EVENT_SIZE`` bytes; the kernel hands one event per read) and parse it.

    Raises:
        OSError: the read failed (EAGAIN on a non-blocking ``fd`` with nothing queued).
        DeviceError: the kernel returned no event.
    """
    return parse_event(os.read(fd, UHID_EVENT_SIZE))


def create2_event(
    descriptor: bytes, name: str, *, vendor: int, product: int, version: int, phys: str = PHYS, uniq: str = ""
) -> bytes:
    """The ``UHID_CREATE2`` event for a device with the report ``descriptor`` (at most
    HID_MAX_DESCRIPTOR_SIZE bytes), ``name`` (at most 127 bytes of UTF-8), ``phys`` and ``uniq``
    (at most 63), on bus BUS_USB with the USB ids ``vendor``, ``product`` and ``version``
    (0..0xFFFF), country 0.

    Raises:
        DeviceError: a field does not fit.
    """
    fields = {"name": (name, 128), "phys": (phys, 64), "uniq": (uniq, 64)}
    encoded = {}
    for key, (text, size) in fields.items():
        encoded[key] = text.encode()
        if len(encoded[key]) >= size:
            raise DeviceError(f"the UHID device's {key} {text!r} must be under {size} bytes")
    if not 0 < len(descriptor) <= UHID_DATA_MAX:
        raise DeviceError(f"a report descriptor of {len(descriptor)} bytes (1..{UHID_DATA_MAX})")
    for key, value in (("vendor", vendor), ("product", product), ("version", version)):
        if not 0 <= value <= 0xFFFF:
            raise DeviceError(f"the UHID device's {key} id {value} is not a 16-bit number")
    head = _CREATE2.pack(
        UHID_CREATE2,
        encoded["name"],
        encoded["phys"],
        encoded["uniq"],
        len(descriptor),
        BUS_USB,
        vendor,
        product,
        version,
        0,
    )
    return head + descriptor
