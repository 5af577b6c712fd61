"""Guest check of two sensors on one machine in a real kernel: two drivers, one per camera serial,
run at once, each with its own pad whose identity comes from its serial, each driven by its own
gel, each with its own config; stopping one leaves the other running.

Run by tests/kernel/guest.py inside qemu (after checks_runtime_remap.py, whose helpers it uses);
asserted on by tests/test_sensors_kernel.py. What stands in for each camera is a predictions file
(the estimates a gel's pipeline gives, replayed in real time as ``run --source PRED.jsonl
--serial X`` does) and not the simulated gel through the pipeline: the emulated guest cannot run
the pipeline in real time even once (checks_davis_pipeline.py needs 200 ms windows and a gesture
ten times slower), let alone twice at once. Everything else is real: each driver is ``run_driver``
(what `neurotouch-hid run` calls) in a process of its own, forked from this one (a Python start
costs tens of seconds here), with its own ``--serial``, ended by its own SIGTERM; its pad is a
uinput device read back with evdev; the user's config folder holds a folder for one of the two
cameras; `devices --json` is the CLI's.
"""

from __future__ import annotations

import json
import os
import select
import signal
import tempfile
import time
from pathlib import Path

import guestlib
from checks_runtime_remap import G, Watcher, _devices, _write_preds, sequence
from evdev import InputDevice, ecodes

TIMEOUT_S = 600
#: How long a pad may take to appear, and then to show its gel's first push (s). At host load
#: 20-25 the pads appeared 31 s after the drivers were forked and LEFT1's A 22 s after that (the
#: run opens its source and starts its threads after its pad); 60 s was once too little.
PUSH_WAIT_S = 180.0
LEFT, RIGHT = "LEFT1", "RIGHT1"
#: LEFT1's own profile (``sensors/LEFT1/profile.yaml``): its pad has a name of its own and a push
#: presses A; the shared default (RIGHT1's) moves the left stick with a push.
LEFT_PROFILE = """\
description: guest check - the left camera's own profile
device: {name: NeuroTouch LEFT1, vendor: 0x045e, product: 0x028e, version: 0x0114}
mappings:
  pad: {input: push_intensity, output: A, press_mm: 2.0, release_mm: 1.0}
"""


def _start(preds: Path, serial: str, env: dict[str, str]) -> tuple[int, int]:
    """``run --source PREDS --serial SERIAL --output gamepad`` (no --profile) in a forked child:
    (its pid, the read end of the pipe its result comes on: JSON, what it said and how it ended)."""
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    _import_what_a_run_imports()
    read_fd, write_fd = os.pipe()
    child = os.fork()
    if child == 0:
        said: list[str] = []
        answer: dict = {"ok": False}
        try:
            os.close(read_fd)
            os.environ.update(env)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            stats = run_driver(
                str(preds), None, "gamepad", DriverOptions(serial=serial, say=said.append, max_lag_us=600_000_000)
            )
            answer = {"ok": True, "summary": stats.summary()}
        except BaseException as exc:  # noqa: BLE001 - handed to the parent
            answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        finally:
            answer["said"] = said[-20:]
            data = json.dumps(answer, default=str).encode()
            while data:
                data = data[os.write(write_fd, data) :]
            os._exit(0)
    os.close(write_fd)
    return child, read_fd


def _import_what_a_run_imports() -> None:
    """Import here, once, what ``run_driver`` imports as it goes: each forked child has it then
    (under emulation an import of these costs seconds, and each child would pay it)."""
    import neurotouch_hid.core.dataset  # noqa: F401
    import neurotouch_hid.engine.engine  # noqa: F401
    import neurotouch_hid.inputs.copilot  # noqa: F401
    import neurotouch_hid.inputs.hide  # noqa: F401
    import neurotouch_hid.mapping.mapper  # noqa: F401
    import neurotouch_hid.service.control  # noqa: F401
    import neurotouch_hid.service.games  # noqa: F401
    import neurotouch_hid.targets.uinput.desktop  # noqa: F401
    import neurotouch_hid.targets.uinput.gamepad  # noqa: F401


def _result(pid: int, fd: int, timeout_s: float = 60.0) -> dict:
    """The child's answer and exit status, once it has ended (killed after ``timeout_s``)."""
    chunks, end = [], time.monotonic() + timeout_s
    while time.monotonic() < end:
        if not select.select([fd], [], [], max(0.0, end - time.monotonic()))[0]:
            break
        chunk = os.read(fd, 65536)
        if not chunk:
            break
        chunks.append(chunk)
    os.close(fd)
    done, status = os.waitpid(pid, os.WNOHANG)
    if done == 0:
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
    answer = json.loads(b"".join(chunks) or b'{"ok": false, "error": "no answer"}')
    answer["exit"] = os.waitstatus_to_exitcode(status)
    return answer


def _alive(pid: int) -> bool:
    return os.waitpid(pid, os.WNOHANG)[0] == 0


def _pad(serial: str) -> str | None:
    found = _devices(f"neurotouch-hid/{serial}")
    return found[0] if len(found) == 1 else None


def check_two_sensors_two_pads_each_its_own() -> dict:
    """Two drivers at once, LEFT1 (a folder of its own with profile.yaml) and RIGHT1 (none: the
    shared default): two pads, phys ``neurotouch-hid/LEFT1`` and ``neurotouch-hid/RIGHT1``, LEFT1's
    named by its own profile. LEFT1's gel holds a push: its pad's A is down and its stick never
    moves; RIGHT1's gel pushes again and again: its stick moves and its A is never pressed.
    `devices --json` lists a driver for each serial, with the pid of its process. SIGTERM to
    LEFT1's: it exits 0, its pad goes with A released; RIGHT1's pad stays, its driver runs on
    and its stick keeps moving; then SIGTERM to RIGHT1's: exit 0, its pad gone, centred."""
    folder = Path(tempfile.mkdtemp(prefix="sensors-"))
    runtime_dir, config = folder / "xdg-runtime", folder / "config"
    runtime_dir.mkdir(mode=0o700)
    own = config / "neurotouch-hid" / "sensors" / LEFT
    own.mkdir(parents=True)
    (own / "profile.yaml").write_text(LEFT_PROFILE)
    env = {"XDG_RUNTIME_DIR": str(runtime_dir), "XDG_CONFIG_HOME": str(config)}
    (folder / LEFT).mkdir()
    (folder / RIGHT).mkdir()
    left_preds = _write_preds(folder / LEFT, sequence((G.PUSH, 5.0, 240.0), lead_in_s=2.0))
    right_preds = _write_preds(folder / RIGHT, sequence(*[(G.PUSH, 6.0, 1.0)] * 150, lead_in_s=2.0))
    codes = ecodes.ecodes
    details: dict = {}
    started = time.monotonic()
    left_pid, left_fd = _start(left_preds, LEFT, env)
    right_pid, right_fd = _start(right_preds, RIGHT, env)
    watchers: dict[str, Watcher] = {}

    def fail(what: str) -> AssertionError:
        """``what``, with how each driver was then and what it said (both stopped first)."""
        nonlocal left_fd, right_fd
        ended = {}
        for serial, pid, fd in ((LEFT, left_pid, left_fd), (RIGHT, right_pid, right_fd)):
            if fd >= 0:
                alive = _alive(pid)
                if alive:
                    os.kill(pid, signal.SIGTERM)
                ended[serial] = {"alive": alive, **_result(pid, fd, 30.0)}
        left_fd = right_fd = -1
        seen = {k: (w.reader.keys, w.reader.axes, len(w.events)) for k, w in watchers.items()}
        return AssertionError(f"{what}; the pads read {seen}; the drivers: {json.dumps(ended)[:3000]}")

    try:
        pads = guestlib.wait_for(
            lambda: (_pad(LEFT) and _pad(RIGHT)) or not (_alive(left_pid) and _alive(right_pid)), PUSH_WAIT_S, 0.1
        )
        if not (pads and _alive(left_pid) and _alive(right_pid)):
            raise fail("the two pads did not appear")
        details["pads_after_s"] = round(time.monotonic() - started, 1)
        for serial in (LEFT, RIGHT):
            device = InputDevice(_pad(serial))
            details[serial] = {"path": device.path, "name": device.name, "phys": device.phys, "uniq": device.uniq}
            details[serial]["ids"] = [device.info.vendor, device.info.product]
            device.close()
            watchers[serial] = Watcher(details[serial]["path"])
        left, right = watchers[LEFT], watchers[RIGHT]
        pressed = lambda: codes["BTN_SOUTH"] in left.pressed or not _alive(left_pid)  # noqa: E731
        if not (guestlib.wait_for(pressed, PUSH_WAIT_S) and _alive(left_pid) and codes["BTN_SOUTH"] in left.pressed):
            raise fail("LEFT1's push did not press A")
        details["a_after_s"] = round(time.monotonic() - started, 1)
        moved = lambda: right.reader.axes.get(ecodes.ABS_X, 0) > 8000 or not _alive(right_pid)  # noqa: E731
        if not (
            guestlib.wait_for(moved, PUSH_WAIT_S)
            and _alive(right_pid)
            and right.reader.axes.get(ecodes.ABS_X, 0) > 8000
        ):
            raise fail("RIGHT1's push did not move its stick")

        code, out, err = guestlib.cli_in_process("devices", "--json", env=env)
        drivers = json.loads(out)["drivers"]
        details["devices"] = {"exit": code, "drivers": drivers, "stderr": err[-500:]}
        details["pids"] = {LEFT: left_pid, RIGHT: right_pid}

        moves_before = len(right.events)
        os.kill(left_pid, signal.SIGTERM)
        details["left_result"] = _result(left_pid, left_fd)
        left_fd = -1
        guestlib.wait_for(lambda: left.reader.gone, 10.0)
        details["left_gone"] = left.reader.gone and _pad(LEFT) is None
        details["left_pressed_at_end"] = sorted(left.pressed)
        details["right_alive_after_left_stopped"] = _alive(right_pid) and _pad(RIGHT) is not None
        # the other driver runs on: its pad keeps getting its gel's pushes
        more = guestlib.wait_for(lambda: len(right.events) > moves_before + 20, 30.0)
        details["right_events_after_left_stopped"] = len(right.events) - moves_before if more else 0
        os.kill(right_pid, signal.SIGTERM)
        details["right_result"] = _result(right_pid, right_fd)
        right_fd = -1
        guestlib.wait_for(lambda: right.reader.gone, 10.0)
        details["right_gone"] = right.reader.gone and _pad(RIGHT) is None
        details["right_axes_at_end"] = {str(k): v for k, v in right.reader.axes.items() if v}
        details["left_axes"] = {
            str(c): v for t, c, v in left.events if t == ecodes.EV_ABS and c in (ecodes.ABS_X, ecodes.ABS_Y) and v
        }
        details["right_pressed_ever"] = sorted({c for t, c, v in right.events if t == ecodes.EV_KEY and v})
    finally:
        for pid, fd in ((left_pid, left_fd), (right_pid, right_fd)):
            if fd >= 0:
                if _alive(pid):
                    os.kill(pid, signal.SIGTERM)
                details.setdefault("cleanup", []).append(_result(pid, fd, 30.0))
        for watcher in watchers.values():
            try:
                watcher.stop()
            except AssertionError as exc:
                details.setdefault("reader_errors", []).append(str(exc))
    return details
