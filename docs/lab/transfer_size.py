"""What the live camera's APS frames cost dv-processing's reader against the host's USB transfer
size, in the test kernel (docs/lab/performance-history.md, "The live camera's USB transfers").

    PYTHONPATH=$PWD python3 docs/lab/transfer_size.py [--json FILE]

On the host it boots the test kernel once (tests/kernel/vm.py, the emulated camera's boot) and runs
itself inside. There the emulated DAVIS-346 (tests/kernel/davis_gadget.py) streams the gel at rest
(the replay's first 0.55 s looped, as checks_davis.py has it) with an APS frame every N-th replay
frame, for each N of :data:`FRAME_EVERY` in turn: many more than the slow tier's one a pass.
dv-processing's own driver opens it anew for each setting of :data:`TRANSFERS`, :data:`ROUNDS`
times in turn, and sets the host's USB transfers (``setTransfersNumber``, ``setTransfersSize``) on
the open camera, as DavisSource's ``_configure`` would; it is polled as DavisSource polls it
(docs/lab/commit_interval.py) for :data:`SECONDS` after :data:`SETTLE_S` not counted. Per
segment: the reader thread's context switches a second (``davis-SERIAL``,
``/proc/self/task/*/status``, voluntary + nonvoluntary) and the polling thread's; what the camera
sent (its log: 16 KiB gadget transfers, short ones, bytes, events and frames queued, bytes dropped)
against what the host received (events, frames); the event batches' age on arrival
(tests/kernel/event_age.py); the guest's CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
KERNEL = REPO / "tests" / "kernel"
sys.path[:0] = [str(KERNEL), str(REPO / "tests"), str(REPO)]

#: (transfers, bytes each): dv-processing 2.0.4's default first.
TRANSFERS = ((32, 8192), (16, 32768), (8, 65536))
#: Measured per setting and round (s); not counted after each switch (s); rounds.
SECONDS, SETTLE_S, ROUNDS = 10.0, 2.0, 2
#: The APS frames sent: every N-th of the replay's (25 a second recorded), each N in turn (the
#: camera's emulation started anew for each).
FRAME_EVERY = (2, 4)

_STATS = re.compile(
    r"davis_gadget: ([\d.]+) sent (\d+) transfers \((\d+) short\), (\d+) bytes; "
    r"queued (\d+) events, (\d+) frames; dropped (\d+) bytes"
)


def _gadget_counts(log: str, until: float) -> tuple:
    """The camera's last stats line before ``until`` (time.monotonic() s): (time, transfers,
    short, bytes, events, frames, dropped)."""
    rows = [(float(m[1]), *map(int, m.groups()[1:])) for m in _STATS.finditer(log)]
    rows = [r for r in rows if r[0] <= until]
    assert rows, f"no stats line before {until}: {log[-1500:]}"
    return rows[-1]


def _poll_for(camera, timed: list, seconds: float) -> int:
    """Poll ``camera`` as DavisSource does for ``seconds`` (up to 8 frames and 64 event batches a
    poll, 0.2 ms between polls that bring nothing); the event batches' rows into ``timed``
    (time.monotonic() s, lowest and highest timestamp us, events); returns the frames read."""
    frames = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        got = False
        for _ in range(8):
            if camera.getNextFrame() is None:
                break
            frames += 1
            got = True
        for _ in range(64):
            store = camera.getNextEventBatch()
            if store is None or not len(store):
                break
            timed.append((time.monotonic(), int(store.getLowestTime()), int(store.getHighestTime()), len(store)))
            got = True
        if not got:
            time.sleep(0.0002)
    return frames


def _switches() -> dict[str, int]:
    """This process's threads' context switches so far (voluntary + nonvoluntary) by ``comm``,
    the reader threads (``davis-*``) summed as ``reader``, the main thread as ``poller``."""
    out = {"reader": 0, "poller": 0}
    for task in Path("/proc/self/task").iterdir():
        try:
            comm = (task / "comm").read_text().strip()
            fields = dict(line.split(":", 1) for line in (task / "status").read_text().splitlines() if ":" in line)
        except OSError:
            continue
        n = int(fields["voluntary_ctxt_switches"]) + int(fields["nonvoluntary_ctxt_switches"])
        if comm.startswith("davis"):
            out["reader"] += n
        elif task.name == str(os.getpid()):
            out["poller"] += n
    return out


def _segment(cam, camera, offset_us: int, seconds: float) -> dict:
    """One measured segment: the figures of the module's docstring."""
    import guestlib
    from event_age import ages, device_clock0

    timed: list = []
    sw0, busy0, t0 = _switches(), guestlib.busy_s(), time.monotonic()
    frames = _poll_for(cam, timed, seconds)
    sw1, busy1, t1 = _switches(), guestlib.busy_s(), time.monotonic()
    _poll_for(cam, [], 1.1)  # polled on until the camera's stats line after t1
    log = camera.log()
    a, b = _gadget_counts(log, t0 + 0.5), _gadget_counts(log, t1 + 0.5)
    span_g = b[0] - a[0]
    span = t1 - t0
    row = {
        "reader_per_s": round((sw1["reader"] - sw0["reader"]) / span, 1),
        "poller_per_s": round((sw1["poller"] - sw0["poller"]) / span, 1),
        "guest_busy": round((busy1 - busy0) / span, 2),
        "received_frames_per_s": round(frames / span, 2),
        "received_events_per_s": round(sum(r[3] for r in timed) / span, 1),
        "sent_transfers_per_s": round((b[1] - a[1]) / span_g, 1),
        "sent_short_per_s": round((b[2] - a[2]) / span_g, 1),
        "sent_bytes_per_s": round((b[3] - a[3]) / span_g),
        "sent_events_per_s": round((b[4] - a[4]) / span_g, 1),
        "sent_frames_per_s": round((b[5] - a[5]) / span_g, 2),
        "dropped_bytes": b[6] - a[6],
    }
    row.update(ages(timed, offset_us, device_clock0(log)))
    return row


def guest(result: Path) -> int:
    """Inside the test kernel: the measurement, its figures to ``result`` (JSON)."""
    import vm

    result.with_name(vm.GUEST_STARTED).write_text(f"{os.getpid()}\n")
    import checks_davis
    import dv_processing as dv
    import guest as guest_script
    from event_age import us

    out: dict = {"setup": guest_script.setup(), "figures": []}
    camera = None
    try:
        for every in FRAME_EVERY:
            checks_davis.FRAME_EVERY = every  # EmulatedCamera's --frame-every
            camera = checks_davis.EmulatedCamera(checks_davis.replay_path())
            camera.wait_ready()
            for k in range(ROUNDS):
                for number, size in TRANSFERS:
                    # opened anew for each: the stream starts over (what a switch left behind is gone)
                    descriptor = next(d for d in dv.io.camera.discover() if d.cameraModel.name == "DAVIS")
                    cam = dv.io.camera.open(descriptor)
                    row = {"frame_every": every, "round": k, "transfers": [number, size]}
                    row["opened"] = [cam.getTransfersNumber(), cam.getTransfersSize()]
                    cam.setTransfersNumber(number)
                    cam.setTransfersSize(size)
                    offset_us = us(cam.getTimestampOffset())
                    _poll_for(cam, [], SETTLE_S)
                    row["read_back"] = [cam.getTransfersNumber(), cam.getTransfersSize()]
                    row.update(_segment(cam, camera, offset_us, SECONDS))
                    del cam
                    out["figures"].append(row)
                    print("transfer_size:", row, flush=True)
            camera.stop()
            out[f"gadget_log_tail_{every}"] = camera.log()[-1500:]
            camera = None
    finally:
        if camera is not None:
            camera.stop()
            out["gadget_log_tail"] = camera.log()[-3000:]
    result.write_text(json.dumps(out, indent=1, default=str))
    return 0


def host(args: argparse.Namespace) -> int:
    """Boot the test kernel with this script as its guest; print (and keep) its figures."""
    import vm

    data = vm.boot(guest_script=Path(__file__).resolve(), modules=("checks_davis",))
    if args.json:
        Path(args.json).write_text(json.dumps(data, indent=1, default=str))
    print("boot:", data.get("_boot"))
    for row in data.get("figures", []):
        print(row)
    return 0


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1].endswith(".json"):  # vm.boot's call, inside the guest
        return guest(Path(sys.argv[1]))
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", default=None, help="also write the guest's whole result here")
    return host(parser.parse_args())


if __name__ == "__main__":
    sys.exit(main())
