"""The :class:`Profile`: the pad to create, the layers and their switches, the named mappings."""

from __future__ import annotations

from pydantic import (
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

from neurotouch_hid.core.controller import MOUSE_BUTTONS
from neurotouch_hid.core.limits import (
    short,
)
from neurotouch_hid.mapping.profile.copilot import (
    MAX_COPILOT_DEVICES,
    OWN_INPUT_NAMES,
    CopilotDevice,
    _refuse_each,
)
from neurotouch_hid.mapping.profile.models import (
    AxisMapping,
    ButtonMapping,
    DeviceSpec,
    LayerSwitch,
    Mapping,
    PointerMapping,
    RelMapping,
    StickMapping,
    _Strict,
)
from neurotouch_hid.mapping.profile.outputs import (
    _ALT,
    _CTRL,
    _DELETE,
    BASE_LAYER,
    DIGITAL_OUTPUTS,
    MAX_PROFILE_KEYS,
)
from neurotouch_hid.mapping.profile.touch import (
    TouchpadMapping,
    _Name,
)


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
