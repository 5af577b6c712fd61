"""The USB gadget's pieces that need no kernel: FunctionFS structs, the report writer, the plan.
The gadget itself is checked in a real kernel (tests/test_gadget_kernel.py)."""

import errno
import os
import struct
import threading
import time

import pytest
from helpers import fill_unread, wait_until

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.targets.gadget import configfs, functionfs
from neurotouch_hid.targets.gadget.ffs import XINPUT_ENDPOINTS
from neurotouch_hid.targets.gadget.writer import RESEND_S, RETRY_S, ReportWriter


def test_functionfs_descriptors_of_the_xinput_pad():
    """functionfs.h's v2 head (magic 3, length, full+high speed), then per speed the interface
    FF/5D/01 with 2 endpoints and the endpoints 0x81 IN and 0x02 OUT, interrupt."""
    data = functionfs.descriptors((0xFF, 0x5D, 0x01), XINPUT_ENDPOINTS)
    magic, length, flags, fs_count, hs_count = struct.unpack_from("<5I", data)
    assert (magic, length, flags, fs_count, hs_count) == (3, len(data), 3, 3, 3)
    speed = bytes.fromhex("0904000002ff5d01010705810320000407050203200008")
    assert data[20:43] == speed
    # high speed: the same in microframes, 2^(n-1) x 125 us: 4 ms -> 6, 8 ms -> 7
    assert data[43:] == speed[:-8] + bytes([0x06]) + speed[-7:-1] + bytes([0x07])


def test_functionfs_strings():
    data = functionfs.strings("pad")
    assert data == struct.pack("<IIIIH", 2, 22, 1, 1, 0x0409) + b"pad\0"


def test_functionfs_events_are_read_whole_only():
    setup = struct.pack("<BBHHHB3x", 0xC1, 0x01, 0x0100, 0, 20, functionfs.SETUP)
    enable = struct.pack("<8xB3x", functionfs.ENABLE)
    events = functionfs.parse_events(setup + enable + b"\x01\x02")
    assert [e.name for e in events] == ["setup", "enable"]
    assert (events[0].request_type, events[0].request, events[0].value, events[0].length) == (0xC1, 1, 0x100, 20)
    assert functionfs.Event(9).name == "unknown 9"


def _read_all(fd: int) -> bytes:
    out = b""
    while True:
        try:
            data = os.read(fd, 65536)
        except BlockingIOError:
            return out
        if not data:  # the writer closed its end
            return out
        out += data


def test_writer_keeps_the_latest_report_while_the_host_is_away_and_sends_it_when_back():
    """A full pipe stands for a host that does not read (EAGAIN): the driver's submits return
    at once, and once the host reads again it gets the latest report, not the ones between."""
    r, w = os.pipe2(os.O_NONBLOCK)
    fill_unread(w)
    writer = ReportWriter(w, "test")
    try:
        submits = threading.Thread(target=lambda: [writer.submit(bytes([i]) * 8) for i in range(100)])
        submits.start()
        submits.join(300)  # only ends a hang: a submit that waited for the host would never return
        assert not submits.is_alive(), "submit blocked while the host was away"
        assert writer.flush(0.05) is False
        drained = _read_all(r)  # the host is back (a retry may land while it drains: kept)
        assert writer.flush(2.0) is True
        time.sleep(0.05)
        got = (drained + _read_all(r)).lstrip(b"\xff")  # what the host read after the filler
        assert got.startswith(bytes([99]) * 8)
        assert set(got) == {99}
    finally:
        writer.stop()
        os.close(r)
        os.close(w)


def test_writer_waiting_for_an_absent_host_tries_a_few_times_a_second_not_every_retry(monkeypatch):
    """A host asleep or unplugged for hours while the board runs: the report it has not taken is
    tried again less and less often (up to every RESEND_S), not every RETRY_S; a host back finds
    it within RESEND_S of its next try. Counted: the writer's writes to the node (each try is one
    wake-up of its thread; the thread's context switches would also count the preemptions and
    GIL waits of a loaded machine)."""
    r, w = os.pipe2(os.O_NONBLOCK)
    fill_unread(w)
    tries = []
    real_write = os.write

    def counted(fd, data):
        if fd == w:
            tries.append(time.monotonic())
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", counted)
    writer = ReportWriter(w, "test")
    try:
        writer.submit(b"held")
        assert wait_until(lambda: len(tries) >= 10, 300)  # the bound only ends a hang
        # the pause after each try doubles from RETRY_S up to RESEND_S: a wait is never shorter
        # than asked, so the gaps are at least those pauses, however slow the machine
        gaps = [b - a for a, b in zip(tries[:9], tries[1:10])]
        least = [min(RETRY_S * 2**i, RESEND_S) for i in range(len(gaps))]
        assert all(gap >= 0.99 * want for gap, want in zip(gaps, least)), list(zip(gaps, least))
        _read_all(r)  # the host is back
        assert writer.flush(30.0)
        assert _read_all(r).startswith(b"held")
    finally:
        writer.stop()
        os.close(r)
        os.close(w)


def test_writer_sends_the_current_report_again_after_a_while():
    """A host that re-enumerated the gadget gets the current state without a change."""
    r, w = os.pipe2(os.O_NONBLOCK)
    writer = ReportWriter(w, "test")
    try:
        writer.submit(b"abc")
        assert writer.flush(1.0)
        time.sleep(RESEND_S * 2.5)
        got = _read_all(r)
        assert got.count(b"abc") >= 2 and set(got) == set(b"abc")
    finally:
        writer.stop()
        os.close(r)
        os.close(w)


def test_writer_for_motion_keeps_every_report_in_order():
    r, w = os.pipe2(os.O_NONBLOCK)
    writer = ReportWriter(w, "mouse", depth=64, resend=False)
    try:
        for i in range(10):
            writer.submit(bytes([i]))
        assert writer.flush(1.0)
        time.sleep(RESEND_S * 1.5)
        assert _read_all(r) == bytes(range(10))
    finally:
        writer.stop()
        os.close(r)
        os.close(w)


@pytest.mark.parametrize(
    ("protocol", "ids", "functions", "ffs"),
    [
        ("hid", (0x1D6B, 0x0104), [("usb0", "hid", 0, 0)], ""),
        ("switch", (0x0F0D, 0x00C1), [("usb0", "switch", 0, 0)], ""),
        ("xinput", (0x045E, 0x028E), [], "xinput"),
        ("xac", (0x1D6B, 0x0104), [("usb0", "xac", 0, 0)], ""),
    ],
)
def test_plan(protocol, ids, functions, ffs):
    plan = configfs.plan(protocol)
    assert (plan.vendor, plan.product) == ids and plan.ffs == ffs
    assert [(f.instance, f.format, f.subclass, f.protocol) for f in plan.hid] == functions
    if protocol in ("xinput", "xac"):
        return
    with_keys = configfs.plan(protocol, keyboard=True, mouse=True)
    assert [(f.instance, f.format, f.subclass, f.protocol) for f in with_keys.hid] == functions + [
        ("usb1", "keyboard", 1, 1),
        ("usb2", "mouse", 1, 2),
    ]


@pytest.mark.parametrize(("keyboard", "mouse"), [(True, False), (False, True)])
@pytest.mark.parametrize("protocol", ["xinput", "xac"])
def test_an_xinput_or_xac_gadget_never_gets_a_keyboard_or_a_mouse(protocol, keyboard, mouse):
    """Windows' XInput driver ignores a pad with other interfaces beside it, and the Adaptive
    Controller a joystick with more in its device: the plan is refused, naming the protocol to use
    instead."""
    with pytest.raises(DeviceError, match="carries the pad alone.*use --protocol hid"):
        configfs.plan(protocol, keyboard=keyboard, mouse=mouse)


def test_the_switch_pad_has_64_byte_endpoints_and_the_xac_joystick_a_1_ms_interval():
    """HORI's wired pads' 64-byte endpoints (f_hid: report_length), the Adaptive Controller's 1 ms."""
    (switch,) = configfs.plan("switch").hid
    (xac,) = configfs.plan("xac").hid
    assert (switch.max_packet, switch.interval_ms) == (64, 0)
    assert (xac.max_packet, xac.interval_ms) == (0, 1)


def test_the_xac_and_hid_gadgets_share_ids_and_are_told_apart_by_their_release(tmp_path, monkeypatch):
    for protocol in ("hid", "xac"):
        plan = configfs.plan(protocol)
        gadget = tmp_path / protocol
        (gadget / "functions").mkdir(parents=True)
        for attr, value in (("idVendor", plan.vendor), ("idProduct", plan.product), ("bcdDevice", plan.version)):
            (gadget / attr).write_text(f"0x{value:04x}\n")
    monkeypatch.setattr(configfs, "gadget_dir", lambda name=configfs.GADGET_NAME: tmp_path / name)
    assert (configfs.protocol_of("hid"), configfs.protocol_of("xac")) == ("hid", "xac")


def test_a_run_of_a_profile_with_keys_on_the_xinput_gadget_is_refused_before_any_gadget_is_made(monkeypatch):
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets.gadget import UsbGadget

    monkeypatch.setattr(configfs, "create", lambda *a, **k: pytest.fail("a gadget was made"))
    monkeypatch.setattr(configfs, "protocol_of", lambda *a, **k: "xinput")
    with pytest.raises(DeviceError, match="presses keys or moves the pointer.*use --protocol hid"):
        UsbGadget("xinput", load_profile("switch-access")).__enter__()


def test_a_profile_with_keys_switched_to_on_the_xinput_gadget_is_told_to_use_hid(tmp_path):
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets.gadget import say_what_cannot_go

    (tmp_path / "ffs.xinput").mkdir()
    said = say_what_cannot_go(load_profile("switch-access"), tmp_path, "xinput")
    assert len(said) == 1 and "use --protocol hid" in said[0]
    assert say_what_cannot_go(load_profile("default"), tmp_path, "xinput") == []


def test_plan_refuses_an_unknown_protocol():
    with pytest.raises(DeviceError, match="expected one of: hid, switch, xinput"):
        configfs.plan("ps5")


def test_read_attr_is_bounded(tmp_path):
    big = tmp_path / "attr"
    big.write_text("x" * (configfs.MAX_ATTR_BYTES * 3) + "\n")
    assert configfs.read_attr(big) == "x" * configfs.MAX_ATTR_BYTES


def test_install_script_installs_the_gadget_unit_for_a_protocol_and_user(tmp_path):
    """install.sh --gadget PROTOCOL:USER writes the oneshot unit with both filled in (DESTDIR:
    nothing live is touched); an unknown protocol is refused with the ones there are."""
    import subprocess
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "packaging" / "install.sh"
    env = {**os.environ, "DESTDIR": str(tmp_path)}
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "passwd").write_text("alice:x:1000:1000::/home/alice:/bin/sh\n")  # the staged system's
    done = subprocess.run(
        ["sh", str(script), "--gadget", "switch:alice", "--bin", "/usr/bin/neurotouch-hid"],
        env=env,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    unit = (tmp_path / "etc/systemd/system/neurotouch-hid-gadget.service").read_text()
    assert "ExecStart=/usr/bin/neurotouch-hid gadget setup --protocol switch --user alice\n" in unit
    assert "ExecStop=/usr/bin/neurotouch-hid gadget remove\n" in unit
    assert "Type=oneshot" in unit and "RemainAfterExit=yes" in unit
    bad = subprocess.run(["sh", str(script), "--gadget", "ps5:bob"], env=env, capture_output=True, text=True)
    assert bad.returncode == 2 and "hid, switch or xinput" in bad.stderr


@pytest.mark.parametrize(
    "owner",
    [
        "bob\nExecStartPre=/bin/touch /tmp/owned",
        "root&x",
        "root|x",
        "%u",
        "root;id",
        "root x",
        "$USER",
        "-root",
        "..",
        "no_such_user_here",
        "x" * 40,
    ],
)
def test_install_script_refuses_a_gadget_user_that_is_not_a_user_name(tmp_path, owner):
    """USER went into the root unit unchecked: a newline added an ExecStartPre= line, & spliced
    text, | left the unit empty; %u, ;, spaces and unknown users were accepted."""
    import subprocess
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "packaging" / "install.sh"
    env = {**os.environ, "DESTDIR": str(tmp_path)}
    done = subprocess.run(
        ["sh", str(script), "--gadget", f"hid:{owner}", "--bin", "/usr/bin/neurotouch-hid"],
        env=env,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    assert "user" in done.stderr
    assert not (tmp_path / "etc/systemd/system/neurotouch-hid-gadget.service").exists()


def test_install_script_writes_the_name_of_an_existing_user_given_by_uid(tmp_path):
    """A uid names its user; the unit gets the name from passwd, not the text given."""
    import subprocess
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "packaging" / "install.sh"
    env = {**os.environ, "DESTDIR": str(tmp_path)}
    done = subprocess.run(
        ["sh", str(script), "--gadget", "hid:0", "--bin", "/usr/bin/neurotouch-hid"],
        env=env,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    unit = (tmp_path / "etc/systemd/system/neurotouch-hid-gadget.service").read_text()
    assert "ExecStart=/usr/bin/neurotouch-hid gadget setup --protocol hid --user root\n" in unit


def test_module_state_reads_sys_module_then_builtin_then_dep(tmp_path):
    from neurotouch_hid.targets.gadget.support import module_state

    mods, sysmod = tmp_path / "lib", tmp_path / "sys"
    mods.mkdir()
    (sysmod / "usb_f_hid").mkdir(parents=True)
    (mods / "modules.builtin").write_text("kernel/drivers/usb/gadget/libcomposite.ko\n")
    (mods / "modules.dep").write_text(
        "kernel/drivers/usb/gadget/function/usb_f_fs.ko.xz: kernel/drivers/usb/gadget/libcomposite.ko.xz\n"
    )
    assert module_state("usb_f_hid", mods, sysmod) == "loaded"
    assert module_state("libcomposite", mods, sysmod) == "built in"
    assert module_state("usb-f-fs", mods, sysmod) == "available"
    assert module_state("dummy_hcd", mods, sysmod) == "missing"
    # no /lib/modules/RELEASE to look in (a container): not known, not "missing"
    assert module_state("libcomposite", tmp_path / "nowhere", sysmod) == "unknown"


def test_no_udc_says_whether_the_class_folder_is_empty_or_absent(tmp_path, monkeypatch):
    monkeypatch.setattr(configfs, "UDC_CLASS", tmp_path / "udc")
    assert "/udc does not exist" in configfs.no_udc()
    (tmp_path / "udc").mkdir()
    assert "/udc is empty" in configfs.no_udc()


def test_raspberry_pi_is_told_by_its_device_tree_model(tmp_path):
    from neurotouch_hid.targets.gadget.support import is_raspberry_pi

    model = tmp_path / "model"
    model.write_bytes(b"Raspberry Pi 5 Model B Rev 1.0\0")
    assert is_raspberry_pi(model)
    model.write_bytes(b"Generic x86\0")
    assert not is_raspberry_pi(model)
    assert not is_raspberry_pi(tmp_path / "none")


def test_hidg_target_sends_changes_only_and_ends_on_the_neutral_report(tmp_path):
    """A FIFO stands for /dev/hidgN (the host reading it): the held state's report once however
    often it is written, then close() sends the neutral report before the node is closed."""
    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.targets.gadget.targets import HidgTarget
    from neurotouch_hid.targets.reports.switch import SWITCH

    node = tmp_path / "hidg0"
    os.mkfifo(node)
    host = os.open(node, os.O_RDONLY | os.O_NONBLOCK)
    target = HidgTarget(node, SWITCH, "test")
    held = ControllerState.neutral()
    held.axes["ABS_X"] = 32767
    for _ in range(5):
        target.write(held)
    time.sleep(0.05)
    got = _read_all(host)
    assert (
        got.endswith(SWITCH.pack(held)) and got.count(SWITCH.pack(held)) == 1
    )  # the neutral first, if not yet replaced
    target.close()
    got = _read_all(host)
    assert got.endswith(SWITCH.neutral()) and len(got) % 8 == 0
    assert target.fileno() is None
    target.close()  # idempotent
    os.close(host)


def test_the_protocol_comes_from_the_option_then_the_profile_then_the_gadget_set_up_then_hid(tmp_path, monkeypatch):
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.targets.gadget import protocol_for
    from neurotouch_hid.targets.reports.switch import PRODUCT, VENDOR

    monkeypatch.setattr(configfs, "CONFIGFS", tmp_path)  # no gadget set up
    plain = Profile()
    switch = Profile.model_validate({"device": {"protocol": "switch"}})
    assert protocol_for(None, plain) == "hid"
    assert protocol_for(None, switch) == "switch"
    assert protocol_for("xinput", switch) == "xinput"
    with pytest.raises(DeviceError, match="unknown protocol 'ps5'"):
        protocol_for("ps5", plain)
    # a Switch gadget made at boot (gadget setup --protocol switch): a plain run speaks it
    gadget = tmp_path / "usb_gadget" / configfs.GADGET_NAME
    gadget.mkdir(parents=True)
    (gadget / "idVendor").write_text(f"0x{VENDOR:04x}\n")
    (gadget / "idProduct").write_text(f"0x{PRODUCT:04x}\n")
    assert protocol_for(None, plain) == "switch"
    assert protocol_for("hid", plain) == "hid"  # the option still wins (the gadget then refuses it)
    (gadget / "functions" / f"ffs.{configfs.FFS_INSTANCE}").mkdir(parents=True)
    assert protocol_for(None, plain) == "xinput"
    assert protocol_for(None, switch) == "switch"  # and the profile


def test_protocol_is_refused_without_output_usb_or_hid():
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.engine.driver import DriverOptions, run_driver

    with pytest.raises(NeurotouchError, match="--protocol switch: only with --output usb .* or --output hid"):
        run_driver("sim", "default", "jsonl", DriverOptions(protocol="switch"))


@pytest.mark.parametrize(
    ("number", "said"),
    [
        (errno.EACCES, "the gadget's device nodes are not this user's\nsudo "),
        (errno.EPERM, "a device policy denies it (a systemd unit's DevicePolicy=closed without DeviceAllow=char-hidg"),
        (errno.ENOENT, "no such node: the gadget is not set up"),
    ],
)
def test_a_hidg_node_that_does_not_open_says_why_by_its_errno(monkeypatch, number, said):
    """EPERM is what a systemd unit's device policy gives (seen in the test kernel's check of the
    packaged unit without its DeviceAllow=char-hidg), EACCES the node's owner, ENOENT no gadget."""
    from neurotouch_hid.targets.gadget.targets import HidgTarget
    from neurotouch_hid.targets.reports import format_for

    def refused(*args, **kwargs):
        raise OSError(number, os.strerror(number))

    monkeypatch.setattr(os, "open", refused)
    with pytest.raises(DeviceError) as raised:
        HidgTarget("/dev/hidg0", format_for("hid"), "test")
    assert said in str(raised.value) and str(raised.value).startswith("cannot open /dev/hidg0 (")


def test_gadget_remove_says_so_when_there_is_no_gadget(tmp_path, monkeypatch, capsys):
    """It said "gadget ... removed" and exited 0 where there was none."""
    from typer.testing import CliRunner

    from neurotouch_hid.cli import app

    monkeypatch.setattr(configfs, "CONFIGFS", tmp_path)
    monkeypatch.setattr(os, "geteuid", lambda: 0)
    result = CliRunner().invoke(app, ["gadget", "remove"])
    assert result.exit_code == 0, result.output
    assert f"no gadget at {tmp_path / 'usb_gadget' / configfs.GADGET_NAME}: nothing to remove" in result.output
    assert "removed" not in result.output


def test_no_configfs_on_a_board_without_a_device_controller_says_the_board_first(tmp_path, monkeypatch):
    """The advice was modprobe and mount only, which cannot help a machine with no USB device port."""
    monkeypatch.setattr(configfs, "CONFIGFS", tmp_path)
    monkeypatch.setattr(configfs.subprocess, "run", lambda *args, **kwargs: None)  # no mount here
    monkeypatch.setattr(configfs, "udcs", lambda: [])
    with pytest.raises(DeviceError) as caught:
        configfs.mount_configfs()
    said = str(caught.value)
    assert said.startswith(f"{tmp_path}/usb_gadget does not exist, and this machine has no USB device controller")
    assert "neurotouch-hid doctor" in said and "modprobe" not in said
    monkeypatch.setattr(configfs, "udcs", lambda: ["dummy_udc.0"])  # a board that has one: load and mount
    with pytest.raises(DeviceError, match="configfs or libcomposite is missing\nsudo modprobe libcomposite"):
        configfs.mount_configfs()


@pytest.mark.parametrize(
    ("release", "has"),
    [("6.1.0-56-amd64", False), ("6.15.9", False), ("6.16.0-rc1", True), ("6.17.2+rpt-rpi-v8", True)],
)
def test_doctor_says_whether_the_hid_function_can_poll_every_1_ms(tmp_path, release, has):
    """The xac protocol's 1 ms interval needs the hid function's ``interval`` attribute (Linux
    6.16): known from a hid function of a gadget here, else from the kernel release."""
    from neurotouch_hid.targets.gadget.support import hid_interval, protocol_notes

    assert hid_interval(release, tmp_path)[0] is has
    note = protocol_notes(release, tmp_path, tmp_path)[0]
    assert ("cannot set its polling interval" in note) is not has
    function = tmp_path / "neurotouch" / "functions" / "hid.usb0"
    function.mkdir(parents=True)
    assert hid_interval(release, tmp_path) == (False, f"seen in {function}")
    (function / "interval").write_text("4\n")
    assert hid_interval(release, tmp_path)[0] is True


def test_the_sudo_commands_given_name_the_command_by_its_absolute_path(tmp_path, monkeypatch):
    """sudo searches only its secure_path, not ~/.local/bin where pipx puts the command: the
    fixes name the running command by its absolute path (a space in it quoted)."""
    import sys

    from neurotouch_hid.service.udev import sudo_command
    from neurotouch_hid.targets.gadget.targets import _why_not

    command = tmp_path / "my bin" / "neurotouch-hid"
    command.parent.mkdir()
    command.write_text("#!/bin/sh\n")
    monkeypatch.setattr(sys, "argv", [str(command), "run"])
    assert sudo_command("gadget remove") == f"sudo '{command}' gadget remove"
    assert _why_not(errno.EACCES).endswith(f"sudo '{command}' gadget setup --user $USER")
    assert _why_not(errno.ENOENT).endswith(f"sudo '{command}' gadget setup --user $USER")
    monkeypatch.setattr(sys, "argv", ["/nowhere/python", "-m"])
    monkeypatch.setenv("PATH", "/nonexistent")
    assert sudo_command("gadget remove") == f"sudo {sys.executable} -m neurotouch_hid.cli gadget remove"


def test_doctor_says_which_interface_for_a_whole_configuration_descriptor_this_kernel_has(tmp_path):
    """Windows' XInput driver reads a 0x21 descriptor FunctionFS cannot carry: doctor names the
    interfaces that could (gadgetfs, raw_gadget) and what to use on Windows meanwhile."""
    from neurotouch_hid.targets.gadget.support import protocol_notes

    (tmp_path / "modules.dep").write_text("kernel/drivers/usb/gadget/legacy/gadgetfs.ko: kernel/udc.ko\n")
    note = protocol_notes("6.1.0", tmp_path / "none", tmp_path)[1]
    assert note.startswith("xinput: gadgetfs available here: a run as root") and "GadgetFS" in note
    (tmp_path / "modules.dep").write_text("")
    note = protocol_notes("6.1.0", tmp_path / "none", tmp_path)[1]
    assert note.startswith("xinput: neither gadgetfs nor raw_gadget") and "Windows will not read xinput" in note
