"""The UHID device answers what a host driver asks of its protocol's row, without a kernel device:
GET_REPORT of every feature report of its format, of its numbered input report, output reports
(UHID_OUTPUT, SET_REPORT of an output report) parsed into Feedback, the current report sent again
when a reader opens it. A socket pair (SOCK_SEQPACKET: one ``struct uhid_event`` a read, as
/dev/uhid hands them, include/uapi/linux/uhid.h) stands in for /dev/uhid. The real kernel's
answers are checked in tests/test_uhid_kernel.py."""

from __future__ import annotations

import errno
import os
import select
import socket
import struct

import pytest

from neurotouch_hid.core.controller import ControllerState, Feedback
from neurotouch_hid.targets.identity import identity_for
from neurotouch_hid.targets.reports.hid import DESCRIPTOR
from neurotouch_hid.targets.uhid import HID_DEFAULT, UhidDevice
from neurotouch_hid.targets.uhid_events import (
    UHID_EVENT_SIZE,
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
)

CAMERA = identity_for("00000499")


class NumberedFormat:
    """A format with a numbered input report (id 1: the left stick's X high byte), feature reports
    5 and 9 (9 carries the MAC) and an output report 2 (``02 STRONG WEAK``)."""

    name = "numbered"
    descriptor = DESCRIPTOR  # the fake kernel does not parse it
    report_length = 3
    feature_ids = (5, 9)

    def pack(self, state: ControllerState) -> bytes:
        return bytes([1, (state.axes["ABS_X"] >> 8) & 0xFF, 0])

    def neutral(self) -> bytes:
        return self.pack(ControllerState.neutral())

    def feature(self, report_id: int, identity) -> bytes:
        if report_id == 5:
            return bytes([5]) + bytes(40)
        if report_id == 9:
            return bytes([9]) + identity.mac[::-1] + bytes(13)
        raise KeyError(report_id)

    def parse_output(self, data: bytes) -> list[Feedback]:
        if len(data) >= 3 and data[0] == 2:
            return [Feedback("rumble", strong=data[1] / 255, weak=data[2] / 255)]
        return []


class Kernel:
    """The kernel's end of the socket pair, and the device on the other end."""

    def __init__(self) -> None:
        ours, self.end = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        ours.setblocking(False)
        self.end.settimeout(5.0)
        self.device = UhidDevice.on_fd(ours.detach(), NumberedFormat(), HID_DEFAULT, start_wait_s=0, camera=CAMERA)
        self.created = self.end.recv(UHID_EVENT_SIZE + 64)

    def send(self, kind: int, body: bytes = b"") -> list[Feedback]:
        self.end.send(kind.to_bytes(4, "little") + body)
        return self.device.feedback()

    def next(self, kind: int) -> bytes:
        while True:
            event = self.end.recv(UHID_EVENT_SIZE + 64)
            if int.from_bytes(event[:4], "little") == kind:
                return event

    def close(self) -> None:
        self.device.close()
        self.end.close()


@pytest.fixture
def kernel():
    made = Kernel()
    yield made
    made.close()


def _get(kernel: Kernel, rtype: int, rnum: int) -> tuple[int, bytes]:
    kernel.end.send(UHID_GET_REPORT.to_bytes(4, "little") + struct.pack("<IBB", 7, rnum, rtype))
    kernel.device.feedback()
    reply = kernel.next(UHID_GET_REPORT_REPLY)
    _, request, err, size = struct.unpack_from("<IIHH", reply)
    assert request == 7
    return err, reply[12 : 12 + size]


def test_every_feature_report_of_the_format_is_answered_with_its_id_first(kernel):
    assert _get(kernel, UHID_FEATURE_REPORT, 5) == (0, bytes([5]) + bytes(40))
    err, pairing = _get(kernel, UHID_FEATURE_REPORT, 9)
    assert err == 0 and pairing[0] == 9 and pairing[1:7] == CAMERA.mac[::-1]
    assert _get(kernel, UHID_FEATURE_REPORT, 0x20) == (errno.EIO, b"")  # not one of the format's


def test_the_numbered_input_report_is_answered_by_its_id_once_a_driver_said_so(kernel):
    kernel.send(UHID_START, (1 << 2).to_bytes(8, "little"))  # UHID_DEV_NUMBERED_INPUT_REPORTS
    state = ControllerState.neutral()
    state.axes["ABS_X"] = 0x4000
    kernel.device.write(state)
    assert _get(kernel, UHID_INPUT_REPORT, 1) == (0, bytes([1, 0x40, 0]))
    assert _get(kernel, UHID_INPUT_REPORT, 0)[0] == errno.EIO


def test_an_input_report_the_driver_does_not_number_is_report_zero(kernel):
    kernel.send(UHID_START, bytes(8))
    assert _get(kernel, UHID_INPUT_REPORT, 0) == (0, bytes([1, 0, 0]))
    assert _get(kernel, UHID_INPUT_REPORT, 1)[0] == errno.EIO


def test_output_reports_become_feedback_from_this_device(kernel):
    body = bytes.fromhex("02ff80").ljust(4096, b"\0") + struct.pack("<HB", 3, UHID_OUTPUT_REPORT)
    (rumble,) = kernel.send(UHID_OUTPUT, body)
    assert (rumble.kind, rumble.strong, rumble.source) == ("rumble", 1.0, kernel.device.what)
    assert kernel.send(UHID_OUTPUT, bytes(4096) + struct.pack("<HB", 5, UHID_OUTPUT_REPORT)) == []  # asks nothing
    # hidraw's write of an output report on a device without an OUT endpoint comes as SET_REPORT
    (again,) = kernel.send(
        UHID_SET_REPORT, struct.pack("<IBBH", 11, 2, UHID_OUTPUT_REPORT, 3) + bytes.fromhex("020040")
    )
    assert again.weak == pytest.approx(0x40 / 255)
    _, request, err = struct.unpack_from("<IIH", kernel.next(UHID_SET_REPORT_REPLY))
    assert (request, err) == (11, 0)
    kernel.send(UHID_SET_REPORT, struct.pack("<IBBH", 12, 5, UHID_FEATURE_REPORT, 1) + b"\5")
    _, request, err = struct.unpack_from("<IIH", kernel.next(UHID_SET_REPORT_REPLY))
    assert (request, err) == (12, errno.EIO)  # no feature report is written to


def test_a_reader_that_opens_it_gets_the_current_report_again(kernel):
    """After a driver is rebound (unbind, bind: STOP, START) and a game opens it, the current
    state is sent again, not left at the kernel's zeros until the next change."""
    kernel.send(UHID_START, bytes(8))
    assert kernel.next(UHID_INPUT2)[6:9] == bytes([1, 0, 0])  # the report held until a driver bound
    state = ControllerState.neutral()
    state.axes["ABS_X"] = 0x2000
    kernel.device.write(state)
    first = kernel.next(UHID_INPUT2)
    kernel.send(UHID_OPEN)
    again = kernel.next(UHID_INPUT2)
    assert again == first and again[6:9] == bytes([1, 0x20, 0])


class FakeClock:
    """``time`` for the device: ``monotonic`` that moves only when ``sleep`` is called;
    ``thread_time`` (the thread's CPU time): ``cpu_per_event`` for each of ``events()`` (none by
    default: the device's own work costs nothing)."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.slept = 0.0
        self.cpu_per_event = 0.0
        self.events = lambda: 0

    def monotonic(self) -> float:
        return self.now

    def thread_time(self) -> float:
        return self.cpu_per_event * self.events()

    def sleep(self, seconds: float) -> None:
        self.now += seconds
        self.slept += seconds
        self.longest = max(getattr(self, "longest", 0.0), seconds)


class _KernelWrites:
    """``os`` for the device, whose writes wait for the test's end to read: /dev/uhid takes every
    write at once, but the socket pair's peer queue holds about ten messages
    (net.unix.max_dgram_qlen), so a flood's replies written faster than the test's reader thread
    is scheduled would fail with EAGAIN where the kernel never refuses one."""

    def __getattr__(self, name: str):
        return getattr(os, name)

    @staticmethod
    def write(fd: int, data: bytes) -> int:
        while True:
            try:
                return os.write(fd, data)
            except BlockingIOError:
                select.select([], [fd], [], 5.0)


@pytest.fixture
def clocked(monkeypatch):
    """A device on a fake kernel whose clock moves only when it sleeps."""
    import types

    from neurotouch_hid.targets import uhid

    clock = FakeClock()
    fake = types.SimpleNamespace(monotonic=clock.monotonic, sleep=clock.sleep, thread_time=clock.thread_time)
    monkeypatch.setattr(uhid, "time", fake)
    monkeypatch.setattr(uhid, "os", _KernelWrites())
    made = Kernel()
    made.clock = clock
    yield made
    made.close()


def _flood(kernel: Kernel, events: list[bytes], replies: int = 0) -> tuple[list[list[Feedback]], list[bytes]]:
    """Send ``events`` from a thread (the socket holds a few dozen) while the device's feedback is
    read until all were handled: what each call returned, and the ``replies`` the device wrote
    back, read from another thread."""
    import threading

    got: list[bytes] = []

    def send() -> None:
        for event in events:
            kernel.end.send(event)

    def receive() -> None:
        while len(got) < replies:
            got.append(kernel.end.recv(UHID_EVENT_SIZE + 64))

    threads = [threading.Thread(target=send), threading.Thread(target=receive)]
    for thread in threads:
        thread.start()
    received: list[list[Feedback]] = []
    before = kernel.device.events
    while kernel.device.events - before < len(events):
        received.append(kernel.device.feedback())
    for thread in threads:
        thread.join(10)
    return received, got


def test_a_flood_of_output_reports_is_handled_at_a_bounded_rate_each_batch_giving_its_last(clocked):
    """A hidraw reader writing output reports 10 k times a second made the UHID device cost a core:
    every event was read, parsed and handed on as soon as it came."""
    from neurotouch_hid.targets.uhid import EVENT_BATCH, HOST_EVENTS_PER_S

    count = 3000
    events = [UHID_OUTPUT.to_bytes(4, "little") + bytes([2, i % 256, 0]) for i in range(count)]
    for index, event in enumerate(events):
        body = event[4:].ljust(4096, b"\0") + struct.pack("<HB", 3, UHID_OUTPUT_REPORT)
        events[index] = event[:4] + body
    received, _ = _flood(clocked, events)
    # no more than the rate allows over the time it took (the device slept, not spun)
    assert count <= HOST_EVENTS_PER_S * clocked.clock.slept + EVENT_BATCH
    assert clocked.clock.slept >= (count - EVENT_BATCH) / HOST_EVENTS_PER_S * 0.99
    # one rumble a call at most, the last one the host sent: the flood's very last is there
    assert max(len(said) for said in received) == 1
    last = [said for said in received if said][-1][0]
    assert (last.kind, last.strong) == ("rumble", ((count - 1) % 256) / 255)


def test_a_flood_of_get_reports_is_answered_every_one_in_order_at_a_bounded_rate(clocked):
    """HIDIOCGINPUT in a loop: each request is answered (the caller waits for it), none faster than
    the rate."""
    from neurotouch_hid.targets.uhid import EVENT_BATCH, HOST_EVENTS_PER_S

    count = 500
    requests = [
        UHID_GET_REPORT.to_bytes(4, "little") + struct.pack("<IBB", n, 1, UHID_INPUT_REPORT) for n in range(count)
    ]
    clocked.send(UHID_START, struct.pack("<Q", 1 << 2))  # numbered input reports
    clocked.next(UHID_INPUT2)
    _, replies = _flood(clocked, requests, replies=count)
    answered = [struct.unpack_from("<IIHH", reply) for reply in replies]
    assert [(kind, request, err) for kind, request, err, _ in answered] == [
        (UHID_GET_REPORT_REPLY, n, 0) for n in range(count)
    ]
    assert count <= HOST_EVENTS_PER_S * clocked.clock.slept + EVENT_BATCH


def test_no_call_sleeps_longer_than_the_loop_may_wait_whatever_the_flood(clocked):
    """The device's feedback is read on the run's one loop, which serves the merged devices and the
    control socket between two calls: the rate's and the CPU share's sleeps are cut into calls of
    at most MAX_REST_S (a whole batch's 64 ms, or a rest of 0.5 s, held them up that long)."""
    from neurotouch_hid.targets.uhid import HOST_CPU_SHARE, MAX_REST_S

    clock = clocked.clock
    clock.cpu_per_event, clock.events = 0.002, lambda: clocked.device.events
    tail = struct.pack("<HB", 3, UHID_OUTPUT_REPORT)
    events = [UHID_OUTPUT.to_bytes(4, "little") + bytes([2, i % 256, 0]).ljust(4096, b"\0") + tail for i in range(300)]
    start_s = clock.now
    _flood(clocked, events)
    assert 0 < clock.longest <= MAX_REST_S <= 0.01  # what the loop's other fds may wait, at most
    # bound kept (the last batch, 64 events, not repaid yet; at equality when the flood ends on a full
    # batch, which float sums of the sleeps miss by 1e-13)
    assert clock.thread_time() <= HOST_CPU_SHARE * (clock.now - start_s) + 64 * clock.cpu_per_event + 1e-9


def test_a_host_at_a_games_pace_is_never_made_to_wait(clocked):
    """Tens of output reports a second, each read as it comes: no sleep, each one handed on."""
    for n in range(50):
        clocked.clock.now += 0.016  # a frame apart
        said = clocked.send(
            UHID_OUTPUT, bytes([2, n, 0]).ljust(4096, b"\0") + struct.pack("<HB", 3, UHID_OUTPUT_REPORT)
        )
        assert [f.strong for f in said] == [n / 255]
    assert clocked.clock.slept == 0


def test_a_flood_on_a_slow_machine_costs_the_feedback_thread_at_most_its_share_of_a_core(clocked):
    """In the emulated test kernel an event cost ~0.6 ms: 1000 a second, the events' bound, still
    took 0.64 of a core (tests/kernel/checks_hostile.py). Each event here costs 2 ms of the
    thread's CPU: the device sleeps so that CPU over wall time stays within its share."""
    from neurotouch_hid.targets.uhid import EVENT_BATCH, HOST_CPU_SHARE

    clock = clocked.clock
    clock.cpu_per_event, clock.events = 0.002, lambda: clocked.device.events
    start_s, start_cpu = clock.now, clock.thread_time()
    tail = struct.pack("<HB", 3, UHID_OUTPUT_REPORT)
    events = [UHID_OUTPUT.to_bytes(4, "little") + bytes([2, i % 256, 0]).ljust(4096, b"\0") + tail for i in range(300)]
    received, _ = _flood(clocked, events)
    spent = clock.thread_time() - start_cpu
    assert spent == pytest.approx(0.6) and len(received) > 1
    # what the last call spent (a batch at most) is repaid at the next one
    assert spent - EVENT_BATCH * clock.cpu_per_event <= HOST_CPU_SHARE * (clock.now - start_s)
