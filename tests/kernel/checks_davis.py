"""Guest checks of the live camera path against an emulated DAVIS-346 on USB (davis_gadget.py).

The gadget replays a simulated gel recording at rest (vm.py makes it on the host and puts it in
the boot's shared folder) as a DAVIS-346 on dummy_hcd; dv-processing's own camera driver opens it
through libusb as it would open the real camera. The gadget is started once, then every part of a
set runs against it, each with its own verdict (a failing part does not hide the others), and
finally SIGTERM, which must unplug it. Two sets, two guest checks:

- :data:`PARTS` (here, in every test run): the USB descriptors, ``neurotouch-hid devices``,
  ``record --source davis`` and the product's DavisSource read directly: the data commit interval
  dv-processing reports and the events' age when they reach the source (event_age.py);
- :data:`PIPELINE_PARTS` (checks_davis_pipeline.py, the slow tier, ``pytest -m slow``):
  ``calibrate --source davis``, ``run --source davis --output jsonl``, the same stream as a
  recording through ``run --source FILE`` (the live camera rests as a recording does: context
  switches per second of both runs' steady states), and ``run --source davis`` on the gamepad with
  the camera unplugged (SIGUSR1) and plugged in again (SIGUSR2) mid-run.

Two things make the commands work under software emulation (tests/kernel/README.md has the
details): the pipeline's numba code is compiled on the host before the boot, for LLVM's generic
x86-64 CPU, into the shared folder (vm.py; compiling it in the guest took longer than 600 s), and
numpy's AVX2 code is turned off (NUMPY_GUEST_ENV: qemu's emulated AVX2 crashed ``calibrate`` in
``np.argsort``).

The guest is emulated and slow: the gadget replays the recording's first 0.55 s (the gel at rest)
in a loop with one APS frame per pass (``--to-s 0.55 --frame-every 14``). A Python start takes
tens of seconds here, so ``devices`` and ``record`` run by the CLI's ``main`` in this process
(``guestlib.cli_in_process``); the commands that run the gesture pipeline are each a process of
their own (numba's and numpy's settings for the guest, :func:`_env`). Run by tests/kernel/guest.py; asserted on by
tests/test_davis_kernel.py.
"""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

import guestlib
import numpy as np
import vm
from evdev import ecodes

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
GADGET = HERE / "davis_gadget.py"
TIMEOUT_S = 1200
COMMAND_TIMEOUT_S = 300
CLI = str(Path(sys.executable).parent / "neurotouch-hid")
#: The part of the replay recording sent, again and again (s from its start): the gel at rest
#: (the simulated session's first gesture starts at 0.6 s).
REST_TO_S = 0.55
#: Frames sent: the first of every 14, i.e. one per pass of the 0.55 s (14 frames) above.
FRAME_EVERY = 14
#: How many runs of 32 recorded events :func:`_match` tries to locate in the source.
HEAD_TRIES = 16
#: ``record``'s event batches (us, its ``batch_us``): a hole in a recording is longer than one.
RECORD_BATCH_US = 10_000
#: The push the gadget plays on SIGHUP (s of the recording: the simulated session's push, from
#: the rest before it to its end), then the part of it held, again and again; both GESTURE_SLOW
#: times slower than recorded (the gel's ~70k events/s at real speed are more than the emulated
#: guest's pipeline processes: tests/kernel/README.md).
PUSH_S, HELD_S, GESTURE_SLOW = (REST_TO_S, 2.0), (1.6, 2.0), 10
#: ``run``'s window on the gamepad (us): under emulation a window's estimate with the gel pushed
#: (homography, contacts, gesture) takes ~100x the host's ~1 ms, so the paper's 10 ms windows
#: fall far behind the camera; 200 ms ones keep up (on the host the same cued push, 10x slower,
#: gives the stick at full deflection with 10 to 200 ms windows).
RUN_WINDOW_US = 200_000
#: ``run``'s allowed lag (ms): a pushed window's estimate takes up to ~0.25 s under emulation, more
#: than the default 200 ms of data that may wait meanwhile; with less, the pipeline dropped 58 %
#: of the push's events and the stick reached only a tenth of its travel. With 3 s, in 2 of 3
#: guest runs on a loaded host, every event of the push was dropped (about 108k of 133k) and the
#: pad never moved: the emulated camera, its gadget and the pipeline share one emulated CPU. The
#: check is of the camera's path and the unplug, not of the emulator's speed: the run may lag.
RUN_MAX_LAG_MS = 30_000
#: The push counts as on the pad once the left stick is this far from the centre on either axis
#: (of 32767: the default profile maps a push's direction times its intensity to the left stick;
#: which way the replay's push goes, tests/test_davis_pipeline_kernel.py compares with the host's
#: run), at most this many seconds after the cue.
PUSHED, PUSH_WAIT_S = 16_000, 120
#: The gadget's log lines when the host starts its stream and when it plays the cue (davis_gadget.py).
STREAM_STARTED, CUE_TAKEN = "stream started", "SIGHUP: playing the cued gesture"
#: The cue is given this long after the run's stream started (s): its first passes (0.55 s of
#: camera time each, an APS frame of the gel at rest first) reach the pipeline before the push.
CUE_AFTER_STREAM_S = 3.0
#: The emulated camera's USB serial number (the gadget's ``--serial``).
CAMERA_SERIAL = "00000001"
#: Name of the replayed recording in the boot's shared folder (vm.py puts it there).
REPLAY_NAME = "davis_replay.aedat4"


def replay_path() -> Path:
    """The recording to replay: beside the result file guest.py was given (the shared folder)."""
    return Path(sys.argv[1]).resolve().parent / REPLAY_NAME


class EmulatedCamera:
    """davis_gadget.py as a child process: started, signalled, stopped; its log kept in a file."""

    def __init__(self, recording: Path) -> None:
        self.log_path = Path("/tmp/davis_gadget.log")
        self._log = open(self.log_path, "w")
        self.t0 = time.monotonic()
        self.proc = subprocess.Popen(
            [
                sys.executable,
                str(GADGET),
                str(recording),
                "--loop",
                "--to-s",
                str(REST_TO_S),
                "--frame-every",
                str(FRAME_EVERY),
                "--gesture",
                "{}:{}".format(*PUSH_S),
                "--hold",
                "{}:{}".format(*HELD_S),
                "--gesture-slow",
                str(GESTURE_SLOW),
                "--serial",
                CAMERA_SERIAL,
            ],
            stdout=subprocess.PIPE,
            stderr=self._log,
            text=True,
        )

    def wait_ready(self, timeout_s: float = 120.0) -> tuple[str, float]:
        """The gadget's ``READY bus B device D`` line and the seconds it took; raises if it never comes."""
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        line = self.proc.stdout.readline().strip() if ready else ""
        assert line.startswith("READY"), f"no READY line in {timeout_s} s: {line!r}; log: {self.log()[-2000:]}"
        return line, time.monotonic() - self.t0

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def said(self, text: str) -> int:
        """How many lines of the gadget's log contain ``text``."""
        return sum(text in line for line in self.log().splitlines())

    def stop(self) -> int | None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode


#: numpy's dispatched SIMD code left out in the guest: qemu 7.2's software emulation (TCG, cpu
#: model "max") reports AVX2, and numpy's AVX2 argsort (x86-simd-sort) crashes there with SIGSEGV
#: (``calibrate`` died in ``np.argsort``); numpy then runs its baseline (x86-64-v2) code.
NUMPY_GUEST_ENV = {"NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"}


def numba_cache() -> Path:
    """The pipeline's numba cache, compiled on the host before the boot (vm.py), in the shared folder."""
    return Path(sys.argv[1]).resolve().parent / vm.GUEST_NUMBA_CACHE


def _env(cache_log: bool = False) -> dict:
    # the pipeline's code comes from the host's cache (compiling it under emulation takes longer
    # than 600 s), which numba uses only for the same target CPU (vm.GUEST_NUMBA_ENV) and the same
    # source files: the commands import this checkout's neurotouch_hid, the one vm.py compiled
    # (the venv's console script would import the package it was installed from, another
    # checkout's path, whose cache is missing: the run then compiled for minutes)
    return dict(
        os.environ,
        PYTHONPATH=os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])]),
        HOME="/tmp",
        COLUMNS="200",
        XDG_CONFIG_HOME="/tmp/davis-config",
        NUMBA_CACHE_DIR=str(numba_cache()),
        **vm.GUEST_NUMBA_ENV,
        **NUMPY_GUEST_ENV,
        **({"NUMBA_DEBUG_CACHE": "1"} if cache_log else {}),  # on stdout
    )


def _command_env() -> dict[str, str]:
    """What :func:`_env` sets that a command run in this process (``guestlib.cli_in_process``)
    can take: numba's and numpy's settings are read when they are imported, so a command that
    runs the pipeline is a process of its own."""
    return {"HOME": "/tmp", "COLUMNS": "200", "XDG_CONFIG_HOME": "/tmp/davis-config"}


def _compiled_in_guest(cache_log: str) -> list[str]:
    """numba's cache log (``_env(cache_log=True)``): the functions compiled here, not loaded."""
    return sorted({line.rsplit("/", 1)[-1].rstrip("'") for line in cache_log.splitlines() if "data saved to" in line})


def _run(cmd: list[str], timeout: float = COMMAND_TIMEOUT_S, cache_log: bool = False) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(
            cmd,
            capture_output=True,
            text=True,
            timeout=timeout,
            cwd="/tmp",
            env=_env(cache_log),
            stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f"{' '.join(cmd)} did not finish in {timeout} s: {exc.stdout!r} {exc.stderr!r}") from None


def _camera_on_usb() -> Path | None:
    for dev in Path("/sys/bus/usb/devices").iterdir():
        try:
            if (dev / "idVendor").read_text().strip() == "152a" and (dev / "idProduct").read_text().strip() == "841a":
                return dev
        except OSError:
            continue
    return None


# --- the parts ---------------------------------------------------------------------------------
def _descriptors(camera: EmulatedCamera) -> dict:
    """What the host sees: ids, firmware version in bcdDevice, the endpoints libcaer uses."""
    dev = _camera_on_usb()
    assert dev is not None, "no 152a:841a device in sysfs"
    attrs = {
        name: (dev / name).read_text().strip()
        for name in ("idVendor", "idProduct", "bcdDevice", "manufacturer", "product", "serial", "speed")
    }
    interface = dev / f"{dev.name}:1.0"

    def enumerated() -> dict | None:
        found = {p.name: (p / "type").read_text().strip() for p in sorted(interface.glob("ep_*"))}
        return found if len(found) >= 2 else None

    # the interface's endpoints appear once the host has set the configuration, which under
    # emulation on a loaded machine can come a few seconds after the device itself
    endpoints = guestlib.wait_for(enumerated, timeout_s=30) or {}
    assert attrs["bcdDevice"].endswith("06"), attrs
    assert endpoints.get("ep_82") == "Bulk" and endpoints.get("ep_81") == "Interrupt", endpoints
    return {"attrs": attrs, "endpoints": endpoints}


def _devices(camera: EmulatedCamera) -> dict:
    """``neurotouch-hid devices --json`` as root: the emulated camera is present, accessible and ready, and
    dv-processing lists it."""
    code, out, _ = guestlib.cli_in_process("devices", "--json", env=_command_env())
    data = json.loads(out)
    assert code == 0 and data["ready"] == 1, data
    (cam,) = data["cameras"]
    assert cam["status"] == "ready" and cam["dv"]["model"] == "DAVIS" and cam["dv"]["firmware"] == 6, cam
    assert cam["usb"]["access"] == "ok" and cam["usb"]["reason"] == "" and cam["serial"] == CAMERA_SERIAL, cam
    return {"message": data["message"], "dv": cam["dv"], "usb": cam["usb"]}


def _match(source: tuple, recorded: tuple, period_us: int) -> dict:
    """The recorded events and frames against the replayed part of the source, which the gadget
    sends again every ``period_us``: each recorded event must be a source event with the same x, y,
    polarity and time offset (the wire's resolution is 1 us) modulo the period, once the first one
    is located; each recorded frame a replayed frame, pixel for pixel."""
    a, fa = source
    b, fb = recorded
    first = min(int(a["timestamp"][0]), fa[0].t_us)
    end = first + int(REST_TO_S * 1e6)
    a = a[a["timestamp"] < end]
    fa = [f for f in fa if f.t_us < end][::FRAME_EVERY]
    assert len(b) > 100, f"only {len(b)} events recorded"
    key_a = np.stack([a["x"], a["y"], a["polarity"]], axis=1).astype(np.int64)
    key_b = np.stack([b["x"], b["y"], b["polarity"]], axis=1).astype(np.int64)
    # locate 32 recorded events in a row in the source; under load the host can drop a packet, so
    # the first run of 32 may hold a gap: the next runs are tried
    start = head_at = None
    for head_at in range(0, min(len(b) - 32, HEAD_TRIES * 32), 32):
        head = key_b[head_at : head_at + 32]
        candidates = np.flatnonzero((key_a[: len(a) - 32] == head[0]).all(axis=1))
        start = next((int(j) for j in candidates if (key_a[j : j + 32] == head).all()), None)
        if start is not None:
            break
    assert start is not None, "the recorded events are not found in the replayed recording"
    rel_a = a["timestamp"] - first
    rel_b = (b["timestamp"] - b["timestamp"][head_at] + rel_a[start]) % period_us
    source_set = set(zip(rel_a.tolist(), *key_a.T.tolist()))
    found = np.array([item in source_set for item in zip(rel_b.tolist(), *key_b.T.tolist())])
    span_us = int(b["timestamp"][-1] - b["timestamp"][0])
    expected = len(a) * span_us / period_us  # events the replay sent in that span, about
    frames = [min(int(np.abs(src.image.astype(int) - f.image.astype(int)).max()) for src in fa) for f in fb]
    # the recorded events on the replay's own time axis (us, loops unwrapped), cut into stretches at
    # every hole: a stretch of camera time longer than a recorded batch (10 ms) and the replay's
    # longest quiet (its loop's seam included) where nothing was recorded though the replay sent
    # events. Within each stretch every event the replay sent must be there.
    t_b = (b["timestamp"].astype(np.int64) - int(b["timestamp"][head_at])) + int(rel_a[start])
    sorted_a = np.sort(rel_a.astype(np.int64))
    quiet_us = int(max(np.diff(sorted_a).max(initial=0), period_us - sorted_a[-1] + sorted_a[0]))
    gaps = np.diff(t_b)
    holes = np.flatnonzero(gaps > quiet_us + RECORD_BATCH_US)
    firsts, lasts = np.r_[0, holes + 1], np.r_[holes, len(t_b) - 1]

    def sent_until(t_us: np.ndarray) -> np.ndarray:  # events the replay sent at or before t_us
        loops, within = np.divmod(t_us, period_us)
        return loops * len(a) + np.searchsorted(sorted_a, within, side="right")

    in_stretches = int((sent_until(t_b[lasts]) - sent_until(t_b[firsts] - 1)).sum())
    return {
        "source_events": len(a),
        "period_us": period_us,
        "recorded_events": len(b),
        "start_index": start,
        "head_at": head_at,
        "span_us": span_us,
        "found_in_source": int(found.sum()),
        "first_not_found": int(np.argmin(found)) if not found.all() else None,
        "sent_in_span_about": round(expected),
        "holes": [(int(t_b[i] - t_b[0]), int(gaps[i])) for i in holes[:8]],
        "hole_us": int(gaps[holes].sum()),
        "sent_outside_holes": in_stretches,
        "frame_t_us": [int(f.t_us - b["timestamp"][0]) for f in fb],
        "recorded_frames": len(fb),
        "frame_shapes": sorted({tuple(f.image.shape) for f in fb}),
        "frame_max_diff": frames,
    }


def _record(camera: EmulatedCamera) -> dict:
    """``record --source davis --seconds 3``: the events and frames the replay sent, as sent."""
    from neurotouch_hid.sources.recording import RecordingReader

    out = Path("/tmp/davis-record.aedat4")
    out.unlink(missing_ok=True)
    code, said, err = guestlib.cli_in_process(
        "record", "--source", "davis", "--seconds", "3", str(out), env=_command_env()
    )
    assert code == 0 and out.exists(), f"exit {code}: {said[-1000:]}{err[-2000:]}"
    with RecordingReader(replay_path()) as src, RecordingReader(out) as rec:
        source, recorded = src.read_all(), rec.read_all()
    period = re.search(r"looped every (\d+) us", camera.log())
    assert period, "the gadget did not say its loop period"
    match = _match(source, recorded, int(period.group(1)))
    assert match["found_in_source"] == match["recorded_events"], match
    assert match["frame_shapes"] == [(260, 346)], match
    # between holes, every event the replay sent was recorded. Holes are where nothing arrived: a
    # guest starved by a loaded host reads slower than the camera sends and dv-processing's queue
    # drops what it cannot hold (41 % of the span has arrived under load). How much of the span
    # arrives is the host's load, not record's: reported, not asserted
    assert match["recorded_events"] == match["sent_outside_holes"], f"{match} {err[-800:]}"
    # one frame per 0.55 s pass: every recorded frame is a replayed one, pixel for pixel
    assert match["recorded_frames"] >= 1 and all(d == 0 for d in match["frame_max_diff"]), match
    return {**match, "said": said[-500:], "stderr": err[-500:]}


def _calibrate(camera: EmulatedCamera) -> dict:
    """``calibrate --source davis --frames 3`` on the gel at rest: it succeeds and writes a
    sensor.yaml (the host-side test compares it with calibrate on the replayed frame itself).
    Nobody pushes the replayed gel: the mirror and rotation are given, the guided check is off."""
    out = Path("/tmp/davis-sensor.yaml")
    out.unlink(missing_ok=True)
    args = ["--frames", "3", "--mirror", "--rotation", "0", "--no-check", "--out", str(out)]
    proc = _run([CLI, "calibrate", "--source", "davis", *args])
    assert proc.returncode == 0 and out.exists(), f"exit {proc.returncode}: {proc.stdout[-1000:]} {proc.stderr[-2000:]}"
    import yaml

    return {"sensor": yaml.safe_load(out.read_text()), "pass_us": int(REST_TO_S * 1e6), "stdout": proc.stdout[-1500:]}


# --- run on the camera: estimates, and the gamepad through an unplug ------------------------------
#: How long a run may take to start under emulation: Python, numba loading the pipeline from the
#: host's cache (about 60 s), dv-processing opening the camera.
RUN_START_S = 300


class _Lines:
    """A child's stderr, read without blocking, each line with the time it was read."""

    def __init__(self, stream) -> None:
        self.fd = stream.fileno()
        os.set_blocking(self.fd, False)
        self.lines: list[tuple[float, str]] = []
        self._partial = ""

    def poll(self) -> None:
        try:
            chunk = os.read(self.fd, 1 << 16).decode(errors="replace")
        except BlockingIOError:
            return
        if chunk:
            now = time.monotonic()
            *done, self._partial = (self._partial + chunk).split("\n")
            self.lines += [(now, line) for line in done]

    def find(self, text: str, after: float = 0.0) -> tuple[float, str] | None:
        return next(((t, line) for t, line in self.lines if text in line and t >= after), None)


def _pad_path(proc: subprocess.Popen, err: "_Lines", timeout_s: float) -> str:
    """The event node of the gamepad ``run`` made, once it exists: the pad of a run for a camera
    carries the camera's identity (``phys`` ``neurotouch-hid/SERIAL``, targets/identity.py), and
    ``run`` finds the emulated camera's serial on the bus (``sources/serial.py``). Raises
    AssertionError with the run's last lines when none comes in ``timeout_s``."""
    from evdev import InputDevice, list_devices

    from neurotouch_hid.targets.identity import identity_for

    phys = identity_for(CAMERA_SERIAL).phys

    def find() -> str | None:
        err.poll()
        for path in list_devices():
            try:
                if InputDevice(path).phys == phys:
                    return path
            except OSError:
                continue
        return None

    path = guestlib.wait_for(lambda: proc.poll() is not None or find(), timeout_s, interval_s=0.5)
    err.poll()
    assert isinstance(path, str), (
        f"no gamepad with phys {phys} within {timeout_s} s (run exited: {proc.poll()}): "
        f"{[line for _, line in err.lines[-8:]]}"
    )
    return path


def _input_devices() -> list[tuple[str, str, str]]:
    """Every input device now: (node, name, phys), for a failure's message."""
    from evdev import InputDevice, list_devices

    found = []
    for path in list_devices():
        try:
            device = InputDevice(path)
            found.append((path, device.name, device.phys))
        except OSError:
            continue
    return found


def _stick_off_centre(reader: guestlib.EventReader) -> int:
    """How far the left stick is from the centre on its farther axis (of 32767)."""
    return max(abs(reader.axes.get(ecodes.ABS_X, 0)), abs(reader.axes.get(ecodes.ABS_Y, 0)))


def _neutral(reader: guestlib.EventReader) -> bool:
    return not reader.keys and all(value == 0 for value in reader.axes.values())


def _run_gamepad_unplug(camera: EmulatedCamera) -> dict:
    """``run --source davis`` on the gamepad with the gel pushed, the camera then unplugged
    (SIGUSR1) mid-push: the pad (read back through evdev) showed the push (the default profile's
    left stick, at least PUSHED off centre) and is neutral by the time the driver reports the camera lost ("gamepad
    centred and released"); nothing is written while the camera is away; plugged in again
    (SIGUSR2), the driver says it is back (it has read data again) and keeps running until SIGTERM
    (exit 0).

    The push is the gadget's cue (SIGHUP: PUSH_S, then HELD_S looped, GESTURE_SLOW times slower),
    given CUE_AFTER_STREAM_S after this run's stream started (the gadget ignores a cue while no
    stream runs: the pad exists before ``run`` has opened the camera), so that the stream's first
    APS frame, the pipeline's reference, shows the gel at rest; ``run`` uses RUN_WINDOW_US windows
    so that the emulated pipeline keeps up."""
    out_path = Path("/tmp/davis-run-gamepad.out")
    streams = camera.said(STREAM_STARTED)
    with open(out_path, "w") as out:
        proc = subprocess.Popen(
            [
                CLI,
                "run",
                "--source",
                "davis",
                "--output",
                "gamepad",
                "--window-us",
                str(RUN_WINDOW_US),
                "--max-lag-ms",
                str(RUN_MAX_LAG_MS),
            ],
            stdout=out,
            stderr=subprocess.PIPE,
            text=True,
            cwd="/tmp",
            env=_env(cache_log=True),
            stdin=subprocess.DEVNULL,
        )
    err = _Lines(proc.stderr)
    reader = None

    def pump_until(pred, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            reader.pump(0.2, max_s=0.2)
            err.poll()
            if pred():
                return True
            assert proc.poll() is None, f"run exited {proc.returncode}: {err.lines[-5:]}"
        return False

    try:
        t_start = time.monotonic()
        reader = guestlib.EventReader(_pad_path(proc, err, RUN_START_S))
        pad_after_s = time.monotonic() - t_start
        streaming = pump_until(lambda: camera.said(STREAM_STARTED) > streams, RUN_START_S)
        assert streaming, f"run did not start the camera's stream: {camera.log()[-1000:]}"
        stream_after_s = time.monotonic() - t_start
        pump_until(lambda: False, CUE_AFTER_STREAM_S)  # the stream's first passes: the gel at rest
        assert _neutral(reader), f"not neutral at rest: {reader.axes} {reader.keys}"
        cues = camera.said(CUE_TAKEN)
        t_cue = time.monotonic()
        camera.proc.send_signal(signal.SIGHUP)
        taken = guestlib.wait_for(lambda: camera.said(CUE_TAKEN) > cues, 30.0)
        assert taken, f"the gadget did not play the cue: {camera.log()[-1000:]}"
        if not pump_until(lambda: _stick_off_centre(reader) >= PUSHED, PUSH_WAIT_S):
            devices = _input_devices()
            proc.send_signal(signal.SIGTERM)  # its summary says what the pipeline processed and dropped
            proc.wait(120)
            err.poll()
            compiled = _compiled_in_guest(out_path.read_text())
            since_cue = [line for line in camera.log().splitlines()[-400:] if " sent " not in line][-12:]
            raise AssertionError(
                f"no push on the pad {PUSH_WAIT_S} s after the cue: {reader.axes}, {len(reader.reports)} reports; "
                f"the run said {[line for _, line in err.lines[-12:]]}; input devices {devices}; "
                f"the camera's log {since_cue}; numba compiled in the guest: {compiled or 'nothing'}"
            )
        pushed_after_s = time.monotonic() - t_cue
        pushed_axes = dict(reader.axes)
        t_unplug = time.monotonic()
        camera.proc.send_signal(signal.SIGUSR1)
        assert pump_until(lambda: err.find("gamepad centred", t_unplug), 120), f"no loss reported: {err.lines[-5:]}"
        t_lost, lost = err.find("gamepad centred", t_unplug)
        reader.pump(0.5)
        assert _neutral(reader), f"not neutral when the loss was reported: {reader.axes} {reader.keys}"
        written = len(reader.reports)
        time.sleep(2)
        camera.proc.send_signal(signal.SIGUSR2)
        t_replug = time.monotonic()
        assert pump_until(lambda: err.find("is back", t_replug), 180), f"not back after the re-plug: {err.lines[-5:]}"
        t_back, back = err.find("is back", t_replug)
        assert len(reader.reports) == written, f"written while the camera was away: {reader.reports[written:]}"
        assert not pump_until(lambda: proc.poll() is not None, 10), "run stopped after the camera came back"
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(120)
        err.poll()
        reader.pump(0.5)
        assert code == 0 and (reader.gone or _neutral(reader)), f"exit {code}, pad {reader.axes} {reader.keys}"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if reader is not None:
            reader.close()
    compiled = _compiled_in_guest(out_path.read_text())
    assert not compiled, f"numba compiled in the guest (the host's cache was not used): {compiled}"
    return {
        "pad_after_s": round(pad_after_s, 1),
        "stream_after_s": round(stream_after_s, 1),
        "pushed_after_cue_s": round(pushed_after_s, 1),
        "pushed_axes": {ecodes.ABS[code]: value for code, value in pushed_axes.items() if value},
        "lost": lost,
        "lost_reported_after_unplug_s": round(t_lost - t_unplug, 1),
        "back": back,
        "back_after_replug_s": round(t_back - t_replug, 1),
        "exit_code": code,
        "stderr": "\n".join(line for _, line in err.lines)[-1500:],
    }


# --- at rest: the live camera's wake-ups against the same recording's ------------------------------
#: A run's steady state starts this long after its first state was written (s): the camera's or
#: the file's first window, the markers found on the first APS frame, the rest recognised.
REST_SETTLE_S = 5.0
#: Its context switches are counted over this long (s).
REST_MEASURE_S = 15.0
#: The live camera's run may make at most this many times the context switches per second of the
#: same recording's run (docs/performance.md, "At rest").
REST_RATIO = 1.5
#: Passes of the replayed rest in the recording ``run --source FILE`` plays: longer than its start
#: to its end (REST_SETTLE_S + REST_MEASURE_S after its first window), with a margin.
REST_PASSES = 60


def _rest_recording(period_us: int) -> Path:
    """What the emulated camera streams, as an AEDAT4 file: the replayed rest (the recording's
    first REST_TO_S, one APS frame per pass, FRAME_EVERY) REST_PASSES times, ``period_us`` apart
    (the gadget's loop), in a folder without a sensor.yaml (``run`` then uses the built-in one, as
    on the camera)."""
    from neurotouch_hid.sources import Frame
    from neurotouch_hid.sources.recording import RecordingReader, RecordingWriter

    with RecordingReader(replay_path()) as reader:
        events, frames = reader.read_all()
    first = min(int(events["timestamp"][0]), frames[0].t_us)
    end = first + int(REST_TO_S * 1e6)
    events = events[events["timestamp"] < end]
    frames = [f for f in frames if f.t_us < end][::FRAME_EVERY]
    out = Path("/tmp/davis-rest/rest.aedat4")
    out.parent.mkdir(exist_ok=True)
    with RecordingWriter(out) as writer:
        for k in range(REST_PASSES):
            shift = k * period_us
            for frame in frames:
                writer.write_frame(Frame(frame.t_us + shift, frame.image))
            lap = events.copy()
            lap["timestamp"] += shift
            writer.write_events(lap)
    return out


def _thread_switches(pid: int) -> dict[str, tuple[int, int]]:
    """Context switches so far of each thread of process ``pid``: ``"TID COMM"`` -> (voluntary,
    nonvoluntary) (``/proc/PID/task/TID/status``, ``comm``); a thread that ended meanwhile is left out."""
    counts = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            comm = (task / "comm").read_text().strip()
            fields = dict(line.split(":", 1) for line in (task / "status").read_text().splitlines() if ":" in line)
        except OSError:
            continue
        counts[f"{task.name} {comm}"] = (
            int(fields["voluntary_ctxt_switches"]),
            int(fields["nonvoluntary_ctxt_switches"]),
        )
    return counts


def _cpu_s(pid: int) -> float:
    """CPU time so far of process ``pid`` (s, user + system of all its threads, ``/proc/PID/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


_COLD_SCRIPT = """
import traceback
from neurotouch_hid.service import warmup
from neurotouch_hid.service.kernel_groups import kernels
for group in warmup.PIPELINE_OF["default"]:
    for name, d in kernels(group).items():
        try:
            magic = d.targetctx.codegen().magic_tuple()
            index = d._cache._cache_file._load_index()
            keys = [key[1] for key in index if len(key) > 1]
            if magic not in keys:
                print(group.name, name, "magic", magic, "index", keys[:2], type(d._cache).__name__)
        except Exception:
            print(group.name, name, traceback.format_exc()[-400:])
"""


def _cold_kernels() -> str:
    """Which kernels of the pipeline's groups the warm-up (``warmup.cached_signatures``) finds no
    code for in the host's cache, and why (the magic tuples, or the exception): said when a run
    compiles in the guest."""
    proc = subprocess.run(
        [sys.executable, "-c", _COLD_SCRIPT], capture_output=True, text=True, cwd="/tmp", env=_env(), timeout=300
    )
    return (proc.stdout[:1500] or "none cold") + proc.stderr[-500:]


def _measured_run(source: str, name: str, camera: EmulatedCamera, cache_log: bool = False) -> dict:
    """``run --source SOURCE --output jsonl`` until SIGTERM, and its steady state from
    REST_SETTLE_S after its first state to REST_MEASURE_S later: context switches per second
    summed over its threads (``/proc/PID/task/*/status``, voluntary + nonvoluntary), per thread
    (voluntary, nonvoluntary), and the share of a CPU it and the emulated camera took. Its states
    go to a file (the first one says the run has started: under emulation Python and numba take
    one to three minutes). Returns ``{"rest": those figures, "states": [...], "stdout": ...,
    "stderr": ...}``; raises AssertionError when no state comes in RUN_START_S or SIGTERM does not
    end it with exit 0."""
    out = Path(f"/tmp/davis-rest/{name}.jsonl")
    out.parent.mkdir(exist_ok=True)
    out.unlink(missing_ok=True)
    err_path, stdout_path = out.with_suffix(".err"), out.with_suffix(".out")
    with open(err_path, "w") as err, open(stdout_path, "w") as stdout:
        proc = subprocess.Popen(
            [CLI, "run", "--source", source, "--output", "jsonl", "--out", str(out)],
            stdout=stdout,
            stderr=err,
            cwd="/tmp",
            env=_env(cache_log),
            stdin=subprocess.DEVNULL,
        )
    try:
        t0 = time.monotonic()
        started = guestlib.wait_for(
            lambda: proc.poll() is not None or (out.exists() and out.stat().st_size > 0), RUN_START_S, interval_s=0.5
        )
        assert started and proc.poll() is None, (
            f"no state within {RUN_START_S} s (exit {proc.poll()}): {err_path.read_text()[-1500:]}; "
            f"numba's cache log (NUMBA_DEBUG_CACHE, when asked): {stdout_path.read_text()[:1500]}; "
            f"the run's warm-up reads its cache as: {_cold_kernels()}"
        )
        start_s = time.monotonic() - t0
        time.sleep(REST_SETTLE_S)
        cpu = (_cpu_s(proc.pid), _cpu_s(camera.proc.pid))
        before, t_before = _thread_switches(proc.pid), time.monotonic()
        time.sleep(REST_MEASURE_S)
        after, t_after = _thread_switches(proc.pid), time.monotonic()
        cpu = (_cpu_s(proc.pid) - cpu[0], _cpu_s(camera.proc.pid) - cpu[1])
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    span = t_after - t_before
    camera_sent = _camera_sent(camera.log(), t_before, t_after)
    rates = {
        tid: [round((n - before.get(tid, (0, 0))[k]) / span, 1) for k, n in enumerate(counts)]
        for tid, counts in after.items()
    }
    stderr = err_path.read_text()
    assert code == 0, f"run --source {source} ended with {code} on SIGTERM: {stderr[-1500:]}"
    rest = {
        "switches_per_s": round(sum(sum(r) for r in rates.values()), 1),
        "voluntary_per_s": round(sum(r[0] for r in rates.values()), 1),
        "per_thread": {tid: r for tid, r in sorted(rates.items(), key=lambda kv: -sum(kv[1])) if sum(r)},
        "threads_gone": sorted(set(before) - set(after)),
        "span_s": round(span, 1),
        "cpu_share": round(cpu[0] / span, 3),
        "camera_cpu_share": round(cpu[1] / span, 3),
        "camera_sent": camera_sent,
        "first_state_after_s": round(start_s, 1),
        "summary": stderr.strip().splitlines()[-1][-400:] if stderr.strip() else "",
    }
    states = [json.loads(line) for line in out.read_text().splitlines()]
    return {"rest": rest, "states": states, "stdout": stdout_path.read_text(), "stderr": stderr}


_SENT = re.compile(r"davis_gadget: ([\d.]+) sent (\d+) transfers \((\d+) short\), (\d+) bytes")
_DELAY = re.compile(r"davis_gadget: ([\d.]+) USB early packet delay ([\d.]+) us")


def _camera_sent(log: str, t_from: float, t_to: float) -> dict:
    """What the emulated camera sent between ``t_from`` and ``t_to`` (time.monotonic(), s), from
    its log's counts (davis_gadget.py logs them once a second): transfers, short ones (the early
    packet delay's) and bytes a second, and the early packet delay (us) the host last wrote
    before ``t_to`` (None: libcaer's default, never written)."""
    counts = [(float(m[1]), *map(int, m.groups()[1:])) for m in _SENT.finditer(log)]
    counts = [c for c in counts if t_from <= c[0] <= t_to]
    delays = [float(m[2]) for m in _DELAY.finditer(log) if float(m[1]) <= t_to]
    sent: dict = {"early_packet_delay_us": delays[-1] if delays else None}
    if len(counts) >= 2 and counts[-1][0] > counts[0][0]:
        (t0, *first), (t1, *last) = counts[0], counts[-1]
        per_s = [round((b - a) / (t1 - t0), 1) for a, b in zip(first, last)]
        sent.update(transfers_per_s=per_s[0], short_per_s=per_s[1], bytes_per_s=per_s[2])
    return sent


#: ``run --source davis``'s steady state, measured by :func:`_run_jsonl` for :func:`_at_rest`.
_MEASURED: dict[str, dict] = {}


def _run_jsonl(camera: EmulatedCamera) -> dict:
    """``run --source davis --output jsonl`` until SIGTERM: estimates (the gel at rest: gesture
    "none") come out of the pipeline that numba loaded from the host's cache, compiling nothing
    in the guest; its steady state's context switches are kept for :func:`_at_rest` (one Python
    start for both)."""
    run = _measured_run("davis", "davis", camera, cache_log=True)
    states = run["states"]
    assert states, f"no states: {run['stderr'][-2000:]}"
    compiled = _compiled_in_guest(run["stdout"])
    assert not compiled, f"numba compiled in the guest (the host's cache was not used): {compiled}"
    assert all({"t_us", "gesture", "intensity_mm", "axes", "buttons"} <= set(s) for s in states), states[0]
    summary = re.search(r"(\d+) windows, (\d+) events, (\d+) frames", run["stderr"])
    assert summary and int(summary.group(1)) > 0, f"no windows processed: {run['stderr'][-1000:]}"
    _MEASURED["davis"] = run["rest"]
    return {
        "states": len(states),
        "gestures": sorted({s["gesture"] for s in states}),
        "first": {k: states[0][k] for k in ("t_us", "gesture", "intensity_mm")},
        "windows": int(summary.group(1)),
        "events": int(summary.group(2)),
        "frames": int(summary.group(3)),
        "cache_loads": sum("data loaded from" in line for line in run["stdout"].splitlines()),
        "summary": run["rest"]["summary"],
        "at_rest": run["rest"],
    }


def _at_rest(camera: EmulatedCamera) -> dict:
    """``run --source davis`` (:func:`_run_jsonl`'s) with the camera streaming the gel at rest
    made at most REST_RATIO times the context switches per second (its threads summed) of ``run``
    on the same stream as a recording, in the same guest: the live camera rests the way a
    recording does (one wake-up a window, docs/performance.md "At rest")."""
    davis = _MEASURED.get("davis")
    assert davis is not None, "run --source davis was not measured (see the run_jsonl part's error)"
    period = re.search(r"looped every (\d+) us", camera.log())  # said once a stream started
    assert period, "the gadget did not say its loop period"
    recording = _measured_run(str(_rest_recording(int(period.group(1)))), "recording", camera)["rest"]
    ratio = davis["switches_per_s"] / recording["switches_per_s"]
    result = {"ratio": round(ratio, 2), "davis": davis, "recording": recording}
    assert ratio <= REST_RATIO, result
    return result


def _event_age(camera: EmulatedCamera) -> dict:
    """DavisSource in this process on the camera (event_age.through_davis_source, a few seconds):
    the data commit interval dv-processing reports and the event batches' age and span, touched
    and at rest. Asserted on by tests/test_davis_kernel.py."""
    import event_age

    return event_age.through_davis_source(camera.log, CAMERA_SERIAL)


#: The parts of the default test run: the camera's USB path, no gesture pipeline (one Python
#: start each, about a minute under emulation).
PARTS = {
    "descriptors": _descriptors,
    "devices": _devices,
    "record": _record,
    "event_age": _event_age,
}
#: The parts that run the gesture pipeline on the camera (numba's code under emulation: about 5
#: minutes on an idle host, 8 to 17 on a loaded one): the slow tier, checks_davis_pipeline.py.
PIPELINE_PARTS = {
    "calibrate": _calibrate,
    "run_jsonl": _run_jsonl,
    "at_rest": _at_rest,
    "run_gamepad_unplug": _run_gamepad_unplug,
}


def against_the_camera(parts: dict) -> dict:
    """The gadget started once, every part of ``parts`` against it, then SIGTERM: it must unplug.

    Returns ``{"ready": ..., "<part>": {"ok": bool, "details" or "error"}, "sigterm": ...}``; fails
    only when the camera never appears."""
    recording = replay_path()
    assert recording.exists(), f"{recording} is missing (vm.py copies the replay recording there)"
    camera = EmulatedCamera(recording)
    results: dict = {}
    try:
        line, seconds = camera.wait_ready()
        results["ready"] = {"line": line, "seconds": round(seconds, 1)}
        for name, part in parts.items():
            t0 = time.monotonic()
            try:
                results[name] = {"ok": True, "details": part(camera)}
            except Exception as exc:  # noqa: BLE001 - recorded for the host-side test of that part
                results[name] = {
                    "ok": False,
                    "error": f"{type(exc).__name__}: {exc}",
                    "traceback": traceback.format_exc()[-3000:],
                }
            results[name]["seconds"] = round(time.monotonic() - t0, 1)
    finally:
        code = camera.stop()
        gone = guestlib.wait_for(lambda: _camera_on_usb() is None, timeout_s=20)
        results["sigterm"] = {
            "ok": code == 0 and bool(gone),
            "exit_code": code,
            "unplugged": bool(gone),
            "log_tail": camera.log()[-3000:],
        }
    return results


def check_emulated_davis() -> dict:
    """:func:`against_the_camera` with :data:`PARTS`."""
    return against_the_camera(PARTS)
