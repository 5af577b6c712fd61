"""The gadget's FunctionFS functions' answers to their host's control requests, byte for byte (HID
1.11 chapter 7; the Xbox 360 pad's vendor requests). In a real kernel: tests/test_gadget_ffs_kernel.py."""

import struct

import pytest

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.stages import Feedback
from neurotouch_hid.targets.gadget import functionfs
from neurotouch_hid.targets.gadget.ffs import ACCEPT, HidState, hid_answer, xinput_answer


class Format:
    """A format with one feature report (0x05, 3 bytes) and an output report (0x02)."""

    name = "test"
    descriptor = bytes(range(70))
    report_length = 4
    feature_ids = (0x05,)

    def pack(self, state: ControllerState) -> bytes:
        return b"\x01\x00\x00\x00"

    def neutral(self) -> bytes:
        return self.pack(ControllerState.neutral())

    def feature(self, report_id: int, identity: object) -> bytes:
        if report_id != 0x05:
            raise KeyError(report_id)
        return bytes([0x05, len(str(identity)), 0xAA])

    def parse_output(self, data: bytes) -> list[Feedback]:
        return [Feedback("rumble", strong=data[1] / 255)] if data[:1] == b"\x02" and len(data) > 1 else []


def setup(request_type: int, request: int, value: int, length: int, index: int = 0) -> functionfs.Event:
    return functionfs.Event(functionfs.SETUP, request_type, request, value, index, length)


def test_the_hid_descriptor_names_the_report_descriptor_and_its_length():
    """HID 1.11, 6.2.1: bLength 9, type 0x21, bcdHID 1.11, country 0, one descriptor: 0x22 of N bytes."""
    assert functionfs.hid_descriptor(300) == bytes.fromhex("09211101000122" + "2c01")


def test_functionfs_descriptors_of_a_hid_interface_carry_the_hid_descriptor_after_the_interface():
    endpoints = (functionfs.Endpoint(0x81, max_packet=64), functionfs.Endpoint(0x02, max_packet=64))
    data = functionfs.descriptors(functionfs.HID_CLASS, endpoints, functionfs.hid_descriptor(70))
    magic, length, flags, fs_count, hs_count = struct.unpack_from("<5I", data)
    assert (magic, length, flags, fs_count, hs_count) == (3, len(data), 3, 4, 4)
    full = bytes.fromhex("0904000002030000010921110100012246000705810340000407050203400004")
    assert data[20 : 20 + len(full)] == full


@pytest.mark.parametrize(
    ("asked", "answer"),
    [
        (setup(0x81, 0x06, 0x2200, 64), bytes(range(64))),  # the report descriptor, cut to wLength
        (setup(0x81, 0x06, 0x2200, 200), bytes(range(70))),
        (setup(0x81, 0x06, 0x2100, 9), bytes.fromhex("092111010001224600")),
        (setup(0x81, 0x06, 0x2300, 9), None),  # a physical descriptor: none
        (setup(0xA1, 0x01, 0x0305, 64), bytes([0x05, len("me"), 0xAA])),  # GET_REPORT(Feature 5)
        (setup(0xA1, 0x01, 0x0305, 2), bytes([0x05, len("me")])),
        (setup(0xA1, 0x01, 0x0309, 64), None),  # a feature id the format has not
        (setup(0xA1, 0x01, 0x0101, 64), b"\x01\x09"),  # GET_REPORT(Input): the last report
        (setup(0xA1, 0x01, 0x0202, 64), None),  # GET_REPORT(Output)
        (setup(0xA1, 0x02, 0x0000, 1), b"\x00"),  # GET_IDLE
        (setup(0xA1, 0x03, 0x0000, 1), b"\x01"),  # GET_PROTOCOL: report
        (setup(0x21, 0x0A, 0x0000, 0), ACCEPT),  # SET_IDLE
        (setup(0x21, 0x09, 0x0202, 48), ACCEPT),  # SET_REPORT(Output)
        (setup(0x21, 0x09, 0x0202, 4096), None),  # a data stage longer than the bound
        (setup(0xC1, 0x01, 0x0100, 20), None),  # a vendor request
        (setup(0x80, 0x06, 0x0100, 18), None),  # a device request is never the function's
    ],
)
def test_the_hid_interface_answers_its_hosts_requests(asked, answer):
    state = HidState(report=b"\x01\x09")
    assert hid_answer(asked, Format(), "me", state) == answer


def test_set_idle_and_set_protocol_are_kept_and_read_back():
    state = HidState()
    assert hid_answer(setup(0x21, 0x0A, 0x0400, 0), Format(), None, state) == ACCEPT
    assert hid_answer(setup(0x21, 0x0B, 0x0000, 0), Format(), None, state) == ACCEPT
    assert hid_answer(setup(0xA1, 0x02, 0x0000, 1), Format(), None, state) == b"\x04"
    assert hid_answer(setup(0xA1, 0x03, 0x0000, 1), Format(), None, state) == b"\x00"


def test_a_format_without_feature_reports_stalls_every_get_feature():
    class Plain(Format):
        feature_ids = ()

    assert hid_answer(setup(0xA1, 0x01, 0x0305, 64), Plain(), None, HidState()) is None


@pytest.mark.parametrize(
    ("asked", "answer"),
    [
        (setup(0xC1, 0x01, 0x0100, 20), bytes.fromhex("00143ff7ffff00000000c0ffc0ff000000000000")),
        (setup(0xC1, 0x01, 0x0000, 8), bytes.fromhex("0008000000000000")),
        (setup(0xC1, 0x01, 0x0000, 4), bytes.fromhex("00080000")),
        (setup(0xC1, 0x01, 0x0200, 20), None),
        (setup(0x41, 0x01, 0x0100, 0), None),
        (setup(0xA1, 0x01, 0x0100, 20), None),
    ],
)
def test_the_xbox_360_pad_answers_the_vendor_requests_of_a_wired_pad(asked, answer):
    """Linux's xpad asks C1 01 0100 (20 bytes) on open, Windows' driver that and C1 01 0000 (8)."""
    assert xinput_answer(asked) == answer


def test_output_reports_of_the_hid_interface_become_feedback_named_after_it():
    from neurotouch_hid.targets.gadget.ffs import HidInterfaceTarget

    target = object.__new__(HidInterfaceTarget)
    target.format, target.what = Format(), "USB gadget (test)"
    assert target.parse(b"\x02\xff") == [Feedback("rumble", strong=1.0, source="USB gadget (test)")]
    assert target.parse(b"\x07") == []
