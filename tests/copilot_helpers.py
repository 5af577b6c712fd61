"""What the copilot's tests share (tests/test_copilot_*.py, test_engine_loop.py): a short-form copilot
profile and a helper's pad as /dev/input lists it."""

from __future__ import annotations

from neurotouch_hid.inputs.match import InputInfo

SHORT_FORM = """\
mappings:
  stick: {input: push, output: left_stick}
copilot:
  - device: "Helper Pad"            # a name, "045e:02ea", or a /dev/input/by-id/ path
  - device: "Switch Box"
    map: {KEY_SPACE: BTN_SOUTH}
"""


HELPER = InputInfo(
    "/dev/input/event7",
    "Helper Pad",
    "usb-0000:00:14.0-2/input0",
    0x045E,
    0x02EA,
    ("/dev/input/by-id/usb-Helper-event-joystick",),
)
