"""Guest check of one driver per camera as it starts when a camera is plugged in: the udev rule's
link of each camera by its serial (``/dev/neurotouch-SERIAL``) and the templated user unit
(``neurotouch-hid@SERIAL.service``), under the user's own ``systemd --user`` (Debian 12's 252).

The camera is checks_packaging.py's emulated one (a 152a:841a gadget on dummy_hcd, serial
00000001); the user is checks_user_unit.py's, with both units installed by ``install.sh --user``
and a config folder for that camera (``~/.config/neurotouch-hid/sensors/00000001/``). The
emulated camera is no DAVIS, so the run itself does not stream: what is checked is which unit
the camera starts and that unplugging it stops that unit. Run by tests/kernel/guest.py; asserted
on by tests/test_sensors_kernel.py.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import guestlib
from checks_gadget import unit_in_this_guest
from checks_packaging import _plug_camera, _unplug_camera
from checks_user_unit import THIS_SYSTEMD, _users_unit

TIMEOUT_S = 300
#: The emulated camera's serial (checks_packaging.py's gadget).
SERIAL = "00000001"
INSTANCE = f"neurotouch-hid@{SERIAL}.service"
SINGLE = "neurotouch-hid.service"
DEVICE = f"dev-neurotouch\\x2d{SERIAL}.device"


def check_a_camera_with_its_own_folder_starts_its_own_instance() -> dict:
    """With ``sensors/00000001/`` in the user's config folder, plugging the camera in gives it
    ``/dev/neurotouch-00000001`` (besides ``/dev/neurotouch``) and starts
    ``neurotouch-hid@00000001.service`` (``run --source davis --serial 00000001``), not the single
    ``neurotouch-hid.service`` (its ``ConditionPathExists=!``); unplugging it stops the instance
    (``BindsTo=`` its link's device unit) and removes the link."""
    t0 = time.monotonic()
    seen: dict = {}

    def edit(unit, unit_file: Path) -> None:
        unit_in_this_guest(unit_file, unit.said)
        unit_in_this_guest(unit_file.with_name("neurotouch-hid@.service"), unit.said)
        (unit.config / "neurotouch-hid" / "sensors" / SERIAL).mkdir(parents=True)

    with _users_unit(THIS_SYSTEMD, edit) as unit:

        def state(name: str) -> str:
            return unit.systemctl("show", "-p", "ActiveState", "--value", name)

        def invocation(name: str) -> str:
            return unit.systemctl("show", "-p", "InvocationID", "--value", name)

        plugged = False
        try:
            time.sleep(1.0)  # the manager's first enumeration of udev's devices
            seen["before"] = {INSTANCE: state(INSTANCE), SINGLE: state(SINGLE)}
            sysdev = _plug_camera()
            plugged = True
            bus, dev = (int(Path(sysdev, n).read_text()) for n in ("busnum", "devnum"))
            node = f"/dev/bus/usb/{bus:03d}/{dev:03d}"
            link = f"/dev/neurotouch-{SERIAL}"
            seen["link"] = guestlib.wait_for(lambda: os.path.realpath(link) == node, 30.0) and node
            seen["wants"] = guestlib.udev_properties(node).get("SYSTEMD_USER_WANTS", "")
            seen["device"] = bool(guestlib.wait_for(lambda: state(DEVICE) == "active", 60.0, 0.2))
            seen["instance_started"] = bool(guestlib.wait_for(lambda: invocation(INSTANCE), 60.0, 0.2))
            seen["instance_exec"] = unit.systemctl("show", "-p", "ExecStart", "--value", INSTANCE)
            time.sleep(1.0)  # the single unit, asked for by the same plug-in, had its chance
            seen["single"] = {
                "invocation": invocation(SINGLE),
                "condition": unit.systemctl("show", "-p", "ConditionResult", "--value", SINGLE),
            }
            _unplug_camera()
            plugged = False
            seen["instance_stopped"] = bool(
                guestlib.wait_for(lambda: state(INSTANCE) in ("inactive", "failed"), 60.0, 0.2)
            )
            seen["link_gone"] = bool(guestlib.wait_for(lambda: not os.path.lexists(link), 10.0))
        finally:
            if plugged:
                _unplug_camera()
    seen["said"] = unit.log()[-1500:].splitlines()[-5:]
    seen["seconds"] = round(time.monotonic() - t0, 1)
    return seen
