"""A SIGTERM before the run has started (neurotouch_hid/stopping.py): the driver stops as it does
during a run, exit 0, every device it made neutral and removed, the merged devices let go; and
the merged devices are grabbed before any output device is made, whatever the output. A real
SIGTERM is sent to this process (pytest runs tests in the main thread, where handlers run); the
devices are recording stand-ins (the kernel's are checked in tests/kernel/checks_road.py)."""

from __future__ import annotations

import os
import signal
import sys
import time
from dataclasses import replace

import pytest
from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch

from neurotouch_hid.core.kinds import OutputKind
from neurotouch_hid.engine import driver
from neurotouch_hid.engine.engine import Engine, RunParts
from neurotouch_hid.engine.mode import RunMode, RunOptions
from neurotouch_hid.engine.stopping import EarlyStop, StopRequested


class Order:
    """What happened, in order, across the stand-ins."""

    def __init__(self) -> None:
        self.events: list[str] = []


class FakeMerge:
    def __init__(self, order: Order) -> None:
        self.order = order

    def grab(self) -> None:
        self.order.events.append("grab")

    def start(self, on_input) -> None:
        self.order.events.append("start")

    def stop(self) -> None:
        self.order.events.append("let go")

    def merge(self, gel):
        return gel

    def feedback(self, request) -> None:
        pass

    def status(self):
        return ("Helper Pad",), ()


class FakeRelay:
    def __init__(self, order: Order) -> None:
        self.order = order

    def merge_for(self, profile):
        return FakeMerge(self.order)

    def __call__(self, request) -> None:
        pass


class Device(RecordingOutput):
    """An output device: its creation, states and close recorded."""

    def __init__(self, order: Order) -> None:
        super().__init__()
        self.order = order
        order.events.append("device made")

    def neutralise(self) -> None:
        super().neutralise()
        self.order.events.append("neutral")

    def close(self) -> None:
        self.order.events.append("device closed")

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.neutralise()
        self.close()


@pytest.fixture
def rig(monkeypatch):
    order = Order()
    monkeypatch.setattr(driver, "copilot_relay", lambda output, say, loop=None: FakeRelay(order))

    def opener(profile, stack, **_):
        return stack.enter_context(Device(order))

    for kind in (OutputKind.GAMEPAD, OutputKind.HID, OutputKind.USB):
        monkeypatch.setitem(driver.OPENERS, kind, opener)
    return order


@pytest.mark.parametrize("output", ["gamepad", "hid", "usb"])
def test_sigterm_while_the_run_is_being_opened_stops_cleanly_with_every_device_neutral(rig, monkeypatch, output):
    """The pad (or UHID device, or gadget) exists, the engine has not started (a first run's
    compile, a camera waited for): SIGTERM returns normally (the command's exit 0), the device
    neutral and closed, the merged devices let go, nothing after."""

    def open_and_wait(self, stack):
        rig.events.append("opening the source")
        os.kill(os.getpid(), signal.SIGTERM)  # the handler raises here, in the main thread
        rig.events.append("never")
        raise AssertionError("the SIGTERM did not stop the opening")

    monkeypatch.setattr(driver.RunAssembly, "open", open_and_wait)
    previous = signal.getsignal(signal.SIGTERM)
    said: list[str] = []
    stats = driver.run_driver("sim", "default", output, driver.DriverOptions(seconds=1, say=said.append))
    assert stats.windows == 0
    assert rig.events == ["grab", "device made", "opening the source", "neutral", "device closed", "let go"]
    assert said[-1] == "stopped (SIGTERM) before the run started: every output released"
    assert signal.getsignal(signal.SIGTERM) is previous  # put back


def test_the_merged_devices_are_grabbed_before_the_device_and_started_by_the_run(rig, monkeypatch):
    """Grabbed (and, as root, hidden) before the pad appears; the engine then only starts reading
    them (no second grab), and lets them go before the device goes."""

    def open_parts(self, stack):
        rig.events.append("source opened")
        return RunParts([batch(0), batch(1000)], FakePipeline(push_batches=1), None, None, False, False, None)

    monkeypatch.setattr(driver.RunAssembly, "open", open_parts)
    monkeypatch.setattr(driver, "run_assembled", _fake_mapper_run(driver.run_assembled))
    driver.run_driver("sim", "default", "hid", driver.DriverOptions(seconds=1))
    assert rig.events[:4] == ["grab", "device made", "source opened", "start"]
    assert rig.events.index("let go") < rig.events.index("device closed")


def _fake_mapper_run(real):
    def run(assembly, profile, subscribers, seconds, options, **kw):
        return real(assembly, {"sign": 1}, subscribers, seconds, replace(options, mapper_factory=FakeMapper), **kw)

    return run


def test_a_sigterm_after_the_devices_but_before_the_engine_stops_the_run_at_once():
    """Between the early handler's last raise and the engine's own handler (the way into the run),
    a SIGTERM is only noted: the engine, once its handlers are in place, stops before any window."""
    out = RecordingOutput()
    with EarlyStop() as early:
        early.quiet()
        os.kill(os.getpid(), signal.SIGTERM)
        assert early.requested.is_set()
        stream = [batch(k * 1000) for k in range(50)]
        runtime = Engine(
            RunParts(stream, FakePipeline(push_batches=2)),
            {"sign": 1},
            [out],
            RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper, early_stop=early),
        )
        stats = runtime.run()
    assert stats.windows == 0 and out.calls[-1] == ("neutralise", None)


def test_the_early_handler_raises_once_and_is_put_back():
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(StopRequested):
        with EarlyStop() as early:
            os.kill(os.getpid(), signal.SIGTERM)
    assert early.requested.is_set()
    with EarlyStop() as early:
        with pytest.raises(StopRequested):
            os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGTERM)  # on the way out: noted, not raised
    assert signal.getsignal(signal.SIGTERM) is previous


def test_a_sigterm_during_an_import_is_raised_once_the_import_is_over(tmp_path, monkeypatch):
    """A SIGTERM while the main thread imports a module (the first run imports the pipeline and
    OpenCV after its first device): the import completes, then the stop is raised. Raised inside
    it, the module would be left half-made (OpenCV's loader then refuses every later import of
    cv2 in the process, "recursion is detected")."""
    (tmp_path / "nt_slow_to_import.py").write_text(
        "import os, signal, time\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "for _ in range(20):\n"
        "    time.sleep(0.01)\n"
        "DONE = True\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "nt_slow_to_import", raising=False)
    imported = None
    with pytest.raises(StopRequested):
        with EarlyStop() as early:
            import nt_slow_to_import

            imported = nt_slow_to_import
            time.sleep(10)  # the deferred SIGTERM interrupts this wait
    assert early.requested.is_set()
    assert imported is not None and imported.DONE
    assert sys.modules["nt_slow_to_import"] is imported
    monkeypatch.delitem(sys.modules, "nt_slow_to_import")


def test_a_sigterm_inside_a_finalizer_still_stops_the_opening():
    """Python drops an exception raised in ``__del__`` (a first run's compile runs llvmlite's
    finalizers): raised there, the stop was lost and the run went on. It is raised after it."""

    class Finalized:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.2)  # the handler runs here, inside __del__

    with pytest.raises(StopRequested):
        with EarlyStop() as early:
            Finalized()  # dropped at once: its __del__ runs now
            time.sleep(10)  # the SIGTERM delivered again interrupts this wait
    assert early.requested.is_set()
