"""Gamepad profiles: the YAML schema, where profiles live, and loading with errors that name the
file, the line, the field, the value found and what was expected.

A profile says which virtual device to create (name, USB ids) and how each *input quantity*
derived from a :class:`~neurotouch_hid.core.estimate.GestureEstimate` drives the gamepad's axes and
buttons (:mod:`neurotouch_hid.core.controller`). The input quantities, all in millimetres and in the
user frame (the gel seen from outside, x right, y up), are zero whenever the gel rests or the
gesture is ``none``:

Vector inputs (2-D, for a stick):

- ``push``: the push's direction (unit vector of ``translation_mm``) times ``intensity_mm``;
  zero unless the gesture is ``push``.
- ``contact``: the first contact point's position ``contacts_mm[0]`` (mm from the gel's centre);
  zero when there is no contact. Its default saturation is the gel radius (30 mm), so the stick
  deflection is the position normalised by the gel radius.

Scalar inputs (for an axis, a trigger, a button or a d-pad direction):

- ``intensity``: ``intensity_mm`` of any gesture; ``push_intensity`` the same for a push only.
- ``push_x``, ``push_y``: the push vector's signed components (mm, +x right, +y up).
- ``push_up``, ``push_down``, ``push_left``, ``push_right``: the push vector's projection on that
  direction when positive, else 0 (mm).
- ``twist``: ``+intensity_mm`` for a counter-clockwise twist, ``-intensity_mm`` for a clockwise
  one; ``twist_ccw``, ``twist_cw``: that twist's intensity (>= 0) or 0.
- ``pinch``, ``zoom``: that gesture's intensity (>= 0) or 0; ``pinch_zoom``: ``+zoom`` or
  ``-pinch``.
- ``contact_x``, ``contact_y``: the first contact's coordinates (mm).

Outputs (evdev names, the Xbox 360 layout of docs/architecture.md): ``left_stick`` (ABS_X, ABS_Y),
``right_stick`` (ABS_RX, ABS_RY), the analogue axes ``ABS_X`` .. ``ABS_RY`` (-32768..32767) and
the triggers ``ABS_Z``, ``ABS_RZ`` (0..255, only the positive side of the input), the 11 buttons
``BTN_SOUTH`` .. ``BTN_THUMBR`` and the d-pad directions ``dpad_up``, ``dpad_down``,
``dpad_left``, ``dpad_right`` (ABS_HAT0X/Y). A stick's user +y (up) becomes evdev's negative y.
Several mappings may drive one output: axis contributions add up (then clamp), buttons are OR-ed.
``A``, ``B``, ``X``, ``Y`` are aliases of the face buttons (:data:`FACE_ALIASES`), and the names
the views show (``LB``, ``RT``, ``Start``, ``L stick``, ``d-pad up``, ``SPACE key``) are taken for
their outputs (:func:`resolve_output`).

Beside the pad (docs/profiles.md): keyboard keys (any evdev ``KEY_*`` name, or a chord such as
``KEY_LEFTSHIFT+KEY_TAB``) and mouse buttons (``BTN_LEFT`` ...) are button-like outputs; the
mouse's ``pointer`` (a vector input -> REL_X/REL_Y velocity), ``REL_X``, ``REL_Y``, ``REL_WHEEL``
and ``REL_HWHEEL`` (a scalar -> velocity) are analogue ones. Every button-like output has an
activator (``mode``: hold, tap, toggle, long_press, double_press, turbo); every analogue output an
anti-deadzone. A mapping may belong to a ``layer``; ``layers:`` says which gesture switches to
each layer.

A ``touchpad:`` section (:class:`TouchpadMapping`) maps the contact points themselves, up to two,
to a touchpad's touch points, and a scalar input to its click, for an output with a touchpad
(the DualSense's); outputs without one ignore it.

The YAML is read within the bounds of :mod:`neurotouch_hid.core.limits` (size, depth, aliases, number
length, duplicate keys; ruamel.yaml's safe loader); the schema is pydantic v2 (``extra="forbid"``,
strict types, finite numbers) and every problem is reported at once as one :class:`ProfileError`.
"""

from __future__ import annotations

import functools
import os
import re
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError
from ruamel.yaml.nodes import MappingNode, ScalarNode, SequenceNode

from neurotouch_hid.core.controller import AXES, BUTTONS, MOUSE_BUTTONS, TOUCH_SLOTS
from neurotouch_hid.core.errors import ProfileError, did_you_mean, in_plain_words
from neurotouch_hid.core.limits import (
    MAX_YAML_BYTES,
    YamlError,
    load_yaml,
    printable,
    read_outside_text,
    short,
    where,
)
from neurotouch_hid.targets.protocols import PROTOCOLS

#: The gel dome's radius (mm); the default saturation of the ``contact`` inputs.
GEL_RADIUS_MM = 30.0
#: Default saturation (mm) of the intensity-like inputs: a firm gesture (paper, figure
#: "accuracy vs intensity": 90 % accuracy from 2.5 mm, labels up to 18 mm).
DEFAULT_SATURATION_MM = 8.0

VECTOR_INPUTS: tuple[str, ...] = ("push", "contact")
SCALAR_INPUTS: tuple[str, ...] = (
    "intensity",
    "push_intensity",
    "push_x",
    "push_y",
    "push_up",
    "push_down",
    "push_left",
    "push_right",
    "twist",
    "twist_ccw",
    "twist_cw",
    "pinch",
    "zoom",
    "pinch_zoom",
    "contact_x",
    "contact_y",
)
#: Stick output name -> its (x axis, y axis).
STICKS: dict[str, tuple[str, str]] = {"left_stick": ("ABS_X", "ABS_Y"), "right_stick": ("ABS_RX", "ABS_RY")}
#: Analogue axes a scalar can drive (the hat axes are driven through the ``dpad_*`` outputs).
ANALOG_AXES: tuple[str, ...] = ("ABS_X", "ABS_Y", "ABS_RX", "ABS_RY", "ABS_Z", "ABS_RZ")
#: d-pad direction -> (hat axis, value when pressed).
DPAD: dict[str, tuple[str, int]] = {
    "dpad_up": ("ABS_HAT0Y", -1),
    "dpad_down": ("ABS_HAT0Y", 1),
    "dpad_left": ("ABS_HAT0X", -1),
    "dpad_right": ("ABS_HAT0X", 1),
}
DIGITAL_OUTPUTS: tuple[str, ...] = BUTTONS + tuple(DPAD)
#: Face-button aliases -> evdev names (the kernel's gamepad.rst positions; xpad reports the Xbox
#: pad's X button as BTN_X, which is the same code as BTN_NORTH, and Y as BTN_Y = BTN_WEST; SDL
#: reads them as its x and y).
FACE_ALIASES: dict[str, str] = {"A": "BTN_SOUTH", "B": "BTN_EAST", "X": "BTN_NORTH", "Y": "BTN_WEST"}
#: The mouse's analogue outputs: ``pointer`` takes a vector input, the others a scalar.
POINTER = "pointer"
REL_OUTPUTS: tuple[str, ...] = ("REL_X", "REL_Y", "REL_WHEEL", "REL_HWHEEL")
#: Default speeds at full deflection: pointer counts (px) per second, wheel detents per second.
DEFAULT_POINTER_SPEED = 1000.0
DEFAULT_WHEEL_SPEED = 8.0
#: Button-like outputs with fixed names (keyboard keys, ``KEY_*``, come on top).
BUTTON_LIKE: tuple[str, ...] = DIGITAL_OUTPUTS + tuple(FACE_ALIASES) + MOUSE_BUTTONS
ALL_OUTPUTS: tuple[str, ...] = tuple(STICKS) + ANALOG_AXES + (POINTER,) + REL_OUTPUTS + BUTTON_LIKE
#: The layer every mapping without ``layer:`` belongs to, active while no other layer is.
BASE_LAYER = "base"
#: Activators (``mode``) of button-like outputs.
MODES: tuple[str, ...] = ("hold", "tap", "toggle", "long_press", "double_press", "turbo")
#: The fields each activator reads: a field set under another mode would do nothing, so it is refused.
MODE_FIELDS: dict[str, tuple[str, ...]] = {
    "dwell_ms": ("long_press", "tap"),
    "tap_ms": ("tap",),
    "double_press_ms": ("double_press",),
    "turbo_hz": ("turbo",),
}
#: ``tap``'s longest keystroke (ms): X11 and Wayland clients repeat a held key after ~500 ms (the
#: X server's and libxkbcommon's usual repeat delay), so a tap stays well below that.
MAX_TAP_MS = 250.0
#: ``long_press``'s dwell (ms) when ``dwell_ms`` is not set; ``tap`` goes down at once then.
DEFAULT_DWELL_MS = 500.0
#: Turbo's highest rate (Hz): one press and one release need two windows of 10 ms.
MAX_TURBO_HZ = 50.0
#: Schema problems listed in one error (the rest are counted): a crafted profile may have thousands.
MAX_PROBLEMS_SHOWN = 10
#: Keys the machine acts on, whatever program has the focus. No profile may press them, and the
#: virtual keyboard never offers them:
#: SysRq (the kernel runs Alt+SysRq+B as a reboot at once, Alt+SysRq+C crashes it;
#: Documentation/admin-guide/sysrq.rst); power, reboot, sleep and hibernate (systemd-logind
#: powers off on KEY_POWER/KEY_POWER2, reboots on KEY_RESTART, suspends on KEY_SLEEP and
#: hibernates on KEY_SUSPEND by default: logind.conf(5), HandlePowerKey= ... HandleRebootKey=);
#: the radio keys (the kernel's rfkill-input handler switches every radio off on them:
#: net/rfkill/input.c).
KERNEL_COMMAND_KEYS = frozenset(
    {
        "KEY_SYSRQ",
        "KEY_POWER",
        "KEY_POWER2",
        "KEY_RESTART",
        "KEY_SLEEP",
        "KEY_SUSPEND",
        "KEY_RFKILL",
        "KEY_WLAN",
        "KEY_BLUETOOTH",
        "KEY_UWB",
        "KEY_WIMAX",
        "KEY_WWAN",
    }
)
#: Longest ``device: name`` (bytes of UTF-8): UINPUT_MAX_NAME_SIZE (80, linux/uinput.h) less its
#: NUL, the smaller of the kernel's two limits (struct uhid_create2_req's name is 128, linux/uhid.h).
DEVICE_NAME_MAX_BYTES = 79
#: Longest profile name (characters): a file name in the user's folder, typed on command lines.
MAX_PROFILE_NAME_CHARS = 64
#: Most keys and buttons in one chord (``KEY_LEFTCTRL+KEY_LEFTSHIFT+KEY_LEFTALT+KEY_LEFTMETA+KEY_T``
#: is five); a chord of hundreds would make the keyboard offer every key.
MAX_CHORD_KEYS = 5
#: Most keyboard keys one profile may press in all (its mappings and chords together): the
#: virtual keyboard offers these, not every key there is.
MAX_PROFILE_KEYS = 64
#: Ctrl+Alt+Delete (and its keypad form): the console keyboard driver reboots on it
#: (drivers/tty/vt/keyboard.c, fn_boot_it). No profile may be able to press all three at once.
_CTRL = frozenset({"KEY_LEFTCTRL", "KEY_RIGHTCTRL"})
_ALT = frozenset({"KEY_LEFTALT", "KEY_RIGHTALT"})
_DELETE = frozenset({"KEY_DELETE", "KEY_KPDOT"})


@functools.cache
def keyboard_keys() -> frozenset[str]:
    """Every evdev ``KEY_*`` name python-evdev knows (linux/input-event-codes.h); without
    python-evdev (an aarch64 install without the ``uinput`` extra), :data:`~neurotouch_hid.core.key_names.KEY_NAMES`."""
    try:
        from evdev import ecodes
    except ImportError:
        from neurotouch_hid.core.key_names import KEY_NAMES

        return KEY_NAMES

    return frozenset(name for name in ecodes.ecodes if name.startswith("KEY_") and name not in ("KEY_MAX", "KEY_CNT"))


def key_chord(output: str) -> tuple[str, ...]:
    """The evdev names a button-like output presses: a face alias resolved, a chord
    (``KEY_LEFTSHIFT+KEY_TAB``) split in order."""
    return tuple(FACE_ALIASES.get(part, part) for part in output.split("+"))


#: The pad's and mouse's names as the live view and docs show them (output/term.py's labels:
#: ``LB``, ``RT``, ``Start``, ``L stick X``, ``d-pad up``, ``left click``) and the long spellings
#: a player types, as a profile may write them -> the profile's own output names. Matched with
#: :func:`_normalised` (case, spaces and hyphens ignored).
PAD_ALIASES: dict[str, str] = {
    "lb": "BTN_TL",
    "rb": "BTN_TR",
    "left_bumper": "BTN_TL",
    "right_bumper": "BTN_TR",
    "back": "BTN_SELECT",
    "select": "BTN_SELECT",
    "start": "BTN_START",
    "guide": "BTN_MODE",
    "ls": "BTN_THUMBL",
    "rs": "BTN_THUMBR",
    "left_stick_click": "BTN_THUMBL",
    "right_stick_click": "BTN_THUMBR",
    "lt": "ABS_Z",
    "rt": "ABS_RZ",
    "left_trigger": "ABS_Z",
    "right_trigger": "ABS_RZ",
    "l_stick": "left_stick",
    "r_stick": "right_stick",
    "l_stick_x": "ABS_X",
    "l_stick_y": "ABS_Y",
    "r_stick_x": "ABS_RX",
    "r_stick_y": "ABS_RY",
    "d_pad_up": "dpad_up",
    "d_pad_down": "dpad_down",
    "d_pad_left": "dpad_left",
    "d_pad_right": "dpad_right",
    "mouse_pointer": "pointer",
    "mouse_x": "REL_X",
    "mouse_y": "REL_Y",
    "mouse_wheel": "REL_WHEEL",
    "mouse_wheel_sideways": "REL_HWHEEL",
    "left_click": "BTN_LEFT",
    "right_click": "BTN_RIGHT",
    "middle_click": "BTN_MIDDLE",
    "mouse_side_button": "BTN_SIDE",
    "mouse_extra_button": "BTN_EXTRA",
    **{face.lower(): code for face, code in FACE_ALIASES.items()},
}
#: Key names a player types that evdev spells otherwise (the left one of a pair).
KEY_ALIASES: dict[str, str] = {
    "SHIFT": "KEY_LEFTSHIFT",
    "CTRL": "KEY_LEFTCTRL",
    "CONTROL": "KEY_LEFTCTRL",
    "ALT": "KEY_LEFTALT",
    "META": "KEY_LEFTMETA",
    "SUPER": "KEY_LEFTMETA",
    "ESCAPE": "KEY_ESC",
    "RETURN": "KEY_ENTER",
}
#: The aliases offered when a name is not known (as the views write them).
SHOWN_ALIASES: tuple[str, ...] = (
    "LB", "RB", "LT", "RT", "Back", "Start", "Guide", "LS", "RS",
    "left_trigger", "right_trigger", "left_bumper", "right_bumper",
)  # fmt: skip


def _normalised(name: str) -> str:
    return name.strip().lower().replace("-", "_").replace(" ", "_")


def resolve_output(written: str) -> str:
    """The profile's output name for ``written``, a name as the views show it or a player types
    it: an output name as it is (``ABS_RZ``, ``KEY_SPACE``); a pad or mouse name of
    :data:`PAD_ALIASES` (``RT`` -> ``ABS_RZ``, ``Start`` -> ``BTN_START``, ``A`` stays ``A``); a
    key without ``KEY_`` or as the view writes it (``SPACE``, ``space``, ``SPACE key`` ->
    ``KEY_SPACE``; ``LEFTSHIFT+TAB key`` -> ``KEY_LEFTSHIFT+KEY_TAB``; ``Shift`` ->
    ``KEY_LEFTSHIFT``). A name none of these knows is returned as written (the schema reports it).
    """
    if written in ALL_OUTPUTS:
        return written
    text = written.strip()
    if text.lower().endswith(" key"):
        text = text[: -len(" key")]
    if "+" not in text:
        return _resolve_part(text, written)
    parts = [_resolve_part(p, p) for p in text.split("+")]
    return "+".join(parts)


def _resolve_part(text: str, unknown: str) -> str:
    if text in BUTTON_LIKE or text.startswith("KEY_"):
        return text
    pad = PAD_ALIASES.get(_normalised(text))
    if pad is not None:
        return pad
    key = text.strip().upper().replace(" ", "").replace("-", "")
    if key in KEY_ALIASES:
        return KEY_ALIASES[key]
    if key and f"KEY_{key}" in keyboard_keys():
        return f"KEY_{key}"
    return unknown


def _expected_outputs() -> str:
    return (
        ", ".join(repr(o) for o in ALL_OUTPUTS)
        + ", or an evdev key name such as 'KEY_SPACE' (several joined by '+': 'KEY_LEFTSHIFT+KEY_TAB'), or a name "
        "as the live view shows it ('LB', 'RT', 'Start', 'L stick', 'd-pad up', 'left click', 'SPACE key')"
    )


#: The default virtual device: an Xbox 360 pad as SDL, Steam and browsers know it.
DEFAULT_DEVICE_NAME = "Microsoft X-Box 360 pad"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


class OneEuroSmoothing(_Strict):
    """The 1-euro filter (Casiez, Roussel, Vogel, CHI 2012) on the input quantity (mm).

    The cut-off frequency rises with the input's speed: ``min_cutoff_hz + beta * |dx/dt|``, dx/dt
    in mm/s, so ``beta`` is in Hz per (mm/s). Lower ``min_cutoff_hz`` = less jitter, more lag;
    higher ``beta`` = less lag on fast moves.
    """

    filter: Literal["one_euro"] = "one_euro"
    min_cutoff_hz: float = Field(1.0, gt=0, description="cut-off frequency at rest (Hz)")
    beta: float = Field(0.05, ge=0, description="speed coefficient, Hz per (mm/s)")
    d_cutoff_hz: float = Field(1.0, gt=0, description="cut-off frequency of the speed estimate (Hz)")


class _Layered(_Strict):
    layer: str = Field(BASE_LAYER, description="the layer this mapping belongs to (see layers:)")

    @field_validator("output", mode="before", check_fields=False)
    @classmethod
    def _as_shown(cls, value: Any) -> Any:
        """A name as the views show it (``RT``, ``Start``, ``SPACE key``) is its output's
        (:func:`resolve_output`)."""
        return resolve_output(value) if isinstance(value, str) else value

    @field_validator("layer")
    @classmethod
    def _known_layer(cls, value: str, info: ValidationInfo) -> str:
        layers = (info.context or {}).get("layers")
        if layers is not None and value != BASE_LAYER and value not in layers:
            raise ValueError(f"'{BASE_LAYER}' or a layer named under layers: ({', '.join(layers) or 'none defined'})")
        return value


class _Analog(_Layered):
    """Response of an analogue output to an input's magnitude m (mm).

    ``t = clip((m - deadzone_mm) / (saturation_mm - deadzone_mm), 0, 1)`` (0 inside the dead zone,
    1 = full deflection from the saturation on), then the curve ``t ** exponent``, then the expo
    ``(1 - expo) * t + expo * t ** 3``, then ``min(gain * t, 1)``, then the anti-deadzone
    ``a + (1 - a) * t`` for t > 0 (a game's own inner dead zone then never swallows a gesture
    past ours); the sign (or a stick's direction) is the input's. ``saturation_mm`` defaults to
    30 mm (the gel radius) for the ``contact`` inputs and to 8 mm for the others.
    """

    deadzone_mm: float = Field(0.5, ge=0, description="inputs with magnitude <= this give 0 (mm)")
    saturation_mm: float | None = Field(None, gt=0, description="magnitude giving full deflection (mm)")
    exponent: float = Field(1.0, gt=0, le=10, description="response curve t ** exponent (1 = linear)")
    expo: float = Field(0.0, ge=0, le=1, description="expo blend (1 - e) t + e t^3 (0 = off)")
    gain: float = Field(1.0, gt=0, le=100, description="multiplies the shaped value (clipped to 1)")
    anti_deadzone: float = Field(
        0.0, ge=0, lt=1, description="smallest non-zero output, as a fraction of full deflection"
    )
    smoothing: OneEuroSmoothing | None = None

    @field_validator("saturation_mm")
    @classmethod
    def _beyond_deadzone(cls, value: float | None, info: ValidationInfo) -> float | None:
        deadzone = info.data.get("deadzone_mm")
        if value is not None and deadzone is not None and value <= deadzone:
            raise ValueError(f"a value > deadzone_mm ({deadzone})")
        return value

    @model_validator(mode="after")
    def _deadzone_below_default_saturation(self):
        """A dead zone at or past the input's default saturation divided by zero (a crash at
        the first window past it) or left the output dead for good."""
        if self.saturation_mm is None and self.deadzone_mm >= self.saturation:
            raise ValueError(
                f"deadzone_mm ({self.deadzone_mm:g}) must be below the saturation ({self.saturation:g} mm, "
                "this input's default): give saturation_mm above it"
            )
        return self

    @property
    def saturation(self) -> float:
        """The effective saturation (mm): ``saturation_mm`` or the input's default."""
        if self.saturation_mm is not None:
            return self.saturation_mm
        return GEL_RADIUS_MM if self.input.startswith("contact") else DEFAULT_SATURATION_MM  # type: ignore[attr-defined]


class StickMapping(_Analog):
    """A vector input (``push`` or ``contact``) -> a stick; dead zone and curve act radially."""

    input: Literal[VECTOR_INPUTS]
    output: Literal[tuple(STICKS)]
    invert_x: bool = False
    invert_y: bool = False


class AxisMapping(_Analog):
    """A scalar input -> one analogue axis (signed) or trigger (positive side only)."""

    input: Literal[SCALAR_INPUTS]
    output: Literal[ANALOG_AXES]
    invert: bool = False


class PointerMapping(_Analog):
    """A vector input -> the mouse pointer's velocity (REL_X/REL_Y counts per second).

    The shaped magnitude (dead zone, curve, anti-deadzone acting radially, like a stick) times
    ``speed`` is the pointer's speed in counts (px) per second at full deflection; user +y (up)
    moves the pointer up (evdev's negative REL_Y).
    """

    input: Literal[VECTOR_INPUTS]
    output: Literal[(POINTER,)]
    speed: float = Field(
        DEFAULT_POINTER_SPEED, gt=0, le=100_000, description="pointer counts per second at full deflection"
    )
    invert_x: bool = False
    invert_y: bool = False


class RelMapping(_Analog):
    """A scalar input -> a relative axis' velocity: ``REL_X``/``REL_Y`` in pointer counts per
    second, ``REL_WHEEL``/``REL_HWHEEL`` in wheel detents per second (written in hi-res 1/120
    detents too). ``speed`` (default 1000 counts/s, 8 detents/s) is the velocity at full
    deflection; +REL_WHEEL scrolls up, +REL_HWHEEL right, user +y of REL_Y moves up."""

    input: Literal[SCALAR_INPUTS]
    output: Literal[REL_OUTPUTS]
    speed: float | None = Field(
        None, gt=0, le=100_000, description="counts (px) or detents per second at full deflection"
    )
    invert: bool = False

    @property
    def velocity_scale(self) -> float:
        """The effective speed: ``speed`` or the output's default."""
        if self.speed is not None:
            return self.speed
        return DEFAULT_WHEEL_SPEED if "WHEEL" in self.output else DEFAULT_POINTER_SPEED


def _release_not_above_press(cls, value: float, info: ValidationInfo) -> float:
    """A hysteresis's ``release_mm`` (the field being validated) is at most its ``press_mm``: the
    one check of every mapping that presses at one level and releases at another."""
    press = info.data.get("press_mm")
    if press is not None and value > press:
        raise ValueError(f"a value <= press_mm ({press})")
    return value


class _Hysteresis(_Strict):
    """Pressed when the input reaches ``press_mm`` (>=), released when it falls below
    ``release_mm`` (<)."""

    input: Literal[SCALAR_INPUTS]
    press_mm: float = Field(2.0, gt=0, description="input (mm) at or above which the button is pressed")
    release_mm: float = Field(1.0, gt=0, description="input (mm) below which it is released again")
    smoothing: OneEuroSmoothing | None = None

    _not_above_press = field_validator("release_mm")(_release_not_above_press)

    @model_validator(mode="after")
    def _default_release_not_above_press(self):
        """``press_mm`` lowered under the default ``release_mm`` (1 mm) made the button press and
        release every window of a steady press: hysteresis needs release <= press."""
        if self.release_mm > self.press_mm:
            raise ValueError(
                f"press_mm ({self.press_mm:g}) is below release_mm ({self.release_mm:g}, the default): "
                f"give release_mm too, at most {self.press_mm:g}"
            )
        return self


class ButtonMapping(_Hysteresis, _Layered):
    """A scalar input -> a button-like output (pad button, d-pad direction, face alias A/B/X/Y,
    mouse button, keyboard key or chord), through hysteresis and an activator.

    The input is *held* from reaching ``press_mm`` (>=) until it falls below ``release_mm`` (<).
    Activators (``mode``), all timed on the estimates' camera clock (us):

    - ``hold``: the output is down while the input is held (a plain press);
    - ``tap``: one keystroke per press: down once the input has been held ``dwell_ms`` (0 when
      not set: at once), for ``tap_ms`` (<= 250 ms, the desktop's key repeat never starts) or
      until the input is let go, whichever comes first; a switch user's one gesture, one key;
    - ``toggle``: each press flips the output;
    - ``long_press``: down once the input has been held ``dwell_ms``, up when it is released
      (a dwell: tremor shorter than that never fires);
    - ``double_press``: down on a second press that starts within ``double_press_ms`` of the
      first one's start, up when that press is released;
    - ``turbo``: while held, down and up at ``turbo_hz`` (down first, half a period each).
    """

    output: Any
    mode: Literal[MODES] = "hold"
    dwell_ms: float | None = Field(
        None,
        ge=0,
        le=60_000,
        description="long_press, tap: how long the input must be held (ms); long_press 500, tap 0 when not set",
    )
    tap_ms: float = Field(100.0, gt=0, le=MAX_TAP_MS, description="tap: how long the key stays down (ms)")
    double_press_ms: float = Field(
        400.0, gt=0, le=5_000, description="double_press: longest time between the two presses' starts (ms)"
    )
    turbo_hz: float = Field(10.0, gt=0, le=MAX_TURBO_HZ, description="turbo: presses per second")

    @field_validator(*MODE_FIELDS)
    @classmethod
    def _read_by_the_mode(cls, value: Any, info: ValidationInfo) -> Any:
        mode = info.data.get("mode")
        modes = MODE_FIELDS[info.field_name]
        if mode is not None and mode not in modes:
            reads = "reads" if len(modes) == 1 else "read"
            raise ValueError(
                f"no {info.field_name} under mode '{mode}': only {' and '.join(modes)} {reads} it "
                f"(set mode: {modes[0]}, or remove {info.field_name})"
            )
        return value

    @property
    def dwell(self) -> float:
        """The effective dwell (ms): ``dwell_ms``, else 500 for long_press and 0 for tap."""
        if self.dwell_ms is not None:
            return self.dwell_ms
        return DEFAULT_DWELL_MS if self.mode == "long_press" else 0.0

    @field_validator("output")
    @classmethod
    def _button_like(cls, value: Any) -> str:
        if not isinstance(value, str):
            raise ValueError(_expected_outputs())
        parts = value.split("+")
        if len(parts) > MAX_CHORD_KEYS:
            raise ValueError(f"a chord of at most {MAX_CHORD_KEYS} keys or buttons (this one has {len(parts)})")
        for part in parts:
            if part not in BUTTON_LIKE and part not in keyboard_keys():
                names = keyboard_keys() if part.startswith("KEY_") else BUTTON_LIKE + SHOWN_ALIASES
                raise ValueError(
                    f"a pad button (BTN_SOUTH ... BTN_THUMBR, A, B, X, Y, LB, RB, Start, Back, Guide, LS, RS, "
                    f"dpad_*), a mouse button ({', '.join(MOUSE_BUTTONS)}) or an evdev key name such as "
                    f"'KEY_SPACE' (several joined by '+'); {short(part)} is none of these{did_you_mean(part, names)}"
                )
        if len(parts) > 1 and any(not p.startswith("KEY_") and p not in MOUSE_BUTTONS for p in parts):
            raise ValueError("a chord of keyboard keys and mouse buttons only, such as 'KEY_LEFTSHIFT+KEY_TAB'")
        banned = sorted(KERNEL_COMMAND_KEYS & set(parts))
        if "KEY_SYSRQ" in banned:
            raise ValueError(
                "a key other than KEY_SYSRQ: the kernel runs SysRq chords as commands (Alt+SysRq+B "
                "reboots the machine at once), so no profile may press it"
            )
        if banned:
            raise ValueError(
                f"a key other than {', '.join(banned)}: the system acts on it (power off, reboot, suspend, "
                "hibernate or radios off, whatever program has the focus), so no profile may press it"
            )
        return "+".join(FACE_ALIASES.get(p, p) for p in parts)

    @property
    def presses(self) -> tuple[str, ...]:
        """The evdev names this mapping presses (:func:`key_chord`)."""
        return key_chord(self.output)


class LayerSwitch(_Hysteresis):
    """The gesture that switches to a layer: ``mode: hold`` -> the layer is active while the input
    is held (hysteresis as for buttons); ``mode: toggle`` -> each press turns it on or off."""

    mode: Literal["hold", "toggle"] = "hold"


_ANY_MAPPING_FIELDS = {
    **ButtonMapping.model_fields,
    **AxisMapping.model_fields,
    **StickMapping.model_fields,
    **PointerMapping.model_fields,
    **RelMapping.model_fields,
}


def _no_such_output(cls, value: Any) -> Any:
    close = ""
    if isinstance(value, str):
        close = did_you_mean(value, ALL_OUTPUTS + SHOWN_ALIASES) or did_you_mean(
            value.upper(), [k.removeprefix("KEY_") for k in keyboard_keys()]
        )
    raise ValueError(_expected_outputs() + close)


#: Chosen only when ``output`` names no known output: reports it with the valid names, and still
#: checks every other field (known name, type, range) so that all problems show at once.
_UnknownOutput = create_model(
    "_UnknownOutput",
    __base__=_Strict,
    input=(Literal[VECTOR_INPUTS + SCALAR_INPUTS], ...),
    output=(Any, ...),
    **{name: (f.annotation, f) for name, f in _ANY_MAPPING_FIELDS.items() if name not in ("input", "output")},
    __validators__={"_unknown_output": field_validator("output")(_no_such_output)},
)


def _output_kind(value: Any) -> str:
    output = value.get("output") if isinstance(value, dict) else getattr(value, "output", None)
    if not isinstance(output, str):
        return "unknown"
    output = resolve_output(output)
    if output in STICKS:
        return "stick"
    if output in ANALOG_AXES:
        return "axis"
    if output == POINTER:
        return "pointer"
    if output in REL_OUTPUTS:
        return "rel"
    if output in BUTTON_LIKE or output.startswith("KEY_") or "+" in output:
        return "button"
    return "unknown"


Mapping = Annotated[
    Union[
        Annotated[StickMapping, Tag("stick")],
        Annotated[AxisMapping, Tag("axis")],
        Annotated[ButtonMapping, Tag("button")],
        Annotated[PointerMapping, Tag("pointer")],
        Annotated[RelMapping, Tag("rel")],
        Annotated[_UnknownOutput, Tag("unknown")],
    ],
    Discriminator(_output_kind),
]
_TAG_MODELS: dict[str, type[BaseModel]] = {
    "stick": StickMapping,
    "axis": AxisMapping,
    "button": ButtonMapping,
    "pointer": PointerMapping,
    "rel": RelMapping,
    "unknown": _UnknownOutput,
}


#: The protocols a profile's ``device: protocol`` may name: the protocol table's
#: (:data:`~neurotouch_hid.targets.protocols.PROTOCOLS`).
PROTOCOL_NAMES = tuple(PROTOCOLS)


class DeviceSpec(_Strict):
    """The virtual device (uinput): its name and USB ids (Xbox 360 pad by default)."""

    name: str = Field(
        DEFAULT_DEVICE_NAME, min_length=1, description=f"device name (printable, <= {DEVICE_NAME_MAX_BYTES} bytes)"
    )
    vendor: int = Field(0x045E, ge=0, le=0xFFFF, description="USB vendor id")
    product: int = Field(0x028E, ge=0, le=0xFFFF, description="USB product id")
    version: int = Field(0x0114, ge=0, le=0xFFFF, description="device version")
    protocol: Literal[PROTOCOL_NAMES] | None = Field(  # type: ignore[valid-type]
        None,
        description="with run --output usb or hid: the protocol the controller speaks (default hid; --protocol "
        "overrides it; targets/protocols.py)",
    )

    @field_validator("name")
    @classmethod
    def _kernel_name(cls, value: str) -> str:
        """The name reaches the kernel as is: ``/proc/bus/input/devices``' ``N: Name=`` line and the
        UHID device's uevent ``HID_NAME=`` line, which libudev and hidapi parse line by line; a
        newline or escape there would add a line of its own."""
        if not value.isprintable():
            raise ValueError(
                "a device name of printable characters (no newline, tab, escape or other control character)"
            )
        size = len(value.encode())
        if size > DEVICE_NAME_MAX_BYTES:
            raise ValueError(
                f"a device name of at most {DEVICE_NAME_MAX_BYTES} bytes of UTF-8 (uinput's limit, 80 with the "
                f"terminating NUL; UHID's is 128): this one is {size} bytes"
            )
        return value


# --- touchpad: the gel's contacts as a touchpad's touch points --------------------------------------
#: Activators the touchpad's click takes.
CLICK_MODES: tuple[str, ...] = ("hold", "toggle", "long_press")


class TouchClick(_Hysteresis):
    """A scalar input -> the touchpad's click, through hysteresis and an activator: ``hold``
    (pressed while the input is held), ``toggle`` (each press flips it) or ``long_press``
    (pressed once the input has been held ``dwell_ms``, 500 when not set)."""

    mode: Literal[CLICK_MODES] = "hold"
    dwell_ms: float | None = Field(
        None, ge=0, le=60_000, description="long_press: how long the input must be held (ms); 500 when not set"
    )

    @field_validator("dwell_ms")
    @classmethod
    def _long_press_only(cls, value: float | None, info: ValidationInfo) -> float | None:
        mode = info.data.get("mode")
        if value is not None and mode is not None and mode != "long_press":
            raise ValueError(
                f"no dwell_ms under mode '{mode}': only long_press reads it (set mode: long_press, or remove dwell_ms)"
            )
        return value

    @property
    def dwell(self) -> float:
        """The effective dwell (ms): ``dwell_ms``, else 500."""
        return DEFAULT_DWELL_MS if self.dwell_ms is None else self.dwell_ms


class TouchpadMapping(_Strict):
    """The gel's contact points (``contacts_mm``, user frame, strongest first) -> the touchpad's
    touch points (``mapping/touchpad.py``), for an output with a touchpad (``--protocol
    dualsense``; the others ignore it).

    The rectangle of ``width_mm`` x ``height_mm`` centred on (``centre_x_mm``, ``centre_y_mm``)
    fills the pad (1920 x 1080): its left edge is x 0, its top edge (user +y is up) y 0; contacts
    past it are held at the edge. The contacts touch from the window whose gesture intensity
    reaches ``press_mm`` until it falls below ``release_mm``; each keeps its touch point and
    tracking id while it moves less than ``match_mm`` between windows, a new contact gets the
    next id, and a contact that is gone lifts its point. ``click`` presses the touchpad.
    """

    max_points: int = Field(2, ge=1, le=TOUCH_SLOTS, description="touch points at most (the strongest contacts)")
    centre_x_mm: float = Field(
        0.0, ge=-GEL_RADIUS_MM, le=GEL_RADIUS_MM, description="the pad's centre on the gel, x (mm)"
    )
    centre_y_mm: float = Field(
        0.0, ge=-GEL_RADIUS_MM, le=GEL_RADIUS_MM, description="the pad's centre on the gel, y (mm)"
    )
    width_mm: float = Field(2 * GEL_RADIUS_MM, gt=0, le=200, description="the gel's width the pad's width covers (mm)")
    height_mm: float = Field(
        2 * GEL_RADIUS_MM, gt=0, le=200, description="the gel's height the pad's height covers (mm)"
    )
    press_mm: float = Field(0.5, gt=0, description="gesture intensity (mm) at or above which the contacts touch")
    release_mm: float = Field(0.25, gt=0, description="gesture intensity (mm) below which they lift")
    match_mm: float = Field(
        10.0, gt=0, le=100, description="farthest a contact moves in a window and stays the same touch (mm)"
    )
    click: TouchClick | None = None

    _not_above_press = field_validator("release_mm")(_release_not_above_press)


_Name = Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]

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


class Profile(_Strict):
    """A profile: the pad to create, the layers and their switches, and the named mappings (see
    the module doc). Keyboard and mouse devices exist only when a mapping uses them
    (:attr:`uses_keyboard`, :attr:`uses_mouse`)."""

    description: str = ""
    device: DeviceSpec = DeviceSpec()
    layers: dict[_Name, LayerSwitch] = Field(default_factory=dict)
    mappings: dict[_Name, Mapping] = Field(default_factory=dict)
    copilot: list[CopilotDevice] = Field(default_factory=list, max_length=MAX_COPILOT_DEVICES)
    touchpad: TouchpadMapping | None = None

    @field_validator("copilot")
    @classmethod
    def _devices_once_and_not_ours(cls, value: list[CopilotDevice], info: ValidationInfo) -> list[CopilotDevice]:
        own = info.data.get("device")
        ours = set(OWN_INPUT_NAMES) | ({own.name} if isinstance(own, DeviceSpec) else set())
        seen: dict[str, int] = {}
        problems = []
        for i, entry in enumerate(value):
            if entry.device in seen:
                problems.append(
                    (
                        (i, "device"),
                        entry.device,
                        f"each device once: {short(entry.device)} is named by entries {seen[entry.device]} and {i} "
                        "(one entry per device; put every map: line of it in one entry)",
                    )
                )
            seen.setdefault(entry.device, i)
            if entry.device in ours:
                problems.append(
                    (
                        (i, "device"),
                        entry.device,
                        "a device other than the driver's own: this is the name of the pad, keyboard or mouse this "
                        "profile makes (a helper's pad of the same model: name it by its /dev/input/by-id/ path, "
                        "or give this profile's pad another name under device:)",
                    )
                )
        _refuse_each("Profile", problems)
        return value

    @field_validator("layers")
    @classmethod
    def _not_base(cls, value: dict) -> dict:
        if BASE_LAYER in value:
            raise ValueError(
                f"layer names other than '{BASE_LAYER}' (the layer of mappings without layer:, always there)"
            )
        return value

    @model_validator(mode="after")
    def _layers_exist(self) -> "Profile":
        unknown = sorted({m.layer for m in self.mappings.values() if m.layer != BASE_LAYER} - set(self.layers))
        if unknown:
            raise ValueError(f"every mapping's layer defined under layers: (missing: {', '.join(unknown)})")
        return self

    @model_validator(mode="after")
    def _no_ctrl_alt_delete(self) -> "Profile":
        keys = self.keyboard_keys
        if keys & _CTRL and keys & _ALT and keys & _DELETE:
            raise ValueError(
                "this profile could hold Ctrl, Alt and Delete at once (it presses "
                f"{', '.join(sorted(keys & (_CTRL | _ALT | _DELETE)))}), and the console reboots the machine "
                "on Ctrl+Alt+Delete: map one of them to another key"
            )
        return self

    @model_validator(mode="after")
    def _few_keys(self) -> "Profile":
        keys = self.keyboard_keys
        if len(keys) > MAX_PROFILE_KEYS:
            raise ValueError(
                f"at most {MAX_PROFILE_KEYS} different keyboard keys in a profile; this one has {len(keys)}"
            )
        return self

    @property
    def keyboard_keys(self) -> frozenset[str]:
        """The keyboard keys (``KEY_*``) its mappings and its merged devices' ``map:`` press (the
        keyboard device offers these)."""
        mapped = frozenset(
            p for m in self.mappings.values() if isinstance(m, ButtonMapping) for p in m.presses if p.startswith("KEY_")
        )
        return mapped | {t for c in self.copilot for t in c.map.values() if t.startswith("KEY_")}

    @property
    def uses_pad(self) -> bool:
        """A mapping drives a pad control (stick, axis, trigger, pad button, d-pad), the profile
        maps the touchpad, or a merged device does (``passthrough`` or a ``map:`` to a pad
        control): the pad is made only then."""
        for m in self.mappings.values():
            if isinstance(m, (StickMapping, AxisMapping)):
                return True
            if isinstance(m, ButtonMapping) and any(p in DIGITAL_OUTPUTS for p in m.presses):
                return True
        if self.touchpad is not None:
            return True
        return any(c.passthrough or any(not t.startswith("KEY_") for t in c.map.values()) for c in self.copilot)

    @property
    def mouse_outputs(self) -> frozenset[str]:
        """The mouse buttons and motions (``REL_*``; ``pointer`` as REL_X, REL_Y) it drives."""
        used: set[str] = set()
        for m in self.mappings.values():
            if isinstance(m, ButtonMapping):
                used.update(p for p in m.presses if p in MOUSE_BUTTONS)
            elif isinstance(m, PointerMapping):
                used.update(("REL_X", "REL_Y"))
            elif isinstance(m, RelMapping):
                used.add(m.output)
        return frozenset(used)

    @property
    def uses_keyboard(self) -> bool:
        """A mapping presses a keyboard key."""
        return bool(self.keyboard_keys)

    @property
    def uses_mouse(self) -> bool:
        """A mapping presses a mouse button or moves the pointer or a wheel."""
        return bool(self.mouse_outputs)


# --- where profiles live ------------------------------------------------------------------------
def shipped_profiles_dir() -> Path:
    """The read-only profiles shipped in the package (``neurotouch_hid/profiles``)."""
    return Path(str(resources.files("neurotouch_hid") / "profiles"))


def user_profiles_dir() -> Path:
    """The user's profiles: ``platformdirs.user_config_dir("neurotouch-hid")/profiles``
    (``$XDG_CONFIG_HOME/neurotouch-hid/profiles`` on Linux). Not created here."""
    import platformdirs

    return Path(platformdirs.user_config_dir("neurotouch-hid")) / "profiles"


def _is_path(name_or_path: str | os.PathLike) -> bool:
    text = str(name_or_path)
    return os.sep in text or text.endswith((".yaml", ".yml"))


def available_profiles() -> dict[str, Path]:
    """Profile name -> file, user profiles shadowing shipped ones of the same name, sorted."""
    found: dict[str, Path] = {}
    for folder in (shipped_profiles_dir(), user_profiles_dir()):
        if folder.is_dir():
            found.update({p.stem: p for p in folder.glob("*.yaml")})
    return dict(sorted(found.items()))


def find_profile(name_or_path: str | os.PathLike) -> Path:
    """The file of a profile: a path (contains ``/`` or ends in ``.yaml``) as is, else the user's
    ``NAME.yaml``, else the shipped one. Raises ProfileError when there is none, or for a name
    longer than :data:`MAX_PROFILE_NAME_CHARS` (the message quotes an excerpt of it, escaped)."""
    if _is_path(name_or_path):
        path = Path(name_or_path)
        try:
            path.stat()
        except FileNotFoundError:
            raise ProfileError(f"profile file {printable(path, 200)} does not exist") from None
        except OSError as exc:  # a name too long, a loop of links, a folder not ours
            raise ProfileError(f"profile file {printable(path, 200)}: {exc.strerror or exc}") from None
        return path
    name = str(name_or_path)
    if len(name) > MAX_PROFILE_NAME_CHARS:
        raise ProfileError(
            f"no profile named '{printable(name)}': a profile name has at most {MAX_PROFILE_NAME_CHARS} characters"
        )
    found = available_profiles().get(name)
    if found is None:
        names = ", ".join(printable(n) for n in available_profiles()) or "none"
        raise ProfileError(
            f"no profile named '{printable(name)}' (available: {names}; user folder: {user_profiles_dir()})"
        )
    return found


def read_profile_text(path: str | os.PathLike) -> str:
    """The text of profile file ``path``, read within the bounds (:func:`~neurotouch_hid.core.limits.
    read_outside_text`: a regular file of at most :data:`~neurotouch_hid.core.limits.MAX_YAML_BYTES`,
    opened without blocking: a FIFO or a link to ``/dev/zero`` is refused, not waited on).

    Raises:
        ProfileError: missing, unreadable, not a regular file, too large, or not UTF-8.
    """
    return read_outside_text(path, MAX_YAML_BYTES, "profile", ProfileError)


def load_profile(name_or_path: str | os.PathLike) -> Profile:
    """Read and validate a profile by name (user folder first, then shipped) or path.

    Raises:
        ProfileError: the file is missing, not YAML, or breaks the schema; the message lists every
            problem as ``FILE:LINE: field: found VALUE; expected ...``.
    """
    path = find_profile(name_or_path)
    return parse_profile(read_profile_text(path), path)


def parse_profile(text: str, source: str | os.PathLike, lines: bool = True) -> Profile:
    """Validate a profile's YAML text; ``source`` (a file name) is only used in error messages,
    with the line of each problem unless ``lines`` is False (a text that is in no file: a change
    about to be written).

    Raises:
        ProfileError: YAML syntax error (with its line) or every schema problem at once.
    """
    try:
        data, root = load_yaml(text)
    except YamlError as exc:
        raise ProfileError(f"{where(source, exc.line)}: not valid YAML: {exc.problem}") from None
    if data is None:
        raise ProfileError(f"{source}:1: the profile is empty; expected a mapping with 'mappings:'")
    layers = data.get("layers") if isinstance(data, dict) else None
    context = {"layers": [str(k) for k in layers] if isinstance(layers, dict) else []}
    try:
        return Profile.model_validate(data, context=context)
    except ValidationError as exc:
        problems = [
            line
            for _, line in sorted((_describe(err, root, source, lines) for err in exc.errors()), key=lambda p: p[0])
        ]
        shown = problems[:MAX_PROBLEMS_SHOWN] + (
            [f"... and {len(problems) - MAX_PROBLEMS_SHOWN} more"] if len(problems) > MAX_PROBLEMS_SHOWN else []
        )
        raise ProfileError(
            f"profile {source} is invalid ({len(problems)} problem{'s' * (len(problems) > 1)}):\n  "
            + "\n  ".join(shown)
        ) from None


# --- error messages -----------------------------------------------------------------------------
def _line_of(root: Any, loc: tuple) -> tuple[int, tuple]:
    """The 1-based line of the YAML node at pydantic's ``loc`` and the loc without union tags.

    A loc element that is no key of the current mapping (a union tag, a missing field) is skipped
    for the walk; the deepest node reached gives the line (a key's own line for mappings).
    """
    node, line, path = root, (root.start_mark.line + 1 if root is not None else 1), []
    for part in loc:
        match = None
        if isinstance(node, MappingNode):
            match = next(((k, v) for k, v in node.value if isinstance(k, ScalarNode) and k.value == str(part)), None)
        elif isinstance(node, SequenceNode) and isinstance(part, int) and 0 <= part < len(node.value):
            match = (node.value[part], node.value[part])
        if match is not None:
            line, node = match[0].start_mark.line + 1, match[1]
            path.append(part)
        elif part not in _TAG_MODELS:
            path.append(part)
            node = None
    return line, tuple(path)


def _model_at(loc: tuple) -> type[BaseModel] | None:
    """The schema model that holds the field at ``loc`` (tags included), for listing its fields."""
    parent = loc[:-1]
    if not parent:
        return Profile
    if parent[-1] in _TAG_MODELS:
        return _TAG_MODELS[parent[-1]]
    if len(parent) == 2 and parent[0] == "layers":
        return LayerSwitch
    if len(parent) == 2 and parent[0] == "copilot":
        return CopilotDevice
    if parent == ("touchpad", "click"):
        return TouchClick
    return {"device": DeviceSpec, "smoothing": OneEuroSmoothing, "touchpad": TouchpadMapping}.get(str(parent[-1]))


def _describe(err: dict, root: Any, source: str | os.PathLike, lines: bool = True) -> tuple[int, str]:
    """(line, ``FILE:LINE: field: found VALUE; expected ...``) for one pydantic error (``FILE:``
    without lines)."""
    line, path = _line_of(root, tuple(err["loc"]))
    at = where(source, line if lines else 0)
    field = ".".join(str(p) for p in path) or "(top level)"
    kind = err["type"]
    if kind == "missing":
        return line, f"{at}: {field}: missing; expected a value (this field is required)"
    if kind == "extra_forbidden":
        model = _model_at(tuple(err["loc"]))
        allowed = f": one of {', '.join(model.model_fields)}" if model is not None else ""
        close = did_you_mean(str(path[-1]), model.model_fields) if model is not None and path else ""
        return (
            line,
            f"{at}: {field}: unknown field (found {short(err['input'])}{close}); expected a known field{allowed}",
        )
    if kind == "string_pattern_mismatch" and path[-1:] == ("[key]",):
        field = ".".join(str(p) for p in path[:-1])
        return line, (
            f"{at}: {field}: found the name {short(err['input'])}; expected a name of letters, "
            "digits and '_' that does not start with a digit"
        )
    if kind == "value_error" and not path and isinstance(err["input"], dict):  # about the whole profile
        message = in_plain_words(err["msg"])
        return line, f"{at}: {message[:1].upper()}{message[1:]}" if message.startswith("this ") else (
            f"{at}: the profile: expected {message.removeprefix('expected ')}"
        )
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return line, f"{at}: {field}: found {short(err['input'])}; expected a mapping (key: value lines)"
    message = in_plain_words(err["msg"])
    expected = message[0].lower() + message[1:] if message else message
    expected = expected.removeprefix("expected ")
    if kind == "literal_error" and path[-1:] == ("input",) and isinstance(err["input"], str):
        expected += did_you_mean(err["input"], VECTOR_INPUTS + SCALAR_INPUTS)
    return line, f"{at}: {field}: found {short(err['input'])}; expected {expected}"
