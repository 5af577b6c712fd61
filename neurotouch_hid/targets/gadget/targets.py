"""The gadget's functions as :class:`~neurotouch_hid.stages.Target` s: ``/dev/hidgN`` nodes and the
XInput pad on FunctionFS.

* :class:`HidgTarget`: one ``hid`` function (the joystick, the Switch pad, the keyboard, the
  mouse). Reports go to ``/dev/hidgN`` (opened non-blocking) through a
  :class:`~neurotouch_hid.targets.gadget.writer.ReportWriter`; the host's output reports (a
  keyboard's LEDs, HORI's vendor report) are read from the same node when it is readable, at
  most :data:`MAX_OUTPUT_REPORT` bytes a read (Documentation/usb/gadget_hid.rst).
* :class:`XInputTarget`: the Xbox 360 pad (interface FF/5D/01, interrupt IN 0x81 and OUT 0x02) on
  a FunctionFS mount: descriptors and strings written to ``ep0``, then ``ep1`` (IN) and ``ep2``
  (OUT) opened (Documentation/usb/functionfs.rst). Two daemon threads read, bounded: ``ep0``'s
  events (a SETUP request for the function is refused by a stall, as functionfs.rst says: I/O
  in the wrong direction) and ``ep2``'s output reports, whose rumble and LED requests
  (:func:`~neurotouch_hid.targets.reports.xinput.parse_output`) become
  :class:`~neurotouch_hid.stages.Feedback`, announced on a pipe (:meth:`XInputTarget.fileno`).

Whatever stops the driver, :meth:`close` sends the neutral report first and waits up to
:data:`NEUTRAL_WAIT_S` for the host to take it.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from neurotouch_hid.controller import ControllerState, Feedback
from neurotouch_hid.errors import DeviceError
from neurotouch_hid.targets.gadget import functionfs
from neurotouch_hid.targets.gadget.writer import QUEUE_MOTION, QUEUE_STATE, ReportWriter

if TYPE_CHECKING:
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.targets.reports import ReportFormat

log = logging.getLogger(__name__)

#: Largest output report read from the host in one read (bytes); longer ones are cut there.
MAX_OUTPUT_REPORT = 64
#: How long :meth:`close` waits for the host to take the neutral report (s).
NEUTRAL_WAIT_S = 0.5
#: Feedback requests kept until :meth:`XInputTarget.feedback` takes them; older ones are dropped.
MAX_PENDING_FEEDBACK = 64
#: Pause after a failed read of ep0 or the OUT endpoint (the host went away) before the next (s).
ERROR_PAUSE_S = 0.05
#: The XInput pad's endpoints: interrupt IN 0x81 (32 bytes every 4 ms) and OUT 0x02 (every 8 ms),
#: as a wired Xbox 360 controller declares them.
XINPUT_ENDPOINTS = (functionfs.Endpoint(0x81, interval=4), functionfs.Endpoint(0x02, interval=8))


class _ReportTarget:
    """What both targets share: reports packed from the state, queued on a
    :class:`~neurotouch_hid.targets.gadget.writer.ReportWriter` only when they change (a mouse's
    motion always), the neutral report on :meth:`neutralise` and first in :meth:`close`."""

    def _start(self, fd: int, fmt: ReportFormat, what: str) -> None:
        self.what = what
        self.format = fmt
        self._motion = fmt.name == "mouse"
        depth = QUEUE_MOTION if self._motion else QUEUE_STATE
        self._writer = ReportWriter(fd, what, depth=depth, resend=not self._motion)
        self._last: bytes | None = None
        self._lock = threading.Lock()
        self._closed = False
        self.neutralise()

    def write(self, state: ControllerState) -> None:
        """Queue ``state``'s report when it differs from the last one (a mouse's motion always)."""
        report = self.format.pack(state)
        with self._lock:
            if self._closed or (report == self._last and not (self._motion and any(state.rel.values()))):
                return
            self._last = report
            self._writer.submit(report)

    def neutralise(self) -> None:
        """Queue the neutral report now."""
        with self._lock:
            if not self._closed:
                self._last = self.format.neutral()
                self._writer.submit(self._last)

    #: Said on each profile readied: what of it the gadget cannot carry (set by the gadget on its
    #: first target; :func:`~neurotouch_hid.targets.gadget.say_what_cannot_go`).
    lacks: Callable[[Profile], object] | None = None

    def prepare(self, profile: Profile) -> None:
        """The function's report layout is the same for every profile; what of ``profile`` the
        gadget cannot carry is said (:attr:`lacks`)."""
        if self.lacks is not None:
            self.lacks(profile)

    def _close_neutral(self) -> bool:
        """Send the neutral report, wait up to :data:`NEUTRAL_WAIT_S` for the host to take it,
        stop the writer; False when already closed."""
        with self._lock:
            if self._closed:
                return False
            self._last = self.format.neutral()
            self._writer.submit(self._last)
            self._closed = True
        if not self._writer.flush(NEUTRAL_WAIT_S):
            log.info("%s: the host did not take the neutral report within %.1f s", self.what, NEUTRAL_WAIT_S)
        self._writer.stop()
        return True


def _why_not(number: int | None) -> str:
    """Why a ``/dev/hidgN`` would not open, and the fix, by the open's errno: EPERM is a device
    policy (the device cgroup: a systemd unit's ``DevicePolicy=``, Documentation/admin-guide/
    cgroup-v1/devices.rst), not the node's owner, which is EACCES."""
    if number == errno.ENOENT:
        return "no such node: the gadget is not set up (or not bound)\nsudo neurotouch-hid gadget setup --user $USER"
    if number == errno.EPERM:
        return (
            "a device policy denies it (a systemd unit's DevicePolicy=closed without DeviceAllow=char-hidg rw, "
            "which packaging/neurotouch-hid.service has)"
        )
    return "the gadget's device nodes are not this user's\nsudo neurotouch-hid gadget setup --user $USER"


class HidgTarget(_ReportTarget):
    """One ``hid`` function's ``/dev/hidgN`` (module docstring), fed with ``format``'s reports.

    Raises:
        DeviceError: the node cannot be opened (missing, or not this user's: the fix says how).
    """

    def __init__(self, node: str | os.PathLike, fmt: ReportFormat, what: str):
        try:
            self._fd = os.open(node, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            raise DeviceError(f"cannot open {node} ({exc.strerror}): {_why_not(exc.errno)}") from None
        self._start(self._fd, fmt, what)

    def fileno(self) -> int | None:
        """The node: readable when the host sent an output report."""
        return None if self._closed else self._fd

    def guarded(self) -> tuple[int, bytes]:
        """The node's descriptor and its neutral report, for the guard that sends it if the
        driver dies (:class:`~neurotouch_hid.guard.Guard`)."""
        return self._fd, self.format.neutral()

    def feedback(self) -> list[Feedback]:
        """Read the host's output reports waiting on the node (bounded: at most 16 reads of
        :data:`MAX_OUTPUT_REPORT` bytes), each parsed by the function's format
        (:meth:`~neurotouch_hid.targets.reports.ReportFormat.parse_output`: a keyboard's LED
        report as a ``"keyboard_leds"`` :class:`Feedback`); one that asks nothing is logged only."""
        out = []
        for _ in range(16):
            try:
                data = os.read(self._fd, MAX_OUTPUT_REPORT)
            except OSError:
                break
            if not data:
                break
            received = self.format.parse_output(data)
            if not received:
                log.debug("%s: output report %s from the host", self.what, data.hex())
            out += [dataclasses.replace(request, source=self.what) for request in received]
        return out

    def close(self) -> None:
        """Neutral report, wait for the host to take it (up to :data:`NEUTRAL_WAIT_S`), close the node."""
        if self._close_neutral():
            os.close(self._fd)


class XInputTarget(_ReportTarget):
    """The Xbox 360 pad on the FunctionFS mount ``mount`` (module docstring).

    ``ready`` (set once the descriptors are written) lets the caller bind the gadget to its UDC:
    a configfs gadget with a FunctionFS function binds only then.

    Raises:
        DeviceError: ``mount``'s ``ep0`` cannot be opened, or the kernel refused the descriptors.
    """

    def __init__(self, mount: str | os.PathLike, fmt: ReportFormat, what: str = "USB gadget (xinput)"):
        from neurotouch_hid.targets.reports.xinput import INTERFACE_CLASS

        mount = Path(mount)
        try:
            self._ep0 = os.open(mount / "ep0", os.O_RDWR | os.O_CLOEXEC)
        except OSError as exc:
            raise DeviceError(
                f"cannot open {mount / 'ep0'} ({exc.strerror}): the XInput gadget is not set up for this user\n"
                "sudo neurotouch-hid gadget setup --protocol xinput --user $USER"
            ) from None
        try:
            os.write(self._ep0, functionfs.descriptors(INTERFACE_CLASS, XINPUT_ENDPOINTS))
            os.write(self._ep0, functionfs.strings("Xbox 360 pad (NeuroTouch)"))
            self._in = os.open(mount / "ep1", os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)
            self._out = os.open(mount / "ep2", os.O_RDWR | os.O_CLOEXEC)
        except OSError as exc:
            os.close(self._ep0)
            raise DeviceError(f"{mount}: the kernel refused the XInput pad's descriptors ({exc.strerror})") from None
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._pending: list[Feedback] = []
        self.enabled = threading.Event()
        self._start(self._in, fmt, what)
        for target, name in ((self._read_events, "ep0 events"), (self._read_out, "OUT endpoint")):
            threading.Thread(target=target, name=f"{what}: {name}", daemon=True).start()

    def fileno(self) -> int | None:
        """A pipe that becomes readable when the host sent rumble or LED requests."""
        return None if self._closed else self._wake_r

    def feedback(self) -> list[Feedback]:
        """The host's rumble and LED requests that arrived since the last call."""
        try:
            os.read(self._wake_r, 4096)
        except OSError:
            pass
        with self._lock:
            taken, self._pending = self._pending, []
        return taken

    def close(self) -> None:
        """Neutral report, wait for the host to take it (up to :data:`NEUTRAL_WAIT_S`), then
        close the endpoints and ``ep0``: FunctionFS then unbinds the gadget from its UDC (a
        thread blocked in a read keeps its file until that read returns, at the unbind)."""
        if not self._close_neutral():
            return
        for fd in (self._in, self._out, self._ep0, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def _announce(self, request: Feedback) -> None:
        with self._lock:
            self._pending = [*self._pending[-(MAX_PENDING_FEEDBACK - 1) :], request]
        try:
            os.write(self._wake_w, b"\0")
        except OSError:
            pass  # the pipe is full: the reader is already told

    def _read_loop(self, fd: int, size: int, where: str, handle: Callable[[bytes], None]) -> None:
        """Thread: read at most ``size`` bytes at a time from ``fd`` and ``handle`` them, until
        the function is closed; a read the kernel refuses meanwhile (host gone) is retried after
        :data:`ERROR_PAUSE_S`."""
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
                self._stall(event)

    def _stall(self, event: functionfs.Event) -> None:
        """Refuse a control request the pad does not answer: I/O in the wrong direction on
        ``ep0`` stalls it (functionfs.rst)."""
        log.debug("%s: refusing request %02x/%02x", self.what, event.request_type, event.request)
        try:
            if event.request_type & 0x80:
                os.read(self._ep0, 0)
            else:
                os.write(self._ep0, b"")
        except OSError:
            pass  # EL2HLT: the stall done

    def _read_out(self) -> None:
        """OUT endpoint reader: one read a packet (its wMaxPacketSize, 32 bytes: a longer read would
        join a full packet and the next, whose report would be lost)."""
        from neurotouch_hid.targets.reports.xinput import MAX_OUTPUT_REPORT as PACKET

        self._read_loop(self._out, PACKET, "OUT endpoint", self._on_output)

    def _on_output(self, data: bytes) -> None:
        received = self.format.parse_output(data)
        for request in received:
            self._announce(dataclasses.replace(request, source=self.what))
        if not received:
            log.debug("%s: output report %s not understood", self.what, data[:MAX_OUTPUT_REPORT].hex())
