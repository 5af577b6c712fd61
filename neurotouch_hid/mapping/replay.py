"""Trying a profile offline: replay estimates through a :class:`Mapper`, sample the axis and
button timeline, summarise and plot it, and tune saturations from what a user actually reaches
(the ``profile test`` and ``profile tune`` commands).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from neurotouch_hid.core.controller import AXES, TRIGGERS, ControllerState
from neurotouch_hid.core.estimate import GestureEstimate
from neurotouch_hid.mapping.inputs import gesture_inputs
from neurotouch_hid.mapping.mapper import Mapper
from neurotouch_hid.mapping.profile import (
    DIGITAL_OUTPUTS,
    DPAD,
    STICKS,
    AxisMapping,
    ButtonMapping,
    PointerMapping,
    Profile,
    RelMapping,
)
from neurotouch_hid.service.extras import require


def replay(profile: Profile, estimates: Iterable[GestureEstimate]) -> list[ControllerState]:
    """Map every estimate, in order, with a fresh :class:`Mapper`; one state per estimate."""
    mapper = Mapper(profile)
    return [mapper.update(e) for e in estimates]


@dataclass(frozen=True)
class TimelineRow:
    """One sample of the timeline: the latest estimate and state at or before ``t_us``."""

    t_us: int
    estimate: GestureEstimate
    state: ControllerState


def sample_timeline(
    estimates: list[GestureEstimate], states: list[ControllerState], every_us: int = 100_000
) -> list[TimelineRow]:
    """Rows every ``every_us`` (us) from the first estimate, each with the latest estimate/state
    at or before that time (``estimates`` and ``states`` aligned, as :func:`replay` returns)."""
    if not estimates:
        return []
    times = np.array([e.t_us for e in estimates], dtype=np.int64)
    samples = np.arange(times[0], times[-1] + 1, every_us, dtype=np.int64)
    index = np.searchsorted(times, samples, side="right") - 1
    return [TimelineRow(int(t), estimates[i], states[i]) for t, i in zip(samples, index)]


def pressed(state: ControllerState) -> list[str]:
    """The buttons and d-pad directions (``dpad_up`` ...) pressed in ``state``, in DIGITAL_OUTPUTS
    order, then the keyboard keys and mouse buttons that are down (sorted)."""
    return [
        name
        for name in DIGITAL_OUTPUTS
        if (state.axes[DPAD[name][0]] == DPAD[name][1] if name in DPAD else state.buttons[name])
    ] + sorted(state.keys)


@dataclass(frozen=True)
class Summary:
    """Per axis the largest deflection (fraction of the half range for sticks, of the range for
    triggers and hats: 0..1) and per button and d-pad direction the number of presses (rising
    edges)."""

    max_deflection: dict[str, float]
    presses: dict[str, int]


def deflection(name: str, value: int) -> float:
    """An axis value as a signed fraction of full deflection (-1..1; triggers 0..1)."""
    low, high, neutral = AXES[name]
    if value >= neutral:
        return (value - neutral) / (high - neutral) if high > neutral else 0.0
    return -(value - neutral) / (low - neutral)


def summarise(states: list[ControllerState]) -> Summary:
    """The largest |deflection| per axis and the press count per button over ``states``."""
    max_deflection = {name: 0.0 for name in AXES}
    presses = {name: 0 for name in DIGITAL_OUTPUTS}
    previous: set[str] = set()
    for state in states:
        for name, value in state.axes.items():
            max_deflection[name] = max(max_deflection[name], abs(deflection(name, value)))
        now = set(pressed(state))
        for name in now - previous:
            presses[name] = presses.get(name, 0) + 1
        previous = now
    return Summary(max_deflection, presses)


@dataclass(frozen=True)
class OutputReach:
    """What one output the profile maps did over a replay: ``detail`` says how far an axis went
    each way (% of full deflection), how many presses a button had or how far a pointer or wheel
    moved (counts); ``reached`` is False when it never left neutral."""

    output: str
    mappings: tuple[str, ...]
    reached: bool
    detail: str


def _is_down(state: ControllerState, name: str) -> bool:
    if name in DPAD:
        return state.axes[DPAD[name][0]] == DPAD[name][1]
    return state.buttons.get(name, False) or name in state.keys


def _span(states: list[ControllerState], axis: str) -> tuple[float, float]:
    values = [deflection(axis, s.axes[axis]) for s in states] or [0.0]
    return min(min(values), 0.0), max(max(values), 0.0)


def _span_text(low: float, high: float) -> str:
    return f"{high:.0%}" if low == 0 else f"{low:+.0%} .. {high:+.0%}"


def reach(profile: Profile, states: list[ControllerState]) -> list[OutputReach]:
    """Every output ``profile`` maps, in the order of its mappings (several mappings of one output
    listed together), with what it did over ``states`` (:class:`OutputReach`). A button's presses
    are its keys' rising edges, except where a longer chord the profile maps holds them too (Tab
    inside Shift+Tab is the chord's press)."""
    outputs: dict[str, list[str]] = {}
    kinds: dict[str, object] = {}
    for name, m in profile.mappings.items():
        outputs.setdefault(m.output, []).append(name)
        kinds.setdefault(m.output, m)
    chords_of = [tuple(m.presses) for m in kinds.values() if isinstance(m, ButtonMapping)]
    result = []
    for output, names in outputs.items():
        m = kinds[output]
        if isinstance(m, ButtonMapping):
            parts = m.presses
            # a chord the profile maps that holds these keys and more is that chord's press
            chords = [c for c in chords_of if set(parts) < set(c)]
            count, before = 0, False
            for state in states:
                now = all(_is_down(state, p) for p in parts)
                now = now and not any(all(_is_down(state, p) for p in c) for c in chords)
                count += now and not before
                before = now
            reached, detail = count > 0, f"{count} press{'es' * (count != 1)}"
        elif isinstance(m, (PointerMapping, RelMapping)):
            if isinstance(m, PointerMapping):
                axes: tuple[str, ...] = ("REL_X", "REL_Y")
            elif m.output in ("REL_WHEEL", "REL_HWHEEL"):  # detents, and the hi-res units desktops scroll by
                axes = (m.output, m.output + "_HI_RES")
            else:
                axes = (m.output,)
            moved = {a: sum(abs(s.rel.get(a, 0)) for s in states) for a in axes}
            reached, detail = any(moved.values()), ", ".join(f"{a} {v} counts" for a, v in moved.items())
        else:
            axes = STICKS.get(output, (output,))
            spans = {a: _span(states, a) for a in axes}
            reached = any(low < 0 or high > 0 for low, high in spans.values())
            detail = ", ".join(f"{a} {_span_text(*span)}" for a, span in spans.items())
        result.append(OutputReach(output, tuple(names), reached, detail))
    return result


def plot_timeline(estimates: list[GestureEstimate], states: list[ControllerState], path: str | os.PathLike) -> None:
    """Draw the gesture intensity, every axis (as deflection -1..1) and every button over time
    (s from the first estimate) to a PNG (matplotlib, Agg backend: the optional extra ``plots``).

    Raises:
        MissingExtraError: matplotlib is not installed (the message says how to install it).
    """
    require("plots", "profile test --plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = estimates[0].t_us if estimates else 0
    t = np.array([(e.t_us - t0) * 1e-6 for e in estimates])
    fig, (ax_in, ax_axes, ax_btn) = plt.subplots(3, 1, sharex=True, figsize=(10, 7))
    intensity = np.array([e.intensity_mm for e in estimates])
    ax_in.plot(t, intensity, color="lightgray", lw=1)
    ax_in.set_ylabel("intensity (mm)")
    gestures = sorted({e.gesture.value for e in estimates})
    for g in gestures:  # each window's gesture type as the dot's colour
        mask = np.array([e.gesture.value == g for e in estimates])
        ax_in.scatter(t[mask], intensity[mask], s=4, label=g)
    ax_in.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=7)  # beside the data
    for name in AXES:
        values = [deflection(name, s.axes[name]) for s in states]
        if any(values):
            ax_axes.plot(t, values, lw=1, label=name)
    ax_axes.set_ylabel("axis deflection")
    ax_axes.set_ylim(-1.05, 1.05)
    if ax_axes.lines:
        ax_axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=7)
    down = [set(pressed(s)) for s in states]
    used = [name for name in DIGITAL_OUTPUTS if any(name in d for d in down)]
    used += sorted(set().union(*down) - set(DIGITAL_OUTPUTS)) if down else []
    for k, name in enumerate(used):
        ax_btn.step(t, [k + 0.8 * (name in d) for d in down], where="post", lw=1)
    ax_btn.set_yticks(range(len(used)), used)
    ax_btn.set_ylabel("buttons")
    ax_btn.set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def tuned_saturations(
    profile: Profile, estimates: Iterable[GestureEstimate], percentile: float = 95.0
) -> dict[str, tuple[float, float]]:
    """Saturations that give full deflection at what this user reaches.

    For every analogue mapping (stick or axis) whose input is an intensity (not ``contact``), the
    ``percentile`` of the input's magnitude (mm) over the estimates where it is non-zero; for a
    trigger, of the side it takes (the input's positive side, its negative one with ``invert``).
    A value not above the mapping's dead zone is raised to 1.25 x the dead zone (the stick must
    move).

    Returns:
        mapping name -> (current saturation mm, suggested saturation mm), only for mappings the
        estimates exercise.
    """
    samples: dict[str, list[float]] = {}
    analog = {
        name: m
        for name, m in profile.mappings.items()
        if not isinstance(m, ButtonMapping) and not m.input.startswith("contact")
    }
    for estimate in estimates:
        inputs = gesture_inputs(estimate)
        for name, m in analog.items():
            if isinstance(m, AxisMapping) and m.output in TRIGGERS:
                magnitude = max(-float(inputs[m.input]) if m.invert else float(inputs[m.input]), 0.0)
            else:
                magnitude = float(np.linalg.norm(inputs[m.input]))
            if magnitude > 0:
                samples.setdefault(name, []).append(magnitude)
    result = {}
    for name, values in samples.items():
        m = analog[name]
        reached = float(np.percentile(values, percentile))
        result[name] = (m.saturation, round(max(reached, 1.25 * m.deadzone_mm, m.deadzone_mm + 0.01), 2))
    return result
