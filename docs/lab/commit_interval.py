"""The live camera's event age against dv-processing's data commit interval, in the test kernel
(docs/lab/performance-history.md, "The live camera's data commit interval").

    PYTHONPATH=$PWD python3 docs/lab/commit_interval.py [--json FILE]

On the host it boots the test kernel once (tests/kernel/vm.py, the emulated camera's boot) and runs
itself inside. There the emulated DAVIS-346 (tests/kernel/davis_gadget.py) streams the gel at rest
(the replay's first 0.55 s looped, as checks_davis.py has it), then, cued, the replay's push ten
times slower and its held part looped. dv-processing's own driver opens it; the camera is polled
as DavisSource polls it (up to 8 APS frames and 64 event batches a poll, 0.2 ms between polls that
bring nothing), the early packet delay the 1 ms dv-processing writes on open, and the data commit
interval (``setTimeInterval``) switched between 10 ms and 1 ms, :data:`SECONDS` each,
:data:`ROUNDS` times each at rest and pushed (0.5 s after each switch are not counted). Per batch
``getNextEventBatch`` returns: its age on arrival, (arrival in the camera's device time) - (its
last event's timestamp), and the same for its first event (tests/kernel/event_age.py). Printed:
p50 / p90 / max per phase and interval, batches and events.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import signal
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
KERNEL = REPO / "tests" / "kernel"
sys.path[:0] = [str(KERNEL), str(REPO / "tests"), str(REPO)]

INTERVALS_US = (10_000, 1_000)
#: Measured per interval, round and phase (s); not counted after each switch (s); rounds.
SECONDS, SETTLE_S, ROUNDS = 2.0, 0.5, 5
#: How long the driver's queue is left unread to see how much it holds (s).
UNREAD_S = 1.5


def _poll_for(camera, timed: list, seconds: float) -> None:
    """Poll ``camera`` as DavisSource does for ``seconds``; the event batches' rows into ``timed``
    (time.monotonic() s, lowest and highest timestamp us, events)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for _ in range(8):
            if camera.getNextFrame() is None:
                break
        got = False
        for _ in range(64):
            store = camera.getNextEventBatch()
            if store is None or not len(store):
                break
            timed.append((time.monotonic(), int(store.getLowestTime()), int(store.getHighestTime()), len(store)))
            got = True
        if not got:
            time.sleep(0.0002)


def _queue_holds(cam, interval_us: int) -> dict:
    """How much the driver's queue holds: with the commit interval at ``interval_us``, polled
    for a second, then left unpolled for :data:`UNREAD_S` and drained: the batches and camera time
    (ms) the drain brought, and the camera time lost between the last batch read before the
    pause and the first after it (ms)."""
    cam.setTimeInterval(datetime.timedelta(microseconds=interval_us))
    before: list = []
    _poll_for(cam, before, 1.0)
    time.sleep(UNREAD_S)
    after: list = []
    _poll_for(cam, after, 0.05)
    assert before and after, "no batches"
    return {
        "interval_us": interval_us,
        "drained_batches": len(after),
        "drained_ms": round((after[-1][2] - after[0][1]) / 1000.0, 1),
        "lost_ms": round((after[0][1] - before[-1][2]) / 1000.0, 1),
    }


def guest(result: Path, seconds: float, rounds: int) -> int:
    """Inside the test kernel: the measurement, its figures to ``result`` (JSON)."""
    import vm

    result.with_name(vm.GUEST_STARTED).write_text(f"{os.getpid()}\n")
    import checks_davis
    import dv_processing as dv
    import guest as guest_script
    import guestlib
    from event_age import ages, device_clock0, us

    out: dict = {"setup": guest_script.setup()}
    camera = checks_davis.EmulatedCamera(checks_davis.replay_path())
    try:
        out["ready"] = camera.wait_ready()
        descriptor = next(d for d in dv.io.camera.discover() if d.cameraModel.name == "DAVIS")
        cam = dv.io.camera.open(descriptor)
        out["opened"] = {
            "time_interval_us": us(cam.getTimeInterval()),
            "early_packet_delay_us": us(cam.getUSBEarlyPacketDelay()),
            "transfers": [cam.getTransfersNumber(), cam.getTransfersSize()],
        }
        offset_us = us(cam.getTimestampOffset())
        _poll_for(cam, [], 2.0)  # the stream's start
        clock0 = device_clock0(camera.log())
        out["figures"] = []
        for phase in ("rest", "push"):
            if phase == "push":
                camera.proc.send_signal(signal.SIGHUP)
                _poll_for(cam, [], 1.0)
            for k in range(rounds):
                for interval in INTERVALS_US:
                    cam.setTimeInterval(datetime.timedelta(microseconds=interval))
                    _poll_for(cam, [], SETTLE_S)
                    timed: list = []
                    busy0, t0 = guestlib.busy_s(), time.monotonic()
                    _poll_for(cam, timed, seconds)
                    row = {"phase": phase, "round": k, "interval_us": interval}
                    row["guest_busy"] = round((guestlib.busy_s() - busy0) / (time.monotonic() - t0), 2)
                    row["read_back_us"] = us(cam.getTimeInterval())
                    row.update(ages(timed, offset_us, clock0))
                    row["rows"] = [
                        (round((t - clock0) * 1e6), lo - offset_us, hi - offset_us, n) for t, lo, hi, n in timed
                    ]
                    out["figures"].append(row)
                    print("commit_interval:", {k: v for k, v in row.items() if k != "rows"}, flush=True)
        out["queue"] = [_queue_holds(cam, interval) for interval in INTERVALS_US for _ in range(2)]
        print("commit_interval: queue", out["queue"], flush=True)
        out["offset_changed"] = us(cam.getTimestampOffset()) != offset_us
        del cam
    finally:
        camera.stop()
        out["gadget_log_tail"] = camera.log()[-2000:]
    result.write_text(json.dumps(out, indent=1, default=str))
    return 0


def _pooled(rows: list[dict]) -> str:
    """The segments' batches pooled: ages (ms) of their last and first events (p50, p90, min,
    max), the camera time a batch spans (ms, p50 and p90), the events' mean age (each batch's
    events taken as spread evenly over its span), and each segment's guest CPU (busy share)."""
    import numpy as np

    raw = np.array([b for r in rows for b in r.get("rows", [])], dtype=np.float64).reshape(-1, 4)
    if not len(raw):
        return "no batches"
    text = []
    for name, column in (("last", 2), ("first", 1)):
        age = (raw[:, 0] - raw[:, column]) / 1000.0
        p50, p90 = np.percentile(age, [50, 90])
        text.append(f"{name} event p50 {p50:.2f} p90 {p90:.2f} min {age.min():.2f} max {age.max():.2f} ms")
    span = (raw[:, 2] - raw[:, 1]) / 1000.0
    mean_age = np.average((raw[:, 0] - (raw[:, 1] + raw[:, 2]) / 2) / 1000.0, weights=raw[:, 3])
    text.append(f"span p50 {np.percentile(span, 50):.2f} p90 {np.percentile(span, 90):.2f} ms")
    text.append(f"events' mean age {mean_age:.2f} ms")
    text.append(f"guest busy {[r.get('guest_busy') for r in rows]}")
    return "; ".join(text)


def host(args: argparse.Namespace) -> int:
    """Boot the test kernel with this script as its guest; print (and keep) its figures."""
    import vm

    data = vm.boot(guest_script=Path(__file__).resolve(), modules=("checks_davis",))
    if args.json:
        Path(args.json).write_text(json.dumps(data, indent=1, default=str))
    print("opened:", data.get("opened"), "boot:", data.get("_boot"))
    for phase in ("rest", "push"):
        for interval in INTERVALS_US:
            rows = [r for r in data.get("figures", []) if r["phase"] == phase and r["interval_us"] == interval]
            batches = sum(r.get("batches", 0) for r in rows)
            events = sum(r.get("events", 0) for r in rows)
            back = [r["read_back_us"] for r in rows]
            print(f"{phase} {interval} us: read back {back}, {batches} batches, {events} events; {_pooled(rows)}")
    return 0


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1].endswith(".json"):  # vm.boot's call, inside the guest
        return guest(Path(sys.argv[1]), SECONDS, ROUNDS)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", default=None, help="also write the guest's whole result here")
    return host(parser.parse_args())


if __name__ == "__main__":
    sys.exit(main())
