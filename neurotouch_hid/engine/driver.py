"""The driver's start-up wiring: the ``run`` and ``demo`` commands put the concrete stages together.

The road goes one way: :func:`run_driver` loads the profile (a bad one fails before any device
exists), opens the subscribers (:func:`open_output`: the uinput devices, JSON lines, the terminal
or live view; :func:`open_outputs`: the live view beside the pad) and hands them, with a
:class:`RunAssembly` of what to open, to the engine (:func:`neurotouch_hid.engine.engine.run_assembled`).
The engine opens the source and the pipeline through the assembly when the run starts
(:meth:`RunAssembly.open`: the first run's compile, the source, the pipeline and its resting
detector), runs them in its threads, and publishes one record per window to the subscribers.
The engine knows the stages only through the seams of :mod:`neurotouch_hid.core.stages`; no stage
knows a view.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from neurotouch_hid.core.errors import DeviceError, NeurotouchError, ProfileError
from neurotouch_hid.core.kinds import MethodKind, OutputKind, SourceKind
from neurotouch_hid.core.stages import Feedback, Subscriber
from neurotouch_hid.core.stats import RunStats
from neurotouch_hid.engine.assembly import RunAssembly, run_assembled
from neurotouch_hid.engine.loop import Loop
from neurotouch_hid.engine.mode import DEFAULT_MAX_LAG_US, RunMode, RunOptions
from neurotouch_hid.engine.stopping import EarlyStop, StopRequested
from neurotouch_hid.mapping.profile import Profile, available_profiles, find_profile, load_profile
from neurotouch_hid.service.serve import served
from neurotouch_hid.sources.open import CameraBackend, open_source
from neurotouch_hid.targets.identity import Identity, identity_for

if TYPE_CHECKING:
    from rich.console import Console

    from neurotouch_hid.enrolment.model import Model
    from neurotouch_hid.inputs.copilot import FeedbackRelay
    from neurotouch_hid.sources.davis import DavisConfig

log = logging.getLogger(__name__)

__all__ = ["CameraBackend", "open_source"]  # the camera's seam and the opener, for the CLI and tests


def open_output(
    kind: str,
    profile: Profile,
    stack: contextlib.ExitStack,
    *,
    out: str | Path | None = None,
    console: Console | None = None,
    say: Callable[[str], None] | None = None,
    inputs: tuple[str | Path | None, ...] = (),
    on_feedback: Callable[[Feedback], None] | None = None,
    protocol: str | None = None,
    identity: Identity | None = None,
    loop: Loop | None = None,
) -> Subscriber:
    """Create one output (:data:`OPENERS` has one opener per kind): ``gamepad`` (the uinput pad
    with the profile's name and ids, and the keyboard and mouse if the profile uses them), ``hid``
    (a HID device on UHID speaking ``protocol``, else the profile's, else ``hid``, the generic
    joystick, docs/reports.md; the keyboard and mouse on uinput where it can be used), ``usb``
    (a USB gadget speaking ``protocol``, else the profile's, else ``hid``:
    :mod:`neurotouch_hid.targets.gadget`), ``jsonl`` (one state line per change to ``out`` or
    stdout; ``out`` may not be one of the run's ``inputs``) or ``term`` (the terminal view; on a
    terminal the live view of :mod:`neurotouch_hid.views.live`: the gel, the gestures, the
    profile, beside the pad). Every device output is one
    :class:`~neurotouch_hid.targets.TargetOutputs` over its targets: ``say`` tells the user about
    what games and hosts send back (rumble, LEDs: the gel has no motor; default: the log), and
    ``on_feedback`` gets each of them (the copilot's merged pads play the rumble). The
    uinput pad is made when the profile first drives a pad control. ``identity``: the camera's
    (:func:`~neurotouch_hid.targets.identity.identity_for`): the pad's ``phys``, the UHID device's
    ``phys`` and ``uniq`` and feature reports, the gadget's serial (None: the default identity,
    whose devices keep the ``phys`` of each output and no ``uniq``). ``loop``: where the targets'
    readable sides wait (the run's :class:`~neurotouch_hid.engine.loop.Loop`; None: a thread of
    their own). Closed by ``stack``.
    Raises DeviceError when /dev/uinput (``gamepad``) or /dev/uhid (``hid``) cannot be used."""
    opener = OPENERS[OutputKind(kind)]
    return opener(
        profile,
        stack,
        out=out,
        console=console,
        say=say,
        inputs=inputs,
        on_feedback=on_feedback,
        protocol=protocol,
        identity=identity if identity is not None else identity_for(None),
        loop=loop,
    )


def _open_gamepad(
    profile: Profile, stack: contextlib.ExitStack, *, say, identity: Identity, on_feedback=None, loop=None, **_
) -> Subscriber:
    from neurotouch_hid.service.extras import require

    require("uinput", "the virtual gamepad (--output gamepad)")
    from neurotouch_hid.targets import TargetOutputs
    from neurotouch_hid.targets.uinput.desktop import UinputOutputs
    from neurotouch_hid.targets.uinput.gamepad import PHYS, GamepadIdentity, VirtualGamepad

    def make_pad(using: Profile) -> VirtualGamepad:
        dev = using.device
        pad = GamepadIdentity(
            name=dev.name,
            vendor=dev.vendor,
            product=dev.product,
            version=dev.version,
            phys=identity.phys if identity.serial else PHYS,  # without a serial: the pad's phys as always
        )
        return VirtualGamepad(pad)

    phys = identity.phys if identity.serial else None  # the keyboard's and mouse's prefix
    devices = UinputOutputs(None, profile, known=known_profiles(), make_pad=make_pad, phys=phys)
    return stack.enter_context(TargetOutputs([devices], say=say, forward=on_feedback, loop=loop))


def _open_hid(
    profile: Profile,
    stack: contextlib.ExitStack,
    *,
    say,
    identity: Identity,
    protocol=None,
    on_feedback=None,
    loop=None,
    **_,
) -> Subscriber:
    from neurotouch_hid.targets import TargetOutputs
    from neurotouch_hid.targets.uhid import UhidDevice, uhid_identity, uhid_protocol
    from neurotouch_hid.targets.uinput.desktop import UinputDesktop

    row = uhid_protocol(protocol, profile)
    with contextlib.ExitStack() as made:  # each target closed if a later one fails
        device = UhidDevice(row.report, uhid_identity(row, profile.device, identity), camera=identity)
        joystick = made.enter_context(device)
        phys = identity.phys if identity.serial else None
        desktop = UinputDesktop(profile, known_profiles(), say=say or log.warning, phys=phys)
        made.callback(desktop.close)
        outputs = TargetOutputs([joystick, desktop], say=say, forward=on_feedback, loop=loop)
        made.pop_all()
    return stack.enter_context(outputs)


def _open_usb(
    profile: Profile,
    stack: contextlib.ExitStack,
    *,
    say,
    protocol,
    identity: Identity,
    on_feedback=None,
    loop=None,
    **_,
) -> Subscriber:
    from neurotouch_hid.targets import TargetOutputs
    from neurotouch_hid.targets.gadget import UsbGadget, protocol_for

    chosen = protocol_for(protocol, profile)
    gadget = stack.enter_context(UsbGadget(chosen, profile, serial=identity.usb_serial, identity=identity))
    return stack.enter_context(TargetOutputs(gadget.targets, say=say, forward=on_feedback, loop=loop))


def _open_jsonl(profile: Profile, stack: contextlib.ExitStack, *, out, inputs, **_) -> Subscriber:
    from neurotouch_hid.views.jsonl import StateJsonlWriter

    return stack.enter_context(StateJsonlWriter(out, inputs))


def _open_term(profile: Profile, stack: contextlib.ExitStack, *, console, **_) -> Subscriber:
    from neurotouch_hid.views.live import LiveView

    return stack.enter_context(LiveView(console))


#: One opener per output kind: ``opener(profile, stack, *, out, console, say, inputs)`` -> the
#: subscriber, entered into ``stack`` (:func:`open_output`).
OPENERS: dict[OutputKind, Callable[..., Subscriber]] = {
    OutputKind.GAMEPAD: _open_gamepad,
    OutputKind.HID: _open_hid,
    OutputKind.USB: _open_usb,
    OutputKind.JSONL: _open_jsonl,
    OutputKind.TERM: _open_term,
}
#: The outputs that are devices: on a terminal, the live view is drawn beside them.
DEVICE_OUTPUTS = (OutputKind.GAMEPAD, OutputKind.HID, OutputKind.USB)


def open_outputs(
    output: Subscriber, kind: str, stack: contextlib.ExitStack, console: Console | None = None
) -> list[Subscriber]:
    """The run's subscribers: ``output`` (what :func:`open_output` made for ``kind``) and, for a
    device output (the virtual gamepad, the HID joystick) on a terminal (``console.is_terminal``),
    the live view drawn beside it, closed by ``stack``."""
    if kind not in DEVICE_OUTPUTS or console is None or not console.is_terminal:
        return [output]
    from neurotouch_hid.views.live import LiveView

    return [output, stack.enter_context(LiveView(console))]


def known_profiles() -> list[Profile]:
    """The shipped and the user's profiles that load (a broken one is left out: ``profile use``
    refuses it anyway); the keyboard and mouse offer what they use from the start."""
    known = []
    for path in available_profiles().values():
        try:
            known.append(load_profile(path))
        except ProfileError:
            continue
    return known


@dataclass(frozen=True)
class DriverOptions:
    """How ``neurotouch-hid run`` runs (:func:`run_driver`), as the command line gives it.

    Attributes:
        seconds: stop after this much camera time (s); None: at the source's end, Ctrl-C or SIGTERM.
        fast: recordings and the simulated gel only: as fast as possible, nothing dropped, the
            resting detection inline (the same input always gives the same states); else paced
            in real time.
        out: the ``jsonl`` output's file (None: standard output).
        window_us: the gesture windows' length (us, >= 1000; the paper's 10 ms).
        sensor: the gel's ``sensor.yaml`` (None: the camera's own, else the shared one).
        seed: the simulated gel's random seed.
        console: where the terminal and live views draw (rich); None: standard output.
        outputs: subscribers that replace those ``output`` names (the demo's fallback, benchmarks).
        davis: the live camera's settings (:class:`~neurotouch_hid.sources.davis.DavisConfig`).
        wait: the live camera: wait for one to be plugged in instead of failing.
        capture: the camera's backend (:class:`~neurotouch_hid.sources.open.CameraBackend`; None: dv-processing).
        say: tells the user what happens (a camera lost and back, a first run's compile).
        stats: where the run is counted (the one a given terminal view shows); None: a new one.
        max_lag_us: real time: data is dropped, oldest first, once the pipeline falls this far
            behind (us of camera time, >= 1000).
        method: the gesture pipeline (``pipeline.methods``: ``default`` or ``paper``).
        model: an adapted model's values over it (``enrolment/model.py``); None: the shipped method.
        finish_gesture: the simulated gel: past ``seconds`` its hand finishes the gesture it
            performs (:class:`~neurotouch_hid.engine.assembly.RunAssembly`).
        protocol: with ``output`` ``usb`` or ``hid``, the protocol the controller speaks (a row of
            :data:`~neurotouch_hid.targets.protocols.PROTOCOLS`; None: the profile's
            ``device: protocol``, else ``hid``).
        serial: the camera the run stands for (:mod:`neurotouch_hid.sources.serial`): the outputs'
            identity, its control socket, its own config where it has one.

    Raises:
        NeurotouchError: ``window_us`` or ``max_lag_us`` under 1000 us, or an unknown ``method``.
    """

    seconds: float | None = None
    fast: bool = False
    out: str | Path | None = None
    window_us: int = 10_000
    sensor: str | Path | None = None
    seed: int = 0
    console: Console | None = None
    outputs: Sequence[Subscriber] | None = None
    davis: DavisConfig | None = None
    wait: bool = False
    capture: CameraBackend | None = None
    say: Callable[[str], None] = log.warning
    stats: RunStats | None = None
    max_lag_us: int = DEFAULT_MAX_LAG_US
    method: str = "default"
    model: Model | None = None
    finish_gesture: bool = False
    protocol: str | None = None
    serial: str | None = None

    def __post_init__(self) -> None:
        if self.window_us < 1000:
            raise NeurotouchError(f"--window-us {self.window_us}: windows must be at least 1000 us")
        if self.max_lag_us < 1000:
            raise NeurotouchError(f"--max-lag-ms {self.max_lag_us / 1000:g}: the lag allowed must be at least 1 ms")
        if self.method not in tuple(MethodKind):
            raise NeurotouchError(f"--method {self.method!r}: expected one of {', '.join(MethodKind)}")


def run_driver(
    source: str = "davis",
    profile: str | Path | None = "default",
    output: str = "gamepad",
    options: DriverOptions = DriverOptions(),
) -> RunStats:
    """``neurotouch-hid run``: load the profile (a bad one raises ProfileError before any device
    exists), open the outputs, then run: the engine opens the source and builds the pipeline
    (:class:`RunAssembly`) and runs until the end.

    ``source``: ``davis``, ``sim`` or a file (a recording, a predictions file); ``profile``: a
    profile's name or path (None: the camera's own ``profile.yaml``, else ``default``);
    ``output``: one of :class:`~neurotouch_hid.core.kinds.OutputKind`; the rest in ``options``
    (:class:`DriverOptions`). Real time (the camera, or paced replays): the resting detector runs
    in its own thread, and data is dropped, oldest first, if the pipeline falls more than
    ``options.max_lag_us`` behind.

    Raises NeurotouchError subclasses for bad input (ProfileError, RecordingError, DeviceError,
    SensorError).
    """
    if output not in tuple(OutputKind):
        raise NeurotouchError(f"unknown output '{output}' (expected one of: {', '.join(OutputKind)})")
    protocol = options.protocol
    if protocol is not None and output not in (OutputKind.USB, OutputKind.HID):
        raise NeurotouchError(f"--protocol {protocol}: only with --output usb (the USB gadget) or --output hid (UHID)")
    seconds, fast, davis, say, stats = options.seconds, options.fast, options.davis, options.say, options.stats
    finish_gesture = options.finish_gesture
    from neurotouch_hid.sources.serial import camera_serial, own_config

    serial = camera_serial(source, options.serial, davis, say)
    if source == SourceKind.DAVIS and serial is not None:  # reopened after an unplug: the same camera
        from neurotouch_hid.sources.davis import DavisConfig

        davis = replace(davis or DavisConfig(), serial=serial)
    identity = identity_for(serial)
    profile, sensor = own_config(source, serial, profile, options.sensor)
    loaded = load_profile(profile)
    inputs = (None if source in tuple(SourceKind) else source, find_profile(profile), sensor)
    try:
        with EarlyStop() as early, contextlib.ExitStack() as stack:
            try:
                # one loop for every descriptor the run waits on, served by a thread of its own until
                # the run's main thread takes it over (a first run's compile: the devices answer meanwhile)
                loop = Loop()
                stack.callback(loop.close)
                loop.run_in_thread("nt-loop")
                copilot = copilot_relay(output, say, loop)
                first = None if copilot is None else copilot.merge_for(loaded)
                if first is not None:  # before the pad or target device exists: games list one controller
                    stack.callback(first.stop)
                    first.grab()
                subscribers = None if options.outputs is None else list(options.outputs)
                if subscribers is None:
                    try:
                        made = open_output(
                            output,
                            loaded,
                            stack,
                            out=options.out,
                            console=options.console,
                            say=say,
                            inputs=inputs,
                            on_feedback=copilot,
                            protocol=protocol,
                            identity=identity,
                            loop=loop,
                        )
                    except DeviceError as exc:
                        raise DeviceError(_and_the_source(str(exc), source, davis)) from None
                    subscribers = open_outputs(made, output, stack, options.console)
                say = said_above(subscribers, say)
                assembly = RunAssembly(
                    source,
                    seconds=seconds,
                    window_us=options.window_us,
                    method=options.method,
                    fast=fast,
                    sensor=sensor,
                    seed=options.seed,
                    davis=davis,
                    wait=options.wait,
                    capture=options.capture,
                    say=say,
                    model=options.model,
                    finish_gesture=finish_gesture,
                )
                options = RunOptions(
                    mode=RunMode.of(pace=not fast, waits=source == SourceKind.SIM),
                    profile_ref=profile,
                    say=say,
                    stats=stats,
                    max_lag_us=options.max_lag_us,
                    merge=first,
                    merge_for=None if copilot is None else copilot.merge_for,
                    early_stop=early,
                    loop=loop,
                )
                return run_assembled(
                    assembly,
                    loaded,
                    subscribers,
                    None if finish_gesture else seconds,  # the source ends it, at rest
                    options,
                    serve=lambda engine: served(engine, profile, serial=serial, games=not fast),
                )
            finally:  # the way out (devices neutral, grabs let go) is not cut short by a SIGTERM
                early.quiet()
    except StopRequested:
        say("stopped (SIGTERM) before the run started: every output released")
        return stats if stats is not None else RunStats()


def copilot_relay(output: str, say: Callable[[str], None], loop: Loop | None = None) -> FeedbackRelay | None:
    """What merges a profile's ``copilot:`` devices into the controller and forwards the rumble
    any target receives to them (:class:`~neurotouch_hid.inputs.copilot.FeedbackRelay`): for every
    device output (:data:`DEVICE_OUTPUTS`: the uinput pad, the UHID device, the USB gadget); None
    for the views; the merged devices wait on ``loop`` (None: each copilot a thread of its own).
    Puts back first the nodes a driver that did not stop cleanly left hidden
    (:func:`~neurotouch_hid.inputs.hide.put_back_stale`)."""
    from neurotouch_hid.inputs.hide import put_back_stale

    put_back_stale(say)
    if output not in DEVICE_OUTPUTS:
        return None
    from neurotouch_hid.inputs.copilot import FeedbackRelay

    return FeedbackRelay(say=say, loop=loop)


def _and_the_source(problem: str, source: str, davis: DavisConfig | None) -> str:
    """The gamepad cannot be made (``problem``, /dev/uinput's): with the live camera, whether it
    can be opened either (the user learns both problems at once, not the second after fixing
    the first); with any other source, that ``--output term`` shows the pad in the terminal."""
    if source == SourceKind.DAVIS:
        from neurotouch_hid.sources.discovery import UsbAccess, discover, explain

        found = discover(dv=False)  # pyusb only: quick, and says what keeps a camera from being opened
        if not any(c.usb is not None and c.usb.access == UsbAccess.OK for c in found.davis346):
            serial = davis.serial if davis is not None else None
            return f"{problem}\nand the camera: {explain(found, serial)}"
        return problem
    return f"{problem}\nor, without the virtual pad, show it in the terminal: --output term"


def said_above(subscribers: list[Subscriber], say: Callable[[str], None]) -> Callable[[str], None]:
    """Where a run's lines for the user go (the first run's compile, a camera lost and back):
    while a terminal view draws on a terminal, through it, above the view
    (:meth:`~neurotouch_hid.views.term.TermView.say`); else ``say``."""
    from neurotouch_hid.views.term import TermView

    for subscriber in subscribers:
        if isinstance(subscriber, TermView) and subscriber.console.is_terminal:
            return subscriber.say
    return say


def gamepad_or_terminal(
    profile: Profile,
    stack: contextlib.ExitStack,
    *,
    console: Console | None = None,
    say: Callable[[str], None] = print,
) -> list[Subscriber]:
    """The virtual gamepad where /dev/uinput is writable (with the live view beside it on a
    terminal); else the terminal view, after saying why in one line (``say``)."""
    try:
        return open_outputs(open_output("gamepad", profile, stack), "gamepad", stack, console)
    except DeviceError as exc:
        reason = str(exc).splitlines()[0]  # the why; the fix's lines follow (udev.uinput_help)
        say(
            f"no writable /dev/uinput ({reason}): showing the gamepad in the terminal instead; "
            "see `neurotouch-hid doctor`"
        )
        return [open_output("term", profile, stack, console=console)]


def run_demo(
    seconds: float | None = 30.0, *, console: Console | None = None, say: Callable[[str], None] = print
) -> RunStats:
    """``neurotouch-hid demo``: the simulated gel performing every gesture, paced in real time,
    through the default profile, to the virtual gamepad (or the terminal view, see
    :func:`gamepad_or_terminal`); past ``seconds`` the hand finishes its gesture, so that the
    demo ends with the gel at rest."""
    profile = load_profile("default")
    with contextlib.ExitStack() as stack:
        outputs = gamepad_or_terminal(profile, stack, console=console, say=say)
        return run_driver(
            "sim",
            "default",
            "gamepad",
            DriverOptions(seconds=seconds, console=console, outputs=outputs, finish_gesture=True),
        )
