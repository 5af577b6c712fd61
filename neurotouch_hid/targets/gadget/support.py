"""Can this machine be a USB gadget, or make a UHID device? What ``doctor`` and ``devices`` say.

A gadget needs a USB device controller (a UDC in ``/sys/class/udc``: a board's device-mode or
OTG port, e.g. a Raspberry Pi 4 or 5's USB-C port with ``dtoverlay=dwc2``), configfs mounted at
``/sys/kernel/config`` and the kernel's ``libcomposite``, ``usb_f_hid`` and ``usb_f_fs`` (loaded:
``/sys/module``; built in: ``modules.builtin``; loadable: ``modules.dep``, both in
``/lib/modules/RELEASE``). ``--output hid`` needs ``/dev/uhid`` readable and writable
(Documentation/hid/uhid.rst). Each missing piece comes with a command that fixes it.

What only some protocols need is said beside (``notes``): whether the kernel's ``hid`` function
has the ``interval`` attribute (Linux 6.16 and later: the ``xac`` protocol's 1 ms polling).
"""

from __future__ import annotations

import platform
from dataclasses import dataclass, field
from pathlib import Path

from neurotouch_hid.core.limits import FileLimitError, read_text_file
from neurotouch_hid.targets.gadget import configfs

#: Largest modules.dep / modules.builtin read (bytes): a distribution kernel's is ~1 MB.
MAX_MODULES_FILE = 16 * 1024 * 1024
#: Where a Raspberry Pi names its model (device tree).
PI_MODEL = Path("/proc/device-tree/model")
#: The UHID node.
UHID = "/dev/uhid"
#: The first kernel whose ``hid`` function has the ``interval`` attribute (configfs; the patch
#: "usb: gadget: hid: allow dynamic interval configuration via configfs", Linux 6.16).
HID_INTERVAL_SINCE = (6, 16)


def release_tuple(release: str) -> tuple[int, int]:
    """(major, minor) of a kernel release string (``6.1.0-56-amd64`` -> (6, 1)); (0, 0) when
    it does not start so."""
    parts = release.split(".")
    try:
        return int(parts[0]), int("".join(c for c in parts[1].split("-")[0] if c.isdigit()) or 0)
    except (IndexError, ValueError):
        return 0, 0


def hid_interval(release: str | None = None, gadgets: Path | None = None) -> tuple[bool, str]:
    """Whether the kernel's ``hid`` function has the ``interval`` attribute, and how that is
    known: from a ``hid`` function of a gadget here (its folder lists the attribute), else from
    the kernel release (:data:`HID_INTERVAL_SINCE`)."""
    gadgets = gadgets or configfs.CONFIGFS / "usb_gadget"
    for function in sorted(gadgets.glob("*/functions/hid.*"))[:16]:
        return (function / "interval").exists(), f"seen in {function}"
    release = release or platform.release()
    return release_tuple(release) >= HID_INTERVAL_SINCE, f"kernel {release}"


#: The kernel interfaces that let user space write a whole configuration descriptor (the Xbox
#: 360 pad's 0x21 descriptor included, which FunctionFS refuses): the legacy GadgetFS and
#: raw-gadget (Documentation/usb/gadget_raw.rst), by module name.
WHOLE_DESCRIPTOR_MODULES = ("gadgetfs", "raw_gadget")


def protocol_notes(
    release: str | None = None, gadgets: Path | None = None, modules_dir: Path | None = None
) -> list[str]:
    """What this kernel means for a protocol that needs more than a plain gadget (one line each):
    the ``xac`` protocol's polling interval (:func:`hid_interval`), and which interface that takes
    a whole configuration descriptor this kernel has (:data:`WHOLE_DESCRIPTOR_MODULES`), which
    Windows' own XInput driver needs: the ``xinput`` pad is made on GadgetFS where it is (a run as
    root making its own gadget), else on FunctionFS, without the descriptor."""
    has, how = hid_interval(release, gadgets)
    if has:
        notes = [f"xac: the hid function's interval is set to 1 ms ({how})"]
    else:
        notes = [
            f"xac: this kernel's hid function cannot set its polling interval ({how}; Linux 6.16 and later can): "
            "the gadget is polled every 10 ms at full speed, which the Xbox Adaptive Controller may refuse"
        ]
    kernel = modules_dir if modules_dir is not None else (Path("/lib/modules") / release if release else None)
    found = [f"{m} {module_state(m, kernel)}" for m in WHOLE_DESCRIPTOR_MODULES]
    found = [f for f in found if not f.endswith(" missing")] or ["neither gadgetfs nor raw_gadget"]
    if module_state("gadgetfs", kernel) != "missing":
        notes.append(
            f"xinput: {', '.join(found)} here: a run as root that makes its own gadget puts the pad on GadgetFS, with "
            "the 0x21 descriptor Windows' XInput driver reads; on a gadget set up before (FunctionFS) it lacks it: "
            "for Windows there, use hid with Steam Input"
        )
    else:
        notes.append(
            f"xinput: {', '.join(found)} here: the pad is made on FunctionFS, which cannot carry the 0x21 descriptor "
            "Windows' XInput driver reads: Windows will not read xinput from this board; use hid with Steam Input"
        )
    return notes


def module_state(name: str, modules_dir: Path | None = None, sys_module: Path = Path("/sys/module")) -> str:
    """``loaded``, ``built in``, ``available`` (a module file is there to load), ``missing``, or
    ``unknown`` where there is no ``/lib/modules/RELEASE`` to look in (a container, a kernel
    installed without its modules), for kernel module ``name`` (``-`` and ``_`` alike)."""
    name = name.replace("-", "_")
    if (sys_module / name).is_dir():
        return "loaded"
    modules_dir = modules_dir or Path("/lib/modules") / platform.release()
    if not modules_dir.is_dir():
        return "unknown"
    for listing, state in (("modules.builtin", "built in"), ("modules.dep", "available")):
        try:
            text = read_text_file(modules_dir / listing, MAX_MODULES_FILE, listing)
        except (OSError, FileLimitError, UnicodeDecodeError):
            continue
        for line in text.splitlines():
            base = line.split(":", 1)[0].rsplit("/", 1)[-1]
            if base.split(".ko", 1)[0].replace("-", "_") == name:
                return state
    return "missing"


def uhid_problem(devnode: str = UHID) -> str | None:
    """Why ``devnode`` cannot be used for ``--output hid`` (missing, not a character device, not
    readable and writable: the same tests as uinput's node), or None when it can."""
    from neurotouch_hid.service.udev import uinput_problem

    problem = uinput_problem(devnode)
    return None if problem is None else problem.replace("uinput", "uhid")


def is_raspberry_pi(model: Path = PI_MODEL) -> bool:
    """The device tree names a Raspberry Pi."""
    try:
        return read_text_file(model, 4096, "device-tree model").startswith("Raspberry Pi")
    except (OSError, FileLimitError, UnicodeDecodeError):
        return False


@dataclass(frozen=True)
class GadgetSupport:
    """What this machine has for ``--output usb``: its UDCs, configfs, the three modules' states
    (:func:`module_state`), the gadget set up (its protocol, None when none), when something
    is missing, ``problems`` (one line each) and ``fixes`` (commands, one a line), and what only
    some protocols need (``notes``: :func:`protocol_notes`)."""

    udcs: list[str]
    configfs: bool
    modules: dict[str, str]
    gadget: str | None
    problems: list[str] = field(default_factory=list)
    fixes: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def possible(self) -> bool:
        """A gadget can be made here."""
        return not self.problems


def gadget_support() -> GadgetSupport:
    """Look at this machine (module docstring)."""
    udcs = configfs.udcs()
    mounted = (configfs.CONFIGFS / "usb_gadget").is_dir()
    modules = {name: module_state(name) for name in configfs.MODULES}
    problems, fixes = [], []
    if not udcs:
        problems.append(configfs.no_udc())
        if is_raspberry_pi():
            fixes += [
                "echo dtoverlay=dwc2,dr_mode=peripheral | sudo tee -a /boot/firmware/config.txt",
                "sudo reboot   # then plug the Pi's USB-C port into the host",
            ]
        else:
            fixes.append(
                "# a board with a USB device-mode (OTG) port is needed, e.g. a Raspberry Pi 4 or 5 (docs/any-host.md)"
            )
    missing = [name for name, state in modules.items() if state == "missing"]
    if missing:
        problems.append(f"the kernel has no {', '.join(missing)}")
        fixes.append(
            "# a kernel built with CONFIG_USB_LIBCOMPOSITE, CONFIG_USB_CONFIGFS_F_HID and CONFIG_USB_CONFIGFS_F_FS"
        )
    notes = protocol_notes()
    if any(state == "unknown" for state in modules.values()):
        notes.insert(0, f"the kernel's modules are not known: no /lib/modules/{platform.release()} to look in")
    loadable = [name for name, state in modules.items() if state == "available"]
    if loadable:
        fixes.append(f"sudo modprobe {' '.join(loadable)}")
    if not mounted and "libcomposite" not in missing:
        if not loadable:
            problems.append("configfs is not mounted at /sys/kernel/config")
        fixes.append("sudo mount -t configfs none /sys/kernel/config")
    return GadgetSupport(udcs, mounted, modules, configfs.protocol_of(), problems, fixes, notes)


def possible_outputs() -> dict[str, str | None]:
    """Each ``--output`` that needs a kernel interface -> None when it works here, else why not:
    ``gamepad`` (uinput), ``hid`` (UHID), ``usb`` (a gadget)."""
    from neurotouch_hid.service.udev import uinput_problem

    support = gadget_support()
    return {
        "gamepad": uinput_problem(),
        "hid": uhid_problem(),
        "usb": None if support.possible else "; ".join(support.problems),
    }
