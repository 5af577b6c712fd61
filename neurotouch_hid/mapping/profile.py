"""Gamepad profiles: the YAML schema, where profiles live, and loading with errors that name the
file, the line, the field, the value found and what was expected.

A profile says which virtual device to create (name, USB ids) and how each *input quantity*
derived from a :class:`~neurotouch_hid.estimate.GestureEstimate` drives the gamepad's axes and
buttons (:mod:`neurotouch_hid.controller`). The input quantities, all in millimetres and in the
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

Outputs (evdev names, the Xbox 360 layout of ARCHITECTURE.md): ``left_stick`` (ABS_X, ABS_Y),
``right_stick`` (ABS_RX, ABS_RY), the analogue axes ``ABS_X`` .. ``ABS_RY`` (-32768..32767) and
the triggers ``ABS_Z``, ``ABS_RZ`` (0..255, only the positive side of the input), the 11 buttons
``BTN_SOUTH`` .. ``BTN_THUMBR`` and the d-pad directions ``dpad_up``, ``dpad_down``,
``dpad_left``, ``dpad_right`` (ABS_HAT0X/Y). A stick's user +y (up) becomes evdev's negative y.
Several mappings may drive one output: axis contributions add up (then clamp), buttons are OR-ed.

The YAML is read with PyYAML's safe loader; the schema is pydantic v2 (``extra="forbid"``,
strict types) and every problem is reported at once as one :class:`ProfileError`.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import yaml
from pydantic import (
    BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationError, ValidationInfo, create_model, field_validator,
)

from neurotouch_hid.controller import BUTTONS
from neurotouch_hid.errors import ProfileError

#: The gel dome's radius (mm); the default saturation of the ``contact`` inputs.
GEL_RADIUS_MM = 30.0
#: Default saturation (mm) of the intensity-like inputs: a firm gesture (paper, figure
#: "accuracy vs intensity": 90 % accuracy from 2.5 mm, labels up to 18 mm).
DEFAULT_SATURATION_MM = 8.0

VECTOR_INPUTS: tuple[str, ...] = ("push", "contact")
SCALAR_INPUTS: tuple[str, ...] = (
    "intensity", "push_intensity", "push_x", "push_y", "push_up", "push_down", "push_left", "push_right",
    "twist", "twist_ccw", "twist_cw", "pinch", "zoom", "pinch_zoom", "contact_x", "contact_y",
)
#: Stick output name -> its (x axis, y axis).
STICKS: dict[str, tuple[str, str]] = {"left_stick": ("ABS_X", "ABS_Y"), "right_stick": ("ABS_RX", "ABS_RY")}
#: Analogue axes a scalar can drive (the hat axes are driven through the ``dpad_*`` outputs).
ANALOG_AXES: tuple[str, ...] = ("ABS_X", "ABS_Y", "ABS_RX", "ABS_RY", "ABS_Z", "ABS_RZ")
#: d-pad direction -> (hat axis, value when pressed).
DPAD: dict[str, tuple[str, int]] = {
    "dpad_up": ("ABS_HAT0Y", -1), "dpad_down": ("ABS_HAT0Y", 1),
    "dpad_left": ("ABS_HAT0X", -1), "dpad_right": ("ABS_HAT0X", 1),
}
DIGITAL_OUTPUTS: tuple[str, ...] = BUTTONS + tuple(DPAD)
ALL_OUTPUTS: tuple[str, ...] = tuple(STICKS) + ANALOG_AXES + DIGITAL_OUTPUTS

#: The default virtual device: an Xbox 360 pad as SDL, Steam and browsers know it.
DEFAULT_DEVICE_NAME = "Microsoft X-Box 360 pad"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


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


class _Analog(_Strict):
    """Response of an analogue output to an input's magnitude m (mm).

    ``t = clip((m - deadzone_mm) / (saturation_mm - deadzone_mm), 0, 1)`` (0 inside the dead zone,
    1 = full deflection from the saturation on), then the curve ``t ** exponent``, then the expo
    ``(1 - expo) * t + expo * t ** 3``, then ``min(gain * t, 1)``; the sign (or a stick's
    direction) is the input's. ``saturation_mm`` defaults to 30 mm (the gel radius) for the
    ``contact`` inputs and to 8 mm for the others.
    """

    deadzone_mm: float = Field(0.5, ge=0, description="inputs with magnitude <= this give 0 (mm)")
    saturation_mm: float | None = Field(None, gt=0, description="magnitude giving full deflection (mm)")
    exponent: float = Field(1.0, gt=0, le=10, description="response curve t ** exponent (1 = linear)")
    expo: float = Field(0.0, ge=0, le=1, description="expo blend (1 - e) t + e t^3 (0 = off)")
    gain: float = Field(1.0, gt=0, le=100, description="multiplies the shaped value (clipped to 1)")
    smoothing: OneEuroSmoothing | None = None

    @field_validator("saturation_mm")
    @classmethod
    def _beyond_deadzone(cls, value: float | None, info: ValidationInfo) -> float | None:
        deadzone = info.data.get("deadzone_mm")
        if value is not None and deadzone is not None and value <= deadzone:
            raise ValueError(f"a value > deadzone_mm ({deadzone})")
        return value

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


class ButtonMapping(_Strict):
    """A scalar input -> a button or d-pad direction, with hysteresis.

    Pressed when the input reaches ``press_mm`` (>=), released when it falls below ``release_mm``
    (<). ``mode: hold`` -> the output follows the pressed state; ``mode: toggle`` -> each press
    flips the output.
    """

    input: Literal[SCALAR_INPUTS]
    output: Literal[DIGITAL_OUTPUTS]
    press_mm: float = Field(2.0, gt=0, description="input (mm) at or above which the button is pressed")
    release_mm: float = Field(1.0, gt=0, description="input (mm) below which it is released again")
    mode: Literal["hold", "toggle"] = "hold"
    smoothing: OneEuroSmoothing | None = None

    @field_validator("release_mm")
    @classmethod
    def _not_above_press(cls, value: float, info: ValidationInfo) -> float:
        press = info.data.get("press_mm")
        if press is not None and value > press:
            raise ValueError(f"a value <= press_mm ({press})")
        return value


_ANY_MAPPING_FIELDS = {**ButtonMapping.model_fields, **AxisMapping.model_fields, **StickMapping.model_fields}
#: Chosen only when ``output`` names no known output: reports it with the valid names, and still
#: checks every other field (known name, type, range) so that all problems show at once.
_UnknownOutput = create_model(
    "_UnknownOutput", __base__=_Strict,
    input=(Literal[VECTOR_INPUTS + SCALAR_INPUTS], ...), output=(Literal[ALL_OUTPUTS], ...),
    **{name: (f.annotation, f) for name, f in _ANY_MAPPING_FIELDS.items() if name not in ("input", "output")},
)


def _output_kind(value: Any) -> str:
    output = value.get("output") if isinstance(value, dict) else getattr(value, "output", None)
    if not isinstance(output, str):
        return "unknown"
    if output in STICKS:
        return "stick"
    if output in ANALOG_AXES:
        return "axis"
    if output in DIGITAL_OUTPUTS:
        return "button"
    return "unknown"


Mapping = Annotated[
    Union[
        Annotated[StickMapping, Tag("stick")],
        Annotated[AxisMapping, Tag("axis")],
        Annotated[ButtonMapping, Tag("button")],
        Annotated[_UnknownOutput, Tag("unknown")],
    ],
    Discriminator(_output_kind),
]
_TAG_MODELS: dict[str, type[BaseModel]] = {
    "stick": StickMapping, "axis": AxisMapping, "button": ButtonMapping, "unknown": _UnknownOutput,
}


class DeviceSpec(_Strict):
    """The virtual device (uinput): its name and USB ids (Xbox 360 pad by default)."""

    name: str = Field(DEFAULT_DEVICE_NAME, min_length=1, max_length=79, description="device name (uinput: < 80 bytes)")
    vendor: int = Field(0x045E, ge=0, le=0xFFFF, description="USB vendor id")
    product: int = Field(0x028E, ge=0, le=0xFFFF, description="USB product id")
    version: int = Field(0x0114, ge=0, le=0xFFFF, description="device version")


class Profile(_Strict):
    """A gamepad profile: the device to create and the named mappings (see the module doc)."""

    description: str = ""
    device: DeviceSpec = DeviceSpec()
    mappings: dict[Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")], Mapping] = Field(default_factory=dict)


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
    ``NAME.yaml``, else the shipped one. Raises ProfileError when there is none."""
    if _is_path(name_or_path):
        path = Path(name_or_path)
        if not path.is_file():
            raise ProfileError(f"profile file {path} does not exist")
        return path
    found = available_profiles().get(str(name_or_path))
    if found is None:
        names = ", ".join(available_profiles()) or "none"
        raise ProfileError(f"no profile named '{name_or_path}' (available: {names}; user folder: {user_profiles_dir()})")
    return found


def load_profile(name_or_path: str | os.PathLike) -> Profile:
    """Read and validate a profile by name (user folder first, then shipped) or path.

    Raises:
        ProfileError: the file is missing, not YAML, or breaks the schema; the message lists every
            problem as ``FILE:LINE: field: found VALUE; expected ...``.
    """
    path = find_profile(name_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ProfileError(f"cannot read profile {path}: {exc}") from exc
    return parse_profile(text, path)


def parse_profile(text: str, source: str | os.PathLike) -> Profile:
    """Validate a profile's YAML text; ``source`` (a file name) is only used in error messages.

    Raises:
        ProfileError: YAML syntax error (with its line) or every schema problem at once.
    """
    try:
        data = yaml.safe_load(text)
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        if isinstance(exc, yaml.reader.ReaderError):  # a character YAML forbids: no mark, a position
            line = text.count("\n", 0, exc.position) + 1
            where = f"{source}:{line}"
            problem = f"character #x{ord(exc.character) if isinstance(exc.character, str) else exc.character:04x} is not allowed in YAML"
        else:
            where = f"{source}:{mark.line + 1}" if mark is not None else str(source)
            problem = " ".join((getattr(exc, "problem", None) or str(exc)).split())  # one line
        raise ProfileError(f"{where}: not valid YAML: {problem}") from None
    if data is None:
        raise ProfileError(f"{source}:1: the profile is empty; expected a mapping with 'mappings:'")
    try:
        return Profile.model_validate(data)
    except ValidationError as exc:
        problems = [line for _, line in sorted((_describe(err, root, source) for err in exc.errors()), key=lambda p: p[0])]
        raise ProfileError(f"profile {source} is invalid ({len(problems)} problem{'s' * (len(problems) > 1)}):\n  " + "\n  ".join(problems)) from None


# --- error messages -----------------------------------------------------------------------------
def _line_of(root: yaml.Node | None, loc: tuple) -> tuple[int, tuple]:
    """The 1-based line of the YAML node at pydantic's ``loc`` and the loc without union tags.

    A loc element that is no key of the current mapping (a union tag, a missing field) is skipped
    for the walk; the deepest node reached gives the line (a key's own line for mappings).
    """
    node, line, path = root, (root.start_mark.line + 1 if root is not None else 1), []
    for part in loc:
        match = None
        if isinstance(node, yaml.MappingNode):
            match = next(((k, v) for k, v in node.value if isinstance(k, yaml.ScalarNode) and k.value == str(part)), None)
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
    return {"device": DeviceSpec, "smoothing": OneEuroSmoothing}.get(str(parent[-1]))


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _describe(err: dict, root: yaml.Node | None, source: str | os.PathLike) -> tuple[int, str]:
    """(line, ``FILE:LINE: field: found VALUE; expected ...``) for one pydantic error."""
    line, path = _line_of(root, tuple(err["loc"]))
    field = ".".join(str(p) for p in path) or "(top level)"
    kind = err["type"]
    if kind == "missing":
        return line, f"{source}:{line}: {field}: missing; expected a value (this field is required)"
    if kind == "extra_forbidden":
        model = _model_at(tuple(err["loc"]))
        allowed = f": one of {', '.join(model.model_fields)}" if model is not None else ""
        return line, f"{source}:{line}: {field}: unknown field (found {_short(err['input'])}); expected a known field{allowed}"
    if kind == "string_pattern_mismatch" and path[-1:] == ("[key]",):
        field = ".".join(str(p) for p in path[:-1])
        return line, (f"{source}:{line}: {field}: found the name {_short(err['input'])}; expected a name of letters, "
                      "digits and '_' that does not start with a digit")
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return line, f"{source}:{line}: {field}: found {_short(err['input'])}; expected a mapping (key: value lines)"
    message = err["msg"].removeprefix("Value error, ")
    expected = message[0].lower() + message[1:] if message else message
    if expected.startswith("input should be "):
        expected = expected.removeprefix("input should be ")
    return line, f"{source}:{line}: {field}: found {_short(err['input'])}; expected {expected}"

