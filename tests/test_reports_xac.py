"""The Adaptive Controller's joystick report, byte for byte (neurotouch_hid/targets/reports/xac.py,
docs/reports.md "xac"), and its descriptor as hid-tools parses it: a Joystick with four 8-bit
axes 0..255, a hat and 12 buttons, nothing else."""

import re

import pytest
from test_reports import DOCS, input_bits, walk

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.targets.reports.xac import XAC


def state(**axes_and_buttons) -> ControllerState:
    s = ControllerState.neutral()
    for name, value in axes_and_buttons.items():
        if name.startswith("ABS_"):
            s.axes[name] = value
        else:
            s.buttons[name] = value
    return s


@pytest.mark.parametrize(
    ("given", "report"),
    [
        (state(), "80808080080000"),
        (state(ABS_X=32767, ABS_Y=-32768), "ff008080080000"),  # left stick right and up
        (state(ABS_RX=-32768, ABS_RY=32767), "808000ff080000"),  # the right stick as Z, Rz
        (state(ABS_HAT0X=1, ABS_HAT0Y=-1), "80808080010000"),  # the hat up-right
        (state(BTN_SOUTH=True, BTN_MODE=True), "80808080080104"),  # button 1 and 11 (the guide)
        (state(ABS_Z=255, ABS_RZ=255), "80808080080000"),  # the triggers are not carried
    ],
)
def test_xac_report_golden_bytes(given, report):
    assert XAC.pack(given).hex() == report
    assert len(XAC.pack(given)) == XAC.report_length == 7


def test_xac_neutral_is_centred_with_nothing_pressed():
    assert XAC.neutral() == bytes.fromhex("80808080080000")


def test_xac_descriptor_is_a_joystick_of_four_8_bit_axes_a_hat_and_12_buttons_nothing_else():
    collections, fields = walk(XAC.descriptor)
    assert collections == [(0x01, 0x04)]  # one Application collection: Generic Desktop Joystick
    assert {f.kind for f in fields} == {"input"}  # no output, no feature report
    sticks, hat, hat_padding, buttons, padding = fields
    assert (sticks.page, sticks.usages, sticks.size, sticks.count, sticks.logical) == (
        0x01, [0x30, 0x31, 0x32, 0x35], 8, 4, (0, 255)
    )  # fmt: skip
    assert (hat.page, hat.usages, hat.size, hat.logical, hat.unit, hat.null_state) == (
        0x01,
        [0x39],
        4,
        (0, 7),
        0x14,
        True,
    )
    assert (buttons.page, buttons.size, buttons.count, buttons.logical) == (0x09, 1, 12, (0, 1))
    assert hat_padding.constant and padding.constant and padding.size * padding.count == 4
    assert input_bits(fields) == 8 * XAC.report_length


def test_docs_give_the_xac_descriptor_byte_for_byte():
    block = re.search(r"<!-- descriptor xac -->\n```\n(.*?)```", DOCS.read_text(), re.S)
    assert block and bytes.fromhex(block.group(1)) == XAC.descriptor
