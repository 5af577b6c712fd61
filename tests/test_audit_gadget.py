"""``gadget setup`` and ``gadget remove`` where a step fails, with configfs faked in a folder
(the real gadget is checked in a real kernel: tests/test_gadget_kernel.py)."""

from __future__ import annotations

import errno
import os

import pytest
from typer.testing import CliRunner

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.targets.gadget import configfs


@pytest.fixture
def root(tmp_path, monkeypatch):
    """configfs in ``tmp_path``, one UDC, and the caller taken for root."""
    monkeypatch.setattr(configfs, "CONFIGFS", tmp_path)
    (tmp_path / "usb_gadget").mkdir()
    monkeypatch.setattr(configfs, "UDC_CLASS", tmp_path / "udc")
    (tmp_path / "udc" / "dummy_udc.0").mkdir(parents=True)
    monkeypatch.setattr(os, "geteuid", lambda: 0)
    return tmp_path


def _cli(*args: str) -> tuple[int, str]:
    """Exit code, and what was printed or the error raised (main() prints it: cli/__init__.py)."""
    from neurotouch_hid.cli import app

    result = CliRunner().invoke(app, ["gadget", *args])
    return result.exit_code, result.output + (str(result.exception) if result.exception else "")


def test_a_setup_that_cannot_bind_leaves_no_gadget_behind(root, monkeypatch):
    """The gadget was left made and unbound: a run then found it and failed on its bind again."""

    def create(plan, **kwargs):
        folder = configfs.gadget_dir()
        folder.mkdir()
        return folder

    def refused(*args, **kwargs):
        raise DeviceError("binding the USB gadget to dummy_udc.0 failed: Device or resource busy")

    monkeypatch.setattr(configfs, "create", create)
    monkeypatch.setattr(configfs, "bind", refused)
    code, said = _cli("setup", "--protocol", "hid", "--user", "0")
    assert code != 0
    assert "Device or resource busy" in said
    assert not configfs.gadget_dir().exists()


def test_gadget_remove_does_not_say_removed_when_the_gadget_is_still_there(root, monkeypatch):
    """It said "gadget ... removed" and exited 0 while the kernel had refused to remove it; the
    next setup then said "exists already: remove it first"."""
    configfs.gadget_dir().mkdir()
    monkeypatch.setattr(configfs, "remove", lambda name=configfs.GADGET_NAME: None)  # the kernel refuses
    code, said = _cli("remove")
    assert code != 0
    assert "could not be removed" in said and " removed\n" not in said


def test_a_udc_held_by_another_gadget_is_named_with_what_to_do(root, monkeypatch):
    """It said only "Device or resource busy"."""
    other = root / "usb_gadget" / "g1"
    other.mkdir()
    (other / "UDC").write_text("dummy_udc.0\n")
    configfs.gadget_dir().mkdir()

    def busy(path, value):
        raise OSError(errno.EBUSY, os.strerror(errno.EBUSY))

    monkeypatch.setattr(configfs, "write_attr", busy)
    with pytest.raises(DeviceError) as caught:
        configfs.bind()
    said = str(caught.value)
    assert f"dummy_udc.0 is used by another gadget, {other}" in said
    assert f"echo > {other}/UDC" in said
    assert (other / "UDC").read_text() == "dummy_udc.0\n"  # another program's gadget is left alone


def test_setup_without_root_gives_the_command_with_every_option_given(monkeypatch):
    """The sudo line it gave dropped --user, --keyboard and --mouse: run as told, the gadget had
    no keyboard."""
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    code, said = _cli("setup", "--protocol", "switch", "--user", "alice", "--keyboard", "--mouse")
    assert code != 0
    assert "gadget setup --protocol switch --user alice --keyboard --mouse" in said


class _Configfs(type(configfs.CONFIGFS)):
    """A folder that makes a gadget's groups as configfs does; a function type named in
    ``missing`` is refused as the kernel refuses one with no module (ENOENT)."""

    missing: tuple[str, ...] = ()

    def mkdir(self, mode=0o777, parents=False, exist_ok=False):
        if self.parent.name == "functions" and self.name.split(".")[0] in self.missing:
            raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(self))
        super().mkdir(mode, parents=True, exist_ok=exist_ok)


@pytest.mark.parametrize(
    ("protocol", "missing", "said"),
    [("hid", "hid", "the kernel has no usb_f_hid"), ("xinput", "ffs", "the kernel has no usb_f_fs")],
)
def test_a_missing_function_module_is_named_with_what_to_do(root, monkeypatch, protocol, missing, said):
    """It said only "No such file or directory: .../functions/hid.usb0"."""
    monkeypatch.setattr(_Configfs, "missing", (missing,))
    monkeypatch.setattr(configfs, "CONFIGFS", _Configfs(root))
    monkeypatch.setattr(configfs.subprocess, "run", lambda *args, **kwargs: None)  # modprobe, mount
    monkeypatch.setattr(configfs, "write_attr", lambda path, value: None)
    with pytest.raises(DeviceError) as caught:
        configfs.create(configfs.plan(protocol))
    assert said in str(caught.value)
    assert "neurotouch-hid doctor" in str(caught.value)


def _chowns(monkeypatch) -> list[tuple[str, int, int]]:
    """os.chown recorded (a test need not be root to say whom a node is handed to)."""
    calls: list[tuple[str, int, int]] = []
    monkeypatch.setattr(os, "chown", lambda path, uid, gid: calls.append((str(path), uid, gid)))
    return calls


def test_the_gadget_nodes_are_the_users_alone_not_their_primary_groups(root, monkeypatch):
    """/dev/hidgN was made mode 0660 with the user's primary group (``users`` where that is the
    default): another user in that group wrote a report and the host read it."""
    import pwd
    import stat

    user = pwd.getpwnam("nobody")
    node = root / "hidg0"
    node.write_bytes(b"")
    os.chmod(node, 0o666)
    monkeypatch.setattr(configfs, "create", lambda plan, **kwargs: configfs.gadget_dir())
    monkeypatch.setattr(configfs, "bind", lambda *args, **kwargs: "dummy_udc.0")
    monkeypatch.setattr(configfs, "hidg_node", lambda instance, *args, **kwargs: node)
    chowns = _chowns(monkeypatch)
    code, said = _cli("setup", "--protocol", "hid", "--user", "nobody")
    assert code == 0, said
    assert stat.S_IMODE(node.stat().st_mode) == 0o600
    assert chowns == [(str(node), user.pw_uid, 0)]
    assert "mode 0600, owned by uid %d (nobody)" % user.pw_uid in said


def test_the_xinput_functionfs_files_are_the_users_alone(root, monkeypatch, tmp_path):
    """The FunctionFS mount (the XInput pad's endpoints) took the user's primary group too."""
    mounts: list[list[str]] = []
    monkeypatch.setattr(configfs, "CONFIGFS", _Configfs(root))
    monkeypatch.setattr(configfs, "FFS_ROOT", tmp_path / "ffs")
    monkeypatch.setattr(configfs, "write_attr", lambda path, value: None)
    monkeypatch.setattr(configfs, "load_modules", lambda *args, **kwargs: None)
    monkeypatch.setattr(configfs, "mount_configfs", lambda *args, **kwargs: None)
    monkeypatch.setattr(configfs.subprocess, "run", lambda cmd, **kwargs: mounts.append(cmd))
    chowns = _chowns(monkeypatch)
    configfs.create(configfs.plan("xinput"), uid=4242)
    (options,) = [cmd[cmd.index("-o") + 1] for cmd in mounts if cmd[:3] == ["mount", "-t", "functionfs"]]
    assert sorted(options.split(",")) == ["fmode=0600", "rmode=0500", "uid=4242"]
    assert {(uid, gid) for _, uid, gid in chowns} == {(4242, 0)}


@pytest.mark.parametrize("user", ["", " "])
def test_an_empty_user_is_refused_not_handed_to_whoever_ran_sudo(root, monkeypatch, user):
    """``--user ''`` handed the gadget to SUDO_UID or root without a word."""
    made = []
    monkeypatch.setattr(configfs, "create", lambda plan, **kwargs: made.append(kwargs))
    monkeypatch.setenv("SUDO_UID", "1000")
    code, said = _cli("setup", "--protocol", "hid", "--user", user)
    assert code != 0 and made == []
    assert "--user is empty" in said


def test_without_user_it_says_whom_it_hands_the_gadget_to(root, monkeypatch):
    node = root / "hidg0"
    node.write_bytes(b"")
    monkeypatch.setattr(configfs, "create", lambda plan, **kwargs: configfs.gadget_dir())
    monkeypatch.setattr(configfs, "bind", lambda *args, **kwargs: "dummy_udc.0")
    monkeypatch.setattr(configfs, "hidg_node", lambda instance, *args, **kwargs: node)
    _chowns(monkeypatch)
    monkeypatch.delenv("SUDO_UID", raising=False)
    code, said = _cli("setup", "--protocol", "hid")
    assert code == 0, said
    assert "owned by uid 0 (root: no --user given and not run through sudo)" in said
