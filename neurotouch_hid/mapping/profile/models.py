"""The profile's mapping models (pydantic v2, strict): smoothing, sticks, axes, pointer and wheels,
buttons with hysteresis and activators, layer switches, the device to create."""

from __future__ import annotations

from typing import Annotated, Any, Literal, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)

from neurotouch_hid.core.controller import MOUSE_BUTTONS
from neurotouch_hid.core.errors import did_you_mean
from neurotouch_hid.core.limits import (
    short,
)
from neurotouch_hid.mapping.profile.outputs import (
    ALL_OUTPUTS,
    ANALOG_AXES,
    BASE_LAYER,
    BUTTON_LIKE,
    DEFAULT_DWELL_MS,
    DEFAULT_POINTER_SPEED,
    DEFAULT_SATURATION_MM,
    DEFAULT_WHEEL_SPEED,
    DEVICE_NAME_MAX_BYTES,
    FACE_ALIASES,
    GEL_RADIUS_MM,
    KERNEL_COMMAND_KEYS,
    MAX_CHORD_KEYS,
    MAX_TAP_MS,
    MAX_TURBO_HZ,
    MODE_FIELDS,
    MODES,
    POINTER,
    REL_OUTPUTS,
    SCALAR_INPUTS,
    SHOWN_ALIASES,
    STICKS,
    VECTOR_INPUTS,
    _expected_outputs,
    key_chord,
    keyboard_keys,
    resolve_output,
)
from neurotouch_hid.targets.protocols import PROTOCOLS

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
