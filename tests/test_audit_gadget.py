"""``gadget setup`` and ``gadget remove`` where a step fails, with configfs faked in a folder
(the real gadget is checked in a real kernel: tests/test_gadget_kernel.py)."""

from __future__ import annotations

import errno
import os

import pytest
from typer.testing import CliRunner

from neurotouch_hid.errors import DeviceError
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
