"""Two gels on one board, one host: one gadget with a pad per camera (``gadget setup --serial A
--serial B``), each run finding its own pad by its serial. In a real kernel:
tests/test_gadget_kernel.py (tests/kernel/checks_gadget_pads.py)."""

import os

import pytest
from helpers import run_main

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.targets.gadget import UsbGadget, configfs


def test_a_gadget_for_two_cameras_has_a_pad_for_each_in_order_and_their_serials_joined():
    plan = configfs.plan("hid", pads=("LEFT1", "RIGHT1"))
    assert [(f.instance, f.format) for f in plan.hid] == [("padLEFT1", "hid"), ("padRIGHT1", "hid")]
    assert plan.serial == "LEFT1-RIGHT1" and plan.ffs == ""
    (switch, _) = configfs.plan("switch", pads=("A", "B")).hid
    assert (switch.format, switch.max_packet) == ("switch", 64)
    assert [f.instance for f in configfs.plan("hid", serial="A", pads=("A",)).hid] == ["usb0"]  # one camera: as ever


@pytest.mark.parametrize(
    ("protocol", "pads", "keyboard", "said"),
    [
        ("xinput", ("A", "B"), False, "xinput gadget carries one pad.*use --protocol hid"),
        ("xac", ("A", "B"), False, "xac gadget carries one pad.*goes alone"),
        ("dualsense", ("A", "B"), False, "dualsense gadget carries one pad"),
        ("hid", ("A", "A"), False, "the same camera twice"),
        ("hid", ("A", "B"), True, "no USB keyboard or mouse"),
    ],
)
def test_a_gadget_for_several_cameras_is_refused_where_it_cannot_be(protocol, pads, keyboard, said):
    with pytest.raises(DeviceError, match=said):
        configfs.plan(protocol, keyboard=keyboard, pads=pads)


def _functions(tmp_path, *instances):
    for instance in instances:
        (tmp_path / f"hid.{instance}").mkdir()
    return tmp_path


def test_each_run_finds_its_own_pad_by_its_serial(tmp_path):
    functions = _functions(tmp_path, "padLEFT1", "padRIGHT1")
    profile = load_profile("default")
    assert UsbGadget("hid", profile, serial="LEFT1")._instances(functions) == ["padLEFT1"]
    assert UsbGadget("hid", profile, serial="RIGHT1")._instances(functions) == ["padRIGHT1"]
    with pytest.raises(
        DeviceError, match="(?s)cameras LEFT1, RIGHT1, none for this one.*--serial LEFT1 --serial RIGHT1 --serial OTHER"
    ):
        UsbGadget("hid", profile, serial="OTHER")._instances(functions)


def test_a_gadget_of_one_pad_is_every_runs_as_before(tmp_path):
    functions = _functions(tmp_path, "usb0", "usb1", "usb2")
    assert UsbGadget("hid", load_profile("default"), serial="LEFT1")._instances(functions) == ["usb0", "usb1", "usb2"]


def test_gadget_setup_for_two_cameras_names_both_in_the_command_it_gives(monkeypatch, capsys):
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    done = run_main(monkeypatch, capsys, ["gadget", "setup", "--serial", "LEFT1", "--serial", "RIGHT1"])
    assert done.returncode == 2 and "gadget setup --protocol hid --serial LEFT1 --serial RIGHT1" in done.stderr
    bad = run_main(monkeypatch, capsys, ["gadget", "setup", "--serial", "LEFT1", "--serial", "x y"])
    assert bad.returncode == 2 and "--serial: camera serial 'x y'" in bad.stderr
