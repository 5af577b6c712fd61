"""The protocol table (neurotouch_hid/targets/protocols.py): every row has its golden bytes, and the
command line, the profile and ``gadget setup`` offer exactly the table's protocols.

A new protocol adds its row there and its golden bytes here
(docs/architecture.md, "Adding a protocol"): the neutral input report, one report with controls
pressed (:func:`pressed`), and each feature report the row answers, for the identity of
:data:`SERIAL`.
"""

from __future__ import annotations

import dataclasses

import pytest

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.targets.protocols import GADGET_FUNCTIONS, PROTOCOLS, TRANSPORTS, by_ids, names, protocol
from neurotouch_hid.targets.reports import FORMATS

#: The camera serial the feature reports' golden bytes are made for.
SERIAL = "00000499"

#: Per protocol: (the neutral input report, :func:`pressed`'s report), hex.
GOLDEN: dict[str, tuple[str, str]] = {
    "hid": ("00000000000000000000080000", "ff7f00800000000000ff020104"),
    "switch": ("0000088080808000", "821002ff00808000"),
    "xinput": (
        "0014000000000000000000000000000000000000",
        "0014081400ffff7fff7f00000000000000000000",
    ),
    "xac": ("80808080080000", "ff008080020104"),
    "dualsense": (
        "0180808080000000080000000000000000000000000000000000000000000000"
        "0080000000800000000000000000000000000000002a00000000000000000000",
        "01ff00808000ff00220801000000000000000000000000000000000000000000"
        "0080000000800000000000000000000000000000002a00000000000000000000",
    ),
}
#: Per protocol: report id -> the feature report for :data:`SERIAL`'s identity, hex (id first).
GOLDEN_FEATURES: dict[str, dict[int, str]] = {
    "dualsense": {
        0x05: "05000000000000c02140dec02140dec02140de1c021c02002000e0002000e0002000e0000000000000",
        0x09: "09c563117d1fee00000000000000000000000000",  # the MAC ee:1f:7d:11:63:c5, last octet first
        0x20: "204a616e202031203230323630303a30303a3030000000000100000000000100000000000000000000000000"
        "2402000000000000000000000000000000000000",
    },
}
#: The formats of the gadget's other functions (keyboard, mouse): neutral report, hex.
GOLDEN_OTHER = {"keyboard": "00" * 8, "mouse": "00" * 5}


def pressed() -> ControllerState:
    """Left stick full right and up, right trigger full, d-pad right, A and the guide button."""
    state = ControllerState.neutral()
    state.axes.update(ABS_X=32767, ABS_Y=-32768, ABS_RZ=255, ABS_HAT0X=1)
    state.buttons.update(BTN_SOUTH=True, BTN_MODE=True)
    return state


def test_every_protocol_has_its_golden_bytes():
    assert set(GOLDEN) == set(PROTOCOLS), "a row without golden bytes (or golden bytes without a row)"
    for name, row in PROTOCOLS.items():
        neutral, full = GOLDEN[name]
        assert row.report.neutral().hex() == neutral, name
        assert row.report.pack(ControllerState.neutral()).hex() == neutral, name
        assert row.report.pack(pressed()).hex() == full, name
        assert len(row.report.neutral()) == row.report.report_length, name


def test_every_feature_report_a_row_answers_has_its_golden_bytes():
    for name, row in PROTOCOLS.items():
        assert set(GOLDEN_FEATURES.get(name, {})) == set(row.report.feature_ids), name
        if not row.report.feature_ids:
            continue
        from neurotouch_hid.targets.identity import identity_for

        identity = identity_for(SERIAL)
        for report_id, golden in GOLDEN_FEATURES[name].items():
            answer = row.report.feature(report_id, identity)
            assert answer.hex() == golden and answer[0] == report_id, (name, report_id)


@pytest.mark.parametrize("name", sorted(FORMATS))
def test_a_feature_id_not_answered_is_a_key_error(name):
    fmt = FORMATS[name]
    unknown = next(i for i in range(256) if i not in fmt.feature_ids)
    with pytest.raises(KeyError):
        fmt.feature(unknown, None)


@pytest.mark.parametrize("name", sorted(FORMATS))
def test_odd_output_reports_are_never_an_error(name):
    fmt = FORMATS[name]
    for data in (b"", b"\x00", b"\xff" * 3, bytes(range(64)), b"\x00\x08\x00\xff\x80" + bytes(4000)):
        kinds = ("rumble", "led", "lightbar", "keyboard_leds")
        assert all(f.kind in kinds for f in fmt.parse_output(data)), (name, data)


def test_output_reports_become_feedback():
    rumble = FORMATS["xinput"].parse_output(bytes.fromhex("000800ff80000000"))[0]
    assert (rumble.kind, rumble.strong, round(rumble.weak, 3)) == ("rumble", 1.0, 0.502)
    assert FORMATS["keyboard"].parse_output(b"\x02")[0].led == 2  # Caps Lock
    assert FORMATS["hid"].parse_output(b"\x01\x02") == []  # the joystick has no output report


def test_the_other_functions_formats_have_their_golden_bytes():
    for name, golden in GOLDEN_OTHER.items():
        assert FORMATS[name].neutral().hex() == golden


def test_rows_are_well_formed():
    for name, row in PROTOCOLS.items():
        assert row.name == name and row.summary and row.report.name in FORMATS
        assert row.transports <= set(TRANSPORTS) and row.gadget_function in GADGET_FUNCTIONS
        assert by_ids(row.vendor, row.product, row.bcd_device) is row, "two rows with the same USB ids and release"
        if "uhid" in row.transports:
            assert row.report.descriptor, name
    with pytest.raises(ValueError, match="transports"):
        dataclasses.replace(PROTOCOLS["hid"], transports=frozenset({"bluetooth"}))


def test_a_protocol_not_in_the_table_or_not_on_a_transport_is_refused_with_the_choices():
    with pytest.raises(NeurotouchError, match=r"unknown protocol 'ps5' \(expected one of: hid, switch, xinput"):
        protocol("ps5")
    with pytest.raises(NeurotouchError, match=r"the xinput protocol does not run on this machine .*: hid"):
        protocol("xinput", "uhid")


def _protocol_choices(*path: str) -> tuple[str, ...]:
    """The choices the command ``path`` names when given an unknown ``--protocol``."""
    import re

    from typer.testing import CliRunner

    from neurotouch_hid.cli import app

    result = CliRunner().invoke(app, [*path, "--protocol", "ps5"])
    assert result.exit_code == 2, result.output
    listed = re.search(r"'ps5' is not one of ([^\n]*)", result.output)
    assert listed, result.output
    return tuple(re.findall(r"'([^']+)'", listed.group(1)))


def test_the_command_line_and_the_profile_offer_the_tables_protocols():
    from typing import get_args

    from neurotouch_hid.mapping.profile import DeviceSpec

    assert _protocol_choices("run") == tuple(PROTOCOLS) == names()
    assert _protocol_choices("gadget", "setup") == names("gadget")
    (literal, _none) = get_args(DeviceSpec.model_fields["protocol"].annotation)
    assert get_args(literal) == tuple(PROTOCOLS)


def test_the_gadget_plan_is_the_rows_ids_strings_and_function():
    from neurotouch_hid.targets.gadget import configfs

    for name in names("gadget"):
        row = PROTOCOLS[name]
        plan = configfs.plan(name, keyboard=not row.alone)
        assert (plan.vendor, plan.product, plan.version) == (row.vendor, row.product, row.bcd_device)
        assert (plan.manufacturer, plan.product_name) == (row.manufacturer, row.product_name)
        assert plan.ffs == configfs.FFS_INSTANCES.get(row.gadget_function, "")
        keyboard = [] if row.alone else ["keyboard"]
        assert [h.format for h in plan.hid] == ([] if plan.ffs else [row.report.name]) + keyboard
        if not plan.ffs:
            assert (plan.hid[0].max_packet, plan.hid[0].interval_ms) == (row.max_packet or 0, row.interval_ms or 0)


def test_doctor_names_the_protocols_each_transport_carries(monkeypatch):
    from neurotouch_hid.service import doctor
    from neurotouch_hid.targets.gadget import support

    monkeypatch.setattr(support, "uhid_problem", lambda *a: None)
    assert doctor.check_uhid().detail.endswith("protocols: " + ", ".join(names("uhid")))
