"""An enrolment's plan: which gesture to prompt when, and for how long (docs/dataset.md,
"Guided session plan (JSON)").

A plan is made from a seed (:func:`make_plan`): every gesture type at least :data:`MIN_REPEATS`
times, pushes towards each of the four directions of the user frame, taps
(:data:`TAP_S`) and holds (:data:`HOLD_S`), each prompt followed by a rest long enough to see the
gel back at rest (:func:`rest_after_s`), all within :data:`MAX_SESSION_S` with room left to ask
again for the prompts that were missed. It is written and read as JSON (:func:`write_plan`,
:func:`read_plan`); ``cue_s`` counts from the recording's first event (or frame). A guided
session runs it as a :class:`Script`, to which the prompts missed are added.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neurotouch_hid.core.errors import DatasetError
from neurotouch_hid.core.estimate import GestureType
from neurotouch_hid.core.limits import read_outside_text, short

#: The gesture types a plan prompts (docs/dataset.md).
PLAN_GESTURES: tuple[GestureType, ...] = (
    GestureType.PUSH,
    GestureType.PINCH,
    GestureType.ZOOM,
    GestureType.TWIST_CW,
    GestureType.TWIST_CCW,
)
#: A push's direction names and their unit vectors in the user frame (x right, y up: "up" is
#: away from the user).
DIRECTIONS: dict[str, tuple[float, float]] = {
    "up": (0.0, 1.0),
    "right": (1.0, 0.0),
    "down": (0.0, -1.0),
    "left": (-1.0, 0.0),
}
#: A whole enrolment lasts at most this (s), the prompts asked again included.
MAX_SESSION_S = 180.0
#: Each gesture type is prompted at least this many times.
MIN_REPEATS = 4
#: How long a tap and a hold are asked to last (s, drawn uniformly).
TAP_S = (0.3, 0.5)
HOLD_S = (1.5, 3.0)
#: The gel at rest before the first cue (s): the pipeline finds its markers on a resting gel.
LEAD_S = 2.0
#: A plan made by :func:`make_plan` ends by this (s), so that prompts missed can be asked again
#: (:func:`rest_after_s` each) within :data:`MAX_SESSION_S`.
PLAN_BUDGET_S = 135.0
#: Largest plan file read (bytes): a plan of a few hundred prompts is ~30 KB.
MAX_PLAN_BYTES = 1 << 20
#: Most prompts a plan file may hold, and the longest prompt (s).
MAX_PROMPTS = 10_000
MAX_PROMPT_S = 60.0
#: Latest cue of a plan's prompt (s from the recording's start): a day; past it no recording
#: reaches (a cue of 1e308 s overflowed the labelling's microseconds).
MAX_CUE_S = 86_400.0


def rest_after_s(seconds: float) -> float:
    """The rest after a prompt of ``seconds`` before the next cue (s): a person starts a few
    hundred ms late and holds up to 40 % longer, the gel creeps back for up to ~1 s, and the
    labels need the gel at rest between gestures."""
    return 2.5 + 0.6 * seconds


@dataclass(frozen=True)
class Prompt:
    """One prompted gesture.

    Attributes:
        gesture: the type asked for (not NONE).
        cue_s: when the prompt appears, s from the recording's first event.
        seconds: how long the gesture should be held (s; a tap when under 1 s).
        direction: a push's direction (a key of :data:`DIRECTIONS`), None otherwise.
    """

    gesture: GestureType
    cue_s: float
    seconds: float
    direction: str | None = None

    @property
    def end_s(self) -> float:
        """When the prompted gesture should be over (s): ``cue_s + seconds``."""
        return self.cue_s + self.seconds

    @property
    def is_tap(self) -> bool:
        """True for a tap (asked for less than a second)."""
        return self.seconds < 1.0

    @property
    def name(self) -> str:
        """Short name for reports: ``push up``, ``twist_cw``."""
        return f"{self.gesture.value} {self.direction}" if self.direction else self.gesture.value

    def what(self) -> str:
        """What to do, in words, for the user (at most 58 characters)."""
        return {
            GestureType.PUSH: f"push the gel {_TOWARDS.get(self.direction or '', 'one way')}",
            GestureType.PINCH: "pinch: two fingers on the gel, move them together",
            GestureType.ZOOM: "zoom: two fingers on the gel, move them apart",
            GestureType.TWIST_CW: "twist clockwise: two fingers turning like a key",
            GestureType.TWIST_CCW: "twist counter-clockwise: two fingers turning like a key",
        }[self.gesture]

    def how(self) -> str:
        """For how long, in words: ``a quick tap`` or ``hold 2.4 s``."""
        return "a quick tap" if self.is_tap else f"hold {self.seconds:.1f} s"

    def instruction(self) -> str:
        """What to do and for how long, in words, for the user."""
        return f"{self.what()}, {self.how()}, then let go"

    def to_json(self) -> dict:
        """The prompt's JSON object (docs/dataset.md), ``direction`` only for a push."""
        data: dict = {"gesture": self.gesture.value, "cue_s": round(self.cue_s, 3), "seconds": round(self.seconds, 3)}
        if self.direction is not None:
            data["direction"] = self.direction
        return data


_TOWARDS = {
    "up": "up (away from you)",
    "down": "down (towards you)",
    "left": "to your left",
    "right": "to your right",
}


@dataclass(frozen=True)
class Plan:
    """An enrolment's prompts, ordered by ``cue_s``, not overlapping."""

    prompts: tuple[Prompt, ...]

    @property
    def end_s(self) -> float:
        """When the last prompt's gesture should be over, plus its rest (s); 0 for no prompt."""
        if not self.prompts:
            return 0.0
        last = self.prompts[-1]
        return last.end_s + rest_after_s(last.seconds)

    def to_json(self) -> dict:
        """The plan's JSON object: ``{"prompts": [...]}``."""
        return {"prompts": [p.to_json() for p in self.prompts]}


#: A cue before the stream's first event (us): later than any camera time, so never due.
NOT_YET_US = 2**62


class Script:
    """A plan as a guided session runs it, read and written from the session's threads: the
    prompts (the plan's, then those asked again), where the stream's time starts, the notes said
    so far and whether the session is over. It is what the person at the gel reads (the prompt
    view) and what the simulated hand follows. Thread-safe.

    Args:
        plan: the prompts asked first.
    Attributes:
        start_us: the stream's first event's timestamp (us, camera clock), from which the cues
            count; None before the first event.
        reached_us: the last timestamp the stream reached (us); None before the first item.
    """

    def __init__(self, plan: Plan) -> None:
        self._lock = threading.Lock()
        self._prompts = list(plan.prompts)
        self._notes: list[str] = []
        self._over = threading.Event()
        self.start_us: int | None = None
        self.reached_us: int | None = None

    def reach(self, first_us: int, last_us: int, events: bool = True) -> None:
        """The stream passed an item from ``first_us`` to ``last_us`` (us); ``events``: it is an
        event batch, and the first anchors :attr:`start_us` (cues count from the recording's
        first event, docs/dataset.md)."""
        with self._lock:
            if self.start_us is None and events:
                self.start_us = int(first_us)
            self.reached_us = int(last_us)

    def prompts(self) -> tuple[Prompt, ...]:
        """The prompts so far: the plan's, then those asked again, in the order asked."""
        with self._lock:
            return tuple(self._prompts)

    def cue_us(self, prompt: Prompt) -> int:
        """``prompt``'s cue on the camera clock (us); :data:`NOT_YET_US`, later than any
        camera time, before the stream's first event (:meth:`reach`)."""
        if self.start_us is None:
            return NOT_YET_US
        return self.start_us + int(round(prompt.cue_s * 1e6))

    def ask_again(self, prompt: Prompt) -> int:
        """Append ``prompt`` (cued after the last one); returns its index."""
        with self._lock:
            self._prompts.append(prompt)
            return len(self._prompts) - 1

    def note(self, line: str) -> None:
        """Say ``line`` to the person (a prompt not seen, asked again)."""
        with self._lock:
            self._notes.append(line)

    def notes(self) -> tuple[str, ...]:
        """The notes so far, oldest first."""
        with self._lock:
            return tuple(self._notes)

    def finish(self) -> None:
        """Every prompt was asked and judged: the session is over."""
        self._over.set()

    @property
    def finished(self) -> bool:
        """:meth:`finish` was called."""
        return self._over.is_set()

    def asked(self) -> Plan:
        """The prompts whose cue the stream reached (those the person was shown)."""
        with self._lock:
            if self.reached_us is None:
                return Plan(())
            return Plan(tuple(p for p in self._prompts if self.cue_us(p) <= self.reached_us))


def make_plan(seed: int = 0) -> Plan:
    """A plan drawn from ``seed`` (the same seed gives the same plan).

    Pushes: a tap and a hold towards each of :data:`DIRECTIONS`; pinch, zoom and both twists:
    two taps and two holds each (:data:`MIN_REPEATS`); in a shuffled order in which no type
    comes twice in a row. Taps last :data:`TAP_S`, holds :data:`HOLD_S`; the first cue is at
    :data:`LEAD_S`, each next one a rest (:func:`rest_after_s`) after the previous prompt's end.
    The plan ends by :data:`PLAN_BUDGET_S`.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xE4201]))
    items: list[tuple[GestureType, str | None, bool]] = []
    for direction in DIRECTIONS:
        items += [(GestureType.PUSH, direction, True), (GestureType.PUSH, direction, False)]
    for gesture in PLAN_GESTURES[1:]:
        items += [(gesture, None, tap) for tap in (True, False) for _ in range(MIN_REPEATS // 2)]
    order = _shuffled_apart(items, rng)
    prompts, t = [], LEAD_S
    for gesture, direction, tap in order:
        seconds = float(rng.uniform(*(TAP_S if tap else HOLD_S)))
        prompts.append(Prompt(gesture, round(t, 3), round(seconds, 3), direction))
        t = prompts[-1].end_s + rest_after_s(seconds)
    plan = Plan(tuple(prompts))
    assert plan.end_s <= PLAN_BUDGET_S, plan.end_s  # 12 holds of at most 3 s and 12 taps: <= 130 s
    return plan


def _shuffled_apart(items: list, rng: np.random.Generator) -> list:
    """``items`` (gesture first) in a random order with no gesture type twice in a row (greedy:
    at each step, one of the items whose type differs from the last, preferring the types with
    the most items left, so that the end does not run out of other types)."""
    left = [items[i] for i in rng.permutation(len(items))]
    out: list = []
    while left:
        counts: dict = {}
        for item in left:
            counts[item[0]] = counts.get(item[0], 0) + 1
        last = out[-1][0] if out else None
        allowed = [g for g in counts if g is not last] or list(counts)
        most = max(counts[g] for g in allowed)
        pick = next(i for i, item in enumerate(left) if item[0] in allowed and counts[item[0]] == most)
        out.append(left.pop(pick))
    return out


def write_plan(plan: Plan, path: str | Path, inputs: Sequence[str | Path | None] = ()) -> Path:
    """Write ``plan`` as JSON (one prompt a line) to ``path`` through a temporary file in the same
    folder, renamed over it at the end (a reader never sees half a plan); ``-`` is standard
    output, a FIFO or a character device is written as it is (``atomic.AtomicFile``).

    Raises:
        OutputError: ``path`` is a symbolic link, a folder or one of ``inputs``.
        DatasetError: the folder does not exist or cannot be written.
    """
    from neurotouch_hid.core.atomic import AtomicFile

    path = Path(path)
    lines = ",\n".join("  " + json.dumps(p.to_json()) for p in plan.prompts)
    text = '{"prompts": [\n' + lines + "\n]}\n" if plan.prompts else '{"prompts": []}\n'
    if str(path) == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
        return path
    try:
        with AtomicFile(path, inputs, what="plan") as fh:
            fh.write(text)
    except OSError as exc:  # the folder missing or unwritable (the disk's refusals are OutputError)
        raise DatasetError(f"{path}: cannot write: {exc.strerror or exc}") from None
    return path


def temp_beside(path: Path, suffix: str = ".tmp") -> Path:
    """A new empty file beside ``path`` (``.NAME.RANDOM`` + ``suffix``) with the umask's mode, as
    ``path`` itself would be made, to be renamed over it.

    Raises DatasetError (naming ``path``) when it cannot be created."""
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}{suffix}"
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666))
            return tmp
        except FileExistsError:
            continue
        except OSError as exc:
            raise DatasetError(f"{path}: cannot write: {exc.strerror}") from None
    raise DatasetError(f"{path}: cannot write: no free temporary name beside it")


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file beside it, renamed over it.

    Raises DatasetError (naming the file) when it cannot be written."""
    tmp = temp_beside(path)
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as exc:
        raise DatasetError(f"{path}: cannot write: {exc.strerror}") from None
    finally:
        tmp.unlink(missing_ok=True)


def read_plan(path: str | Path) -> Plan:
    """Read a plan file (docs/dataset.md, "Guided session plan (JSON)") through the bounded reader.

    Fields other than ``gesture``, ``cue_s``, ``seconds`` and a push's ``direction`` are
    ignored; so is a ``direction`` that is not one of :data:`DIRECTIONS` or not a push's.

    Raises:
        DatasetError: the file cannot be read, is larger than :data:`MAX_PLAN_BYTES`, is not
            UTF-8 JSON, is not an object with a list ``prompts``, or a prompt lacks a field or has
            a bad value, or the prompts are not ordered by ``cue_s`` or overlap; the message names
            the file, the prompt (1-based) and field, what was found and what was expected.
    """
    path = Path(path)
    text = read_outside_text(path, MAX_PLAN_BYTES, "session plan", DatasetError)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}:{exc.lineno}: not JSON: {exc.msg}") from None
    except (ValueError, RecursionError):
        raise DatasetError(f"{path}: not a session plan (a number or nesting out of bounds)") from None
    if not isinstance(data, dict) or not isinstance(data.get("prompts"), list):
        raise DatasetError(
            f'{path}: a session plan is a JSON object {{"prompts": [...]}} (docs/dataset.md), found {short(data)}'
        )
    items = data["prompts"]
    if len(items) > MAX_PROMPTS:
        raise DatasetError(f"{path}: {len(items)} prompts, at most {MAX_PROMPTS} (docs/limits.md)")
    prompts: list[Prompt] = []
    for number, item in enumerate(items, start=1):
        at = f"{path}: prompt {number}"
        if not isinstance(item, dict):
            raise DatasetError(f"{at}: expected a JSON object with gesture, cue_s, seconds, found {short(item)}")
        gesture = item.get("gesture")
        if gesture not in [g.value for g in PLAN_GESTURES]:
            names = ", ".join(g.value for g in PLAN_GESTURES)
            found = "nothing" if "gesture" not in item else short(gesture)
            raise DatasetError(f"{at}: field 'gesture': expected one of {names}, found {found}")
        cue = _number(item, "cue_s", at, f"a time in seconds from 0 to {MAX_CUE_S:g}", lambda v: 0 <= v <= MAX_CUE_S)
        seconds = _number(
            item, "seconds", at, f"a duration in seconds, > 0 and <= {MAX_PROMPT_S:g}", lambda v: 0 < v <= MAX_PROMPT_S
        )
        direction = item.get("direction")
        known = gesture == GestureType.PUSH.value and isinstance(direction, str) and direction in DIRECTIONS
        prompt = Prompt(GestureType(gesture), cue, seconds, direction if known else None)
        if prompts and cue < prompts[-1].end_s:
            before = prompts[-1]
            raise DatasetError(
                f"{at}: field 'cue_s': {cue:g} s is before the end of prompt {number - 1} "
                f"({before.cue_s:g} + {before.seconds:g} s): prompts must be ordered by cue_s and not overlap"
            )
        prompts.append(prompt)
    return Plan(tuple(prompts))


def _number(item: dict, key: str, at: str, expected: str, ok) -> float:
    if key not in item:
        raise DatasetError(f"{at}: field {key!r} is missing: expected {expected}")
    value = item[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not ok(value):
        raise DatasetError(f"{at}: field {key!r}: expected {expected}, found {short(value)}")
    return float(value)
