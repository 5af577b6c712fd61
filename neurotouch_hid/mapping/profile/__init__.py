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

The package's modules: ``outputs`` (the names a profile writes), ``models`` (the mappings),
``touch`` (``touchpad:``), ``copilot`` (``copilot:``), ``schema`` (:class:`Profile`), ``files``
(where profiles live, loading, error messages); every public name is importable from here.
"""

from neurotouch_hid.mapping.profile.copilot import (  # noqa: F401 (the package's public names)
    AXIS_POLICIES,
    BUTTON_POLICIES,
    MAX_COPILOT_DEVICES,
    OWN_INPUT_NAMES,
    STABLE_PATH_PREFIX,
    CopilotDevice,
    control_of,
)
from neurotouch_hid.mapping.profile.files import (  # noqa: F401 (the package's public names)
    _is_path,
    available_profiles,
    find_profile,
    load_profile,
    parse_profile,
    read_profile_text,
    shipped_profiles_dir,
    user_profiles_dir,
)
from neurotouch_hid.mapping.profile.models import (  # noqa: F401 (the package's public names)
    DEFAULT_DEVICE_NAME,
    PROTOCOL_NAMES,
    AxisMapping,
    ButtonMapping,
    DeviceSpec,
    LayerSwitch,
    Mapping,
    OneEuroSmoothing,
    PointerMapping,
    RelMapping,
    StickMapping,
)
from neurotouch_hid.mapping.profile.outputs import (  # noqa: F401 (the package's public names)
    ALL_OUTPUTS,
    ANALOG_AXES,
    BASE_LAYER,
    BUTTON_LIKE,
    DEFAULT_DWELL_MS,
    DEFAULT_POINTER_SPEED,
    DEFAULT_SATURATION_MM,
    DEFAULT_WHEEL_SPEED,
    DEVICE_NAME_MAX_BYTES,
    DIGITAL_OUTPUTS,
    DPAD,
    FACE_ALIASES,
    GEL_RADIUS_MM,
    KERNEL_COMMAND_KEYS,
    KEY_ALIASES,
    MAX_CHORD_KEYS,
    MAX_PROBLEMS_SHOWN,
    MAX_PROFILE_KEYS,
    MAX_PROFILE_NAME_CHARS,
    MAX_TAP_MS,
    MAX_TURBO_HZ,
    MODE_FIELDS,
    MODES,
    PAD_ALIASES,
    POINTER,
    REL_OUTPUTS,
    SCALAR_INPUTS,
    SHOWN_ALIASES,
    STICKS,
    VECTOR_INPUTS,
    key_chord,
    keyboard_keys,
    resolve_output,
)
from neurotouch_hid.mapping.profile.schema import (  # noqa: F401 (the package's public names)
    Profile,
)
from neurotouch_hid.mapping.profile.touch import (  # noqa: F401 (the package's public names)
    CLICK_MODES,
    TouchClick,
    TouchpadMapping,
)
