"""A profile's ``copilot:`` section: the devices merged into the pad and how each control combines."""

from __future__ import annotations

import functools
import os
import re
from typing import Any, Literal

from pydantic import (
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from neurotouch_hid.core.controller import AXES, BUTTONS
from neurotouch_hid.core.errors import did_you_mean
from neurotouch_hid.core.limits import (
    short,
)
from neurotouch_hid.mapping.profile.models import (
    _Strict,
)
from neurotouch_hid.mapping.profile.outputs import (
    DIGITAL_OUTPUTS,
    DPAD,
    FACE_ALIASES,
    KERNEL_COMMAND_KEYS,
    keyboard_keys,
)

# --- copilot: devices merged into the pad ---------------------------------------------------------
#: What a button does when the gel and a merged device both act on it: pressed while either presses.
BUTTON_POLICIES: tuple[str, ...] = ("either",)
#: What an axis does when both act: the value further from centre, the gel's (``gel``) or the
#: device's (``helper``) while it is off centre, else the other's, or the ``sum`` (clipped).
AXIS_POLICIES: tuple[str, ...] = ("further", "gel", "helper", "sum")
#: Most devices one profile merges.
MAX_COPILOT_DEVICES = 8
#: A device's ids as the user writes them: ``045e:02ea`` (USB vendor:product, hex).
_IDS_PATTERN = r"^[0-9A-Fa-f]{4}:[0-9A-Fa-f]{4}$"
#: The names of the keyboard and mouse the driver makes (``targets/uinput/desktop.py``): never merged.
OWN_INPUT_NAMES: tuple[str, ...] = ("NeuroTouch keyboard", "NeuroTouch mouse")
#: Where stable paths of input devices live (udev's persistent links).
STABLE_PATH_PREFIX = "/dev/input/"


def _refuse_each(model: str, problems: list[tuple[tuple, Any, str]]) -> None:
    """Raise every problem a validator found at once, each at its own place (so each gets its own
    line): ``problems`` is a list of (loc under the field, the value found, what was expected).

    Raises:
        ValidationError: when ``problems`` is not empty (pydantic prefixes the field's loc).
    """
    if problems:
        raise ValidationError.from_exception_data(
            model,
            [
                InitErrorDetails(
                    type=PydanticCustomError("value_error", "{expected}", {"expected": expected}), loc=loc, input=found
                )
                for loc, found, expected in problems
            ],
        )


@functools.cache
def _device_codes() -> frozenset[str]:
    """Every evdev key, button and absolute-axis name (``KEY_*``, ``BTN_*``, ``ABS_*``) python-evdev knows."""
    from evdev import ecodes

    prefixes, limits = ("KEY_", "BTN_", "ABS_"), ("_MAX", "_CNT")
    return frozenset(name for name in ecodes.ecodes if name.startswith(prefixes) and not name.endswith(limits))


def control_of(output: str) -> str:
    """The pad control an output drives: a face alias resolved, a ``dpad_*`` direction as its hat
    axis (``ABS_HAT0X``/``ABS_HAT0Y``); any other name as it is."""
    output = FACE_ALIASES.get(output, output)
    return DPAD[output][0] if output in DPAD else output


class CopilotDevice(_Strict):
    """One input device merged into the pad (docs/profiles.md, "Copilot").

    ``device`` names it: its name as the kernel reports it (``neurotouch-hid devices`` lists them),
    its USB ids ``vvvv:pppp`` (hex), or a stable path under ``/dev/input/`` (``by-id/...``).
    ``map``: its controls (evdev names: ``KEY_SPACE``, ``BTN_SOUTH``, ``ABS_X``) -> what they drive:
    a key or button -> a pad button, ``A``/``B``/``X``/``Y``, ``dpad_*`` or a keyboard key; an axis
    -> a pad axis (``ABS_X`` .. ``ABS_RZ``, ``ABS_HAT0X``/``Y``). ``passthrough``: the device's pad
    controls (a pad's buttons, sticks, triggers and d-pad) drive the same controls of the pad,
    unless ``map`` says otherwise. ``policy``: per pad control, what it does when the gel (and the
    devices listed before this one) and this device both act: ``either`` for a button, ``further``
    (the default), ``gel``, ``helper`` or ``sum`` for an axis."""

    device: str = Field(min_length=1, max_length=255, description="a device name, 'vvvv:pppp' or a /dev/input/ path")
    map: dict[str, str] = Field(default_factory=dict, max_length=64)
    passthrough: bool = True
    policy: dict[str, Literal[BUTTON_POLICIES + AXIS_POLICIES]] = Field(default_factory=dict, max_length=64)

    @field_validator("device")
    @classmethod
    def _device_form(cls, value: str) -> str:
        if not value.isprintable():
            raise ValueError("a device name of printable characters")
        if value.startswith("/") and not os.path.normpath(value).startswith(STABLE_PATH_PREFIX):
            raise ValueError(
                f"a path under {STABLE_PATH_PREFIX} (such as /dev/input/by-id/usb-...-event-joystick); "
                f"{short(value)} is {short(os.path.normpath(value))}"
            )
        return value.lower() if re.match(_IDS_PATTERN, value) else value

    @field_validator("map")
    @classmethod
    def _known_controls(cls, value: dict[str, str]) -> dict[str, str]:
        out, problems = {}, []
        for source, target in value.items():
            if source not in _device_codes():
                problems.append(
                    (
                        (source,),
                        source,
                        "a control of the device (an evdev name such as 'KEY_SPACE', 'BTN_SOUTH' or 'ABS_X'); "
                        f"{short(source)} is none{did_you_mean(source, _device_codes())}",
                    )
                )
                continue
            written, target = target, FACE_ALIASES.get(target, target)
            if source.startswith("ABS_"):
                if target not in AXES:
                    problems.append(((source,), written, f"a pad axis ({', '.join(AXES)}) for the axis {source}"))
            elif target in KERNEL_COMMAND_KEYS:
                problems.append(
                    (
                        (source,),
                        written,
                        f"a key other than {target}: the system acts on it, so no profile may press it",
                    )
                )
            elif target not in DIGITAL_OUTPUTS and target not in keyboard_keys():
                problems.append(
                    (
                        (source,),
                        written,
                        "a pad button (BTN_SOUTH ... BTN_THUMBR, A, B, X, Y), a d-pad direction (dpad_*) or a "
                        f"keyboard key such as 'KEY_SPACE' for {source}",
                    )
                )
            out[source] = target
        _refuse_each("CopilotDevice", problems)
        return out

    @field_validator("policy")
    @classmethod
    def _policies_fit(cls, value: dict[str, str], info: ValidationInfo) -> dict[str, str]:
        mapped = info.data.get("map") or {}
        passthrough = info.data.get("passthrough", True)
        reach = set(AXES) | set(BUTTONS) if passthrough else {control_of(t) for t in mapped.values()}
        problems = []
        for control, policy in value.items():
            pad = control_of(control)
            if pad not in AXES and pad not in BUTTONS:
                problems.append(
                    (
                        (control,),
                        control,
                        "a pad control (an axis ABS_X .. ABS_HAT0Y, a button BTN_SOUTH .. BTN_THUMBR, A, B, X, Y "
                        f"or dpad_*) for each policy; {short(control)} is none",
                    )
                )
            elif pad not in reach:
                problems.append(
                    (
                        (control,),
                        policy,
                        f"a policy only on a control this device drives; {control} is not one of them (passthrough "
                        f"is off and map: drives {', '.join(sorted(reach)) or 'nothing'})",
                    )
                )
            elif policy not in (allowed := BUTTON_POLICIES if pad in BUTTONS else AXIS_POLICIES):
                kind = "a button" if pad in BUTTONS else "an axis"
                problems.append(((control,), policy, f"the policy {' or '.join(allowed)} for {control} ({kind})"))
        _refuse_each("CopilotDevice", problems)
        return value

    @property
    def policies(self) -> dict[str, str]:
        """Pad control (``ABS_*``, ``BTN_*``) -> policy, aliases and d-pad directions resolved."""
        return {control_of(c): p for c, p in self.policy.items()}
