"""A replay of an AEDAT4 recording behind dv-processing's camera interface, with faults.

The live source (``neurotouch_hid/sources/davis.py``) is written against a small capture
interface: ``discover()`` and ``open(descriptor)`` of ``dv_processing.io.camera``, and a handful of
the camera's methods. :class:`ReplayWorld` offers the same calls, answering them from a real
recording (the real DAVIS-346 street recording, a simulated street or gel) played in time, as a
camera watching that scene would: a camera opened at time w delivers what the scene shows from w
on, in packets of at least :data:`PACKET_US` as time passes (a DAVIS sends a USB packet every few
ms), held at least the USB early packet delay and the data commit interval the source set
(dv-processing's :data:`OPEN_TIME_INTERVAL_US` until then), with the recording's own (Unix-time)
timestamps.

Time is the wall clock, or a :class:`ManualClock` the test controls: it moves only when the code
under test sleeps (``DavisSource(clock=clock.monotonic, sleep=clock.sleep)``), so that a loaded
machine plays the same scene at the same times as an idle one.

Faults are scripted in seconds from the world's start:

* ``unplug``: from ``start_s`` the camera is gone: every camera opened before reports
  ``isRunning() == False`` for good and delivers nothing; ``discover()`` lists nothing and
  ``open()`` raises until ``end_s``, when the camera can be found and opened again.
* ``stall``: from ``start_s`` to ``end_s`` the open camera keeps running but delivers nothing;
  what the scene showed meanwhile is lost.

This is a fake for tests, standing in for the USB camera only: the code under test is the real
DavisSource, pipeline, runtime and mapper.
"""

from __future__ import annotations

import datetime
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import dv_processing as dv
import numpy as np

from neurotouch_hid.sources.dv import store_from_events
from neurotouch_hid.sources.recording import RecordingReader

#: The shortest span of events one ``getNextEventBatch`` hands out (us).
PACKET_US = 2_000
#: The data commit interval (us) dv-processing 2.0.4 opens a DAVIS with (``getTimeInterval``).
OPEN_TIME_INTERVAL_US = 10_000


class ManualClock:
    """A monotonic clock (s) that moves only when someone sleeps on it (thread-safe)."""

    def __init__(self) -> None:
        self._now = 0.0
        self._lock = threading.Lock()

    def monotonic(self) -> float:
        with self._lock:
            return self._now

    def sleep(self, seconds: float) -> None:
        with self._lock:
            self._now += max(0.0, seconds)


@dataclass(frozen=True)
class Fault:
    """``kind`` ("unplug" or "stall") between ``start_s`` and ``end_s`` wall seconds (end may be inf)."""

    kind: str
    start_s: float
    end_s: float = math.inf


@dataclass(frozen=True)
class ReplayDescriptor:
    """What ``discover()`` lists (the fields of dv-processing's DeviceDescriptor that are used)."""

    serialNumber: str
    cameraModel: dv.io.camera.CameraModel = dv.io.camera.CameraModel.DAVIS


@dataclass(frozen=True)
class _Frame:
    timestamp: int
    image: np.ndarray


@dataclass
class ReplayWorld:
    """The scene of ``recording`` played in time (``clock``: a :class:`ManualClock`, or None for
    the wall clock) from the first ``discover()`` (when a source first looks for a camera, so that
    setting up the code under test costs no scene time), and the camera on it.

    Attributes:
        searches: seconds (from the start) of every ``discover()`` call: the source's attempts
            to find the camera.
        settings: the DAVIS settings the source applied, as (method name, value) pairs.
        early_packet_delays: (seconds from the start, us) of every USB early packet delay the
            source set: a camera holds events that long at least (:data:`PACKET_US` otherwise).
        time_intervals: (seconds from the start, us) of every data commit interval the source
            set (``setTimeInterval``): a camera holds events that long at least too.
    """

    recording: Path
    faults: tuple[Fault, ...] = ()
    clock: ManualClock | None = None
    serial: str = "00000499"
    searches: list[float] = field(default_factory=list)
    settings: list[tuple[str, object]] = field(default_factory=list)
    early_packet_delays: list[tuple[float, int]] = field(default_factory=list)
    time_intervals: list[tuple[float, int]] = field(default_factory=list)

    def __post_init__(self) -> None:
        with RecordingReader(self.recording) as reader:
            self.events, self.frames = reader.read_all()
        self.t0_us = min(int(self.events["timestamp"][0]), self.frames[0].t_us)
        self.event_ts = np.ascontiguousarray(self.events["timestamp"])
        self.frame_ts = np.array([f.t_us for f in self.frames], dtype=np.int64)
        self._start: float | None = None
        self._lock = threading.Lock()

    # --- the clock -------------------------------------------------------------------------
    def now_s(self) -> float:
        """Seconds since the world started (the first ``discover()``)."""
        now = time.monotonic if self.clock is None else self.clock.monotonic
        with self._lock:
            if self._start is None:
                self._start = now()
            return now() - self._start

    def source_clock(self) -> dict:
        """The keywords that put a DavisSource on this world's clock (none for the wall clock)."""
        return {} if self.clock is None else {"clock": self.clock.monotonic, "sleep": self.clock.sleep}

    def t_us(self, wall_s: float) -> int:
        """The recording's timestamp (us) the scene shows at ``wall_s``."""
        return self.t0_us + int(wall_s * 1e6)

    def _in(self, kind: str, wall_s: float) -> bool:
        return any(f.kind == kind and f.start_s <= wall_s < f.end_s for f in self.faults)

    def stalled_mask(self, ts_us: np.ndarray) -> np.ndarray:
        """True for timestamps the scene showed during a stall (never delivered)."""
        mask = np.zeros(len(ts_us), dtype=bool)
        for f in self.faults:
            if f.kind == "stall":
                mask |= (ts_us >= self.t_us(f.start_s)) & (ts_us < self.t_us(min(f.end_s, 1e9)))
        return mask

    # --- dv_processing.io.camera's calls ---------------------------------------------------
    def discover(self) -> list[ReplayDescriptor]:
        now = self.now_s()
        self.searches.append(now)
        return [] if self._in("unplug", now) else [ReplayDescriptor(self.serial)]

    def open(self, descriptor: ReplayDescriptor) -> "ReplayCamera":
        now = self.now_s()
        if self._in("unplug", now) or descriptor.serialNumber != self.serial:
            raise RuntimeError(f"Failed to open device {descriptor.serialNumber}: device not found")
        return ReplayCamera(self, now)


class ReplayCamera:
    """One opened camera of a :class:`ReplayWorld` (the dv-processing camera calls DavisSource makes)."""

    def __init__(self, world: ReplayWorld, opened_s: float):
        self._world = world
        self._opened_s = opened_s
        start = world.t_us(opened_s)
        self._event_at = int(np.searchsorted(world.event_ts, start, side="right"))
        self._frame_at = int(np.searchsorted(world.frame_ts, start, side="right"))
        self._delay_us = 0  # the early packet delay the source set (none yet)
        self._interval_us = OPEN_TIME_INTERVAL_US  # the data commit interval
        self._held_us = max(PACKET_US, self._interval_us)  # handed out once the oldest waited this long

    def getCameraName(self) -> str:
        return f"DAVIS346_{self._world.serial}"

    def getEventResolution(self) -> tuple[int, int]:
        return (346, 260)

    def isFrameStreamAvailable(self) -> bool:
        return True

    def _unplugged(self) -> bool:
        now = self._world.now_s()
        return any(f.kind == "unplug" and self._opened_s < f.start_s <= now for f in self._world.faults)

    def isRunning(self) -> bool:
        return not self._unplugged()

    def _deliverable(self) -> bool:
        return not self._unplugged() and not self._world._in("stall", self._world.now_s())

    def getNextEventBatch(self) -> dv.EventStore | None:
        if not self._deliverable():
            return None
        w = self._world
        now_us = w.t_us(w.now_s())
        if self._event_at < len(w.event_ts) and now_us - w.event_ts[self._event_at] < self._held_us:
            return None  # the packet is not full yet
        stop = int(np.searchsorted(w.event_ts, now_us, side="right"))
        if stop <= self._event_at:
            return None
        events = w.events[self._event_at : stop]
        self._event_at = stop
        events = events[~w.stalled_mask(events["timestamp"])]
        return store_from_events(events) if len(events) else None

    def getNextFrame(self) -> _Frame | None:
        if not self._deliverable():
            return None
        w = self._world
        now_us = w.t_us(w.now_s())
        while self._frame_at < len(w.frames) and w.frame_ts[self._frame_at] <= now_us:
            frame = w.frames[self._frame_at]
            self._frame_at += 1
            if not w.stalled_mask(np.array([frame.t_us]))[0]:
                return _Frame(frame.t_us, frame.image)
        return None

    # DAVIS settings (dv_processing.io.camera.DAVIS): recorded for the tests to check
    def setFrameInterval(self, interval: datetime.timedelta) -> None:
        self._world.settings.append(("setFrameInterval", interval))

    def setAutoExposure(self, enabled: bool) -> None:
        self._world.settings.append(("setAutoExposure", enabled))

    def setExposureDuration(self, duration: datetime.timedelta) -> None:
        self._world.settings.append(("setExposureDuration", duration))

    def setUSBEarlyPacketDelay(self, delay: datetime.timedelta) -> None:
        us = int(delay / datetime.timedelta(microseconds=1))
        self._world.settings.append(("setUSBEarlyPacketDelay", delay))
        self._world.early_packet_delays.append((self._world.now_s(), us))
        self._delay_us = us
        self._held_us = max(PACKET_US, self._delay_us, self._interval_us)

    # the data commit interval (dv_processing.io.camera.CameraInputBase)
    def setTimeInterval(self, interval: datetime.timedelta) -> None:
        us = int(interval / datetime.timedelta(microseconds=1))
        self._world.settings.append(("setTimeInterval", interval))
        self._world.time_intervals.append((self._world.now_s(), us))
        self._interval_us = us
        self._held_us = max(PACKET_US, self._delay_us, self._interval_us)

    def getTimeInterval(self) -> datetime.timedelta:
        return datetime.timedelta(microseconds=self._interval_us)
