"""``neurotouch-hid gadget setup`` and ``gadget remove``: the privileged step of ``run --output usb``.

``setup`` (as root, once per boot: packaging/neurotouch-hid-gadget.service runs it) makes the
configfs gadget (:mod:`neurotouch_hid.targets.gadget.configfs`) and hands its device nodes to a
user, so that ``run --output usb`` never runs as root; ``remove`` takes it away again.
"""

from __future__ import annotations

import os
import pwd
from typing import List, Optional

import typer

from neurotouch_hid.cli.common import console
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.targets.protocols import choices as protocol_choices
from neurotouch_hid.targets.protocols import help_text as protocol_help

#: The protocols a gadget speaks (the protocol table's).
GadgetProtocol = protocol_choices("gadget")

gadget_app = typer.Typer(
    help="Make or remove the USB gadget that run --output usb uses (as root).", no_args_is_help=True
)


def _owner(user: Optional[str]) -> tuple[int, str]:
    """The uid the gadget is handed to and who that is, in words: ``user`` (a name or a uid of
    this machine's passwd), else the user who ran sudo (``SUDO_UID``), else root.

    Raises:
        NeurotouchError: ``user`` is empty or names no user here.
    """
    if user is not None:
        if not user.strip():
            raise NeurotouchError("--user is empty: give the name of the user who runs run --output usb")
        try:
            entry = pwd.getpwnam(user) if not user.isdigit() else pwd.getpwuid(int(user))
        except KeyError:
            raise NeurotouchError(f"--user {user!r}: no such user on this machine") from None
        return entry.pw_uid, f"uid {entry.pw_uid} ({entry.pw_name})"
    sudo = os.environ.get("SUDO_UID", "")
    if sudo.isdigit():
        uid = int(sudo)
        try:
            name = pwd.getpwuid(uid).pw_name
        except KeyError:
            name = "no name in passwd"
        return uid, f"uid {uid} ({name}, who ran sudo; --user NAME for another)"
    return 0, "uid 0 (root: no --user given and not run through sudo)"


@gadget_app.command("setup")
def setup(
    protocol: GadgetProtocol = typer.Option(
        "hid",
        "--protocol",
        help=f"{protocol_help('gadget')} (docs/any-host.md)",
    ),
    user: Optional[str] = typer.Option(None, "--user", help="who may use the gadget (default: the user who ran sudo)"),
    keyboard: bool = typer.Option(False, "--keyboard", help="add a USB keyboard (keys; not with xinput, xac)"),
    mouse: bool = typer.Option(False, "--mouse", help="add a USB mouse (the pointer; not with xinput, xac)"),
    serial: Optional[List[str]] = typer.Option(
        None,
        "--serial",
        help="the camera whose pad this is: the gadget's USB serial number derives from it; given twice or more "
        "(hid, switch), one pad per camera in one gadget, each run --serial finding its own",
    ),
) -> None:
    """Make the USB gadget (configfs) and hand its device nodes to a user; as root.

    The hid, switch and xac gadgets are bound to the first USB device controller at once; a
    FunctionFS one (xinput, dualsense) binds when run --output usb has written its descriptors.
    Two gels on one board, one host: ``--serial A --serial B`` makes one pad per camera."""
    from neurotouch_hid.targets.gadget import configfs
    from neurotouch_hid.targets.identity import identity_for

    protocol = str(protocol)
    serials = serial or []
    try:
        usb_serials = [identity_for(s).usb_serial for s in serials] or [identity_for(None).usb_serial]
    except ValueError as exc:
        raise NeurotouchError(f"--serial: {exc}") from None
    if os.geteuid() != 0:
        given = [f"--user {user}"] if user else []
        given += [flag for flag, wanted in (("--keyboard", keyboard), ("--mouse", mouse)) if wanted]
        given += [f"--serial {s}" for s in serials]
        raise NeurotouchError(
            f"gadget setup needs root:\n{_sudo('gadget setup --protocol ' + ' '.join([protocol, *given]))}"
        )
    uid, whom = _owner(user)
    pads = tuple(usb_serials) if len(usb_serials) > 1 else ()
    plan = configfs.plan(protocol, keyboard, mouse, usb_serials[0], pads=pads)
    configfs.remove()
    folder = configfs.create(plan, uid=uid)
    try:  # a step that fails leaves no gadget half made (unbound, or its nodes not the user's)
        if not plan.ffs:
            configfs.bind()
        nodes = []
        for function in plan.hid:
            node = configfs.hidg_node(function.instance)
            hand_over(node, uid)
            nodes.append((node, function))
    except BaseException:
        configfs.remove()
        raise
    for node, function in nodes:
        camera = function.instance.removeprefix(configfs.PAD_PREFIX) if pads else ""
        whose = f" (camera {camera}'s pad)" if camera else ""
        console.print(f"{node}: {function.format}{whose}, mode 0600, owned by {whom}", highlight=False)
    if plan.ffs:
        console.print(
            f"{configfs.FFS_ROOT / plan.ffs}: the {protocol} pad (FunctionFS), mode 0600, owned by {whom}",
            highlight=False,
        )
    console.print(
        f"gadget {folder} ({protocol}) ready; bound to: {configfs.bound_udc() or 'none yet'}", highlight=False
    )


def hand_over(node, uid: int) -> None:
    """Make ``node`` (a ``/dev/hidgN``: whoever writes it is the host's controller) the user
    ``uid``'s alone: owner ``uid``, group root, mode 0600. Not the user's primary group, which
    other users share (``users`` on many distributions) and would let them drive the host.

    Raises:
        OSError: the node is gone or cannot be changed (not root).
    """
    os.chown(node, uid, 0)
    os.chmod(node, 0o600)


@gadget_app.command("remove")
def remove() -> None:
    """Unbind and remove the USB gadget; as root."""
    from neurotouch_hid.targets.gadget import configfs

    if os.geteuid() != 0:
        raise NeurotouchError(f"gadget remove needs root:\n{_sudo('gadget remove')}")
    folder = configfs.gadget_dir()
    if not folder.exists():
        console.print(f"no gadget at {folder}: nothing to remove", highlight=False)
        return
    configfs.remove()
    if folder.exists():
        raise NeurotouchError(
            f"gadget {folder} could not be removed: something still uses it (a run --output usb: stop it), "
            f"then again:\n{_sudo('gadget remove')}"
        )
    console.print(f"gadget {folder} removed", highlight=False)


def _sudo(args: str) -> str:
    from neurotouch_hid.service.udev import sudo_command

    return sudo_command(args)
