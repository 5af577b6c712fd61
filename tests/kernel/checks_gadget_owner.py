"""Who may write the USB gadget's device nodes once ``gadget setup --user USER`` handed them over:
whoever writes ``/dev/hidgN`` (or the XInput pad's FunctionFS files) is the other host's
controller. A user "bob" (the guest's ``nobody``) is given the gadget; "carol" (``daemon``), whose
process has bob's primary group, must not be able to open its nodes for writing, bob must.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_gadget_owner_kernel.py. Each
``gadget setup`` runs in this process (``guestlib.cli_in_process``), then ``gadget remove``; the
opens are made by a forked child that drops to the user's uid and groups first.
"""

from __future__ import annotations

import os
import pwd
import stat

import guestlib
from checks_gadget import _kernel

from neurotouch_hid.targets.gadget import configfs

TIMEOUT_S = 300


def _open_as(path: os.PathLike, uid: int, gid: int) -> int:
    """0 when a process of ``uid`` whose only group is ``gid`` opens ``path`` for writing, else
    the errno it got."""
    pid = os.fork()
    if pid == 0:  # the child: only system calls, then _exit
        code = 255
        try:
            os.setgroups([gid])
            os.setgid(gid)
            os.setuid(uid)
            os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
            code = 0
        except OSError as exc:
            code = exc.errno or 255
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status)


def check_gadget_nodes_are_the_users_alone() -> dict:
    """``gadget setup --user nobody`` for ``hid`` and ``xinput``: each node's mode, owner and group,
    and whether its owner and another user of the owner's primary group can open it to write."""
    _kernel()
    bob, carol = pwd.getpwnam("nobody"), pwd.getpwnam("daemon")
    found: dict = {"bob": bob.pw_uid, "bob_gid": bob.pw_gid}
    for protocol in ("hid", "xinput"):
        setup = guestlib.cli_in_process("gadget", "setup", "--protocol", protocol, "--user", "nobody")
        assert setup[0] == 0, f"gadget setup --protocol {protocol}: {setup}"
        try:
            if protocol == "hid":
                node = configfs.hidg_node(configfs.plan(protocol).hid[0].instance)
            else:
                node = configfs.FFS_ROOT / configfs.FFS_INSTANCE / "ep0"
            st = os.stat(node)
            found[protocol] = {
                "node": str(node),
                "mode": oct(stat.S_IMODE(st.st_mode)),
                "uid": st.st_uid,
                "gid": st.st_gid,
                "owner_opens": _open_as(node, bob.pw_uid, bob.pw_gid),
                "group_member_opens": _open_as(node, carol.pw_uid, bob.pw_gid),
                "said": setup[1].strip().splitlines()[:2],
            }
        finally:
            removed = guestlib.cli_in_process("gadget", "remove")
            assert removed[0] == 0, f"gadget remove: {removed}"
    return found
