"""The controller as a USB device for another computer or a console: a configfs USB gadget.

A Linux board with a USB device-mode port (a UDC: a Raspberry Pi 4 or 5's USB-C port with
``dtoverlay=dwc2``) presents the controller to the host at the other end of the cable, in one
of three protocols (docs/reports.md has their reports, docs/any-host.md the set-up):

* ``hid``: a generic USB HID joystick (``hid.usb0``), for Windows, macOS, Linux, Android and the
  Xbox Adaptive Controller;
* ``switch``: the HORIPAD-style pad a Nintendo Switch accepts (``hid.usb0``, HORI's ids);
* ``xinput``: the Xbox 360 wired pad (``ffs.xinput``, FunctionFS), which Windows' XInput driver
  and Linux's ``xpad`` bind to;

plus a boot keyboard (``hid.usb1``) and a mouse (``hid.usb2``) in the same composite gadget when
the profile uses keys or the mouse (an iPad's or an Android tablet's switch access takes a USB
keyboard).

:class:`UsbGadget` opens a run's targets: it uses the gadget a privileged ``neurotouch-hid
gadget setup`` made (:mod:`~neurotouch_hid.targets.gadget.configfs`), or, run as root with none
there, makes it itself and removes it when the run ends. Beside the ``hid`` functions it starts
a guard (:mod:`~neurotouch_hid.guard`) that sends their neutral reports if the
driver dies without closing them (SIGKILL, a crash).
"""

from __future__ import annotations

import logging
import os
import time
from typing import TYPE_CHECKING

from neurotouch_hid.errors import DeviceError
from neurotouch_hid.guard import Guard
from neurotouch_hid.targets.gadget import configfs

if TYPE_CHECKING:
    from pathlib import Path

    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.stages import Target

log = logging.getLogger(__name__)

#: Pause between the neutral report taken by the host and the removal of a gadget the run made:
#: once the host's input device is gone, evdev drops what a game had not read yet (the uinput
#: pad's RELEASE_GRACE_S).
RELEASE_GRACE_S = 0.05
#: Which hid function instance carries which report format, whatever the gadget's protocol.
INSTANCES = {"usb1": "keyboard", "usb2": "mouse"}


def say_what_cannot_go(profile: Profile, functions: Path) -> list[str]:
    """Warn (the log) of what of ``profile`` the gadget (its configfs ``functions`` folder) cannot
    carry to the host: keys with no keyboard function, the pointer or mouse buttons with no mouse
    function, keys the boot keyboard's report has no usage for (docs/reports.md). Returns the
    lines said."""
    from neurotouch_hid.targets.reports.keyboard import unrepresentable

    lines = []
    if profile.uses_keyboard and not (functions / "hid.usb1").is_dir():
        lines.append("the profile presses keys but the USB gadget has no keyboard: gadget setup --keyboard")
    elif profile.uses_keyboard and (dropped := unrepresentable(profile.keyboard_keys)):
        lines.append(f"the USB keyboard has no usage for {', '.join(dropped)}: the host gets nothing for them")
    if profile.uses_mouse and not (functions / "hid.usb2").is_dir():
        lines.append("the profile moves the pointer or clicks but the USB gadget has no mouse: gadget setup --mouse")
    for line in lines:
        log.warning(line)
    return lines


def protocol_for(requested: str | None, profile: Profile, name: str = configfs.GADGET_NAME) -> str:
    """The protocol of a run: ``--protocol`` when given, else the profile's ``device: protocol``,
    else that of the gadget set up here (``gadget setup``, or the boot unit that runs it:
    :func:`~neurotouch_hid.targets.gadget.configfs.protocol_of`), else ``hid``. Raises
    DeviceError for an unknown one."""
    from neurotouch_hid.errors import NeurotouchError
    from neurotouch_hid.targets.protocols import protocol as protocol_row

    protocol = requested or getattr(profile.device, "protocol", None) or configfs.protocol_of(name) or "hid"
    try:
        return protocol_row(protocol, "gadget").name
    except NeurotouchError as exc:
        raise DeviceError(str(exc)) from None


class UsbGadget:
    """The run's gadget and its targets (module docstring), as a context manager.

    ``protocol``: ``hid``, ``switch`` or ``xinput``; ``profile``: whether a keyboard and a mouse
    function are made (when this run makes the gadget); ``serial``: the iSerialNumber of a gadget
    this run makes (the camera's ``Identity.usb_serial``; None: the default). :attr:`targets` are ready after
    ``__enter__``; ``__exit__`` closes them (neutral first) and removes a gadget this run made.

    Raises (from ``__enter__``):
        DeviceError: no gadget of this protocol and not root; no UDC; the nodes are not this user's.
    """

    def __init__(self, protocol: str, profile: Profile, *, name: str = configfs.GADGET_NAME, serial: str | None = None):
        self.protocol = protocol
        self.profile = profile
        self.name = name
        self.serial = serial or configfs.DEFAULT_USB_SERIAL  # iSerialNumber of a gadget this run makes
        self.targets: list[Target] = []
        self.made = False
        self._guard: Guard | None = None

    def __enter__(self) -> "UsbGadget":
        found = configfs.protocol_of(self.name)
        if found is None:
            if os.geteuid() != 0:
                raise DeviceError(
                    f"no USB gadget is set up for --output usb (no {configfs.gadget_dir(self.name)})\n"
                    f"sudo neurotouch-hid gadget setup --protocol {self.protocol} --user $USER"
                )
            plan = configfs.plan(self.protocol, self.profile.uses_keyboard, self.profile.uses_mouse, self.serial)
            configfs.create(plan, name=self.name)
            self.made = True
        elif found != self.protocol:
            raise DeviceError(
                f"the USB gadget set up here speaks {found}, not {self.protocol}\n"
                f"sudo neurotouch-hid gadget setup --protocol {self.protocol} --user $USER"
            )
        try:
            self._open()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _open(self) -> None:
        from neurotouch_hid.targets.gadget.targets import HidgTarget, XInputTarget
        from neurotouch_hid.targets.protocols import protocol as protocol_row
        from neurotouch_hid.targets.reports import format_for

        functions = configfs.gadget_dir(self.name) / "functions"
        row = protocol_row(self.protocol, "gadget")
        if row.gadget_function == "xinput":  # its descriptors first: the gadget binds only then
            pad = XInputTarget(configfs.FFS_ROOT / configfs.FFS_INSTANCE, row.report)
            self.targets.append(pad)
        if not configfs.bound_udc(self.name):
            configfs.bind(self.name)
        for instance in sorted(p.name.removeprefix("hid.") for p in functions.glob("hid.*")):
            fmt = format_for(INSTANCES[instance]) if instance in INSTANCES else row.report
            node = configfs.hidg_node(instance, self.name)
            self.targets.append(HidgTarget(node, fmt, f"USB gadget ({fmt.name}, {node})"))
        if self.targets:
            self.targets[0].lacks = lambda profile: say_what_cannot_go(profile, functions)  # on each profile
        say_what_cannot_go(self.profile, functions)
        nodes = [target.guarded() for target in self.targets if isinstance(target, HidgTarget)]
        if nodes:
            try:
                self._guard = Guard(nodes)
            except OSError as exc:
                log.warning(
                    "the USB gadget's guard could not start (%s): if the driver is killed, the host keeps its last"
                    " report until the gadget is unplugged",
                    exc.strerror or exc,
                )

    def __exit__(self, *exc: object) -> None:
        for target in reversed(self.targets):
            try:
                target.close()
            except OSError as error:
                log.warning("%s: closing failed: %s", target.what, error)
        self.targets = []
        if self._guard is not None:  # after the neutral reports, before the nodes can go
            self._guard.release()
            self._guard = None
        if self.made:
            time.sleep(RELEASE_GRACE_S)  # the host's readers take the neutral report before the device goes
            configfs.remove(self.name)
            self.made = False
