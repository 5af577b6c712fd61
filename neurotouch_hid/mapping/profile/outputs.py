"""The outputs a profile names: the pad's controls, keyboard keys and chords, mouse buttons and
motion, and how a written name resolves to one (aliases and the views' names)."""

from __future__ import annotations

import functools

from neurotouch_hid.core.controller import BUTTONS, MOUSE_BUTTONS

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
