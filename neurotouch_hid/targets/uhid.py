"""A HID device on this machine made from user space through ``/dev/uhid``: the kernel's HID
drivers bind to it (hid-generic for the joystick), and it appears as an input device (evdev) and a
``/dev/hidrawN`` node that hidapi, SDL's HIDAPI drivers and Steam read.

The interface is the kernel's Documentation/hid/uhid.rst and include/uapi/linux/uhid.h, written
in ``uhid_events.py`` as the packed little-endian ``struct uhid_event`` (a u32 type, then the request): the device
is made with ``UHID_CREATE2`` (name, phys, uniq, bus BUS_USB, vendor, product, version, the report
descriptor), fed with ``UHID_INPUT2`` (one input report each) and removed with ``UHID_DESTROY``.
The kernel answers with ``UHID_START`` when a HID driver binds (input reports are refused before
it: EINVAL) and ``UHID_STOP`` when it unbinds, ``UHID_OPEN``/``UHID_CLOSE`` as readers come and
go, ``UHID_OUTPUT`` with an output report, and ``UHID_GET_REPORT``/``UHID_SET_REPORT`` requests
that must be answered (``*_REPLY`` with the request's id; uhid.rst: the kernel gives up after 5 s
and the caller gets EIO). Every event the kernel sends is read by one reader,
:func:`read_event`, bounded to the struct's size and its data fields to ``UHID_DATA_MAX``, in
batches of :data:`EVENT_BATCH`, at most :data:`HOST_EVENTS_PER_S` a second and
:data:`HOST_CPU_SHARE` of a core (a flooding host waits; :meth:`UhidDevice.feedback`).

:class:`UhidDevice` is a :class:`~neurotouch_hid.core.stages.Target`: it writes a state's report only
when the report changed, keeps the last one while no driver is bound and sends it when one
binds (``UHID_START``) or a reader opens it (``UHID_OPEN``: a driver rebound, a game started),
answers a GET_REPORT of its input report with the current report and of each feature report of
its format (:attr:`~neurotouch_hid.targets.reports.ReportFormat.feature_ids`) with
:meth:`~neurotouch_hid.targets.reports.ReportFormat.feature` (other requests with EIO), reads the
host's output reports (``UHID_OUTPUT``, and a SET_REPORT of an output report, answered 0) through
:meth:`~neurotouch_hid.targets.reports.ReportFormat.parse_output` into
:class:`~neurotouch_hid.core.controller.Feedback`, and on ``close`` sends the
neutral report, waits ``RELEASE_GRACE_S`` for readers to see it, then destroys the device
(:class:`~neurotouch_hid.targets.closing.NeutralOnClose`, as the uinput devices do); a driver killed
without closing leaves that to its guard (:mod:`~neurotouch_hid.service.guard`), which holds a copy of the
descriptor. No library: hid-tools (GPL) is not used at run time.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import os
import select
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.errors import DeviceError, NeurotouchError
from neurotouch_hid.service.udev import char_device_problem, uhid_help
from neurotouch_hid.targets.closing import NeutralOnClose
from neurotouch_hid.targets.uhid_events import (
    _GET_REPORT_REPLY,
    _INPUT2,
    _SET_REPORT_REPLY,
    PHYS,
    UHID_CLOSE,
    UHID_DATA_MAX,
    UHID_DESTROY,
    UHID_DEV_NUMBERED_INPUT_REPORTS,
    UHID_FEATURE_REPORT,
    UHID_GET_REPORT,
    UHID_GET_REPORT_REPLY,
    UHID_INPUT2,
    UHID_INPUT_REPORT,
    UHID_OPEN,
    UHID_OUTPUT,
    UHID_OUTPUT_REPORT,
    UHID_SET_REPORT,
    UHID_SET_REPORT_REPLY,
    UHID_START,
    UHID_STOP,
    UhidEvent,
    create2_event,
    read_event,
)

if TYPE_CHECKING:
    from neurotouch_hid.core.stages import Feedback
    from neurotouch_hid.mapping.profile import DeviceSpec, Profile
    from neurotouch_hid.service.guard import Guard
    from neurotouch_hid.targets.identity import Identity
    from neurotouch_hid.targets.protocols import ProtocolRow
    from neurotouch_hid.targets.reports import ReportFormat

log = logging.getLogger(__name__)

#: it the device stays and its report is sent when a driver binds.
START_WAIT_S = 2.0
#: Most events from the kernel the device handles a second (OUTPUT, GET_REPORT, SET_REPORT, ...): a
#: game's rumble and a driver's requests are tens a second. A hidraw reader flooding it (output
#: writes, HIDIOCGINPUT) is answered at this rate and no faster: the call reading it sleeps
#: meanwhile (:data:`MAX_REST_S` at a time), a GET_REPORT's caller waits for its answer (one
#: request at a time per device), output reports beyond the kernel's queue (UHID_BUFSIZE, 32
#: events) are dropped by the kernel: a flood costs a bounded share of a core, not the pipeline's.
HOST_EVENTS_PER_S = 1000
#: Most events handled in one call of :meth:`UhidDevice.feedback` (one wake-up of the run's loop).
EVENT_BATCH = 64
#: Most of one core handling the kernel's events may take (the CPU time of the calls that handle
#: them, ``time.thread_time``, over the wall time): past it :meth:`UhidDevice.feedback` first
#: sleeps. :data:`HOST_EVENTS_PER_S` bounds how many events a flood gets answered, this what they
#: cost on any machine: in the emulated test kernel an event cost 0.5-1 ms, so that 1000 a second
#: took half a core (tests/kernel/checks_hostile.py).
HOST_CPU_SHARE = 0.1
#: Longest sleep of one :meth:`UhidDevice.feedback` call (s), for either bound: the call is made on
#: the run's one loop (:mod:`neurotouch_hid.engine.loop`), which serves the merged devices, the
#: control socket and the other targets between two calls, so a flood makes them wait this long
#: at most; what is still owed is slept at the next calls.
MAX_REST_S = 0.01

#: After UHID_START, how long the device waits for its driver's next request while the driver has
#: not read every feature report of the format yet (s): hid-playstation reads the DualSense's
#: pairing, firmware and calibration reports as it binds and gives each up after 5 s (uhid.rst),
#: before any reader of the device runs; a driver that reads none (hid-generic) costs this once.
PROBE_QUIET_S = 2.0


@dataclass(frozen=True)
class HidIdentity:
    """What the UHID device tells the system it is: name and USB ids (vendor, product, version),
    ``phys`` and ``uniq`` (the camera's, :class:`~neurotouch_hid.targets.identity.Identity`: SDL
    and Steam tell two devices of the same ids apart by them)."""

    name: str
    vendor: int
    product: int
    version: int
    phys: str = PHYS
    uniq: str = ""


#: The identity of the HID joystick when the profile names the Xbox 360 pad's ids: pid.codes'
#: vendor 0x1209 and its test product 0x0001 (https://pid.codes, for open hardware and software).
#: Hosts and SDL know 045e:028e as an Xbox 360 pad speaking XInput, and would read the generic
#: joystick's report with an Xbox 360 pad's mapping, so those ids are never given to it.
HID_DEFAULT = HidIdentity("NeuroTouch HID joystick", 0x1209, 0x0001, 0x0100)
_XBOX_360 = (0x045E, 0x028E)


def hid_identity(device: DeviceSpec, camera: Identity | None = None) -> HidIdentity:
    """The HID joystick's identity for a profile's ``device:`` section: its name and ids, unless
    they are the Xbox 360 pad's (every shipped profile's), which give :data:`HID_DEFAULT`'s ids
    (and its name when the profile's is the Xbox pad's own); ``phys`` and ``uniq`` from the
    camera's :class:`~neurotouch_hid.targets.identity.Identity` (None, or one without a serial:
    :data:`PHYS` and no uniq, as runs without a serial always had)."""
    where = {} if camera is None or not camera.serial else {"phys": camera.phys, "uniq": camera.uniq}
    if (device.vendor, device.product) != _XBOX_360:
        return HidIdentity(device.name, device.vendor, device.product, device.version, **where)
    name = HID_DEFAULT.name if "X-Box 360" in device.name else device.name
    return HidIdentity(name, HID_DEFAULT.vendor, HID_DEFAULT.product, HID_DEFAULT.version, **where)


def uhid_protocol(requested: str | None, profile: Profile) -> ProtocolRow:
    """The protocol of a UHID run: ``requested`` (``--protocol``) when given, else the profile's
    ``device: protocol`` when it runs on UHID, else ``hid`` (a profile written for a USB gadget's
    Switch or XInput pad still runs here, as the generic joystick).

    Raises:
        DeviceError: ``requested`` is unknown or does not run on UHID (the message lists those that do).
    """
    from neurotouch_hid.targets.protocols import DEFAULT_PROTOCOL, PROTOCOLS, protocol

    if requested is None:
        named = getattr(profile.device, "protocol", None)
        ok = named in PROTOCOLS and "uhid" in PROTOCOLS[named].transports
        requested = named if ok else DEFAULT_PROTOCOL
    try:
        return protocol(requested, "uhid")
    except NeurotouchError as exc:
        raise DeviceError(str(exc)) from None


def uhid_identity(row: ProtocolRow, device: DeviceSpec, camera: Identity | None = None) -> HidIdentity:
    """The UHID device's name and ids for the protocol ``row``: the profile's ``device:``
    (:func:`hid_identity`) where the row lets a profile choose them, else the row's own (a host
    driver binds by them); ``phys`` and ``uniq`` from ``camera`` as :func:`hid_identity` says,
    except that a row with feature reports (the DualSense's, whose pairing report carries the
    camera's MAC) always has that MAC as ``uniq``: the default identity's without a serial, as
    hid-playstation would set it anyway."""
    if row.profile_ids:
        return hid_identity(device, camera)
    where = {} if camera is None or not camera.serial else {"phys": camera.phys, "uniq": camera.uniq}
    if row.report.feature_ids:  # a device that tells its MAC (the DualSense): uniq is that MAC, always
        from neurotouch_hid.targets.identity import identity_for

        where["uniq"] = (camera or identity_for(None)).uniq
    return HidIdentity(row.product_name, row.vendor, row.product, row.bcd_device, **where)


def uhid_problem(devnode: str = "/dev/uhid") -> str | None:
    """Why ``devnode`` cannot be used to create a HID device (missing, not a character device,
    not readable and writable), or None when it can."""
    return char_device_problem(devnode, "uhid")


class UhidDevice(NeutralOnClose):
    """One UHID device speaking ``fmt`` (a :class:`~neurotouch_hid.targets.reports.ReportFormat`
    with a descriptor), as a :class:`~neurotouch_hid.core.stages.Target`.

    Args:
        fmt: the report format (its descriptor and :meth:`pack`).
        identity: name and USB ids (:func:`hid_identity`).
        devnode: the uhid node.
        start_wait_s: how long to wait for a HID driver to bind (UHID_START) before returning.
        camera: the camera's identity (:func:`~neurotouch_hid.targets.identity.identity_for`): what
            the feature reports carry (a MAC); None: the default one. (``phys`` and ``uniq`` are
            ``identity``'s.)
        guard: start a :class:`~neurotouch_hid.service.guard.Guard` with its own copy of the
            descriptor: if the driver dies without closing (SIGKILL), it sends the neutral report
            and keeps the device :data:`~neurotouch_hid.service.guard.LINGER_S` more for the
            readers to take it (the device goes with the last copy: without the guard the host's
            readers would last have read the held report, a DualSense's touch points active).

    Raises:
        DeviceError: ``devnode`` is missing or not writable (the message's next lines say how to
            fix it: :func:`~neurotouch_hid.service.udev.uhid_help`), or the kernel refuses the device.
    """

    def __init__(
        self,
        fmt: ReportFormat,
        identity: HidIdentity,
        devnode: str = "/dev/uhid",
        *,
        start_wait_s: float = START_WAIT_S,
        camera: Identity | None = None,
        guard: bool = True,
    ) -> None:
        problem = uhid_problem(devnode)
        if problem:
            raise DeviceError(f"{problem}\n{uhid_help()}")
        try:
            fd = os.open(devnode, os.O_RDWR | os.O_CLOEXEC | os.O_NONBLOCK)
        except OSError as exc:
            raise DeviceError(f"cannot open {devnode}: {exc.strerror}\n{uhid_help()}") from None
        self._begin(fd, fmt, identity, camera, start_wait_s, devnode)
        if guard:
            self._start_guard()

    @classmethod
    def on_fd(
        cls,
        fd: int,
        fmt: ReportFormat,
        identity: HidIdentity,
        *,
        start_wait_s: float = START_WAIT_S,
        camera: Identity | None = None,
    ) -> UhidDevice:
        """The device made on ``fd``, an open, non-blocking /dev/uhid descriptor (or what stands
        in for it: a SOCK_SEQPACKET socket keeps one event per read, as /dev/uhid does), owned
        from here on. Raises DeviceError as the constructor does."""
        device = cls.__new__(cls)
        device._begin(fd, fmt, identity, camera, start_wait_s, f"fd {fd}")
        return device

    def _begin(
        self, fd: int, fmt: ReportFormat, identity: HidIdentity, camera: Identity | None, wait_s: float, where: str
    ) -> None:
        from neurotouch_hid.targets.identity import identity_for

        self.fmt = fmt
        self.identity = identity
        self.camera = camera or identity_for(None)
        self.what = f"UHID {fmt.name} device"
        self._lock = threading.RLock()
        self._closed = False
        self.started = False  # a HID driver is bound (UHID_START .. UHID_STOP)
        self.opened = 0  # readers the kernel reported (UHID_OPEN - UHID_CLOSE)
        self.events = 0  # events read from the kernel
        self.dev_flags = 0  # UHID_START's UHID_DEV_NUMBERED_* flags
        self.asked: set[int] = set()  # the feature reports a driver or reader has asked for
        self._guard: Guard | None = None
        self._last = fmt.neutral()
        self._budget, self._budget_at = float(EVENT_BATCH), time.monotonic()  # events it may handle now
        self._spent, self._spent_since = 0.0, time.monotonic()  # CPU time handling events (s) since when
        self._fd = fd
        try:
            event = create2_event(
                fmt.descriptor,
                identity.name,
                vendor=identity.vendor,
                product=identity.product,
                version=identity.version,
                phys=identity.phys,
                uniq=identity.uniq,
            )
            os.write(self._fd, event)
        except DeviceError:
            os.close(self._fd)
            raise
        except OSError as exc:
            os.close(self._fd)
            raise DeviceError(f"the kernel refused to create the UHID device on {where}: {exc.strerror}") from None
        self._wait_for_start(wait_s)

    def _start_guard(self) -> None:
        """The guard of the ``guard`` argument (class docstring); a guard that cannot start is
        said, and the device works on without one."""
        from neurotouch_hid.service.guard import LINGER_S, Guard

        neutral = self.fmt.neutral()
        try:
            self._guard = Guard(
                [(self._fd, _INPUT2.pack(UHID_INPUT2, len(neutral)) + neutral)],
                linger_s=LINGER_S,
                what=f"the {self.what}",
            )
        except OSError as exc:
            log.warning("the %s's guard could not start (%s): if the driver is killed, the host's readers keep its "
                        "last report until the device goes", self.what, exc)  # fmt: skip

    def _wait_for_start(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while not self.started:
            left = end - time.monotonic()
            if left <= 0 or not select.select([self._fd], [], [], left)[0]:
                log.warning("no HID driver bound the %s within %.1f s; its reports wait for one", self.what, seconds)
                return
            self.feedback()
        # the bound driver may read the feature reports now, before this device's reader runs
        # (the run's loop): serve it here until it has them all or is quiet
        while not set(self.fmt.feature_ids) <= self.asked:
            if not select.select([self._fd], [], [], PROBE_QUIET_S)[0]:
                return
            self.feedback()

    def fileno(self) -> int | None:
        """The /dev/uhid descriptor: readable when the kernel sent an event."""
        return None if self._closed else self._fd

    def write(self, state: ControllerState) -> None:
        """Send ``state``'s input report (``UHID_INPUT2``) if it differs from the last one; while
        no driver is bound it is kept and sent when one binds. Nothing after :meth:`close`.

        Raises:
            DeviceError: the kernel refused the report for another reason than an unbound device.
        """
        report = self.fmt.pack(state)
        with self._lock:
            if self._closed or report == self._last:
                return
            self._last = report
            if self.started:
                self._send(report)

    def _send(self, report: bytes) -> None:
        try:
            os.write(self._fd, _INPUT2.pack(UHID_INPUT2, len(report)) + report)
        except OSError as exc:
            if exc.errno == errno.EINVAL:  # no driver bound (between STOP and START)
                self.started = False
                return
            raise DeviceError(f"writing to the {self.what} failed: {exc.strerror}") from None

    def neutralise(self) -> None:
        """Send the neutral report: sticks centred, triggers 0, hat centred, nothing pressed."""
        self.write(ControllerState.neutral())

    def prepare(self, profile: Profile) -> None:
        """Nothing: the device keeps its identity and layout for the whole run (programs keep their handle)."""

    def feedback(self) -> list[Feedback]:
        """Read the events the kernel queued (:func:`read_event`, non-blocking, at most
        :data:`EVENT_BATCH` per call) and handle them: START and OPEN send the current report,
        GET_REPORT and SET_REPORT are answered, OUTPUT is parsed. At most :data:`HOST_EVENTS_PER_S`
        are handled a second: past that the call first sleeps (at most :data:`MAX_REST_S`) and
        handles what that sleep allows; and handling them takes at most :data:`HOST_CPU_SHARE` of a
        core: past that the call first sleeps (:meth:`_rest`), and handles nothing while more is
        owed. Returns the rumble and LED requests of
        the output reports read (:meth:`~neurotouch_hid.targets.reports.ReportFormat.parse_output`),
        each with this device as its ``source``, the last of each kind only: a batch's earlier
        ones were already replaced by the host."""
        now = self._rest()
        if now is None:  # still owed: nothing handled before the next call
            return []
        self._budget = min(float(EVENT_BATCH), self._budget + (now - self._budget_at) * HOST_EVENTS_PER_S)
        self._budget_at = now
        if self._budget < 1:  # a flood: wait for what MAX_REST_S allows (the loop serves the rest meanwhile)
            wait = min((EVENT_BATCH - self._budget) / HOST_EVENTS_PER_S, MAX_REST_S)
            time.sleep(wait)
            self._budget, self._budget_at = self._budget + wait * HOST_EVENTS_PER_S, time.monotonic()
        latest: dict[str, Feedback] = {}
        cpu = time.thread_time()
        for _ in range(int(self._budget)):
            with self._lock:
                if self._closed:
                    break
                try:
                    event = read_event(self._fd)
                except BlockingIOError:
                    break
                except OSError as exc:
                    raise DeviceError(f"reading the {self.what}'s events failed: {exc.strerror}") from None
                self.events += 1
                self._budget -= 1
                for request in self._handle(event):
                    latest.pop(request.kind, None)
                    latest[request.kind] = request
        self._spent += time.thread_time() - cpu
        return [dataclasses.replace(request, source=self.what) for request in latest.values()]

    def _rest(self) -> float | None:
        """Sleep as long as keeps the CPU time the previous calls spent handling events at most
        :data:`HOST_CPU_SHARE` of the wall time since (at most :data:`MAX_REST_S` a call); the
        time now (``time.monotonic``), or None when more is owed (the rest at the next call,
        which handles nothing before). Only the handling is counted (the calling thread may do
        other work between calls): events at a game's pace never wait."""
        now = time.monotonic()
        owed = self._spent / HOST_CPU_SHARE - (now - self._spent_since)
        if owed > 0:
            rest = min(owed, MAX_REST_S)
            time.sleep(rest)
            now = time.monotonic()
            self._spent = (owed - rest) * HOST_CPU_SHARE  # not repaid yet: owed at the next call
        else:
            self._spent = 0.0
        self._spent_since = now
        return None if self._spent > 0 else now

    def _handle(self, event: UhidEvent) -> list[Feedback]:
        if event.type == UHID_START:
            self.started, self.dev_flags = True, event.dev_flags
            self._send(self._last)
        elif event.type == UHID_STOP:
            self.started = False
        elif event.type == UHID_OPEN:
            self.opened += 1
            if self.started:  # a reader (re)opened it, e.g. after its driver was rebound: the current state
                self._send(self._last)
        elif event.type == UHID_CLOSE:
            self.opened = max(0, self.opened - 1)
        elif event.type == UHID_GET_REPORT:
            answer = self._report(event.rtype, event.rnum)
            if answer is None:
                reply = _GET_REPORT_REPLY.pack(UHID_GET_REPORT_REPLY, event.id, errno.EIO, 0)
            else:
                reply = _GET_REPORT_REPLY.pack(UHID_GET_REPORT_REPLY, event.id, 0, len(answer)) + answer
            os.write(self._fd, reply)
        elif event.type == UHID_SET_REPORT:
            error = 0 if event.rtype == UHID_OUTPUT_REPORT else errno.EIO
            os.write(self._fd, _SET_REPORT_REPLY.pack(UHID_SET_REPORT_REPLY, event.id, error))
            if event.rtype == UHID_OUTPUT_REPORT:
                return self._parse(event.data)
        elif event.type == UHID_OUTPUT:
            return self._parse(event.data)
        else:
            log.debug("%s: event type %d ignored", self.what, event.type)
        return []

    def _report(self, rtype: int, rnum: int) -> bytes | None:
        """The answer to GET_REPORT(``rtype``, ``rnum``), None when there is none: the current
        input report (number 0, or its own id, byte 0, when START said the input reports are
        numbered), or a feature report of
        the format's ``feature_ids`` for :attr:`camera`."""
        numbered = bool(self.dev_flags & UHID_DEV_NUMBERED_INPUT_REPORTS)
        if rtype == UHID_INPUT_REPORT and rnum == (self._last[0] if numbered else 0):
            return self._last
        if rtype == UHID_FEATURE_REPORT and rnum in self.fmt.feature_ids:
            self.asked.add(rnum)
            return self.fmt.feature(rnum, self.camera)[:UHID_DATA_MAX]
        return None

    def _parse(self, data: bytes) -> list[Feedback]:
        """An output report through the format; one that asks nothing is logged only."""
        received = self.fmt.parse_output(data)
        if not received:
            log.debug("%s: an output report of %d bytes asks nothing: ignored", self.what, len(data))
        return received

    def _destroy(self) -> None:
        """``UHID_DESTROY``, then close /dev/uhid (which alone would remove the device too).
        :meth:`close` (:class:`~neurotouch_hid.targets.closing.NeutralOnClose`) calls it after the
        neutral report and the release grace."""
        try:
            os.write(self._fd, UHID_DESTROY.to_bytes(4, "little"))
        except OSError as exc:
            log.warning("%s: UHID_DESTROY failed (%s); closing /dev/uhid removes it", self.what, exc)
        os.close(self._fd)
        if self._guard is not None:  # after the neutral report and the device: nothing left to send
            self._guard.release()
            self._guard = None

    def __enter__(self) -> UhidDevice:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
