"""How old the emulated camera's events are when the host's reader gets them (guest side).

The emulated DAVIS-346 (davis_gadget.py) stamps an event with its device time, ``(time.monotonic()
- clock0) x 1e6`` us in the guest's own clock, where ``clock0`` is the moment it answered the host's
timestamp reset (its log says it: :func:`device_clock0`), and sends it when that time comes.
dv-processing 2.0.4 hands the events out with the device time + its timestamp offset
(``camera.getTimestampOffset()``, a ``datetime.timedelta``). So an event batch's age when
``getNextEventBatch`` returns it is (arrival in device time) - (its event's device time), with no
clock but the guest's monotonic one.

What makes the age: the camera's USB early packet delay (how long data that does not fill a
transfer waits in its FX3), and dv-processing's data commit interval (``getTimeInterval``;
libcaer's packet container interval: a container of events is committed to the queue the host
polls only when an event passes the interval, on the USB thread), then the poll itself.
"""

from __future__ import annotations

import datetime
import re
import time
from typing import Any

import numpy as np

_RESET = re.compile(r"timestamp reset: device time 0 at monotonic ([\d.]+) s")


def device_clock0(log: str) -> float:
    """The emulated camera's last timestamp reset (time.monotonic(), s) from its log.

    Raises:
        AssertionError: the log says none (the host never reset the camera's time).
    """
    found = _RESET.findall(log)
    assert found, "the emulated camera logged no timestamp reset"
    return float(found[-1])


def us(delta: datetime.timedelta) -> int:
    """A dv-processing duration (``datetime.timedelta``) in whole us."""
    return int(delta / datetime.timedelta(microseconds=1))


class TimedCamera:
    """A dv-processing camera whose every non-empty event batch is noted with its arrival: the
    rows (time.monotonic() s, lowest and highest timestamp us, events) in :attr:`batches`; and
    each data commit interval set, (time.monotonic() s, us) in :attr:`intervals`. All other calls
    go to the camera as they are."""

    def __init__(self, camera: Any) -> None:
        self._camera = camera
        self.batches: list[tuple[float, int, int, int]] = []
        self.intervals: list[tuple[float, int]] = []

    def setTimeInterval(self, interval):  # noqa: N802 - dv-processing's name
        self.intervals.append((time.monotonic(), us(interval)))
        return self._camera.setTimeInterval(interval)

    def getNextEventBatch(self):  # noqa: N802 - dv-processing's name
        store = self._camera.getNextEventBatch()
        if store is not None and len(store):
            self.batches.append((time.monotonic(), int(store.getLowestTime()), int(store.getHighestTime()), len(store)))
        return store

    def __getattr__(self, name: str) -> Any:
        return getattr(self._camera, name)


class TimedBackend:
    """``dv_processing.io.camera`` whose ``open`` gives a :class:`TimedCamera` (the last in
    :attr:`camera`): DavisSource's ``backend``."""

    def __init__(self, backend: Any) -> None:
        self._backend = backend
        self.camera: TimedCamera | None = None

    def discover(self) -> list:
        return self._backend.discover()

    def open(self, descriptor: Any) -> TimedCamera:
        self.camera = TimedCamera(self._backend.open(descriptor))
        return self.camera


def ages(batches: list[tuple[float, int, int, int]], offset_us: int, clock0: float) -> dict:
    """The batches' ages when they arrived (ms): of their last event (``last_*``) and of their
    first (``first_*``), p50, p90 and max, and how many batches and events.

    Args:
        batches: (arrival time.monotonic() s, lowest and highest timestamp us, events), as
            :class:`TimedCamera` notes them.
        offset_us: the camera's timestamp offset (``getTimestampOffset()``, us).
        clock0: the emulated camera's device time 0 (:func:`device_clock0`).
    """
    if not batches:
        return {"batches": 0, "events": 0}
    rows = np.array(batches, dtype=np.float64)
    arrival_us = (rows[:, 0] - clock0) * 1e6
    out: dict = {"batches": len(rows), "events": int(rows[:, 3].sum())}
    for name, column in (("last", 2), ("first", 1)):
        age_ms = (arrival_us - (rows[:, column] - offset_us)) / 1000.0
        p50, p90 = np.percentile(age_ms, [50, 90])
        out.update(
            {f"{name}_p50_ms": round(p50, 2), f"{name}_p90_ms": round(p90, 2), f"{name}_max_ms": round(age_ms.max(), 2)}
        )
    return out


#: The event-age part's stream (s): the first SETTLE_S not counted (the stream's start), then
#: TOUCH_S as a touched gel's (the consumer says nothing of a rest), then REST_S resting.
SETTLE_S, TOUCH_S, REST_S = 0.5, 2.0, 1.5
#: The resting batches are those the resting stream read whose events the camera stamped this long
#: (s) after the source set the resting commit interval (what the host parses from then on is
#: committed at it; what it had parsed before, at 1 ms): not after the consumer said the gel rests,
#: as the source switches at its next poll, which a busy guest delays (in CI at host load ~10 the
#: guest read 1 ms batches 0.46-0.66 s old after the switch: picked by their arrival, the "resting"
#: ones were that backlog; picked by their stamps after the consumer's word, a CI run counted 342
#: batches of 0.9 ms at p50).
REST_MARGIN_S = 0.1
#: The resting windows' length the part's consumer says (us): the default 10 ms windows.
REST_WINDOW_US = 10_000


def spans(batches: list[tuple[float, int, int, int]]) -> dict:
    """How long a span of camera time each batch holds (ms, its last event's timestamp - its
    first's), p50 and p90: the part of its first event's age that the data commit interval makes
    (libcaer commits a container once an event passes the interval), whatever the emulation's speed."""
    if not batches:
        return {}
    rows = np.array(batches, dtype=np.float64)
    p50, p90 = np.percentile((rows[:, 2] - rows[:, 1]) / 1000.0, [50, 90])
    return {"span_p50_ms": round(p50, 2), "span_p90_ms": round(p90, 2)}


def through_davis_source(log: Any, serial: str) -> dict:
    """The product's DavisSource on the emulated camera through dv-processing's real driver: the
    data commit interval the driver reports once the source opened it (``getTimeInterval``, us)
    and while its consumer says the gel rests, and the event batches' ages and spans (:func:`ages`,
    :func:`spans`) in each. ``log`` gives the emulated camera's log (its timestamp reset)."""
    import dv_processing as dv

    from neurotouch_hid.sources.davis import DavisConfig, DavisSource

    backend = TimedBackend(dv.io.camera)
    with DavisSource(DavisConfig(serial=serial), backend=backend) as source:
        camera = backend.camera
        opened_us = us(camera.getTimeInterval())
        offset_us = us(camera.getTimestampOffset())
        t0 = time.monotonic()
        rest_from = t0 + SETTLE_S + TOUCH_S
        stream = source.stream(seconds=SETTLE_S + TOUCH_S + REST_S)
        stream.poll_pause.resting = lambda: REST_WINDOW_US if time.monotonic() >= rest_from else None
        for _ in stream:
            pass
        read_at_rest = len(camera.batches)  # the next stream's first poll reads at 1 ms again
        at_rest = {
            "time_interval_us": us(camera.getTimeInterval()),
            "early_packet_delay_us": us(camera.getUSBEarlyPacketDelay()),
        }
        stream.poll_pause.resting = None
        next(iter(source.stream(seconds=0.3)), None)  # the first poll after the rest sets both back
        after_us = us(camera.getTimeInterval())
    clock0 = device_clock0(log())
    touched = [b for b in camera.batches if t0 + SETTLE_S <= b[0] < rest_from]
    # at rest: the events the camera stamped after the switch (+ REST_MARGIN_S), by their device time,
    # not by when they came: a lagging guest still reads the batches committed before it for a while
    switched = next((t for t, value in camera.intervals if t >= rest_from and value == REST_WINDOW_US), rest_from)
    rest_us = (switched + REST_MARGIN_S - clock0) * 1e6 + offset_us
    resting = [b for b in camera.batches[:read_at_rest] if b[1] >= rest_us]
    return {
        "opened_time_interval_us": opened_us,
        "touched": {**ages(touched, offset_us, clock0), **spans(touched)},
        "at_rest": {
            **at_rest,
            "switched_after_s": round(switched - rest_from, 3),
            **ages(resting, offset_us, clock0),
            **spans(resting),
        },
        "after_rest_time_interval_us": after_us,
    }
