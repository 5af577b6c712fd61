"""Runs INSIDE the qemu guest (tests/kernel/vm.py boots it): every guest check, one JSON file.

Usage (by vm.py): ``python3 tests/kernel/guest.py OUT/result.json [MODULE ...]``: with MODULEs
(e.g. ``checks_davis``), only those check modules (vm.py boots two guests one after the other, each
with its share of the modules, ``vm.guest_parts()``), in name order.

0. Write ``OUT/guest-started`` (``vm.GUEST_STARTED``): the host then knows the boot reached this
   script (a boot that never does is booted again). Every check prints a line as it starts and as it
   ends: vng's log on the host shows where a guest stopped.
1. Setup: load the modules (uinput, joydev, ...), put the project's udev rules into
   /run/udev/rules.d (read by udev like /etc/udev/rules.d), start systemd-udevd, trigger, settle.
2. Every ``tests/kernel/checks_*.py`` module, in name order; in each, every function named
   ``check_*``, in the order written. A check takes no argument and returns a dict of details
   (JSON-able); it fails by raising (AssertionError with a message is best). Each check has
   ``CHECK_TIMEOUT_S`` (or the module's own ``TIMEOUT_S``).
3. The result file maps ``"<module>.<check>"`` (e.g. ``"checks_gamepad.check_evdev_roundtrip"``)
   to ``{"ok": bool, "seconds": float, "details": {...}}`` or ``{"ok": false, "error": "..."}``;
   it is rewritten after every check, so a crash leaves the results so far.

To add checks (e.g. ``neurotouch-hid run`` end to end), add a ``checks_<topic>.py`` here and assert
on ``guest_results()["checks_<topic>.check_<name>"]`` from a test file.
"""

from __future__ import annotations

import importlib.util
import inspect
import json
import os
import platform
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
sys.path[:0] = [str(HERE), str(REPO)]  # guestlib, and the checkout's neurotouch_hid

import guestlib  # noqa: E402
from vm import GUEST_STARTED  # noqa: E402

CHECK_TIMEOUT_S = 300  # per check; generous, a loaded host under software emulation is slow


class CheckTimeout(Exception):
    pass


def _on_alarm(signum, frame):
    raise CheckTimeout("check timed out")


def setup() -> dict:
    """Our udev rules, udevd, modules; returns what was done (the ``setup`` entry of the result)."""
    details: dict = {"kernel": platform.release(), "python": sys.version.split()[0]}
    rules = Path("/run/udev/rules.d")
    rules.mkdir(parents=True, exist_ok=True)
    installed = []
    for src in sorted((REPO / "udev").glob("*.rules")):
        (rules / src.name).write_text(src.read_text())
        installed.append(src.name)
    details["rules"] = installed
    details["udevd"] = guestlib.start_udevd()  # rules loaded before the modules' devices appear
    details["modprobe"] = {m: guestlib.sh(["modprobe", m]).returncode == 0 for m in ("uinput", "evdev", "joydev")}
    guestlib.sh(["udevadm", "trigger", "--action=add", "--subsystem-match=misc", "--sysname-match=uinput"])
    guestlib.settle()
    return details


def load_check_modules(only: list[str] | None = None) -> list:
    """The check modules, in name order: those named in ``only`` (module names), or all."""
    modules = []
    for path in sorted(HERE.glob("checks_*.py")):
        if only and path.stem not in only:
            continue
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        modules.append(module)
    return modules


def _checks(module) -> list:
    funcs = [
        f
        for name, f in vars(module).items()
        if name.startswith("check_") and inspect.isfunction(f) and f.__module__ == module.__name__
    ]
    return sorted(funcs, key=lambda f: f.__code__.co_firstlineno)


def run_one(func, timeout_s: int, name: str) -> dict:
    """Run one check under its alarm; its line on the console (vng's log on the host) before and
    after. The entry's ``seconds`` is its wall time, ``cpu_s`` the guest's CPU time meanwhile."""
    print(f"guest: {name} ...", flush=True)
    t0, busy0 = time.monotonic(), guestlib.busy_s()
    signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(timeout_s)
    try:
        details = func() or {}
        entry = {"ok": True, "details": details}
    except BaseException as exc:  # a check must never take the other checks down
        entry = {"ok": False, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()[-4000:]}
    finally:
        signal.alarm(0)
    entry["seconds"] = round(time.monotonic() - t0, 2)
    entry["cpu_s"] = round(guestlib.busy_s() - busy0, 1)
    print(f"guest: {name} {'ok' if entry['ok'] else 'FAILED'} in {entry['seconds']} s", flush=True)
    return entry


def main(out: Path, only: list[str] | None = None) -> int:
    out.with_name(GUEST_STARTED).write_text(f"{os.getpid()}\n")  # the host's sign that the boot reached us
    results: dict = {}

    def save() -> None:
        out.write_text(json.dumps(results, indent=1, sort_keys=True, default=str))

    t0 = time.monotonic()
    results["setup"] = run_one(setup, 120, "setup")
    save()
    try:
        modules = load_check_modules(only)
    except Exception:
        results["load_checks"] = {"ok": False, "error": traceback.format_exc()[-4000:]}
        save()
        return 1
    for module in modules:
        for func in _checks(module):
            name = f"{module.__name__}.{func.__name__}"
            results[name] = run_one(func, getattr(module, "TIMEOUT_S", CHECK_TIMEOUT_S), name)
            save()
    results["_guest"] = {"seconds": round(time.monotonic() - t0, 1)}
    save()
    subprocess.run(["sync"])
    return 0 if all(v.get("ok", True) for v in results.values()) else 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main(Path(sys.argv[1]), sys.argv[2:]))
