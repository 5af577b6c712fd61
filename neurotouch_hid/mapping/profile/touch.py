"""A profile's ``touchpad:`` section: the gel's contact points as a touchpad's touch points."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    Field,
    ValidationInfo,
    field_validator,
)

from neurotouch_hid.core.controller import TOUCH_SLOTS
from neurotouch_hid.mapping.profile.models import (
    _Hysteresis,
    _release_not_above_press,
    _Strict,
)
from neurotouch_hid.mapping.profile.outputs import (
    DEFAULT_DWELL_MS,
    GEL_RADIUS_MM,
)

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
