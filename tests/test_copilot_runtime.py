"""The runtime with a copilot: each window merged and a helper's press published at once, a profile
switch releasing the old merge, and the helper's pad driving the pad while the gel's camera is
missing. The real devices (grab, hot-plug, rumble) are checked in a real kernel:
tests/kernel/checks_copilot.py."""

from __future__ import annotations

import threading

import pytest
from copilot_helpers import SHORT_FORM
from runtime_fakes import EstimatesThrough

from neurotouch_hid.core.controller import ControllerState
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.mapping.merge import NEUTRAL, Levels, merge_state
from neurotouch_hid.mapping.profile import parse_profile


# --- the runtime ----------------------------------------------------------------------------------
class ScriptedMerge:
    """A Merge whose device's levels the test sets; ``press`` calls the runtime's ``on_input``
    from another thread, as the copilot's thread does."""

    def __init__(self):
        self.levels = NEUTRAL
        self.events: list[str] = []
        self.on_input = None

    def start(self, on_input):
        self.events.append("start")
        self.on_input = on_input

    def merge(self, gel):
        return merge_state(gel, [(self.levels, {})])

    def feedback(self, request):
        self.events.append(f"feedback {request.kind}")

    def stop(self):
        self.events.append("stop")

    def status(self):
        return (("Helper Pad",), ()) if "stop" not in self.events else ((), ("Helper Pad",))

    def press(self, levels):
        self.levels = levels
        thread = threading.Thread(target=self.on_input)
        thread.start()
        thread.join()


class Written:
    wants_markers = False

    def __init__(self):
        self.states: list[ControllerState] = []
        self.calls: list[str] = []

    def publish(self, record):
        if record.state_changed:
            self.states.append(record.state)
            self.calls.append("write")

    def neutralise(self):
        self.calls.append("neutralise")

    def prepare(self, profile):
        self.calls.append("prepare")


def test_the_runtime_merges_each_window_and_publishes_a_helpers_press_at_once():
    profile = parse_profile(SHORT_FORM, "p.yaml")
    merge, out = ScriptedMerge(), Written()
    gate = threading.Event()

    def source():
        yield GestureEstimate(
            t_us=10_000, gesture=GestureType.PUSH, resting=False, intensity_mm=6.0, translation_mm=(6.0, 0.0)
        )
        gate.wait(30)  # the gel holds its push: no window comes meanwhile
        yield GestureEstimate(t_us=20_000)

    rt = Engine(RunParts(source(), EstimatesThrough()), profile, [out], RunOptions(mode=RunMode.FAST, merge=merge))

    def helper():
        from helpers import wait_until

        wait_until(lambda: out.states, 30)
        merge.press(Levels(axes={"ABS_X": -32768}, buttons=frozenset({"BTN_SOUTH"})))
        merge.press(Levels(axes={"ABS_X": -32768}, buttons=frozenset({"BTN_SOUTH"})))  # no change: nothing
        gate.set()

    thread = threading.Thread(target=helper)
    thread.start()
    stats = rt.run()
    thread.join()
    first, pressed, *rest = out.states
    assert first.axes["ABS_X"] > 20000 and not first.buttons["BTN_SOUTH"]  # the gel's push alone
    assert pressed.axes["ABS_X"] == -32768 and pressed.buttons["BTN_SOUTH"]  # the helper's, before the next window
    assert rest == []  # the gel at rest: the helper's stick and button alone, as the pad shows already
    assert merge.events == ["start", "stop"] and out.calls[-1] == "neutralise"
    assert stats.states_written == len(out.states) and stats.merged == ("Helper Pad",)


def test_a_profile_switch_releases_the_old_merge_and_starts_the_new_ones():
    made: list[ScriptedMerge | None] = []

    def merge_for(profile):
        made.append(ScriptedMerge() if profile.copilot else None)
        return made[-1]

    with_copilot = parse_profile(SHORT_FORM, "p.yaml")
    without = parse_profile("mappings: {}\n", "q.yaml")
    out = Written()
    started = threading.Event()

    def source():
        yield GestureEstimate(t_us=10_000)
        started.wait(30)

    rt = Engine(
        RunParts(source(), EstimatesThrough()), with_copilot, [out], RunOptions(mode=RunMode.FAST, merge_for=merge_for)
    )
    thread = threading.Thread(target=rt.run)
    thread.start()
    from helpers import wait_until

    wait_until(lambda: made and made[0].events == ["start"], 30)
    rt.switch_profile(without)
    assert made[0].events == ["start", "stop"] and made[1] is None and rt.stats.merged == ()
    rt.switch_profile(with_copilot)
    assert made[2].events == ["start"]
    started.set()
    thread.join(30)
    assert made[2].events == ["start", "stop"]


def test_a_profile_switched_while_the_run_starts_its_merge_shows_the_new_profiles_devices():
    """A switch that comes while the run is starting the merged devices waits for it: the run does
    not note the devices it started after the switch released them (the status said a released
    helper's pad was merged)."""
    asked, switching = threading.Event(), threading.Event()

    class SlowStatus(ScriptedMerge):
        def status(self):  # what the devices are now, told a while later
            now = super().status()
            if not asked.is_set():
                asked.set()
                switching.wait(30)
                threading.Event().wait(0.3)  # the switch, unhindered, is over by then
            return now

    made: list[ScriptedMerge | None] = []

    def merge_for(profile):
        made.append(SlowStatus() if profile.copilot else None)
        return made[-1]

    gate, begun = threading.Event(), threading.Event()

    def source():  # read from the source's thread, which starts after the merged devices
        begun.set()
        yield GestureEstimate(t_us=10_000)
        gate.wait(30)

    options = RunOptions(mode=RunMode.FAST, merge_for=merge_for)
    rt = Engine(RunParts(source(), EstimatesThrough()), parse_profile(SHORT_FORM, "p.yaml"), [Written()], options)
    thread = threading.Thread(target=rt.run)
    thread.start()
    try:
        assert asked.wait(30)
        switching.set()
        rt.switch_profile(parse_profile("mappings: {}\n", "q.yaml"))
        assert made[0].events == ["start", "stop"] and made[1] is None
        assert begun.wait(30)  # the run's own note of its merged devices is behind it
        assert rt.stats.merged == () and rt.stats.missing == ()
    finally:
        gate.set()
        thread.join(30)


@pytest.mark.parametrize("camera", ["waiting", "lost"])
def test_the_helpers_pad_drives_the_pad_while_the_gels_camera_is_missing(camera):
    """No camera yet, or the camera lost after a window: the helper's pad is merged (grabbed, so
    the game does not see it apart) and its press and stick reach the pad at once, over a gel at
    rest; the driver's stop leaves the pad neutral."""
    from helpers import wait_until

    from neurotouch_hid.sources import SourceStatus, StatusKind

    profile = parse_profile(SHORT_FORM, "p.yaml")
    merge, out = ScriptedMerge(), Written()
    gate = threading.Event()

    def source():
        if camera == "waiting":
            yield SourceStatus(StatusKind.WAITING, "waiting for a camera")
        else:
            yield GestureEstimate(t_us=10_000)
            yield SourceStatus(StatusKind.LOST, "camera lost")
        gate.wait(30)

    rt = Engine(RunParts(source(), EstimatesThrough()), profile, [out], RunOptions(mode=RunMode.LIVE, merge=merge))
    thread = threading.Thread(target=rt.run)
    thread.start()
    wait_until(lambda: merge.on_input is not None and (camera == "waiting" or rt.stats.camera_losses == 1), 30)
    merge.press(Levels(axes={"ABS_X": -32768}, buttons=frozenset({"BTN_SOUTH"})))
    gate.set()
    thread.join(30)
    pressed = [s for s in out.states if s.buttons["BTN_SOUTH"]]
    assert pressed and pressed[0].axes["ABS_X"] == -32768 and pressed[0].axes["ABS_Y"] == 0
    assert out.calls[-1] == "neutralise"
