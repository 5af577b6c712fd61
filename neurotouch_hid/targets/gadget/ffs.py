"""The gadget's FunctionFS functions as :class:`~neurotouch_hid.core.stages.Target` s: the Xbox 360 pad
and a HID interface that answers its host's control requests itself.

A FunctionFS function (Documentation/usb/functionfs.rst) is user space's: its ``ep0`` takes the
descriptors and strings, then gives the host's control requests for the function as SETUP events,
which the function answers on ``ep0`` (a write for a request that reads, a read for one that
writes; I/O in the wrong direction stalls it). ``ep1`` (interrupt IN) and ``ep2`` (interrupt OUT)
are the endpoints, in the order the descriptors declare them.

* :class:`XInputTarget`: the wired Xbox 360 pad, interface FF/5D/01. It answers the vendor
  requests a host's XInput driver asks (``C1 01``: :func:`xinput_answer`) and reads rumble and
  LED requests on its OUT endpoint.
* :class:`HidInterfaceTarget`: a HID interface (class 3 and its HID descriptor, HID 1.11) for a
  protocol whose host reads feature reports: the kernel's ``hid`` function (f_hid) of Linux 6.1
  answers every GET_REPORT with zeros, so this one answers them itself (:func:`hid_answer`):
  GET_DESCRIPTOR of the report descriptor, GET_REPORT (input and feature reports, the format's
  :meth:`feature`), SET_IDLE, GET_IDLE, GET/SET_PROTOCOL, SET_REPORT and the OUT endpoint's
  output reports, parsed by the format's ``parse_output`` into
  :class:`~neurotouch_hid.core.stages.Feedback`.

Two daemon threads per function read, bounded: ``ep0``'s events and the OUT endpoint. Feedback is
announced on a pipe (:meth:`FfsTarget.fileno`; the last 64 requests kept: ``targets._Announced``).
When the function's files close (the driver killed included), the kernel unbinds the gadget and
the host sees it unplugged, its readers having last read the report before; the gadget's guard
(:meth:`FfsTarget.guarded`) holds a copy of the IN endpoint, so that a killed driver's host reads
the neutral report first.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.service.udev import sudo_command
from neurotouch_hid.targets.gadget import functionfs
from neurotouch_hid.targets.gadget.targets import MAX_OUTPUT_REPORT, _Announced, _ReportTarget

if TYPE_CHECKING:
    from neurotouch_hid.targets.reports import ReportFormat

log = logging.getLogger(__name__)

#: Pause after a failed read of ep0 or the OUT endpoint (the host went away) before the next (s).
ERROR_PAUSE_S = 0.05
#: Largest data stage read from a host's control request (bytes); a longer one is stalled.
MAX_CONTROL_DATA = 1024
#: The XInput pad's endpoints: interrupt IN 0x81 (32 bytes every 4 ms) and OUT 0x02 (every 8 ms),
#: as a wired Xbox 360 controller declares them.
XINPUT_ENDPOINTS = (functionfs.Endpoint(0x81, interval=4), functionfs.Endpoint(0x02, interval=8))

#: Standard and HID class requests (USB 2.0 table 9-4; HID 1.11, 7.2).
GET_DESCRIPTOR = 0x06
GET_REPORT, GET_IDLE, GET_PROTOCOL, SET_REPORT, SET_IDLE, SET_PROTOCOL = 0x01, 0x02, 0x03, 0x09, 0x0A, 0x0B
#: Report types in GET_REPORT/SET_REPORT's wValue high byte (HID 1.11, 7.2.1).
INPUT, OUTPUT, FEATURE = 1, 2, 3
#: bmRequestType of the requests answered: standard, class and vendor, to the interface.
STANDARD_IN, CLASS_IN, CLASS_OUT, VENDOR_IN = 0x81, 0xA1, 0x21, 0xC1

#: What a wired Xbox 360 pad answers to the vendor request ``C1 01`` (to the interface), by
#: wValue: 0x0100 (20 bytes) the input report's capabilities, which controls the pad has (buttons
#: 3F F7, triggers FF FF, the sticks' significant bits C0 FF), and 0x0000 (8 bytes) the output's
#: (the rumble report's header, no motor bits claimed). Linux's xpad asks 0x0100 when the pad is
#: opened (``xpad_start_input``: "unable to receive magic message" when it is stalled); Windows'
#: driver asks both. Source: captures of a wired pad documented by Santroller
#: (controller-reverse-engineering/xbox-360-controllers.md, github.com/Santroller/Santroller,
#: quoting the ViGEm forum's "XInput capabilities" thread); the bytes only.
XINPUT_CAPABILITIES = {
    0x0100: bytes.fromhex("00143ff7ffff00000000c0ffc0ff000000000000"),
    0x0000: bytes.fromhex("0008000000000000"),
}


def xinput_answer(event: functionfs.Event) -> bytes | None:
    """The Xbox 360 pad's answer to one SETUP ``event`` (:data:`XINPUT_CAPABILITIES`, cut to the
    host's wLength), None for any other request (stalled)."""
    if event.request_type == VENDOR_IN and event.request == 0x01 and event.value in XINPUT_CAPABILITIES:
        return XINPUT_CAPABILITIES[event.value][: event.length]
    return None


@dataclasses.dataclass
class HidState:
    """What :func:`hid_answer` reads and keeps: the interface's idle rate (4 ms units, HID 1.11
    7.2.4) and protocol (1 report, 0 boot), and the input report the host last got."""

    idle: int = 0
    protocol: int = 1
    report: bytes = b""


#: :func:`hid_answer`'s answer to a request that writes (SET_*): take the data stage.
ACCEPT = b""


def hid_answer(event: functionfs.Event, fmt: ReportFormat, identity: object, state: HidState) -> bytes | None:
    """A HID interface's answer to one SETUP ``event`` (HID 1.11, 7.1 and 7.2), for the report
    format ``fmt`` and the device's ``identity`` (:class:`~neurotouch_hid.targets.identity.Identity`,
    handed to ``fmt.feature``):

    * GET_DESCRIPTOR: the report descriptor (type 0x22) or the HID descriptor (0x21);
    * GET_REPORT: an input report (``state.report``), a feature report of ``fmt.feature_ids``
      (``fmt.feature(id, identity)``);
    * GET_IDLE, GET_PROTOCOL: ``state``'s; SET_IDLE, SET_PROTOCOL: kept in ``state``;
    * SET_REPORT: :data:`ACCEPT` (the data stage is read and handed to the format).

    Answers of a request that reads are cut to its wLength. None: stall (an unknown request, a
    report id the format has not, a data stage longer than :data:`MAX_CONTROL_DATA`)."""
    kind, number = event.value >> 8, event.value & 0xFF
    if event.request_type == STANDARD_IN and event.request == GET_DESCRIPTOR:
        if kind == functionfs.REPORT_DESCRIPTOR_TYPE:
            return fmt.descriptor[: event.length]
        if kind == functionfs.HID_DESCRIPTOR_TYPE:
            return functionfs.hid_descriptor(len(fmt.descriptor))[: event.length]
        return None
    if event.request_type == CLASS_IN:
        if event.request == GET_REPORT and kind == INPUT and state.report:
            return state.report[: event.length]
        if event.request == GET_REPORT and kind == FEATURE and number in getattr(fmt, "feature_ids", ()):
            return fmt.feature(number, identity)[: event.length]
        if event.request == GET_IDLE:
            return bytes([state.idle])[: event.length]
        if event.request == GET_PROTOCOL:
            return bytes([state.protocol])[: event.length]
        return None
    if event.request_type == CLASS_OUT:
        if event.request == SET_IDLE:
            state.idle = event.value >> 8
            return ACCEPT
        if event.request == SET_PROTOCOL:
            state.protocol = event.value & 0x01
            return ACCEPT
        if event.request == SET_REPORT and event.length <= MAX_CONTROL_DATA:
            return ACCEPT
    return None


def _fix(protocol: str) -> str:
    setup = sudo_command(f"gadget setup --protocol {protocol} --user $USER")
    return f"the {protocol} gadget is not set up for this user\n{setup}"


class FfsTarget(_Announced, _ReportTarget):
    """A FunctionFS function on the mount ``mount`` (module docstring): ``descriptors`` and the
    interface's name written to ``ep0``, ``ep1`` (IN) and ``ep2`` (OUT) opened, the two reader
    threads started. Subclasses answer control requests (:meth:`answer`, :meth:`received`) and
    parse the OUT endpoint's reports (:meth:`parse`).

    Raises:
        DeviceError: ``mount``'s ``ep0`` cannot be opened (``fix`` says what to do), or the kernel
            refused the descriptors.
    """

    #: The OUT endpoint's packet size (bytes): one read a packet.
    out_packet = 32

    def __init__(self, mount: str | os.PathLike, fmt: ReportFormat, what: str, descriptors: bytes, name: str, fix: str):
        mount = Path(mount)
        try:
            self._ep0 = os.open(mount / "ep0", os.O_RDWR | os.O_CLOEXEC)
        except OSError as exc:
            raise DeviceError(f"cannot open {mount / 'ep0'} ({exc.strerror}): {fix}") from None
        try:
            os.write(self._ep0, descriptors)
            os.write(self._ep0, functionfs.strings(name))
            self._in = os.open(mount / "ep1", os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)
            self._out = os.open(mount / "ep2", os.O_RDWR | os.O_CLOEXEC)
        except OSError as exc:
            os.close(self._ep0)
            raise DeviceError(f"{mount}: the kernel refused the {what}'s descriptors ({exc.strerror})") from None
        self._open_announcements()
        self.enabled = threading.Event()
        self._start(self._in, fmt, what)
        for target, part in ((self._read_events, "ep0 events"), (self._read_out, "OUT endpoint")):
            threading.Thread(target=target, name=f"{what}: {part}", daemon=True).start()

    def guarded(self) -> tuple[int, bytes]:
        """The IN endpoint's descriptor and the neutral report, for the guard that sends it if
        the driver dies (:class:`~neurotouch_hid.service.guard.Guard`): its copy keeps the function open
        (FunctionFS unbinds the gadget once every file of it is closed) until it has."""
        return self._in, self.format.neutral()

    def close(self) -> None:
        """Neutral report, wait for the host to take it (up to ``NEUTRAL_WAIT_S``), then close the
        endpoints and ``ep0``: FunctionFS then unbinds the gadget from its UDC (a thread blocked in
        a read keeps its file until that read returns, at the unbind)."""
        if not self._close_neutral():
            return
        for fd in (self._in, self._out, self._ep0):
            try:
                os.close(fd)
            except OSError:
                pass
        self._close_announcements()

    def answer(self, event: functionfs.Event) -> bytes | None:
        """The answer to a SETUP event: the data for a request that reads, :data:`ACCEPT` for
        one that writes (its data stage goes to :meth:`received`), None to stall it."""
        return None

    def received(self, event: functionfs.Event, data: bytes) -> None:
        """The data stage of a request :meth:`answer` accepted."""

    def parse(self, data: bytes) -> list[Feedback]:
        """One report from the OUT endpoint as feedback."""
        return []

    def _read_loop(self, fd: int, size: int, where: str, handle: Callable[[bytes], None]) -> None:
        """Thread: read at most ``size`` bytes at a time from ``fd`` and ``handle`` them, until
        the function is closed; a read the kernel refuses meanwhile (host gone, or a control
        transfer it gave up on: EIDRM) is retried after :data:`ERROR_PAUSE_S`."""
        while True:
            try:
                data = os.read(fd, size)
            except OSError as exc:
                if self._closed:
                    return
                log.debug("%s: %s: %s", self.what, where, exc)
                time.sleep(ERROR_PAUSE_S)
                continue
            handle(data)

    def _read_events(self) -> None:
        self._read_loop(self._ep0, 4 * functionfs.EVENT.size, "ep0", self._on_events)

    def _on_events(self, data: bytes) -> None:
        for event in functionfs.parse_events(data):
            log.debug("%s: %s", self.what, event.name)
            if event.type == functionfs.ENABLE:
                self.enabled.set()
            elif event.type in (functionfs.DISABLE, functionfs.UNBIND):
                self.enabled.clear()
            elif event.type == functionfs.SETUP:
                self._setup(event)

    def _setup(self, event: functionfs.Event) -> None:
        """Answer one control request on ``ep0``; a request not answered is stalled (I/O in the
        wrong direction, functionfs.rst). A host that gave up on the transfer meanwhile makes the
        write or read fail (EIDRM): logged, the next event is read."""
        reply = self.answer(event)
        reads = bool(event.request_type & 0x80)
        log.debug("%s: request %02x/%02x %04x: %s", self.what, event.request_type, event.request, event.value,
                  "stall" if reply is None else len(reply))  # fmt: skip
        try:
            if reply is None:
                os.read(self._ep0, 0) if reads else os.write(self._ep0, b"")
            elif reads:
                os.write(self._ep0, reply)
            else:
                self.received(event, os.read(self._ep0, event.length))
        except OSError as exc:
            if reply is not None:  # a stall ends in EL2HLT: that is the stall done
                log.debug("%s: request %02x/%02x: %s", self.what, event.request_type, event.request, exc)

    def _read_out(self) -> None:
        """OUT endpoint reader: one read a packet (a longer read would join a full packet and the
        next, whose report would be lost)."""
        self._read_loop(self._out, self.out_packet, "OUT endpoint", self._on_output)

    def _on_output(self, data: bytes) -> None:
        requests = self.parse(bytes(data[:MAX_OUTPUT_REPORT]))
        if requests:
            self._announce(requests)
        else:
            log.debug("%s: output report %s not understood", self.what, bytes(data[:MAX_OUTPUT_REPORT]).hex())


class XInputTarget(FfsTarget):
    """The Xbox 360 pad on the FunctionFS mount ``mount`` (module docstring).

    ``enabled`` is set once the host configured it. Raises DeviceError (:class:`FfsTarget`)."""

    def __init__(self, mount: str | os.PathLike, fmt: ReportFormat, what: str = "USB gadget (xinput)"):
        from neurotouch_hid.targets.reports.xinput import INTERFACE_CLASS
        from neurotouch_hid.targets.reports.xinput import MAX_OUTPUT_REPORT as PACKET

        self.out_packet = PACKET
        descriptors = functionfs.descriptors(INTERFACE_CLASS, XINPUT_ENDPOINTS)
        super().__init__(mount, fmt, what, descriptors, "Xbox 360 pad (NeuroTouch)", _fix("xinput"))

    def answer(self, event: functionfs.Event) -> bytes | None:
        """:func:`xinput_answer`."""
        return xinput_answer(event)

    def parse(self, data: bytes) -> list[Feedback]:
        """Rumble and LED requests (:func:`~neurotouch_hid.targets.reports.xinput.parse_output`)."""
        from neurotouch_hid.targets.reports.xinput import parse_output

        request = parse_output(data, self.what)
        return [request] if request is not None else []


class HidInterfaceTarget(FfsTarget):
    """A HID interface on the FunctionFS mount ``mount`` (module docstring), speaking ``fmt``:
    class 3 and its HID descriptor, interrupt IN and OUT endpoints of ``max_packet`` bytes every
    ``interval_ms``; feature reports answered with ``fmt.feature(id, identity)``.

    Raises DeviceError (:class:`FfsTarget`)."""

    def __init__(
        self,
        mount: str | os.PathLike,
        fmt: ReportFormat,
        identity: object = None,
        *,
        what: str = "",
        max_packet: int = 64,
        interval_ms: int = 4,
        name: str = "NeuroTouch controller",
    ):
        self.identity = identity
        self.out_packet = max_packet
        self._hid = HidState()
        endpoints = (
            functionfs.Endpoint(0x81, max_packet=max_packet, interval=interval_ms),
            functionfs.Endpoint(0x02, max_packet=max_packet, interval=interval_ms),
        )
        descriptors = functionfs.descriptors(
            functionfs.HID_CLASS, endpoints, functionfs.hid_descriptor(len(fmt.descriptor))
        )
        what = what or f"USB gadget ({fmt.name})"
        super().__init__(mount, fmt, what, descriptors, name, _fix(fmt.name))

    def write(self, state) -> None:
        """Queue ``state``'s report when it changed; it is also what GET_REPORT(Input) answers."""
        super().write(state)
        self._hid.report = self._last or b""

    def neutralise(self) -> None:
        """Queue the neutral report now."""
        super().neutralise()
        if hasattr(self, "_hid"):
            self._hid.report = self._last or b""

    def answer(self, event: functionfs.Event) -> bytes | None:
        """:func:`hid_answer`."""
        try:
            return hid_answer(event, self.format, self.identity, self._hid)
        except Exception as exc:  # a format's answer must never end the thread that answers the host
            log.warning("%s: no answer to request %02x/%02x %04x: %s", self.what, event.request_type,
                        event.request, event.value, exc)  # fmt: skip
            return None

    def received(self, event: functionfs.Event, data: bytes) -> None:
        """A SET_REPORT's data: an output report is parsed as the OUT endpoint's are; a feature
        report the host sets is logged only."""
        if event.request == SET_REPORT and event.value >> 8 == OUTPUT:
            self._on_output(data)
        elif event.request == SET_REPORT:
            log.debug("%s: report %04x set by the host: %s", self.what, event.value, data[:MAX_OUTPUT_REPORT].hex())

    def parse(self, data: bytes) -> list[Feedback]:
        """``fmt.parse_output``, each request named after this target."""
        parse = getattr(self.format, "parse_output", None)
        if parse is None:
            return []
        return [dataclasses.replace(request, source=self.what) for request in parse(data)]
