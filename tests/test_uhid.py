"""The UHID target without a kernel device: the struct uhid_event layouts (include/uapi/linux/uhid.h),
the bounded event reader, the identity, and the DeviceError paths of `run --output hid`. The
device itself is checked in a real kernel (tests/test_uhid_kernel.py)."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.core.kinds import OutputKind
from neurotouch_hid.engine.driver import OPENERS, DriverOptions, run_driver
from neurotouch_hid.mapping.profile import DeviceSpec, load_profile
from neurotouch_hid.service.udev import RULES_FILE, UHID_RULE
from neurotouch_hid.targets.reports.hid import HID_JOYSTICK
from neurotouch_hid.targets.uhid import HID_DEFAULT, UhidDevice, hid_identity
from neurotouch_hid.targets.uhid_events import (
    UHID_CREATE2,
    UHID_DESTROY,
    UHID_EVENT_SIZE,
    UHID_GET_REPORT,
    UHID_INPUT2,
    UHID_INPUT_REPORT,
    UHID_OUTPUT,
    UHID_SET_REPORT,
    UHID_START,
    create2_event,
    parse_event,
    read_event,
)
from neurotouch_hid.targets.uinput.desktop import UinputDesktop


def test_the_event_size_is_the_kernels():
    # sizeof(struct uhid_event): u32 type + the union, whose largest member uhid_create2_req
    # (128+64+64+2+2+4+4+4+4+4096 = 4372) is padded to the union's 8-byte alignment
    assert UHID_EVENT_SIZE == 4 + 4376 == 4380
    header = Path("/usr/include/linux/uhid.h")
    if header.exists() and shutil.which("cc"):  # the kernel's own header, as the C compiler reads it
        with tempfile.TemporaryDirectory() as folder:
            source = Path(folder) / "size.c"
            source.write_text(
                "#include <linux/uhid.h>\n#include <stdio.h>\n"
                'int main(void) { printf("%zu", sizeof(struct uhid_event)); }\n'
            )
            subprocess.run(["cc", str(source), "-o", f"{folder}/size"], check=True)
            assert subprocess.run([f"{folder}/size"], capture_output=True, text=True, check=True).stdout == "4380"


def test_create2_puts_every_field_at_its_offset():
    event = create2_event(HID_JOYSTICK.descriptor, "pad", vendor=0x1209, product=0x0001, version=0x0100, uniq="u1")
    assert int.from_bytes(event[0:4], "little") == UHID_CREATE2
    assert event[4:132].rstrip(b"\0") == b"pad"
    assert event[132:196].rstrip(b"\0") == b"neurotouch-hid/uhid"
    assert event[196:260].rstrip(b"\0") == b"u1"
    rd_size, bus, vendor, product, version, country = struct.unpack_from("<HHIIII", event, 260)
    assert (rd_size, bus, vendor, product, version, country) == (len(HID_JOYSTICK.descriptor), 3, 0x1209, 1, 0x100, 0)
    assert event[280:] == HID_JOYSTICK.descriptor


@pytest.mark.parametrize(
    ("field", "kwargs", "message"),
    [
        ("name", {"name": "x" * 128}, "name .* must be under 128 bytes"),
        ("vendor", {"vendor": 0x10000}, "vendor id 65536 is not a 16-bit number"),
        ("descriptor", {"descriptor": b""}, "report descriptor of 0 bytes"),
    ],
)
def test_create2_refuses_what_does_not_fit(field, kwargs, message):
    args = {"descriptor": HID_JOYSTICK.descriptor, "name": "pad", "vendor": 1, "product": 2, "version": 3} | kwargs
    descriptor, name = args.pop("descriptor"), args.pop("name")
    with pytest.raises(DeviceError, match=message):
        create2_event(descriptor, name, **args)


def _event(kind: int, body: bytes) -> bytes:
    return kind.to_bytes(4, "little") + body


def test_parse_reads_each_request_and_bounds_its_data():
    start = parse_event(_event(UHID_START, (5).to_bytes(8, "little")))
    assert (start.type, start.dev_flags) == (UHID_START, 5)
    get = parse_event(_event(UHID_GET_REPORT, struct.pack("<IBB", 77, 0, UHID_INPUT_REPORT)))
    assert (get.id, get.rnum, get.rtype) == (77, 0, UHID_INPUT_REPORT)
    setr = parse_event(_event(UHID_SET_REPORT, struct.pack("<IBBH", 9, 1, 0, 3) + b"abcdef"))
    assert (setr.id, setr.rnum, setr.data) == (9, 1, b"abc")
    huge = parse_event(_event(UHID_SET_REPORT, struct.pack("<IBBH", 9, 1, 0, 65535) + b"z" * 9000))
    assert len(huge.data) == 4096  # UHID_DATA_MAX, whatever size the event claims
    output = parse_event(_event(UHID_OUTPUT, b"\1\2".ljust(4096, b"\0") + struct.pack("<HB", 2, 1)))
    assert (output.data, output.rtype) == (b"\1\2", 1)
    short = parse_event(_event(UHID_OUTPUT, b""))  # a short event is zero-extended
    assert short.data == b""
    with pytest.raises(DeviceError, match="not an event"):
        parse_event(b"\1\0")


def test_read_event_takes_one_read_of_at_most_one_event():
    r, w = os.pipe()
    try:
        os.write(w, _event(UHID_START, bytes(8)) + b"x" * 10_000)
        assert read_event(r).type == UHID_START
        assert len(os.read(r, 100_000)) == 8 + 10_000 + 4 - UHID_EVENT_SIZE
    finally:
        os.close(r)
        os.close(w)


def test_the_xbox_ids_of_the_shipped_profiles_become_the_hid_identity():
    assert hid_identity(load_profile("default").device) == HID_DEFAULT
    named = hid_identity(DeviceSpec(name="My pad"))
    assert (named.name, named.vendor, named.product) == ("My pad", HID_DEFAULT.vendor, HID_DEFAULT.product)
    own = hid_identity(DeviceSpec(name="Own", vendor=0x1234, product=0x5678, version=2))
    assert (own.name, own.vendor, own.product, own.version) == ("Own", 0x1234, 0x5678, 2)


def test_a_missing_dev_uhid_says_how_to_fix_it(tmp_path):
    node = str(tmp_path / "uhid")
    with pytest.raises(DeviceError, match=f"{node} does not exist .*uhid module") as info:
        UhidDevice(HID_JOYSTICK, HID_DEFAULT, node)
    assert "sudo modprobe uhid" in str(info.value) and "install.sh --system" in str(info.value)
    (tmp_path / "uhid").write_bytes(b"")
    with pytest.raises(DeviceError, match="not a character device"):
        UhidDevice(HID_JOYSTICK, HID_DEFAULT, node)


def test_the_udev_rule_gives_the_seat_dev_uhid():
    assert UHID_RULE in RULES_FILE.read_text().splitlines()


def test_run_output_hid_without_uhid_fails_before_any_device_exists():
    if os.path.exists("/dev/uhid"):
        pytest.skip("this machine has /dev/uhid: the kernel check covers it")
    with pytest.raises(DeviceError, match="/dev/uhid does not exist"):
        run_driver("sim", "default", "hid", DriverOptions(seconds=0.1))


def test_every_output_kind_has_one_opener():
    assert set(OPENERS) == set(OutputKind)


def test_keyboard_and_mouse_without_uinput_are_said_not_sent(tmp_path):
    lines: list[str] = []
    profile = load_profile("switch-access")
    assert profile.keyboard_keys
    desktop = UinputDesktop(profile, [profile], say=lines.append, devnode=str(tmp_path / "uinput"))
    desktop.prepare(profile)  # said once per profile
    desktop.prepare(load_profile("default"))  # uses neither: nothing to say
    assert len(lines) == 1
    assert lines[0].startswith("the profile's keyboard outputs are not sent: ")
    assert "does not exist" in lines[0]
    desktop.close()


def test_a_killed_driver_s_uhid_guard_sends_the_neutral_report_before_the_device_goes():
    """A driver killed without closing (SIGKILL): the guard's copy of the descriptor keeps the
    device, the guard sends the neutral report as UHID_INPUT2 and lingers before its copy goes
    (a socket stands for /dev/uhid; tests/kernel/checks_dualsense.py kills a real run)."""
    import socket

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.service.guard import LINGER_S

    ours, kernel = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    ours.setblocking(False)
    kernel.settimeout(10.0)
    device = UhidDevice.on_fd(ours.detach(), HID_JOYSTICK, HID_DEFAULT, start_wait_s=0)
    try:
        assert int.from_bytes(kernel.recv(UHID_EVENT_SIZE)[:4], "little") == UHID_CREATE2
        kernel.send(UHID_START.to_bytes(4, "little") + bytes(8))
        device.feedback()
        held = ControllerState.neutral()
        held.axes["ABS_X"] = 32767
        device.write(held)
        device._start_guard()
        got = [kernel.recv(UHID_EVENT_SIZE) for _ in range(2)]  # START's report, the held one
        input2 = struct.Struct("<IH")
        assert got[1][input2.size :] == HID_JOYSTICK.pack(held)
        guard = device._guard
        os.close(guard._write_end)  # the driver dies: the kernel closes its end of the pipe
        guard._write_end = -1
        sent = kernel.recv(UHID_EVENT_SIZE)
        t_sent = time.monotonic()
        assert input2.unpack_from(sent) == (UHID_INPUT2, len(HID_JOYSTICK.neutral()))
        assert sent[input2.size :] == HID_JOYSTICK.neutral()
        assert guard._proc.wait(30) == 0
        assert time.monotonic() - t_sent >= LINGER_S * 0.5  # it stayed for the readers
    finally:
        device._guard = None
        device.close()
        kernel.close()


def test_a_uhid_device_closed_in_order_releases_its_guard_which_sends_nothing():
    import socket

    ours, kernel = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    ours.setblocking(False)
    kernel.settimeout(10.0)
    device = UhidDevice.on_fd(ours.detach(), HID_JOYSTICK, HID_DEFAULT, start_wait_s=0)
    device._start_guard()
    guard = device._guard
    device.close()
    assert guard._proc.returncode == 0 and device._guard is None
    kernel.setblocking(False)
    types = []
    while True:
        try:
            event = kernel.recv(UHID_EVENT_SIZE)
        except BlockingIOError:
            break
        if not event:  # every copy of the device's descriptor closed
            break
        types.append(int.from_bytes(event[:4], "little"))
    assert types == [UHID_CREATE2, UHID_DESTROY]  # nothing from the guard
    kernel.close()
