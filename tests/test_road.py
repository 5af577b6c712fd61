"""One road through the driver (docs/architecture.md, "The road"): the runtime publishes one record
per window; the outputs and views are subscribers behind one typed interface; no source,
pipeline or mapper knows a view."""

from __future__ import annotations

import ast
import contextlib
import inspect
from pathlib import Path

from runtime_fakes import FakeMapper, FakePipeline, batch

from neurotouch_hid.core.estimate import GestureType, MarkerPositions
from neurotouch_hid.core.stages import Subscriber, WindowRecord
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.mapping.profile import load_profile
from neurotouch_hid.sources.open import open_source

PACKAGE = Path(__file__).resolve().parents[1] / "neurotouch_hid"


class Collector:
    """Keeps every record; asks for markers when told to."""

    def __init__(self, wants_markers: bool = False):
        self.wants_markers = wants_markers
        self.records: list[WindowRecord] = []
        self.neutralised = 0

    def publish(self, record: WindowRecord) -> None:
        self.records.append(record)

    def neutralise(self) -> None:
        self.neutralised += 1

    def prepare(self, profile) -> None:
        pass


class MarkerPipeline(FakePipeline):
    def __init__(self):
        super().__init__(push_batches=2)
        self.asked = 0

    def markers(self):
        import numpy as np

        self.asked += 1
        return MarkerPositions(np.zeros((3, 2)), np.ones((3, 2)))


def test_every_window_is_published_once_to_every_subscriber_with_what_changed():
    first, second = Collector(), Collector()
    stream = [batch(k * 1000) for k in range(5)]
    stats = Engine(
        RunParts(stream, FakePipeline(push_batches=2)),
        {"sign": 1},
        [first, second],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper),
    ).run()
    assert len(first.records) == len(second.records) == stats.windows == 5
    assert [r is s for r, s in zip(first.records, second.records)] == [True] * 5  # the same record
    changed = [(r.state_changed, r.gesture_changed) for r in first.records]
    assert changed == [(True, True), (True, False), (True, True), (False, False), (False, False)]
    assert first.records[-1].stats is stats and first.neutralised == second.neutralised == 1


def test_markers_are_copied_only_when_a_subscriber_draws_them():
    pipeline = MarkerPipeline()
    blind = Collector()
    Engine(
        RunParts([batch(0), batch(1000)], pipeline),
        {"sign": 1},
        [blind],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper),
    ).run()
    assert pipeline.asked == 0 and all(r.markers is None for r in blind.records)
    pipeline = MarkerPipeline()
    drawing = Collector(wants_markers=True)
    Engine(
        RunParts([batch(0), batch(1000)], pipeline),
        {"sign": 1},
        [blind, drawing],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper),
    ).run()
    assert pipeline.asked == 2 and all(r.markers is not None for r in drawing.records)


def test_the_simulated_hand_says_what_it_performs_and_the_record_carries_it():
    """The source's truth reaches a view through the record, not through the view's own hook."""
    from neurotouch_hid.engine.assembly import build_pipeline

    collector = Collector()
    with contextlib.ExitStack() as stack:
        opened = open_source("sim", stack, seconds=4.0, labelled=True, batch_us=1000)
        pipeline, _ = build_pipeline(opened.sensor, 10_000, resting_beside=False)
        Engine(
            RunParts(opened.stream, pipeline, sensor=opened.sensor, labelled=opened.labelled),
            load_profile("default"),
            [collector],
            RunOptions(mode=RunMode.FAST),
        ).run()
    performed = [r.performed for r in collector.records]
    assert all(r.labelled for r in collector.records) and opened.labelled
    assert performed[0] is not None and performed[-1] is not None
    assert {p.gesture for p in performed} - {GestureType.NONE}  # the hand performed a gesture
    # the label in force: never one from after the window's end
    assert all(p.t_us <= r.estimate.t_us for p, r in zip(performed, collector.records))


def test_an_unlabelled_source_publishes_no_performed_gesture(sim_push_only_recording):
    collector = Collector()
    with contextlib.ExitStack() as stack:
        opened = open_source(str(sim_push_only_recording), stack)
        from neurotouch_hid.engine.assembly import build_pipeline

        pipeline, _ = build_pipeline(opened.sensor, 10_000, resting_beside=False)
        Engine(
            RunParts(opened.stream, pipeline, labelled=opened.labelled),
            load_profile("default"),
            [collector],
            RunOptions(mode=RunMode.FAST),
        ).run()
    assert collector.records and not opened.labelled
    assert all(r.performed is None and not r.labelled for r in collector.records)


def test_every_output_is_a_subscriber():
    """The devices (behind TargetOutputs), JSON lines, the terminal and live views: one interface."""
    from neurotouch_hid.targets import TargetOutputs
    from neurotouch_hid.views.jsonl import StateJsonlWriter
    from neurotouch_hid.views.live import LiveView
    from neurotouch_hid.views.term import TermView

    members = {name for name, _ in inspect.getmembers(Subscriber) if not name.startswith("_")}
    members |= set(Subscriber.__annotations__)
    assert members == {"publish", "neutralise", "prepare", "wants_markers"}
    for output in (TargetOutputs, StateJsonlWriter, TermView, LiveView):
        assert all(hasattr(output, m) for m in members - {"wants_markers"}), output
        assert "wants_markers" in vars(output) or "wants_markers" in inspect.getsource(output), output


def test_every_device_is_a_target_and_none_is_a_subscriber_of_its_own():
    """The uinput pad, keyboard and mouse, the UHID device, the gadget's functions: each a Target,
    written to only through TargetOutputs (one output path, one feedback path)."""
    from neurotouch_hid.core.stages import Target
    from neurotouch_hid.targets.gadget.ffs import HidInterfaceTarget, XInputTarget
    from neurotouch_hid.targets.gadget.targets import HidgTarget
    from neurotouch_hid.targets.uhid import UhidDevice
    from neurotouch_hid.targets.uinput.desktop import UinputDesktop, UinputOutputs, VirtualKeyboard, VirtualMouse
    from neurotouch_hid.targets.uinput.gamepad import VirtualGamepad

    members = {name for name, _ in inspect.getmembers(Target) if not name.startswith("_")}
    assert members == {"write", "neutralise", "prepare", "fileno", "feedback", "close"}
    devices = (VirtualGamepad, VirtualKeyboard, VirtualMouse, UinputOutputs, UinputDesktop, UhidDevice)
    for device in (*devices, HidgTarget, XInputTarget, HidInterfaceTarget):
        assert all(callable(getattr(device, m, None)) for m in members), device
        assert not hasattr(device, "publish"), f"{device.__name__} is a subscriber of its own"
    assert "Thread(" not in inspect.getsource(VirtualGamepad), "a rumble thread of the pad's own"


def _imported(module_folder: str) -> set[str]:
    found = set()
    for path in (PACKAGE / module_folder).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                found.add(node.module)
            elif isinstance(node, ast.Import):
                found |= {a.name for a in node.names}
    return found


def test_no_source_pipeline_or_mapper_module_knows_a_view():
    for folder in ("sources", "pipeline", "mapping"):
        views = {m for m in _imported(folder) if m.startswith(("neurotouch_hid.views", "neurotouch_hid.core.stages"))}
        views |= {m for m in _imported(folder) if m.startswith("neurotouch_hid.engine")}
        assert views == set(), folder
    for path in PACKAGE.joinpath("sources").rglob("*.py"):
        assert "scene" not in path.read_text(), path


def test_no_any_in_the_outputs():
    for path in PACKAGE.joinpath("output").rglob("*.py"):
        tree = ast.parse(path.read_text())
        names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
        assert "Any" not in names, path
