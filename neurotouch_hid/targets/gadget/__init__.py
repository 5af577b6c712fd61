"""The controller as a USB device for another computer or a console: a configfs USB gadget.

A Linux board with a USB device-mode port (a UDC: a Raspberry Pi 4 or 5's USB-C port with
``dtoverlay=dwc2``) presents the controller to the host at the other end of the cable, in one
of the protocol table's protocols that run on a gadget (:mod:`neurotouch_hid.targets.protocols`;
docs/reports.md has their reports, docs/any-host.md the hosts and the set-up), by the row's
gadget function:

* ``hid`` (the kernel's ``hid`` function, ``hid.usb0``, ``/dev/hidgN``): the generic joystick,
  the HORIPAD-style Switch pad, the Adaptive Controller's joystick;
* ``xinput`` (``ffs.xinput``, FunctionFS): the Xbox 360 wired pad, which Linux's ``xpad`` binds
  to (:mod:`~neurotouch_hid.targets.gadget.ffs`);
* ``ffs-hid`` (``ffs.pad``, FunctionFS): a HID interface that answers its host's requests itself,
  for a protocol whose host reads feature reports (:mod:`~neurotouch_hid.targets.gadget.ffs`);

plus a boot keyboard (``hid.usb1``) and a mouse (``hid.usb2``) in the same composite gadget when
the profile uses keys or the mouse (an iPad's or an Android tablet's switch access takes a USB
keyboard), except beside a pad whose row says it goes alone (``xinput``, ``xac``: their hosts
ignore a device with more): there a profile with keys or the pointer is refused, with the
protocol to use instead.

:class:`UsbGadget` opens a run's targets: it uses the gadget a privileged ``neurotouch-hid
gadget setup`` made (:mod:`~neurotouch_hid.targets.gadget.configfs`), or, run as root with none
there, makes it itself and removes it when the run ends. Beside the ``hid`` functions it starts
a guard (:mod:`~neurotouch_hid.service.guard`) that sends their neutral reports if the
driver dies without closing them (SIGKILL, a crash).
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.service.guard import LINGER_S, Guard
from neurotouch_hid.service.udev import sudo_command
from neurotouch_hid.targets.gadget import configfs
from neurotouch_hid.targets.protocols import PROTOCOLS

if TYPE_CHECKING:
    from neurotouch_hid.core.stages import Target
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.targets.identity import Identity

log = logging.getLogger(__name__)

#: Pause between the neutral report taken by the host and the removal of a gadget the run made:
#: once the host's input device is gone, evdev drops what a game had not read yet (the uinput
#: pad's RELEASE_GRACE_S).
RELEASE_GRACE_S = 0.05
#: What an ``xinput`` run says: FunctionFS cannot carry the 17-byte descriptor of type 0x21 that
#: follows the FF/5D/01 interface of every XInput device Windows reads (``ffs_do_single_desc``
#: takes a class descriptor after a HID, CCID or DFU interface only), and the projects that
#: presented a 360 pad without it report that Windows binds its driver and reads no data.
XINPUT_ON_WINDOWS = (
    "the xinput pad is made on FunctionFS (GadgetFS is used only by a run as root that makes its own gadget, on a "
    "kernel that has it): Windows' own XInput driver will not read it from this board (it lacks the 0x21 "
    "descriptor FunctionFS cannot carry); for Windows use --protocol hid with Steam Input"
)
#: Which hid function instance carries which report format, whatever the gadget's protocol.
INSTANCES = {"usb1": "keyboard", "usb2": "mouse"}


def say_what_cannot_go(profile: Profile, functions: Path, protocol: str = "hid") -> list[str]:
    """Warn (the log) of what of ``profile`` the gadget (its configfs ``functions`` folder, speaking
    ``protocol``) cannot carry to the host: keys or the pointer beside a pad that goes alone (the
    protocol table's ``alone``), keys with no keyboard function, the pointer or mouse buttons with
    no mouse function, keys the boot keyboard's report has no usage for (docs/reports.md).
    Returns the lines said."""
    from neurotouch_hid.targets.reports.keyboard import unrepresentable

    lines = []
    alone = protocol in PROTOCOLS and PROTOCOLS[protocol].alone
    if alone and (profile.uses_keyboard or profile.uses_mouse):
        lines.append(f"the profile presses keys or moves the pointer, but {configfs.alone(protocol)}")
    elif profile.uses_keyboard and not (functions / "hid.usb1").is_dir():
        lines.append("the profile presses keys but the USB gadget has no keyboard: gadget setup --keyboard")
    elif profile.uses_keyboard and (dropped := unrepresentable(profile.keyboard_keys)):
        lines.append(f"the USB keyboard has no usage for {', '.join(dropped)}: the host gets nothing for them")
    if profile.uses_mouse and not alone and not (functions / "hid.usb2").is_dir():
        lines.append("the profile moves the pointer or clicks but the USB gadget has no mouse: gadget setup --mouse")
    for line in lines:
        log.warning(line)
    return lines


def protocol_for(requested: str | None, profile: Profile, name: str = configfs.GADGET_NAME) -> str:
    """The protocol of a run: ``--protocol`` when given, else the profile's ``device: protocol``,
    else that of the gadget set up here (``gadget setup``, or the boot unit that runs it:
    :func:`~neurotouch_hid.targets.gadget.configfs.protocol_of`), else ``hid``. Raises
    DeviceError for an unknown one."""
    from neurotouch_hid.core.errors import NeurotouchError
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
        DeviceError: no gadget of this protocol and not root; no UDC; the nodes are not this user's;
            a profile with keys or the pointer on a protocol whose gadget carries the pad alone
            (``xinput``, ``xac``: the protocol table's ``alone``).
    """

    def __init__(
        self,
        protocol: str,
        profile: Profile,
        *,
        name: str = configfs.GADGET_NAME,
        serial: str | None = None,
        identity: Identity | None = None,
    ):
        self.protocol = protocol
        self.identity = identity  # the feature reports' (a DualSense's MAC); None: the default identity
        self.profile = profile
        self.name = name
        self.serial = serial or configfs.DEFAULT_USB_SERIAL  # iSerialNumber of a gadget this run makes
        self.targets: list[Target] = []
        self.made = False
        self._gadgetfs = False  # this run mounted GadgetFS (the xinput pad on it)
        self._guard: Guard | None = None

    def __enter__(self) -> "UsbGadget":
        if PROTOCOLS[self.protocol].alone and (self.profile.uses_keyboard or self.profile.uses_mouse):
            raise DeviceError(f"the profile presses keys or moves the pointer, but {configfs.alone(self.protocol)}")
        found = configfs.protocol_of(self.name)
        if found is None and os.geteuid() == 0 and PROTOCOLS[self.protocol].gadget_function == "xinput":
            if self._open_gadgetfs():
                return self
        if found is None:
            if os.geteuid() != 0:
                raise DeviceError(
                    f"no USB gadget is set up for --output usb (no {configfs.gadget_dir(self.name)})\n"
                    + sudo_command(f"gadget setup --protocol {self.protocol} --user $USER")
                )
            plan = configfs.plan(self.protocol, self.profile.uses_keyboard, self.profile.uses_mouse, self.serial)
            configfs.create(plan, name=self.name)
            self.made = True
        elif found != self.protocol:
            raise DeviceError(
                f"the USB gadget set up here speaks {found}, not {self.protocol}\n"
                + sudo_command(f"gadget setup --protocol {self.protocol} --user $USER")
            )
        try:
            self._open()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _open_gadgetfs(self) -> bool:
        """The ``xinput`` pad on GadgetFS, where this kernel has it (root, no gadget set up): its
        whole configuration descriptor, the 0x21 descriptor in place, as Windows' driver reads it
        (:mod:`~neurotouch_hid.targets.gadget.gadgetfs`). False (said on the log) when it cannot
        be had: the run then makes the pad on FunctionFS."""
        from neurotouch_hid.targets.gadget import gadgetfs

        row = PROTOCOLS[self.protocol]
        try:
            self._gadgetfs = gadgetfs.mount()
            pad = gadgetfs.GadgetFsXInputTarget(
                gadgetfs.ROOT,
                row.report,
                (row.vendor, row.product, row.bcd_device),
                (row.manufacturer, row.product_name, self.serial),
            )
        except (DeviceError, OSError) as exc:
            log.info("GadgetFS not used (%s): the xinput pad is made on FunctionFS", exc)
            if self._gadgetfs:
                gadgetfs.unmount()
            self._gadgetfs = False
            return False
        pad.lacks = lambda profile: say_what_cannot_go(profile, gadgetfs.ROOT, self.protocol)  # on each profile
        self.targets.append(pad)
        return True

    def _open(self) -> None:
        from neurotouch_hid.targets.gadget.ffs import HidInterfaceTarget, XInputTarget
        from neurotouch_hid.targets.gadget.targets import HidgTarget
        from neurotouch_hid.targets.identity import identity_for
        from neurotouch_hid.targets.protocols import protocol as protocol_row
        from neurotouch_hid.targets.reports import format_for

        functions = configfs.gadget_dir(self.name) / "functions"
        row = protocol_row(self.protocol, "gadget")
        # a FunctionFS function's descriptors first: the gadget binds only then
        mount = configfs.FFS_ROOT / configfs.FFS_INSTANCES.get(row.gadget_function, "")
        if row.gadget_function == "xinput":
            log.warning(XINPUT_ON_WINDOWS)  # GadgetFS could not be had (_open_gadgetfs)
            self.targets.append(XInputTarget(mount, row.report))
        elif row.gadget_function == "ffs-hid":
            identity = self.identity or identity_for(None)
            packet, interval = row.max_packet or row.report.report_length, row.interval_ms or 4
            pad = HidInterfaceTarget(mount, row.report, identity, max_packet=packet, interval_ms=interval,
                                     name=row.product_name)  # fmt: skip
            self.targets.append(pad)
        if not configfs.bound_udc(self.name):
            configfs.bind(self.name)
        for instance in self._instances(functions):
            fmt = format_for(INSTANCES[instance]) if instance in INSTANCES else row.report
            node = configfs.hidg_node(instance, self.name)
            self.targets.append(HidgTarget(node, fmt, f"USB gadget ({fmt.name}, {node})"))
        if self.targets:
            self.targets[0].lacks = lambda profile: say_what_cannot_go(profile, functions, self.protocol)  # each one
        say_what_cannot_go(self.profile, functions, self.protocol)
        guarded = [target for target in self.targets if hasattr(target, "guarded")]  # hidg nodes, FunctionFS
        ffs = any(not isinstance(target, HidgTarget) for target in guarded)
        if guarded:
            try:  # a FunctionFS function's gadget goes when its guard ends: it stays for the host's readers
                self._guard = Guard([target.guarded() for target in guarded], linger_s=LINGER_S if ffs else 0.0)
            except OSError as exc:
                log.warning(
                    "the USB gadget's guard could not start (%s): if the driver is killed, the host keeps its last"
                    " report until the gadget is unplugged",
                    exc.strerror or exc,
                )

    def _instances(self, functions: Path) -> list[str]:
        """The gadget's ``hid`` function instances this run writes: all of them, but in a gadget
        with a pad per camera (``gadget setup --serial A --serial B``) only this camera's pad
        (:func:`~neurotouch_hid.targets.gadget.configfs.pad_instance` of :attr:`serial`).

        Raises:
            DeviceError: a gadget with a pad per camera has none for this one.
        """
        found = sorted(p.name.removeprefix("hid.") for p in functions.glob("hid.*"))
        pads = [i for i in found if i.startswith(configfs.PAD_PREFIX)]
        if not pads:
            return found
        mine = configfs.pad_instance(self.serial)
        if mine not in pads:
            cameras = [p.removeprefix(configfs.PAD_PREFIX) for p in pads]
            given = " ".join(f"--serial {c}" for c in [*cameras, self.serial])
            fix = sudo_command(f"gadget setup --protocol {self.protocol} {given}")
            raise DeviceError(
                f"the USB gadget set up here has a pad for each of the cameras {', '.join(cameras)}, none for this "
                f"one ({self.serial}: run --serial gives it)\n{fix}"
            )
        return [i for i in found if i == mine or not i.startswith(configfs.PAD_PREFIX)]

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
        if self._gadgetfs:
            from neurotouch_hid.targets.gadget import gadgetfs

            gadgetfs.unmount()
            self._gadgetfs = False
        if self.made:
            time.sleep(RELEASE_GRACE_S)  # the host's readers take the neutral report before the device goes
            configfs.remove(self.name)
            self.made = False
