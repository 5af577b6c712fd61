"""Guest checks of a gesture whose type changes mid-gesture, read back from the real uinput pad.

Run by tests/kernel/guest.py inside qemu; asserted on by tests/test_type_handover_kernel.py. As
in checks_runtime_remap.py the runtime is fed estimates (a predictions file: the emulated guest
cannot run the pipeline in real time); the runtime, the shipped profiles, the Mapper and the
uinput pad are real, and what is asserted is what evdev reads back, report by report.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from checks_runtime import timeline
from checks_runtime_remap import STEP_US, _expected, _run_in_process
from evdev import ecodes

from neurotouch_hid.core.estimate import GestureType

G = GestureType


def one_gesture(*parts: tuple[GestureType, float], level: float = 4.0, rest_s: float = 0.6) -> list:
    """timeline() segments of one gesture whose type changes: ramp up 0.2 s as the first type,
    each (type, seconds) at ``level`` mm, ramp down 0.2 s as the last type, rest ``rest_s``."""
    first, last = parts[0][0], parts[-1][0]
    segments = [(0.2, first, lambda f: level * f)]
    segments += [(seconds, kind, lambda f: level) for kind, seconds in parts]
    return segments + [(0.2, last, lambda f: level * (1 - f)), (rest_s, G.NONE, lambda f: 0.0)]


LEAD_IN = [(1.0, G.NONE, lambda f: 0.0)]


def _reports(reports: list[list[tuple[int, int, int]]]) -> list[dict[int, int]]:
    """The pad's absolute axes after every report (guestlib.EventReader.reports: the events up
    to each SYN_REPORT; axes not reported yet are 0)."""
    axes: dict[int, int] = {}
    out = []
    for report in reports:
        for kind, code, value in report:
            if kind == ecodes.EV_ABS:
                axes[code] = value
        out.append(dict(axes))
    return out


def check_default_stick_and_trigger_never_both_held() -> dict:
    """``run --profile default``: a push (left stick) read as pinch (left trigger) for 0.6 s in
    its middle, then push again: in no report is the stick off-centre while the trigger is
    pulled, and both were reached."""
    estimates = timeline(LEAD_IN + one_gesture((G.PUSH, 0.6), (G.PINCH, 0.6), (G.PUSH, 0.6)), STEP_US)
    expected = _expected("default", estimates)
    assert not any(s.axes["ABS_Z"] > 0 and (s.axes["ABS_X"] or s.axes["ABS_Y"]) for s in expected)
    watchers, stats, _ = _run_in_process("default", estimates, Path(tempfile.mkdtemp(prefix="handover-")))
    reports = _reports(watchers["pad"].reader.reports)
    both = [r for r in reports if r.get(ecodes.ABS_Z, 0) > 0 and (r.get(ecodes.ABS_X, 0) or r.get(ecodes.ABS_Y, 0))]
    trigger = max(r.get(ecodes.ABS_Z, 0) for r in reports)
    stick = max(abs(r.get(ecodes.ABS_X, 0)) + abs(r.get(ecodes.ABS_Y, 0)) for r in reports)
    assert stats.dropped_items == 0, f"the runtime dropped {stats.dropped_items} items"
    assert not both, f"{len(both)} reports with the stick and the trigger both held, e.g. {both[0]}"
    assert trigger > 0 and stick > 0, (trigger, stick)
    return {"reports": len(reports), "both_held": len(both), "max_trigger": trigger, "max_stick": stick}


def toggle_profile(folder: Path) -> str:
    """The shipped accessibility profile with its twists toggling A and B (``mode: toggle``
    instead of its one-press ``tap``): the file's path."""
    from neurotouch_hid.mapping.profile import find_profile

    text = find_profile("accessibility").read_text(encoding="utf-8")
    assert text.count("mode: tap") == 2, "accessibility.yaml no longer taps A and B"
    path = folder / "accessibility-toggle.yaml"
    path.write_text(text.replace("mode: tap", "mode: toggle").replace("    tap_ms: 150\n", ""), encoding="utf-8")
    return str(path)


def check_accessibility_toggle_flips_once_per_gesture() -> dict:
    """``run --profile`` accessibility with toggles: a counter-clockwise twist (toggles A) read
    as pinch for 0.16 s in its middle, then a clockwise twist (toggles B): A goes down once and
    stays down until B has gone down (the twist's return after the pinch is no second press);
    the run's end releases both."""
    twist_read_as_pinch = one_gesture((G.TWIST_CCW, 0.4), (G.PINCH, 0.16), (G.TWIST_CCW, 0.4))
    estimates = timeline(LEAD_IN + twist_read_as_pinch + one_gesture((G.TWIST_CW, 0.4)), STEP_US)
    folder = Path(tempfile.mkdtemp(prefix="handover-"))
    profile = toggle_profile(folder)
    assert _expected(profile, estimates)[-1].buttons["BTN_SOUTH"], "the Mapper itself flips A twice"
    watchers, stats, _ = _run_in_process(profile, estimates, folder)
    names = {ecodes.BTN_SOUTH: "BTN_SOUTH", ecodes.BTN_EAST: "BTN_EAST"}
    keys = [(names.get(c, str(c)), v) for t, c, v in watchers["pad"].events if t == ecodes.EV_KEY and v in (0, 1)]
    assert stats.dropped_items == 0, f"the runtime dropped {stats.dropped_items} items"
    south = [k for k in keys if k[0] == "BTN_SOUTH"]
    assert south == [("BTN_SOUTH", 1), ("BTN_SOUTH", 0)], keys
    assert keys.index(("BTN_SOUTH", 0)) > keys.index(("BTN_EAST", 1)), keys
    assert not watchers["pad"].pressed
    return {"keys": keys}
