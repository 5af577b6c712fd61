"""The UHID joystick and the paths by which the driver stops, without a kernel device: a fake
kernel on a socket pair (SOCK_SEQPACKET: one ``struct uhid_event`` a read, as /dev/uhid hands
them, include/uapi/linux/uhid.h) stands in for /dev/uhid. The device itself is checked in a real
kernel (tests/test_uhid_kernel.py)."""

from __future__ import annotations

import os
import socket
import struct
import threading

import pytest
from helpers import wait_until
from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.targets import TargetOutputs
from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
from neurotouch_hid.targets.uhid import HID_DEFAULT, UhidDevice
from neurotouch_hid.targets.uhid_events import UHID_GET_REPORT, UHID_GET_REPORT_REPLY, UHID_INPUT_REPORT, UHID_START


class FakeUhid:
    """A UhidDevice whose /dev/uhid is one end of a socket pair; ``kernel`` is the other end."""

    def __init__(self) -> None:
        self.device = UhidDevice(HID_JOYSTICK, HID_DEFAULT, "/dev/null", start_wait_s=0)
        ours, self.kernel = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        ours.setblocking(False)
        os.close(self.device._fd)
        self.device._fd = ours.detach()
        self.kernel.settimeout(5.0)

    def send(self, kind: int, body: bytes = b"") -> None:
        self.kernel.send(kind.to_bytes(4, "little") + body)

    def get_report(self, request: int) -> bytes:
        """A GET_REPORT of the input report, as hidraw's HIDIOCGINPUT asks it; the reply's bytes."""
        self.send(UHID_GET_REPORT, struct.pack("<IBB", request, 0, UHID_INPUT_REPORT))
        while True:
            event = self.kernel.recv(8192)
            if int.from_bytes(event[:4], "little") == UHID_GET_REPORT_REPLY:
                return event


class LedTarget:
    """A target whose readable side brings a keyboard LED feedback per byte written to it."""

    what = "uinput keyboard"

    def __init__(self) -> None:
        self.read_fd, self.write_fd = os.pipe()

    def fileno(self) -> int:
        return self.read_fd

    def feedback(self) -> list[Feedback]:
        return [Feedback("keyboard_leds", led=2, source=self.what) for _ in os.read(self.read_fd, 100)]

    def write(self, state) -> None:
        pass

    def neutralise(self) -> None:
        pass

    def prepare(self, profile) -> None:
        pass

    def close(self) -> None:
        for fd in (self.read_fd, self.write_fd):
            os.close(fd)


def test_a_line_that_cannot_be_said_does_not_stop_the_joystick_answering_the_host():
    """stderr gone (a closed pipe) while the host lights Caps Lock: the UHID joystick still
    answers GET_REPORT (else hidraw's HIDIOCGINPUT waits 5 s, then EIO) and still sees a HID
    driver bind (else it never sends a report again)."""
    uhid, leds = FakeUhid(), LedTarget()
    said: list[str] = []

    def say(line: str) -> None:
        said.append(line)
        raise BrokenPipeError(32, "Broken pipe")

    with TargetOutputs([uhid.device, leds], say=say):
        os.write(leds.write_fd, b"x")
        assert wait_until(lambda: said, 5)
        reply = uhid.get_report(7)
        assert struct.unpack_from("<IIHH", reply) == (UHID_GET_REPORT_REPLY, 7, 0, 13)
        assert reply[12:25] == HID_JOYSTICK.neutral()
        uhid.send(UHID_START, bytes(8))
        assert wait_until(lambda: uhid.device.started, 5)
    uhid.kernel.close()


class FakeUinput:
    """The python-evdev UInput of a VirtualGamepad: a pipe as its fd, the kernel's requests queued
    in ``pending``; what the pad answers is kept."""

    device = None

    def __init__(self) -> None:
        self.read_fd, self.write_fd = os.pipe()
        self.fd = self.read_fd
        self.pending: list = []
        self.uploads_answered = 0
        self.lock = threading.Lock()

    def request(self, *events) -> None:
        with self.lock:
            self.pending.extend(events)
        os.write(self.write_fd, b"x")

    def read(self):
        os.read(self.read_fd, 100)
        with self.lock:
            events, self.pending = self.pending, []
        return events

    def write(self, *args) -> None:
        pass

    def syn(self) -> None:
        pass

    def end_upload(self, upload) -> None:
        self.uploads_answered += 1

    def end_erase(self, erase) -> None:
        pass

    def close(self) -> None:
        for fd in (self.read_fd, self.write_fd):
            os.close(fd)


def test_a_rumble_line_that_cannot_be_said_does_not_leave_the_game_s_next_upload_unanswered(monkeypatch):
    """The kernel blocks a game's EVIOCSFF until the pad answers (uinput's 30 s time-out): a
    failing ``on_effect`` (stderr gone) must not stop the pad answering the next upload."""
    from evdev import InputEvent, ecodes, ff

    from neurotouch_hid.targets.uinput import gamepad

    fake = FakeUinput()
    monkeypatch.setattr(gamepad, "create_uinput", lambda *a, **k: fake)

    def begin(ui, kind, request_id):
        request = ff.UInputUpload()
        request.request_id = request_id
        request.effect.type = ecodes.FF_RUMBLE
        return request

    monkeypatch.setattr(gamepad, "_begin_ff_request", begin)
    lines: list[str] = []

    def on_effect(line: str) -> None:
        lines.append(line)
        raise BrokenPipeError(32, "Broken pipe")

    pad = gamepad.VirtualGamepad(on_effect=on_effect)
    with TargetOutputs([pad]):  # the run's one feedback path reads the pad
        upload = InputEvent(0, 0, ecodes.EV_UINPUT, ecodes.UI_FF_UPLOAD, 0)
        fake.request(upload)
        assert wait_until(lambda: fake.uploads_answered == 1, 5)
        fake.request(InputEvent(0, 0, ecodes.EV_UINPUT, ecodes.UI_FF_UPLOAD, 1))
        assert wait_until(lambda: fake.uploads_answered == 2, 5)
        assert lines  # said (and failed) once: the same line is said at most once a second


class FakeMerge:
    """A profile's merged devices: whether they are grabbed (started and not stopped)."""

    def __init__(self) -> None:
        self.grabbed = False

    def start(self, on_input) -> None:
        self.grabbed = True

    def stop(self) -> None:
        self.grabbed = False

    def merge(self, gel):
        return gel

    def status(self):
        return (), ()


def test_a_profile_switch_that_lands_after_the_run_stopped_grabs_nothing_and_says_why():
    """``profile use`` (or a game starting) answered while the driver stops, after the run let the
    merged devices go: the helper's pad must not be grabbed again with nobody left to let it go."""
    merges: list[FakeMerge] = []

    def merge_for(profile):
        merges.append(FakeMerge())
        return merges[-1]

    out = RecordingOutput()
    rt = Engine(
        RunParts((batch(i * 1000) for i in range(5)), FakePipeline()),
        {"sign": 1},
        [out],
        RunOptions(
            mode=RunMode.FAST, mapper_factory=FakeMapper, merge_for=merge_for, profile_loader=lambda ref: {"sign": -1}
        ),
    )
    rt.run()
    assert out.calls[-1] == ("neutralise", None) and not any(m.grabbed for m in merges)
    with pytest.raises(NeurotouchError, match="stopping"):
        rt.use_profile("other")
    assert not any(m.grabbed for m in merges)
    assert out.calls[-1] == ("neutralise", None)


class FailingOutput(RecordingOutput):
    """An output whose neutral report cannot be sent (a USB host gone, a closed node)."""

    def neutralise(self):
        super().neutralise()
        raise OSError(5, "Input/output error")


class FailingMerge(FakeMerge):
    def stop(self) -> None:
        super().stop()
        raise OSError(19, "No such device")


def test_the_runs_last_neutral_reaches_every_output_when_one_or_a_merged_device_fails():
    """Whatever stops the driver, every output is sent neutral: one output's failing neutral
    report, or merged devices whose release fails, must not keep the others from theirs."""
    first, second = FailingOutput(), RecordingOutput()
    rt = Engine(
        RunParts((batch(i * 1000) for i in range(5)), FakePipeline()),
        {"sign": 1},
        [first, second],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper, merge_for=lambda profile: FailingMerge()),
    )
    with pytest.raises(OSError):
        rt.run()
    assert second.calls[-1] == ("neutralise", None), second.calls
