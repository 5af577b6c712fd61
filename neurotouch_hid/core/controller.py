"""What the mapping hands to the outputs: the state of a standard (Xbox 360 layout) gamepad.

The layout is docs/architecture.md's: sticks ABS_X/Y/RX/RY in -32768..32767 (evdev convention: +x
right, +y *down*), triggers ABS_Z/RZ in 0..255, d-pad ABS_HAT0X/Y in -1..1, and 11 buttons.
Beside the pad, a profile may drive a keyboard and a mouse (uinput devices of their own):
:attr:`ControllerState.keys` holds the keyboard keys and mouse buttons that are down (evdev names,
``KEY_*`` and ``BTN_LEFT`` ...), :attr:`ControllerState.rel` the relative motion of this step
(``REL_X``/``REL_Y`` in pointer counts, ``REL_WHEEL``/``REL_HWHEEL`` in detents and their
``*_HI_RES`` twins in 1/120 detent). Motion is an impulse, not a level: a state with motion is
always written, and the neutral state has none.
A touchpad (the DualSense's, docs/profiles.md "Touchpad") has up to :data:`TOUCH_SLOTS` touch
points, :attr:`ControllerState.touches`, and a click, :attr:`ControllerState.touch_click`; outputs
without a touchpad ignore both.
A :class:`ControllerState` is a plain value; the neutral state (:meth:`ControllerState.neutral`)
is what every output writes before it stops. What comes back the other way, from a game or a host
to a device (rumble, LEDs), is a :class:`Feedback`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: Axis name -> (minimum, maximum, neutral value), evdev names.
AXES: dict[str, tuple[int, int, int]] = {
    "ABS_X": (-32768, 32767, 0),
    "ABS_Y": (-32768, 32767, 0),
    "ABS_RX": (-32768, 32767, 0),
    "ABS_RY": (-32768, 32767, 0),
    "ABS_Z": (0, 255, 0),
    "ABS_RZ": (0, 255, 0),
    "ABS_HAT0X": (-1, 1, 0),
    "ABS_HAT0Y": (-1, 1, 0),
}
#: The axes that rest at their minimum (the triggers): they take only the positive side of a value.
TRIGGERS = frozenset(name for name, (low, _, neutral) in AXES.items() if low == neutral)

#: The mouse's buttons (evdev names); every other key-like output name is a keyboard key.
MOUSE_BUTTONS: tuple[str, ...] = ("BTN_LEFT", "BTN_RIGHT", "BTN_MIDDLE", "BTN_SIDE", "BTN_EXTRA")
#: The mouse's relative axes: pointer counts, wheel detents and the wheels' hi-res 1/120 detents.
MOUSE_REL: tuple[str, ...] = ("REL_X", "REL_Y", "REL_WHEEL", "REL_HWHEEL", "REL_WHEEL_HI_RES", "REL_HWHEEL_HI_RES")

#: The 11 buttons of the Xbox 360 layout, evdev names, in SDL's usual order.
BUTTONS: tuple[str, ...] = (
    "BTN_SOUTH",
    "BTN_EAST",
    "BTN_NORTH",
    "BTN_WEST",
    "BTN_TL",
    "BTN_TR",
    "BTN_SELECT",
    "BTN_START",
    "BTN_MODE",
    "BTN_THUMBL",
    "BTN_THUMBR",
)


#: The touchpad's size in its own units, the DualSense's (hid-playstation's DS_TOUCHPAD_WIDTH and
#: DS_TOUCHPAD_HEIGHT): x 0..1919 from the left, y 0..1079 from the top.
TOUCHPAD_WIDTH, TOUCHPAD_HEIGHT = 1920, 1080
#: Touch points a touchpad reports at once (the DualSense's two).
TOUCH_SLOTS = 2
#: Tracking ids run 0..TRACKING_IDS - 1 (the DualSense's 7 bits) and then wrap to 0.
TRACKING_IDS = 128


@dataclass(frozen=True)
class TouchPoint:
    """One touch point of the touchpad.

    Attributes:
        id: tracking id, 0..127: the same while its contact lasts, a new one for a new touch.
        x: 0..1919 (:data:`TOUCHPAD_WIDTH` - 1), from the left edge.
        y: 0..1079 (:data:`TOUCHPAD_HEIGHT` - 1), from the top edge.
        active: touching; False once lifted (``id``, ``x`` and ``y`` are then the last ones, which
            hosts ignore: the DualSense's inactive bit).
    """

    id: int
    x: int
    y: int
    active: bool = True


def _neutral_axes() -> dict[str, int]:
    return {name: neutral for name, (_, _, neutral) in AXES.items()}


def _released_buttons() -> dict[str, bool]:
    return {name: False for name in BUTTONS}


@dataclass
class ControllerState:
    """Axes (evdev name -> int in the axis' range) and buttons (evdev name -> pressed) of the pad;
    ``keys``: keyboard keys and mouse buttons that are down (evdev names); ``rel``: this step's
    relative motion (evdev name -> int counts, zero entries left out); ``touches``: the
    touchpad's slots in order (slot 0 first, at most :data:`TOUCH_SLOTS`; None or a missing slot
    has no point), ``touch_click``: the touchpad pressed down."""

    t_us: int = 0
    axes: dict[str, int] = field(default_factory=_neutral_axes)
    buttons: dict[str, bool] = field(default_factory=_released_buttons)
    keys: frozenset[str] = frozenset()
    rel: dict[str, int] = field(default_factory=dict)
    touches: tuple[TouchPoint | None, ...] = ()
    touch_click: bool = False

    @classmethod
    def neutral(cls, t_us: int = 0) -> "ControllerState":
        """All axes centred (triggers at 0), all buttons released, no touch point, no click."""
        return cls(t_us=t_us)

    def is_neutral(self) -> bool:
        """True when every axis is at its neutral value, no button or key is pressed, nothing
        moves and nothing touches the touchpad."""
        return (
            all(self.axes[n] == AXES[n][2] for n in AXES)
            and not any(self.buttons.values())
            and not self.keys
            and not any(self.rel.values())
            and not self.touching
            and not self.touch_click
        )

    @property
    def touching(self) -> bool:
        """A touch point is active."""
        return any(point is not None and point.active for point in self.touches)


@dataclass(frozen=True)
class Feedback:
    """What a game or a host sent back to a target: rumble or a player LED.

    Attributes:
        kind: ``"rumble"``, ``"led"`` (a pad's player LED), ``"lightbar"`` (a DualSense's light
            bar's colour in ``led``) or ``"keyboard_leds"`` (a USB keyboard's Num/Caps/Scroll Lock,
            Compose, Kana bits in ``led``).
        strong, weak: rumble magnitudes 0..1 (the low- and high-frequency motors; 0 stops).
        duration_ms: how long the rumble lasts (None: until the next one).
        led: the player LED pattern as the protocol numbers it (xpad's 0..15; the DualSense's
            five LEDs as bits 0-4), for ``"led"``; the LED bits (0..31), for ``"keyboard_leds"``;
            the colour as 0xRRGGBB, for ``"lightbar"`` (the DualSense's light bar).
        source: the target that received it (its ``what``), for the user's log line.
        effect: the game's effect id on an evdev pad (the EV_FF code it plays and stops it with;
            several may play at once, Documentation/input/ff.rst); None from a target whose rumble
            is one state (a USB host's output report), each request replacing the last.
    """

    kind: str
    strong: float = 0.0
    weak: float = 0.0
    duration_ms: int | None = None
    led: int | None = None
    source: str = ""
    effect: int | None = None
