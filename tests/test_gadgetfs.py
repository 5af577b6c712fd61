"""The Xbox 360 pad's descriptors on GadgetFS, byte for byte against a wired pad's (the
configuration dumps the 360 raw-gadget and GP2040-CE-style projects copy), and its answers to
the requests GadgetFS hands to user space. In a real kernel: tests/test_gadget_kernel.py."""

import pytest

from neurotouch_hid.targets.gadget import gadgetfs
from neurotouch_hid.targets.gadget.functionfs import Event

#: A wired Xbox 360 pad's first interface as its configuration descriptor carries it (49 bytes):
#: config (bmAttributes 0xA0: remote wake-up), interface FF/5D/01, the 17-byte 0x21 descriptor
#: naming endpoints 0x81 and 0x02, the interrupt endpoints (32 bytes, 4 and 8 ms).
WIRED_PAD = bytes.fromhex(
    "09 02 31 00 01 01 00 a0 fa  09 04 00 00 02 ff 5d 01 00"
    " 11 21 00 01 01 25 81 14 00 00 00 00 13 02 08 00 00  07 05 81 03 20 00 04  07 05 02 03 20 00 08"
)


#: A wired pad's device descriptor (045e:028e, release 1.14, class FF/FF/FF, ep0 8 bytes).
WIRED_PAD_DEVICE = bytes.fromhex("12 01 00 02 ff ff ff 08 5e 04 8e 02 14 01 01 02 03 01")


def test_the_full_speed_configuration_is_a_wired_pads_but_for_remote_wake_up():
    ours = gadgetfs.configuration()
    assert len(ours) == len(WIRED_PAD) == 49
    assert ours[7] == 0x80 and WIRED_PAD[7] == 0xA0  # GadgetFS refuses a configuration with remote wake-up
    assert ours[:7] + ours[8:] == WIRED_PAD[:7] + WIRED_PAD[8:]
    assert ours[18:35] == gadgetfs.XINPUT_CLASS_DESCRIPTOR and ours[18:20] == b"\x11\x21"


def test_an_endpoints_high_speed_descriptor_counts_microframes():
    """GadgetFS takes an endpoint's full- and high-speed descriptors together; at high speed
    bInterval n means 2^(n-1) microframes of 125 us."""
    assert gadgetfs.endpoint_descriptor(0x81, 4, True) == bytes.fromhex("07058103200006")  # 32 x 125 us
    assert gadgetfs.endpoint_descriptor(0x02, 8, True) == bytes.fromhex("07050203200007")  # 64 x 125 us


def test_the_device_descriptor_is_a_wired_pads():
    assert gadgetfs.device_descriptor(0x045E, 0x028E, 0x0114) == WIRED_PAD_DEVICE


@pytest.mark.parametrize(
    ("asked", "answer"),
    [
        (Event(4, 0x80, 0x06, 0x0300, 0, 255), b"\x04\x03\x09\x04"),
        (Event(4, 0x80, 0x06, 0x0302, 0x0409, 255), bytes([12, 3]) + "Pad 1".encode("utf-16-le")),
        (Event(4, 0x80, 0x06, 0x0302, 0x0409, 4), bytes([12, 3, ord("P"), 0])),
        (Event(4, 0x80, 0x06, 0x0304, 0x0409, 255), None),
        (Event(4, 0x00, 0x09, 0x0001, 0, 0), b""),  # SET_CONFIGURATION: acknowledged
        (Event(4, 0x80, 0x00, 0, 0, 2), b"\x00\x00"),  # GET_STATUS
        (Event(4, 0xC1, 0x01, 0x0100, 0, 20), bytes.fromhex("00143ff7ffff00000000c0ffc0ff000000000000")),
        (Event(4, 0x21, 0x09, 0x0200, 0, 8), None),
    ],
)
def test_the_pad_answers_what_gadgetfs_hands_over(asked, answer):
    pad = object.__new__(gadgetfs.GadgetFsXInputTarget)
    pad._strings = ("Microsoft", "Pad 1", "00000001")
    assert pad.answer(asked) == answer


def test_endpoint_files_are_found_by_number_and_direction_whatever_the_controller_names_them(tmp_path):
    for name in ("dummy_udc", "ep1in-bulk", "ep1out-bulk", "ep2out-bulk", "ep12out-bulk", "ep5in-int"):
        (tmp_path / name).touch()
    assert gadgetfs.endpoint_file(tmp_path, 1, "in").name == "ep1in-bulk"
    assert gadgetfs.endpoint_file(tmp_path, 2, "out").name == "ep2out-bulk"
    with pytest.raises(Exception, match="no endpoint 3 in"):
        gadgetfs.endpoint_file(tmp_path, 3, "in")


def _pad_on(root):
    """The pad's endpoint handling alone (no UDC file, no events thread) on ``root``'s files."""
    import os
    import threading
    import types

    pad = object.__new__(gadgetfs.GadgetFsXInputTarget)
    pad.root, pad.what, pad._closed = root, "test pad", False
    pad._null = os.open(os.devnull, os.O_RDWR)
    pad._in, pad._out = os.dup(pad._null), os.dup(pad._null)
    pad._configured, pad._generation = False, 0
    pad.connected, pad._lock = threading.Event(), threading.Lock()
    pad._open_announcements()
    pad._reader, pad._reading, pad._can_interrupt = None, False, gadgetfs._install_interrupt()
    pad._writer = types.SimpleNamespace(writing=False, thread_id=None)
    return pad


def test_the_endpoints_are_enabled_in_place_of_dev_null_and_put_back_when_the_configuration_ends(tmp_path):
    """The report writer holds one descriptor number for the pad's life: an enabled endpoint's
    file is put there, and /dev/null again when the host's configuration ends (a closed number
    could be taken by any file the process opens next, and a report written into it). The OUT
    endpoint's reader, blocked in a read no host will answer, is interrupted and ends (a
    transfer under way holds GadgetFS's endpoint lock, which unbinding the gadget waits for)."""
    import os

    (tmp_path / "ep1in-bulk").touch()
    os.mkfifo(tmp_path / "ep2out-bulk")  # the OUT endpoint's reader waits on it as on a real one
    writer = os.open(tmp_path / "ep2out-bulk", os.O_RDWR)
    pad = _pad_on(tmp_path)
    numbers, null = (pad._in, pad._out), os.fstat(pad._null)
    pad._enable()
    assert pad.connected.is_set() and (pad._in, pad._out) == numbers
    assert os.fstat(pad._in).st_ino == (tmp_path / "ep1in-bulk").stat().st_ino
    tag_and_descriptors = (tmp_path / "ep1in-bulk").read_bytes()
    assert tag_and_descriptors == b"\x01\0\0\0" + bytes.fromhex("0705810320000407058103200006")
    pad._enable()  # SET_CONFIGURATION again, no reset between: kept as it is
    assert os.fstat(pad._in).st_ino == (tmp_path / "ep1in-bulk").stat().st_ino
    import fcntl
    import termios

    from helpers import wait_until

    def waiting() -> bool:  # the tag and descriptors written to the FIFO read, the next read begun
        left = fcntl.ioctl(writer, termios.FIONREAD, b"\0\0\0\0")
        return pad._reading and int.from_bytes(left, "little") == 0

    assert wait_until(waiting, 5.0)  # blocked in its read: nothing more comes
    pad._disable()
    assert not pad.connected.is_set() and (pad._in, pad._out) == numbers
    assert all(os.fstat(fd).st_rdev == null.st_rdev for fd in numbers)
    pad._reader.join(5.0)
    assert not pad._reader.is_alive()
    os.close(writer)


def test_an_endpoint_that_will_not_enable_leaves_no_file_open_and_the_pad_unconfigured(tmp_path):
    """A file left open keeps GadgetFS's endpoint busy (EBUSY) for the next configuration."""
    import os

    pad = _pad_on(tmp_path)
    (tmp_path / "ep1in-bulk").touch()  # no OUT endpoint: the second open fails
    before = set(os.listdir("/proc/self/fd"))
    with pytest.raises(Exception, match="no endpoint 2 out"):
        pad._enable()
    assert set(os.listdir("/proc/self/fd")) == before
    assert not pad.connected.is_set() and not pad._configured


def test_a_report_write_that_fails_closes_the_gate_until_the_endpoints_owner_opens_it_again():
    """GadgetFS: a bus reset ends the configuration; a report written again before the pad knows
    would wait on the old endpoint and keep it busy for the next configuration."""
    import os
    import threading

    from helpers import wait_until

    from neurotouch_hid.targets.gadget.writer import ReportWriter

    gone_r, gone_w = os.pipe()
    os.close(gone_r)  # EPIPE: the host is away
    gate = threading.Event()
    gate.set()
    writer = ReportWriter(gone_w, "test", gate=gate)
    try:
        writer.submit(b"first")
        assert wait_until(lambda: not gate.is_set(), 5.0)
        back_r, back_w = os.pipe()
        os.set_blocking(back_r, False)
        writer.fd = back_w
        writer.submit(b"second")
        with pytest.raises(BlockingIOError):
            os.read(back_r, 64)  # nothing while the gate is closed
        gate.set()
        assert wait_until(lambda: _read(back_r) == b"second", 5.0)
    finally:
        writer.stop()


def _read(fd: int) -> bytes:
    import os

    try:
        return os.read(fd, 64)
    except BlockingIOError:
        return b""


def test_a_kernel_without_gadgetfs_leaves_the_pad_to_functionfs_and_nothing_mounted(monkeypatch, caplog):
    """Where GadgetFS cannot be had, the run makes the pad on FunctionFS (which then says that
    Windows will not read it): nothing of GadgetFS is left behind."""
    import logging

    from neurotouch_hid.core.errors import DeviceError
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets.gadget import UsbGadget

    def no_gadgetfs(root=gadgetfs.ROOT):
        raise DeviceError("mounting GadgetFS at /dev/gadget failed: unknown filesystem type 'gadgetfs'")

    monkeypatch.setattr(gadgetfs, "mount", no_gadgetfs)
    monkeypatch.setattr(gadgetfs, "unmount", lambda *a: pytest.fail("nothing was mounted"))
    gadget = UsbGadget("xinput", load_profile("default"))
    with caplog.at_level(logging.INFO):
        assert gadget._open_gadgetfs() is False
    assert gadget.targets == [] and gadget._gadgetfs is False
    assert "the xinput pad is made on FunctionFS" in caplog.text and "unknown filesystem type" in caplog.text


def test_a_pad_made_on_functionfs_says_windows_will_not_read_it(tmp_path, monkeypatch, caplog):
    import logging

    from neurotouch_hid.core.errors import DeviceError
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets.gadget import XINPUT_ON_WINDOWS, UsbGadget, configfs

    monkeypatch.setattr(configfs, "FFS_ROOT", tmp_path / "ffs")  # no FunctionFS mounted there
    monkeypatch.setattr(configfs, "gadget_dir", lambda name=configfs.GADGET_NAME: tmp_path / name)
    with caplog.at_level(logging.WARNING), pytest.raises(DeviceError):
        UsbGadget("xinput", load_profile("default"))._open()
    assert XINPUT_ON_WINDOWS in caplog.text and "use --protocol hid with Steam Input" in XINPUT_ON_WINDOWS


def test_the_hosts_requests_are_answered_on_the_loop_when_the_pads_descriptor_is_readable():
    """No thread of its own waits for the UDC's file: its events make the pad's one descriptor
    (an epoll over the UDC's file and the OUT endpoint's announcements) readable, and the loop's
    call of ``feedback`` reads and answers them, then hands on the rumble the OUT endpoint's
    reader announced. A socket stands in for the UDC's file (events in, answers out)."""
    import select
    import socket
    import threading

    from neurotouch_hid.core.controller import Feedback

    host, udc = socket.socketpair()
    pad = object.__new__(gadgetfs.GadgetFsXInputTarget)
    pad.what, pad._closed, pad._strings = "test pad", False, ("Microsoft", "Pad 1", "00000001")
    pad._dev, pad._lock = udc.fileno(), threading.Lock()
    pad._open_announcements()
    pad._ready = select.epoll()
    pad._ready.register(pad._dev, select.EPOLLIN)
    pad._ready.register(pad._wake_r, select.EPOLLIN)
    pad._events_ready = select.poll()
    pad._events_ready.register(pad._dev, select.POLLIN)

    def readable() -> bool:
        return bool(select.select([pad.fileno()], [], [], 0)[0])

    assert not readable()
    get_string = gadgetfs.EVENT.pack(0x80, 0x06, 0x0302, 0x0409, 255, gadgetfs.SETUP)
    host.sendall(get_string * 2)
    assert readable()
    assert pad.feedback() == []
    assert host.recv(256) == (bytes([12, 3]) + "Pad 1".encode("utf-16-le")) * 2  # both answered
    assert not readable()
    rumble = Feedback("rumble", strong=0.5, source="test pad")
    threading.Thread(target=pad._announce, args=([rumble],)).start()  # as the OUT endpoint's reader does
    assert select.select([pad.fileno()], [], [], 5.0)[0]
    assert pad.feedback() == [rumble] and not readable()
    pad._ready.close()
    pad._close_announcements()
    host.close()
    udc.close()


def test_closing_hands_the_host_the_neutral_report_twice_before_the_pad_goes(tmp_path):
    """The pad's close sends the neutral report, and once the host took it, once more (a host
    that keeps one transfer queued, as xpad does, takes the second only after it handled the
    first), and only then closes the UDC's file, which unbinds the pad (the host's readers lose
    what they had not read). A pipe stands in for the IN endpoint, a socket for the UDC's file."""
    import os
    import select
    import socket

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.targets.reports.xinput import XINPUT

    host_in, pad_in = os.pipe()
    host, udc = socket.socketpair()
    pad = _pad_on(tmp_path)
    os.dup2(pad_in, pad._in)
    os.close(pad_in)
    pad._dev, pad._ready = udc.detach(), select.epoll()
    pad.connected.set()  # the host configured the pad: reports go out
    pad._start(pad._in, XINPUT, "test pad", gate=pad.connected)
    pushed = ControllerState(axes={"ABS_X": 32767})
    pad.write(pushed)
    assert pad._writer.flush(5.0)  # the host took the push
    pad.close()
    data = b""
    while chunk := os.read(host_in, 4096):  # to the end: the pad closed its side
        data += chunk
    reports = [data[at : at + 20] for at in range(0, len(data), 20)]
    assert XINPUT.pack(pushed) in reports
    assert reports[-2:] == [XINPUT.neutral()] * 2, [r.hex() for r in reports]
    assert host.recv(64) == b""  # the UDC's file closed, after them
    os.close(host_in)
    host.close()
