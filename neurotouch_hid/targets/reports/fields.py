"""Values of a :class:`~neurotouch_hid.core.controller.ControllerState` as report fields: clamped to
a field's logical range (HID 1.11, 5.8: a value outside Logical Minimum..Maximum is a null or an
error, so it never goes on the wire), and :class:`InputOnly`, the feature and output answers of a
format that has neither."""

from __future__ import annotations

from typing import TYPE_CHECKING

from neurotouch_hid.core.controller import AXES, ControllerState, Feedback

if TYPE_CHECKING:
    from neurotouch_hid.targets.identity import Identity


def clamp(value: int, lo: int, hi: int) -> int:
    """``value`` as an int within ``lo..hi``."""
    return min(max(int(value), lo), hi)


def axis(state: ControllerState, name: str) -> int:
    """``state``'s axis ``name`` (an evdev name of :data:`~neurotouch_hid.core.controller.AXES`) clamped
    to its range; a missing axis is neutral."""
    lo, hi, neutral = AXES[name]
    return clamp(state.axes.get(name, neutral), lo, hi)


class InputOnly:
    """What a format with no feature report and no output report answers
    (:class:`~neurotouch_hid.targets.reports.ReportFormat`): no feature ids, and every output
    report read as nothing."""

    feature_ids: tuple[int, ...] = ()

    def feature(self, report_id: int, identity: Identity) -> bytes:
        """Raises KeyError: the format has no feature report."""
        raise KeyError(report_id)

    def parse_output(self, data: bytes) -> list[Feedback]:
        """``[]``: the format has no output report the driver acts on."""
        return []
