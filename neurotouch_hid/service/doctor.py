"""``neurotouch-hid doctor``: is this machine ready to run the driver? Each failure comes with its fix.

Checks: the DAVIS-346 is on USB, each camera's /dev/bus/usb node is readable and writable and not
held by another program, dv-processing lists the camera (all three from one
:func:`neurotouch_hid.sources.discovery.discover`, the same look-up as ``neurotouch-hid devices``),
/dev/uinput exists and is writable, whether /dev/uhid is usable (``--output hid``) and this machine
can be a USB gadget (``--output usb``: a UDC, configfs, libcomposite, usb_f_hid, usb_f_fs; warnings
only), the udev rules are installed, dv-processing / numba / evdev
import (with versions), where numba caches the compiled pipeline (a warning when nowhere: it compiles
in memory at every start), and (a warning only) the plug-and-play systemd user unit is installed.

The report is plain lines, one per check, each fix's steps on lines of their own (a command alone
on its line, so it can be copied), never wrapped: the same text on a terminal (coloured) and in a
pipe or a file. The fixes name the udev rule and install script shipped with this installation
(absolute paths, :mod:`neurotouch_hid.service.udev`) and this installation's own Python and command.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import platform
import shlex
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from neurotouch_hid.service.extras import EXTRAS, missing_message
from neurotouch_hid.service.udev import (
    INSTALL_SCRIPT,
    RULES_DIRS,
    RULES_INSTALL,
    RULES_NAME,
    installed_rules,
    this_command,
    uhid_help,
    uinput_help,
    uinput_problem,
)
from neurotouch_hid.sources.discovery import CameraStatus, Discovery, discover
from neurotouch_hid.sources.usb_probe import CAMERA_USB_ID, pip_command
from neurotouch_hid.targets.protocols import names as protocol_names

SERVICE_NAME = "neurotouch-hid.service"
#: The per-camera unit template (packaging/neurotouch-hid@.service, docs/several-sensors.md).
TEMPLATE_NAME = "neurotouch-hid@.service"
#: The distribution that brings ``import evdev`` here, as pyproject.toml chooses it: the
#: precompiled evdev-binary on x86_64 (its only wheels), the source evdev elsewhere.
EVDEV_DIST = "evdev-binary" if platform.machine() == "x86_64" else "evdev"
#: (import name, distribution name) of the libraries the driver needs at run time.
LIBRARIES = (("dv_processing", "dv-processing"), ("numba", "numba"), ("evdev", EVDEV_DIST))

OK, FAIL, WARN, SKIP = "ok", "fail", "warn", "skip"


@dataclass(frozen=True)
class Check:
    """One line of the report. ``status``: ok, fail (exit code 1), warn or skip (do not fail);
    ``fix``: the steps, one a line (newline-separated), each command alone on its line."""

    name: str
    status: str
    detail: str
    fix: str = ""


def check_camera(found: Discovery) -> Check:
    """A DAVIS-346 (USB 152a:841a) is on USB: fail when there is none, or pyusb cannot list USB devices."""
    cameras = found.davis346
    if not cameras:
        others = [c.label() for c in found.cameras if not c.is_davis346]
        seen = f" (dv-processing sees only: {', '.join(others)})" if others else ""
        if found.usb_error is not None:
            return Check(
                "camera on USB",
                FAIL,
                f"pyusb cannot list USB devices ({found.usb_error}){seen}",
                f"{pip_command()} install --force-reinstall pyusb libusb-package",
            )
        return Check(
            "camera on USB",
            FAIL,
            f"no DAVIS-346 ({CAMERA_USB_ID}) on USB{seen}",
            f"plug the NeuroTouch's USB cable in (a USB 3 port), then check that this lists it:\n"
            f"lsusb -d {CAMERA_USB_ID}",
        )
    where = ", ".join(
        f"bus {c.bus} device {c.address}" + (f" (serial {c.serial})" if c.serial else "") for c in cameras
    )
    return Check("camera on USB", OK, f"DAVIS-346 at {where}")


def check_camera_access(found: Discovery) -> Check:
    """Each camera's /dev/bus/usb node is readable and writable by this user and no other program
    holds it (skip when there is no camera, or pyusb could not look)."""
    usb = [c for c in found.cameras if c.usb is not None]
    if not usb:
        return Check("camera permissions", SKIP, "no camera to check")
    unusable = (CameraStatus.NO_ACCESS, CameraStatus.BUSY, CameraStatus.ERROR, CameraStatus.GONE)
    bad = [c for c in usb if c.status in unusable]
    if bad:
        fixes = list(dict.fromkeys(c.fix for c in bad))
        return Check("camera permissions", FAIL, "; ".join(c.problem for c in bad), "\nor: ".join(fixes))
    return Check("camera permissions", OK, ", ".join(c.node for c in usb) + " readable and writable")


def check_camera_dv(found: Discovery) -> Check:
    """dv-processing lists every accessible camera (the live source opens cameras through it);
    skip when no camera is accessible."""
    accessible = (CameraStatus.READY, CameraStatus.NOT_IN_DV, CameraStatus.DV_UNAVAILABLE)
    usable = [c for c in found.cameras if c.status in accessible]
    if not usable:
        return Check("dv-processing sees the camera", SKIP, "no accessible camera to look for")
    missing = [c for c in usable if not c.ready]
    if missing:
        return Check("dv-processing sees the camera", FAIL, "; ".join(c.problem for c in missing), missing[0].fix)
    return Check(
        "dv-processing sees the camera",
        OK,
        ", ".join(f"{c.dv.model} serial {c.dv.serial} firmware {c.dv.firmware}" if c.dv else c.label() for c in usable),
    )


def check_uinput(devnode: str = "/dev/uinput") -> Check:
    """/dev/uinput exists, is a character device and is writable (see targets/uinput/gamepad.py)."""
    problem = uinput_problem(devnode)
    if problem:
        return Check("virtual gamepad (uinput)", FAIL, problem, uinput_help())
    return Check("virtual gamepad (uinput)", OK, f"{devnode} is writable")


def check_rules(dirs: tuple[str, ...] = RULES_DIRS) -> Check:
    """The project's udev rules file is in one of udev's rules folders."""
    found = installed_rules(dirs)
    if found:
        return Check("udev rules", OK, found)
    return Check("udev rules", FAIL, f"{RULES_NAME} is not in {', '.join(dirs)}", RULES_INSTALL)


def _import_failed(module: str, dist: str, exc: Exception) -> Check:
    return Check(
        dist,
        FAIL,
        f"import {module} failed: {type(exc).__name__}: {exc}",
        f"{pip_command()} install --upgrade {dist}",
    )


def check_library(module: str, dist: str) -> Check:
    """``module`` imports; the detail is its distribution's version (else the version of the
    distribution that did install ``module``: an older environment's evdev, say)."""
    try:
        importlib.import_module(module)
    except ModuleNotFoundError as exc:
        extra = next((name for name, modules in EXTRAS.items() if module in modules), None)
        if extra is None or exc.name != module:
            return _import_failed(module, dist, exc)
        # an optional extra's module (python-evdev on aarch64): only the outputs that use it need it
        return Check(
            dist,
            WARN,
            missing_message(extra, "--output gamepad, the uinput keyboard and mouse and copilot:", module)
            + "; --output hid makes its pad without it",
            f"pipx inject neurotouch-hid {' '.join(EXTRAS[extra].values())}\n"
            f"or: {pip_command()} install 'neurotouch-hid[{extra}]'",
        )
    except Exception as exc:  # an ImportError, or a broken native library underneath
        return _import_failed(module, dist, exc)
    version = "version unknown"
    for name in (dist, *importlib.metadata.packages_distributions().get(module.split(".")[0], ())):
        try:
            version = importlib.metadata.version(name) + ("" if name == dist else f" ({name})")
            break
        except importlib.metadata.PackageNotFoundError:
            continue
    return Check(dist, OK, version)


def check_jit_cache() -> Check:
    """Where numba caches the pipeline's compiled code (jit_cache.py); a warning when it cannot
    cache anywhere lasting and compiles at every start."""
    from neurotouch_hid.service.jit_cache import MEMORY, TEMPORARY, chosen

    cache = chosen()
    if cache.kind in (MEMORY, TEMPORARY):
        return Check(
            "compiled-code cache (numba)",
            WARN,
            cache.describe(),
            "make ~/.cache writable, or set XDG_CACHE_HOME (or NUMBA_CACHE_DIR) to a writable folder",
        )
    from neurotouch_hid.service.warmup import PIPELINE_OF, is_cold

    if any(is_cold(group) for group in PIPELINE_OF["default"]):
        detail = f"{cache.describe()}; empty yet: the first run compiles the pipeline into it (about 25 s of CPU, once)"
    else:
        detail = f"{cache.describe()}; the pipeline is compiled: runs start at once"
    return Check("compiled-code cache (numba)", OK, detail)


def user_config_dir() -> Path:
    """$XDG_CONFIG_HOME, else ~/.config: where install.sh --user puts the unit (XDG base dirs)."""
    return Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config")


def check_service(config: Path | None = None) -> Check:
    """The plug-and-play systemd user unit is installed in ``config``/systemd/user (default:
    :func:`user_config_dir`) or system-wide, and the command its ExecStart names is there (a
    warning only: `run` works without). Where cameras have config folders of their own
    (:func:`~neurotouch_hid.service.serials.configured_serials`) the single unit steps aside: then the
    per-camera template must be installed too, or no driver starts on plug-in."""
    config = config or user_config_dir()
    dirs = (config / "systemd/user", Path("/etc/systemd/user"), Path("/usr/lib/systemd/user"))
    found = [str(d / SERVICE_NAME) for d in dirs if (d / SERVICE_NAME).is_file()]
    fix = f"sh {shlex.quote(str(INSTALL_SCRIPT))} --user" + (
        f" --bin {shlex.quote(command)}" if (command := this_command()) else ""
    )
    if found:
        gone = _missing_exec(Path(found[0]))
        if gone:
            return Check(
                "plug-and-play service", WARN, f"{found[0]} runs {gone}, which is not there (it cannot start)", fix
            )
        from neurotouch_hid.service.serials import configured_serials

        serials = configured_serials()
        if not serials:
            return Check("plug-and-play service", OK, found[0])
        instances = ", ".join(f"neurotouch-hid@{s}.service" for s in serials)
        if not any((d / TEMPLATE_NAME).is_file() for d in dirs):
            return Check(
                "plug-and-play service",
                WARN,
                f"{found[0]} steps aside for the cameras with a config folder of their own ({', '.join(serials)}), "
                f"but {TEMPLATE_NAME}, which would start one driver for each, is not installed: nothing starts "
                "when a camera is plugged in (docs/several-sensors.md)",
                fix,
            )
        return Check("plug-and-play service", OK, f"one driver per camera with a config folder: {instances}")
    return Check(
        "plug-and-play service",
        WARN,
        f"{SERVICE_NAME} is not installed (start by hand with `neurotouch-hid run`)",
        fix,
    )


def _missing_exec(unit: Path) -> str | None:
    """The absolute command the unit's ExecStart= runs when it is not an executable file (install.sh
    quotes a path with a space and doubles its %), else None."""
    from neurotouch_hid.core.limits import MAX_YAML_BYTES, read_outside_text

    try:
        text = read_outside_text(unit, MAX_YAML_BYTES, "systemd unit", ValueError)
    except ValueError:  # unreadable, too large, not text: the unit's own problem, not told here
        return None
    for line in text.splitlines():
        if line.startswith("ExecStart="):
            try:
                words = shlex.split(line.removeprefix("ExecStart="))
            except ValueError:
                return None
            command = words[0].replace("%%", "%") if words else ""
            if command.startswith("/") and not (os.path.isfile(command) and os.access(command, os.X_OK)):
                return command
            return None
    return None


def check_model() -> Check:
    """Which model ``run``, ``track``, ``eval`` and ``profile test`` use by default: the user's
    adapted model (``enrolment/model.py``, written by ``neurotouch-hid adapt``) or the shipped
    method; a failure when the user's model file is there but cannot be used."""
    from neurotouch_hid.enrolment.model import ModelError, describe, resolve_model, user_model_path

    try:
        model = resolve_model(None)
    except ModelError as exc:
        return Check(
            "gesture model",
            FAIL,
            str(exc),
            f"neurotouch-hid adapt ENROLMENT --out {user_model_path()}\nor remove {user_model_path()}",
        )
    if model is None:
        return Check(
            "gesture model", OK, f"the shipped method (no {user_model_path()}; `neurotouch-hid adapt` fits one)"
        )
    return Check("gesture model", OK, describe(model))


def check_copilot(
    profiles: dict[str, object] | None = None, devices: list | None = None, hiding: bool | None = None
) -> Check:
    """The devices the profiles' ``copilot:`` sections name (the shipped and the user's,
    ``profiles``: name -> loaded profile): which are plugged in (``devices``: the input devices now,
    :func:`~neurotouch_hid.inputs.match.mergeable_devices`) and which the driver would wait for.
    A present device this user cannot read fails (the driver cannot merge it), one it cannot write
    warns (merged, but no rumble: python-evdev opens it read-only); a warning when the driver could
    not hide them from games (``hiding``: default :func:`~neurotouch_hid.inputs.hide.may_hide`,
    root only) or a device is missing."""
    from neurotouch_hid.inputs.copilot import unhidden_note
    from neurotouch_hid.inputs.hide import may_hide
    from neurotouch_hid.inputs.match import mergeable_devices, presence

    if profiles is None:
        from neurotouch_hid.core.errors import ProfileError
        from neurotouch_hid.mapping.profile import available_profiles, load_profile

        profiles = {}
        for name, path in available_profiles().items():
            try:
                profiles[name] = load_profile(path)
            except ProfileError:  # a broken profile is for `profile check` to report
                continue
    with_copilot = {name: p for name, p in profiles.items() if getattr(p, "copilot", None)}
    if not with_copilot:
        return Check("copilot devices", SKIP, "no profile merges other devices (copilot:)")
    devices = mergeable_devices() if devices is None else devices
    parts, missing, closed, read_only, present = [], [], [], [], []
    for name, profile in with_copilot.items():
        found = presence([c.device for c in profile.copilot], devices)
        present += [info for _, info in found if info is not None]
        for rule, info in found:
            if info is None:
                missing.append(rule)
            elif not os.access(info.path, os.R_OK):
                closed.append(f"{rule} ({info.path})")
            elif not os.access(info.path, os.W_OK):
                read_only.append(f"{rule} ({info.path})")
        shown = ", ".join(f"{rule} at {info.path}" if info else f"{rule} missing" for rule, info in found)
        parts.append(f"{name}: {shown}")
    detail = "; ".join(parts)
    if closed:
        return Check(
            "copilot devices",
            FAIL,
            f"{detail}; not readable by this user: {', '.join(closed)} (the driver cannot merge them; "
            "after the command below, log out and in again)",
            "sudo usermod -aG input $USER",
        )
    if read_only:
        return Check(
            "copilot devices",
            WARN,
            f"{detail}; not writable by this user: {', '.join(read_only)} (merged, but a game's rumble is "
            "not played on them; after the command below, log out and in again)",
            "sudo usermod -aG input $USER",
        )
    note = "" if (may_hide() if hiding is None else hiding) else unhidden_note(present[0] if present else None)
    if missing or note:
        waited = " (a missing device is waited for and merged when it comes)" if missing else ""
        return Check("copilot devices", WARN, f"{detail}{waited}", note)
    return Check("copilot devices", OK, detail)


def check_calibration() -> Check:
    """Which gel geometry the camera's runs (``run``, the service, ``enrol``) use: the user's
    calibration (``calibrate``'s sensor.yaml, :func:`~neurotouch_hid.core.sensor.user_sensor_path`)
    with its values, or the built-in one (a warning: a real gel differs); a failure when the file
    is there but invalid (:class:`~neurotouch_hid.core.errors.SensorError`'s message)."""
    from neurotouch_hid.core.errors import SensorError
    from neurotouch_hid.core.sensor import SensorGeometry, user_sensor_path

    path = user_sensor_path()
    if not path.exists():
        return Check(
            "calibration",
            WARN,
            f"none ({path} does not exist): the camera's runs use the built-in geometry, not your gel's",
            "neurotouch-hid calibrate",
        )
    try:
        g = SensorGeometry.load(path)
    except SensorError as exc:
        return Check("calibration", FAIL, str(exc), f"neurotouch-hid calibrate\nor remove {path}")
    creep = "creep not measured" if g.creep is None else f"creep q {g.creep[0]:.2f}, tau {g.creep[1]:.2f} s"
    return Check(
        "calibration",
        OK,
        f"{path}: gel at ({g.gel_center_px[0]:.0f}, {g.gel_center_px[1]:.0f}) px, radius {g.gel_radius_px:.0f} px, "
        f"{g.px_per_mm:.2f} px/mm, {'mirrored' if g.mirror else 'not mirrored'}, rotation {g.rotation_deg:g} deg, "
        f"{creep}",
    )


def check_gadget() -> Check:
    """This machine can be a USB gadget for ``run --output usb`` (a UDC, configfs, libcomposite,
    usb_f_hid, usb_f_fs: :mod:`neurotouch_hid.targets.gadget.support`), with what only some
    protocols need (its notes: the ``xac`` protocol's polling interval); a warning when not (the
    uinput pad does not need it)."""
    from neurotouch_hid.targets.gadget.support import gadget_support

    found = gadget_support()
    modules = ", ".join(f"{name} {state}" for name, state in found.modules.items())
    if all(state == "unknown" for state in found.modules.values()):
        modules = f"its modules not known: no /lib/modules/{platform.release()} to look in"
        found.notes.remove(next(n for n in found.notes if n.startswith("the kernel's modules are not known")))
    if not found.possible:
        return Check(
            "USB gadget (--output usb)", WARN, "; ".join(found.problems) + f" ({modules})", "\n".join(found.fixes)
        )
    set_up = f"gadget set up: {found.gadget}" if found.gadget else "no gadget set up yet"
    speaks = f"protocols: {', '.join(protocol_names('gadget'))}"
    notes = "".join(f"; {note}" for note in found.notes)
    return Check(
        "USB gadget (--output usb)",
        OK,
        f"UDC {', '.join(found.udcs)}; {modules}; {set_up}; {speaks}{notes}",
        "\n".join(found.fixes),
    )


def check_uhid() -> Check:
    """/dev/uhid is usable for ``run --output hid``; a warning when not."""
    from neurotouch_hid.targets.gadget.support import UHID, uhid_problem

    problem = uhid_problem()
    if problem:
        return Check("HID device here (--output hid)", WARN, problem, uhid_help())
    speaks = ", ".join(protocol_names("uhid"))
    return Check("HID device here (--output hid)", OK, f"{UHID} is readable and writable; protocols: {speaks}")


def camera_drivers(found: Discovery, drivers: list | None = None) -> list[dict]:
    """What runs for each camera: one row per DAVIS-346 on the bus, then one per running driver
    whose camera is not on the bus (the simulated gel, a recording, a camera unplugged). A row:
    ``serial`` (None: unknown), ``camera`` (where it is, None when not on the bus), ``driver``
    (:meth:`~neurotouch_hid.service.control.RunningDriver.to_json`, None when none runs for it) and
    ``config`` (the files of its own config folder, :mod:`neurotouch_hid.service.serials`; empty: the
    shared ones). ``drivers``: :func:`~neurotouch_hid.service.control.running_drivers` (asked when None)."""
    from neurotouch_hid.service.control import running_drivers
    from neurotouch_hid.service.serials import SENSOR_FILES, own_file

    drivers = running_drivers() if drivers is None else drivers
    by_serial = {d.serial: d for d in drivers}
    unnamed = by_serial.pop(None, None)  # a driver started without --serial: the only camera's

    def own(serial: str | None) -> list[str]:
        try:
            return [name for role, name in SENSOR_FILES.items() if own_file(serial, role) is not None]
        except ValueError:  # a serial that cannot name a folder has none
            return []

    rows = []
    cameras = found.davis346
    for camera in cameras:
        driver = by_serial.pop(camera.serial, None) if camera.serial else None
        if driver is None and unnamed is not None and len(cameras) == 1:
            driver, unnamed = unnamed, None
        rows.append(
            {
                "serial": camera.serial,
                "camera": f"bus {camera.bus} device {camera.address}",
                "driver": driver.to_json() if driver else None,
                "config": own(camera.serial),
            }
        )
    for driver in ([unnamed] if unnamed else []) + sorted(by_serial.values(), key=lambda d: d.serial or ""):
        rows.append({"serial": driver.serial, "camera": None, "driver": driver.to_json(), "config": own(driver.serial)})
    return rows


def describe_camera_driver(row: dict) -> str:
    """One line of :func:`camera_drivers`: the camera, what runs for it and its config."""
    who = f"camera {row['serial']}" if row["serial"] else "camera (serial unknown)"
    where = f" ({row['camera']})" if row["camera"] else " (not on the bus)"
    driver = row["driver"]
    if driver is None:
        runs = "no driver runs for it"
    else:
        unit = f" in {driver['unit']}" if driver["unit"] else ""
        runs = f"driver pid {driver['pid']}{unit}, {driver['status']}"
    config = f"own {', '.join(row['config'])}" if row["config"] else "shared config"
    return f"{who}{where}: {runs}; {config}"


def check_drivers(found: Discovery, drivers: list | None = None) -> Check:
    """Which driver runs for each camera, and which config it uses (:func:`camera_drivers`); a
    warning when several cameras are plugged in and none has a folder of its own (the single
    plug-and-play unit then drives only one of them: docs/several-sensors.md)."""
    from neurotouch_hid.service.serials import configured_serials, sensor_dir

    rows = camera_drivers(found, drivers)
    if not rows:
        return Check("drivers per camera", SKIP, "no camera and no driver running")
    detail = "; ".join(describe_camera_driver(r) for r in rows)
    serials = [c.serial for c in found.davis346 if c.serial]
    if len(found.davis346) > 1 and not configured_serials():
        fix = "\n".join(f"mkdir -p {shlex.quote(str(sensor_dir(s)))}" for s in serials[:4])
        return Check(
            "drivers per camera",
            WARN,
            f"{detail} ({len(found.davis346)} cameras and none has a config folder of its own: the plug-and-play "
            "service drives one of them; a folder each gives each its own, docs/several-sensors.md)",
            fix,
        )
    return Check("drivers per camera", OK, detail)


def run_checks() -> list[Check]:
    """Every check, in the order the report shows them."""
    found = discover()
    return [
        check_camera(found),
        check_camera_access(found),
        check_camera_dv(found),
        check_drivers(found),
        check_uinput(),
        check_uhid(),
        check_gadget(),
        check_rules(),
        *(check_library(m, d) for m, d in LIBRARIES),
        check_jit_cache(),
        check_service(),
        check_calibration(),
        check_model(),
        check_copilot(),
    ]


#: doctor's lines are wrapped at this many columns (or the terminal's width, when narrower), the
#: continuation under the detail; a fix's command is never wrapped or cut (it is copied whole).
REPORT_COLUMNS = 100


def report(checks: list[Check], console: Console) -> int:
    """Print the checks (status, name, detail, wrapped at :data:`REPORT_COLUMNS` with the
    continuation under the detail) with each fix's lines indented under it (a command whole, a
    ``#`` comment wrapped as comments), and a last line that counts the problems; return the exit
    code (1 if any check failed, else 0)."""
    import textwrap

    style = {OK: "green", FAIL: "bold red", WARN: "yellow", SKIP: "dim"}
    width = max(len(c.name) for c in checks) if checks else 0
    columns = min(REPORT_COLUMNS, console.width) if console.is_terminal else REPORT_COLUMNS

    def say(line: str) -> None:
        console.print(line, highlight=False, markup=True, soft_wrap=True)

    for c in checks:
        head = f"{c.status:<4} {c.name:<{width}}  "
        lines = textwrap.wrap(
            head + c.detail, columns, subsequent_indent=" " * len(head), break_on_hyphens=False, break_long_words=False
        ) or [head]
        say(f"[{style[c.status]}]{c.status:<4}[/]{escape(lines[0][4:])}")
        for line in lines[1:]:
            say(escape(line))
        for step in c.fix.splitlines():
            if step.lstrip().startswith("#"):
                wrapped = textwrap.wrap(
                    step, columns - 6, subsequent_indent="# ", break_on_hyphens=False, break_long_words=False
                )
                for line in wrapped:
                    say(f"      {escape(line)}")
            else:
                say(f"      {escape(step)}")
    failed = [c.name for c in checks if c.status == FAIL]
    problems = f"[bold red]{len(failed)} problem(s):[/] {escape(', '.join(failed))}"
    say(problems if failed else "[green]all checks passed[/]")
    return 1 if failed else 0
