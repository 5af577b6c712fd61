"""The live camera's poll (``DavisSource``, neurotouch_hid/sources/davis.py) draining a backlog: what it
costs to take every queued APS frame and place each among the events (docs/performance.md, "Event path
and noise filter").

A recording (the real DAVIS-346 street recording beside the repository by default, or ``--recording``)
is cut into the packets a DAVIS-346 sends (``--packet-us``, dv-processing ``EventStore`` values) and its
APS frames (``dv.Frame``), all queued at once in a stand-in for dv-processing's camera, as a consumer
that fell behind finds them. ``DavisSource`` polls it until it is empty (what ``stream`` does between
two waits: every queued packet, up to 64 a poll, and every queued frame, up to 8 a poll, placed in time
order), once with the frames and once with a camera that has none. Printed: M events/s of each drain
(events / CPU s of this thread, the machine being shared), the ratio, and the time-ordering step alone
per poll that holds a frame.

Run: ``python3 benchmarks/bench_live_poll.py`` (``--help`` for options).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import dv_processing as dv
import numpy as np

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.sources import Frame
from neurotouch_hid.sources.davis import DavisConfig, DavisSource, in_time_order
from neurotouch_hid.sources.dv import store_from_events
from neurotouch_hid.sources.recording import RecordingReader

STREET = Path(__file__).resolve().parents[2] / "shared" / "data" / "davis346-street" / "recording.aedat4"


class QueuedCamera:
    """dv-processing's camera calls DavisSource makes, answered from packets and frames queued at once."""

    def __init__(self, stores: list, frames: list) -> None:
        self._stores, self._frames = list(stores), list(frames)

    def getCameraName(self) -> str:
        return "DAVIS346_bench"

    def getEventResolution(self) -> tuple[int, int]:
        return (346, 260)

    def isFrameStreamAvailable(self) -> bool:
        return True

    def isRunning(self) -> bool:
        return True

    def getNextFrame(self):
        return self._frames.pop(0) if self._frames else None

    def getNextEventBatch(self):
        return self._stores.pop(0) if self._stores else None


class Backend:
    def __init__(self, camera: QueuedCamera) -> None:
        self.camera = camera

    def discover(self) -> list:
        return [type("D", (), {"serialNumber": "1", "cameraModel": dv.io.camera.CameraModel.DAVIS})()]

    def open(self, descriptor) -> QueuedCamera:
        return self.camera


def drain(stores: list, frames: list) -> tuple[float, int, int]:
    """CPU s of polling a camera with ``stores`` and ``frames`` queued until it is empty, the polls
    made and the frames taken."""
    source = DavisSource(DavisConfig(exposure_us=None), backend=Backend(QueuedCamera(stores, frames)))
    source._open_or_raise()
    polls = taken = 0
    t0 = time.thread_time()
    while True:
        items, failure = source._read()
        if failure is not None or not items:
            break
        polls += 1
        taken += sum(isinstance(i, Frame) for i in items)
    return time.thread_time() - t0, polls, taken


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--recording", type=Path, default=STREET, help="an AEDAT4 file (default: the street)")
    parser.add_argument("--packet-us", type=int, default=1000, help="events per queued packet (us of camera time)")
    parser.add_argument("--repeat", type=int, default=5, help="drains per case; the fastest is printed")
    args = parser.parse_args()
    if args.packet_us <= 0 or args.repeat <= 0:
        parser.error("--packet-us and --repeat must be positive")
    try:
        with RecordingReader(args.recording) as reader:
            events, frames = reader.read_all()
    except (NeurotouchError, OSError) as exc:
        parser.error(str(exc))
    if len(events) == 0 or not frames:
        parser.error(f"{args.recording}: the benchmark needs events and APS frames")
    ts = events["timestamp"]
    edges = np.arange(int(ts[0]), int(ts[-1]) + args.packet_us + 1, args.packet_us)
    cuts = np.searchsorted(ts, edges)
    packets = [events[a:b] for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
    stores = [store_from_events(p) for p in packets]
    dv_frames = [dv.Frame(f.t_us, f.image) for f in frames]
    n = len(events)
    with_frames = min(drain(stores, dv_frames) for _ in range(args.repeat))
    without = min(drain(stores, []) for _ in range(args.repeat))
    print(f"{args.recording.name}: {n} events in {len(packets)} packets of {args.packet_us} us, {len(frames)} frames")
    cpu, polls, taken = with_frames
    print(f"drain with the frames:   {n / cpu / 1e6:.2f} M events/s ({polls} polls, {taken} frames)")
    print(f"drain without frames:    {n / without[0] / 1e6:.2f} M events/s ({without[1]} polls)")
    print(f"ratio with / without:    {with_frames[0] / without[0]:.3f}")
    # the ordering step alone, on a full poll (64 packets) holding one frame
    batch = packets[:64]
    middle = Frame(int(batch[len(batch) // 2]["timestamp"][0]), frames[0].image)
    k = 2000
    t0 = time.thread_time()
    for _ in range(k):
        in_time_order([middle], batch)
    print(f"ordering one frame among {len(batch)} packets: {(time.thread_time() - t0) / k * 1e6:.1f} us per poll")


if __name__ == "__main__":
    main()
