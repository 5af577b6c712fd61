"""The Xbox 360 pad through the legacy GadgetFS (``gadgetfs.ko``): the whole configuration
descriptor written by user space, so the 17-byte descriptor of type 0x21 follows the FF/5D/01
interface as on a real wired pad (FunctionFS refuses a class descriptor after a vendor interface).

GadgetFS (drivers/usb/gadget/legacy/inode.c, include/uapi/linux/usb/gadgetfs.h) is a file system
mounted at ``/dev/gadget``: one file named after the UDC takes, in one write, the tag 0, the full-
speed configuration descriptor (with every interface, class and endpoint descriptor), an optional
high-speed one and the device descriptor; the gadget then binds to that UDC. A wired pad is a
full-speed device: no high-speed configuration is written, so the UDC runs at full speed and the
host reads the wired pad's configuration descriptor (GadgetFS's ``max_speed``). The same file
gives the events (12 bytes each: an 8-byte setup packet or the speed, then the type: connect,
disconnect, setup, suspend) and answers control requests as FunctionFS's ep0 does (a write for a
request that reads, a read for one that writes, I/O in the wrong direction stalls). Each endpoint
is a file named after the UDC's endpoint (``ep1in-bulk`` on dummy_hcd, ``ep1in`` on dwc2), enabled
by writing the tag 1 and its full- and high-speed endpoint descriptors once the host set the
configuration (the speed is known then; GadgetFS waits for the request's acknowledgement before
the host goes on); then its reads and writes are the transfers. A bus reset or a disconnect ends
the configuration: the transfers under way fail, the files are closed, and the next
SET_CONFIGURATION opens them again (as GadgetFS's own example, usb.c, does).

The UDC's file supports poll(2) (inode.c, ``ep0_poll``: readable while events are queued); the
endpoint files do not (their reads and writes wait in the kernel until the host's transfer). So
the events are read and answered on the run's loop, with the rumble and LED requests the OUT
endpoint's reader thread announces: :meth:`GadgetFsXInputTarget.fileno` is an epoll descriptor
over both, readable when either is; the OUT endpoint keeps its reader thread and the IN endpoint
its report writer. GadgetFS refuses a
configuration that asks for remote wake-up (``is_valid_config``), so bmAttributes is 0x80 where a
real pad has 0xA0. Closing the UDC's file unbinds the gadget: the host sees the pad unplugged.

A transfer on an endpoint file waits for the host in the kernel holding that endpoint's lock
(``ep_io``), and unbinding the gadget waits for that lock (``destroy_ep_files``): a read of the
OUT endpoint, or a report the host does not read, would make closing the UDC's file hang for
ever (seen in Debian 12's 6.1 on dummy_hcd, whose unbind does not cancel them). So when a
configuration ends (and before the UDC's file closes) the endpoints' descriptor numbers are
pointed at /dev/null and the threads still in a transfer get :data:`INTERRUPT`, a signal with a
handler that does nothing: the kernel cancels the transfer (EINTR), Python tries the read or the
write again on /dev/null, which returns at once, and the endpoint's file closes.

The descriptors are a wired Xbox 360 controller's first interface (045e:028e; the 0x21
descriptor's bytes as the wired pad's configuration dumps give them, e.g. the one GP2040-CE's and
the 360 raw-gadget projects copy), without the audio, plug-in and security interfaces.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import select
import signal
import struct
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from neurotouch_hid.core.controller import Feedback
from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.targets.closing import RELEASE_GRACE_S
from neurotouch_hid.targets.gadget.ffs import xinput_answer
from neurotouch_hid.targets.gadget.functionfs import Event
from neurotouch_hid.targets.gadget.targets import _Announced, _ReportTarget

if TYPE_CHECKING:
    from neurotouch_hid.targets.reports import ReportFormat

log = logging.getLogger(__name__)

#: Where GadgetFS is mounted.
ROOT = Path("/dev/gadget")
#: ``struct usb_gadgetfs_event``: the setup packet (or the speed), the type (u32).
EVENT = struct.Struct("<BBHHHI")
#: Event types (``enum usb_gadgetfs_event_type``).
NOP, CONNECT, DISCONNECT, SETUP, SUSPEND = range(5)
#: The pad's endpoints: interrupt IN 1 and OUT 2, 32 bytes, every 4 and 8 ms at full speed.
IN_ADDRESS, OUT_ADDRESS, PACKET = 0x81, 0x02, 32
#: The 17-byte descriptor of type 0x21 after the FF/5D/01 interface of a wired pad, which names
#: its IN and OUT endpoints (bytes 6 and 13).
XINPUT_CLASS_DESCRIPTOR = bytes(
    [0x11, 0x21, 0x00, 0x01, 0x01, 0x25, IN_ADDRESS, 0x14, 0x00, 0x00, 0x00, 0x00, 0x13, OUT_ADDRESS, 0x08, 0x00, 0x00]
)
#: Pause after a failed read before the next (s).
ERROR_PAUSE_S = 0.05
#: The signal that ends a transfer the host will never finish (module docstring): a real-time
#: signal, left to applications by the C library, with a handler that does nothing.
INTERRUPT = signal.SIGRTMIN + 4
#: Longest time the threads of an ended configuration are interrupted for (s), 10 ms apart.
UNBLOCK_S = 2.0
#: Longest wait for an endpoint's file that the last configuration left busy (s); well inside the
#: 5 s a host gives SET_CONFIGURATION.
BUSY_WAIT_S = 1.0
#: Most reads of the UDC's file in one call of ``feedback`` (4 events each): the loop's other
#: descriptors are served between, and it comes back while events are queued.
MAX_EVENT_READS = 8


def endpoint_descriptor(address: int, interval_ms: int, high_speed: bool) -> bytes:
    """A 7-byte interrupt endpoint descriptor (USB 2.0, 9.6.6) of :data:`PACKET` bytes; at high
    speed the interval in 2^(n-1) microframes."""
    interval = max(1, (interval_ms * 8).bit_length()) if high_speed else interval_ms
    return struct.pack("<BBBBHB", 7, 0x05, address, 0x03, PACKET, interval)


def configuration() -> bytes:
    """The full-speed configuration descriptor with its interface, the 0x21 descriptor and the
    endpoints (49 bytes): one interface FF/5D/01, bus powered, 500 mA, no remote wake-up (module
    docstring), the endpoints polled every 4 and 8 ms."""
    interface = bytes([9, 0x04, 0, 0, 2, 0xFF, 0x5D, 0x01, 0])
    body = (
        interface
        + XINPUT_CLASS_DESCRIPTOR
        + endpoint_descriptor(IN_ADDRESS, 4, False)
        + endpoint_descriptor(OUT_ADDRESS, 8, False)
    )
    return struct.pack("<BBHBBBBB", 9, 0x02, 9 + len(body), 1, 1, 0, 0x80, 0xFA) + body


def device_descriptor(vendor: int, product: int, release: int) -> bytes:
    """The 18-byte device descriptor: class FF/FF/FF as a wired pad's, strings 1-3, one
    configuration (GadgetFS sets bMaxPacketSize0 to the UDC's ep0)."""
    return struct.pack("<BBHBBBBHHHBBBB", 18, 0x01, 0x0200, 0xFF, 0xFF, 0xFF, 8, vendor, product, release, 1, 2, 3, 1)


def string_descriptor(text: str) -> bytes:
    """A string descriptor (USB 2.0, 9.6.7): UTF-16LE, at most 126 characters."""
    data = text[:126].encode("utf-16-le")
    return bytes([2 + len(data), 0x03]) + data


def endpoint_file(root: Path, number: int, direction: str) -> Path:
    """The UDC's endpoint file for endpoint ``number`` in ``direction`` (``in``/``out``):
    ``ep1in-bulk`` (dummy_hcd), ``ep1in`` (dwc2). Raises DeviceError when it has none."""
    pattern = re.compile(rf"ep{number}{direction}(-.*)?$")
    found = sorted(p for p in root.iterdir() if pattern.match(p.name))
    if not found:
        raise DeviceError(f"{root}: this USB device controller has no endpoint {number} {direction}")
    return found[0]


class GadgetFsXInputTarget(_Announced, _ReportTarget):
    """The Xbox 360 pad on GadgetFS mounted at ``root`` (module docstring), with the strings
    ``manufacturer``, ``product``, ``serial``. Its events are answered in :meth:`feedback`,
    called by the run's loop when :meth:`fileno` is readable (the host's enumeration waits for
    it: the driver's loop serves it from the pad's making on).

    Raises:
        DeviceError: no UDC file in ``root``, or the kernel refused the descriptors.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        fmt: ReportFormat,
        ids: tuple[int, int, int],
        strings: tuple[str, str, str],
        what: str = "USB gadget (xinput, GadgetFS)",
    ):
        root = Path(root)
        udc = sorted(p for p in root.iterdir() if not p.name.startswith("ep")) if root.is_dir() else []
        if not udc:
            raise DeviceError(f"{root}: no GadgetFS here (sudo modprobe gadgetfs; sudo mount -t gadgetfs none {root})")
        self.root, self._strings = root, strings
        self._dev = os.open(udc[0], os.O_RDWR | os.O_CLOEXEC)
        try:
            os.write(
                self._dev,
                struct.pack("<I", 0) + configuration() + device_descriptor(*ids),
            )
        except OSError as exc:
            os.close(self._dev)
            raise DeviceError(f"{udc[0]}: the kernel refused the Xbox 360 pad's descriptors ({exc.strerror})") from None
        # The endpoints keep these two descriptor numbers for the pad's life: while the host has
        # not configured it they stand for /dev/null, and an endpoint's file is put in their place
        # (dup2) once enabled, so that the report writer never holds a number that a closed file
        # left for another to take.
        self._null = os.open(os.devnull, os.O_RDWR | os.O_CLOEXEC)
        self._in, self._out = os.dup(self._null), os.dup(self._null)
        self._configured = False
        self._generation = 0  # one more at each configuration and at each end of one
        self._reader: threading.Thread | None = None
        self._reading = False  # the reader is in a read (so alive: a signal finds it)
        self._can_interrupt = _install_interrupt()
        self._open_announcements()
        # what the loop waits on: the UDC's file (its events) and the announcements' pipe
        self._ready = select.epoll()
        self._ready.register(self._dev, select.EPOLLIN)
        self._ready.register(self._wake_r, select.EPOLLIN)
        self._events_ready = select.poll()
        self._events_ready.register(self._dev, select.POLLIN)
        self.connected = threading.Event()
        self._start(self._in, fmt, what, gate=self.connected)

    def fileno(self) -> int | None:
        """An epoll descriptor, readable when the host sent a request or an event (a connect, a
        reset) to the UDC's file, or rumble or LED requests on the OUT endpoint."""
        return None if self._closed else self._ready.fileno()

    def feedback(self) -> list[Feedback]:
        """The loop: the events queued on the UDC's file read and answered (the host's control
        requests, its SET_CONFIGURATION enabling the endpoints: :meth:`_enable`, which may wait
        up to :data:`BUSY_WAIT_S`; a reset or disconnect: :meth:`_disable`, up to
        :data:`UNBLOCK_S`), then the rumble and LED requests that arrived since the last call."""
        for _ in range(MAX_EVENT_READS):
            if self._closed or not any(mask & select.POLLIN for _, mask in self._events_ready.poll(0)):
                break  # (a poll that says only POLLHUP, an aborted request, has cleared it)
            try:
                data = os.read(self._dev, 4 * EVENT.size)
            except OSError as exc:
                log.debug("%s: events: %s", self.what, exc)
                break
            self._handle_events(data)
        return self._take_announced()

    def close(self) -> None:
        """Neutral report, taken twice by the host (its driver handled the first,
        ``_close_neutral``), then :data:`RELEASE_GRACE_S` for the host's readers to read it, then
        close the endpoints and the UDC's file (its owner no longer asks for :meth:`feedback`):
        GadgetFS unbinds the gadget (``dev_release``) and the host sees the pad unplugged."""
        if not self._close_neutral(twice=True):
            return
        # The order matters: closing the UDC's file unbinds the pad at once, and evdev then drops
        # what its readers had not read (a read answers ENODEV). The neutral report reaches xpad
        # after the writer's write returned (2-21 ms in the test kernel) and a reader after that
        # (3-17 ms): without this pause the pad was unbound 16-102 ms after xpad had the report,
        # with nothing meant to wait for the readers between, and a loaded machine's reader lost
        # it. Nothing else waits for the host here: the UDC's events are the run's loop's, which
        # stopped before the engine's neutral report.
        time.sleep(RELEASE_GRACE_S)
        self._disable()  # no transfer left under way: the UDC's file can close (module docstring)
        self._generation += 1
        self._ready.close()
        for fd in (self._in, self._out, self._dev, self._null):
            try:
                os.close(fd)
            except OSError:
                pass
        self._close_announcements()

    def _enable(self) -> None:
        """Open and enable the two endpoints once the host set the configuration (GadgetFS's
        own example does it there, before the request is acknowledged: the host's next request
        waits for it), put them in place and start the OUT endpoint's reader. A second
        SET_CONFIGURATION without a reset between keeps the endpoints as they are.

        Raises:
            OSError: an endpoint would not open or enable (the files opened are closed).
        """
        if self._configured:
            return
        opened: list[int] = []
        try:
            for address, interval in ((IN_ADDRESS, 4), (OUT_ADDRESS, 8)):
                fd = _open_endpoint(endpoint_file(self.root, address & 0x0F, "in" if address & 0x80 else "out"))
                opened.append(fd)
                fs, hs = (endpoint_descriptor(address, interval, speed) for speed in (False, True))
                os.write(fd, struct.pack("<I", 1) + fs + hs)
        except (OSError, DeviceError):
            for fd in opened:
                os.close(fd)  # an endpoint's file stays busy while it is open
            raise
        os.dup2(opened[0], self._in, inheritable=False)
        os.dup2(opened[1], self._out, inheritable=False)
        for fd in opened:
            os.close(fd)
        self._configured = True
        self._generation += 1
        self.connected.set()
        self._reader = threading.Thread(
            target=self._read_out, args=(self._generation,), name=f"{self.what}: OUT endpoint", daemon=True
        )
        self._reader.start()

    def _disable(self) -> None:
        """The configuration ended (disconnect, bus reset, SET_CONFIGURATION 0): no more
        reports, the endpoints' numbers back to /dev/null. The endpoints' files close once
        their last transfer returns (the reset cancelled it) and GadgetFS disables them then."""
        self.connected.clear()
        if not self._configured:
            return
        self._configured = False
        self._generation += 1
        os.dup2(self._null, self._in, inheritable=False)
        os.dup2(self._null, self._out, inheritable=False)
        self._unblock()

    def _unblock(self) -> None:
        """Interrupt the OUT endpoint's reader and the report writer while they are still in a
        transfer of the configuration that ended (module docstring); said on the log when they
        stay in one (then closing the UDC's file may hang)."""
        deadline = time.monotonic() + UNBLOCK_S
        while True:
            busy = [self._reader.ident] if self._reader is not None and self._reading else []
            busy += [self._writer.thread_id] if self._writer.writing else []
            if not busy:
                return
            if not self._can_interrupt or time.monotonic() > deadline:
                log.warning("%s: a transfer of the last configuration is still under way", self.what)
                return
            for ident in busy:
                try:
                    signal.pthread_kill(ident, INTERRUPT)
                except (ProcessLookupError, TypeError):
                    pass
            time.sleep(0.01)

    def _handle_events(self, data: bytes) -> None:
        """The events read from the UDC's file (:data:`EVENT` each), in order."""
        for request_type, request, value, index, length, kind in EVENT.iter_unpack(data[: len(data) // 12 * 12]):
            try:
                if kind in (CONNECT, DISCONNECT):  # a connect purges a disconnect still queued
                    self._disable()
                elif kind == SETUP:
                    self._setup(Event(4, request_type, request, value, index, length))
            except OSError as exc:
                log.info("%s: event %d: %s", self.what, kind, exc)

    def answer(self, event: Event) -> bytes | None:
        """The answer to a request GadgetFS hands over: string descriptors, GET_STATUS,
        GET_INTERFACE, SET_INTERFACE and SET_CONFIGURATION (acknowledged), the vendor requests
        ``C1 01`` (:func:`~neurotouch_hid.targets.gadget.ffs.xinput_answer`); None: stall."""
        if event.request_type == 0x80 and event.request == 0x06 and event.value >> 8 == 0x03:
            index = event.value & 0xFF
            if index == 0:
                return b"\x04\x03\x09\x04"[: event.length]
            if 1 <= index <= len(self._strings):
                return string_descriptor(self._strings[index - 1])[: event.length]
            return None
        if event.request == 0x00 and event.request_type in (0x80, 0x81, 0x82):
            return b"\x00\x00"[: event.length]
        if event.request_type == 0x81 and event.request == 0x0A:
            return b"\x00"[: event.length]
        if (event.request_type, event.request) in ((0x00, 0x09), (0x01, 0x0B)):
            return b""
        return xinput_answer(event)

    def _setup(self, event: Event) -> None:
        if (event.request_type, event.request) == (0x00, 0x09):
            try:
                self._enable() if event.value else self._disable()
            except (OSError, DeviceError) as exc:  # acknowledged all the same: GadgetFS forbids stalling it
                log.warning("%s: the endpoints were not enabled: %s", self.what, exc)
        reply = self.answer(event)
        reads = bool(event.request_type & 0x80)
        try:
            if reply is None:
                os.read(self._dev, 0) if reads else os.write(self._dev, b"")
            elif reads:
                os.write(self._dev, reply)
            else:
                os.read(self._dev, event.length)
        except OSError as exc:
            if reply is not None:
                log.debug("%s: request %02x/%02x: %s", self.what, event.request_type, event.request, exc)

    def _read_out(self, generation: int) -> None:
        """The host's output reports (rumble, LEDs) while this configuration lasts. Any error
        ends it: a read tried again after a reset, before the events thread saw it, would wait
        on the old configuration's endpoint and keep its file busy for the next one."""
        from neurotouch_hid.targets.reports.xinput import parse_output

        while not self._closed and generation == self._generation:
            self._reading = True
            try:
                data = os.read(self._out, PACKET)
            except OSError as exc:
                log.debug("%s: OUT endpoint: %s", self.what, exc)
                return
            finally:
                self._reading = False
            if generation != self._generation:
                return  # /dev/null's end of file, or the last report of an ended configuration
            request = parse_output(data, self.what) if data else None
            if request is not None:
                self._announce([request])


def _install_interrupt() -> bool:
    """Give :data:`INTERRUPT` its handler that does nothing, unless it has one already: True
    when it has ours (a signal handler is set in the main thread only; elsewhere: False, unless
    a pad made in the main thread set it before)."""
    current = signal.getsignal(INTERRUPT)
    if current is _interrupted:
        return True
    if current not in (signal.SIG_DFL, None) or threading.current_thread() is not threading.main_thread():
        return False
    signal.signal(INTERRUPT, _interrupted)
    return True


def _interrupted(signum: int, frame: object) -> None:
    """:data:`INTERRUPT`'s handler: nothing; its delivery ends the transfer (module docstring)."""


def _open_endpoint(path: Path) -> int:
    """Open an endpoint's file; while the last configuration's file of it has not closed yet
    (its transfer returning from the reset), GadgetFS says EBUSY: tried again for up to
    :data:`BUSY_WAIT_S`.

    Raises:
        OSError: it would not open.
    """
    deadline = time.monotonic() + BUSY_WAIT_S
    while True:
        try:
            return os.open(path, os.O_RDWR | os.O_CLOEXEC)
        except OSError as exc:
            if exc.errno != errno.EBUSY or time.monotonic() > deadline:
                raise
            time.sleep(ERROR_PAUSE_S / 5)


def mount(root: Path = ROOT) -> bool:
    """Load ``gadgetfs`` and mount it at ``root`` (root only); True when this call mounted it.

    Raises:
        DeviceError: the kernel has no GadgetFS, or the mount failed.
    """
    import subprocess

    subprocess.run(["modprobe", "gadgetfs"], check=False, capture_output=True)
    if os.path.ismount(root):
        return False
    root.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "gadgetfs", "gadgetfs", str(root)], check=False, capture_output=True)
    if done.returncode:
        try:
            root.rmdir()
        except OSError:
            pass
        raise DeviceError(f"mounting GadgetFS at {root} failed: {done.stderr.decode(errors='replace').strip()}")
    return True


def unmount(root: Path = ROOT, tries: int = 30) -> None:
    """Unmount GadgetFS at ``root`` (retried 0.1 s apart while a closed file's last read returns)
    and remove the folder."""
    import subprocess

    for _ in range(tries):
        if not os.path.ismount(root):
            break
        subprocess.run(["umount", str(root)], check=False, capture_output=True)
        time.sleep(0.1)
    try:
        root.rmdir()
    except OSError:
        pass
