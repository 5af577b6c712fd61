"""The live DAVIS-346 event camera inside the NeuroTouch gel, through dv-processing.

dv-processing 2.0.4 opens cameras with ``dv_processing.io.camera.discover()`` and
``dv_processing.io.camera.open(descriptor)`` (its libusb-based DAVIS driver; the ``CameraCapture``
class of older releases became this module). This module turns the camera's event batches and APS
frames into the stream every source yields (docs/architecture.md, sources), and keeps that stream
alive through faults:

* **No camera at start**: :class:`DavisSource` raises :class:`~neurotouch_hid.core.errors.DeviceError`
  with what to do (``sources/discovery.py`` says whether a 152a:841a device is on USB at all, or
  present but not accessible and which udev rule to install). dv-processing's own ``open()`` with
  no camera raises a raw IndexError; we never call it without a descriptor from ``discover()``.
  ``wait=True`` waits for a camera instead.
* **Unplugged, failing or stalled mid-run** (``stream(reconnect=True)``): the stream yields a
  :class:`~neurotouch_hid.sources.SourceStatus` ``"lost"`` at once, retries with exponential
  back-off (:func:`backoff_delays`), and yields ``"resumed"`` before the first data of the camera
  that came back. A stream without data for ``stall_timeout_s`` is treated like an unplug (the
  camera is closed and opened again). Without ``reconnect`` a fault raises DeviceError.
* **A consumer slower than the camera**: one poll takes everything queued, up to 64 event packets
  and 8 APS frames, each frame placed before the events at or after its timestamp
  (:func:`in_time_order`): the frames do not fall behind the events.
* **Events as soon as they reach the host**: dv-processing opens a DAVIS with a 10 ms data commit
  interval (``getTimeInterval``; libcaer's packet container interval: the events a USB transfer
  brings reach the queue this source polls only once an event passes the interval), so events
  waited up to 10 ms on the host, about 5 ms on average, before the source saw them. The source
  sets it to :data:`COMMIT_INTERVAL_US` (1 ms, the early packet delay's) when it opens the camera
  (``DavisConfig.commit_interval_us``: ``record``, for which latency does not count, keeps 10 ms,
  whose batches fill the driver's queue with ten times the camera time).
* **A resting gel**: while the stream's consumer says the gel rests
  (:attr:`~neurotouch_hid.sources.PollPause.resting`), the camera's USB early packet delay (how
  long data that does not fill a USB transfer waits in the camera's FX3) and dv-processing's data
  commit interval are the resting windows' length, at most :data:`REST_EARLY_PACKET_DELAY_US` and
  :data:`REST_COMMIT_INTERVAL_US`, instead of :data:`EARLY_PACKET_DELAY_US` and
  :data:`COMMIT_INTERVAL_US`: a resting gel's noise events come in one short transfer a window,
  not one a millisecond, the host's reader wakes as often, and its queue gets one batch a window.
  Meanwhile a poll that brings nothing waits for the camera's
  next transfer (the last one's arrival + that delay), not only for the window's end: polls
  before it would find nothing. At the first window that does not rest both are set back, from
  the source's thread at its next poll (what the camera held then goes at once).

The capture interface
---------------------
The source uses a small part of dv-processing's camera API, so that tests can drive it with a
replay of AEDAT4 recordings (tests/camera_replay.py) instead of a camera:

* a *backend* with ``discover() -> list[descriptor]`` and ``open(descriptor) -> camera``
  (``dv_processing.io.camera`` itself is the real one); a descriptor has ``serialNumber`` (str)
  and ``cameraModel`` (``dv_processing.io.camera.CameraModel``);
* a *camera* with ``getCameraName()``, ``getEventResolution()`` ((width, height) or None),
  ``isFrameStreamAvailable()``, ``isRunning()``, ``getNextEventBatch()`` (None or an event store
  with ``len()`` and ``numpy()``), ``getNextFrame()`` (None or a frame with ``timestamp`` (us) and
  ``image`` (uint8)), ``setTimeInterval`` (the data commit interval; dv-processing
  ``io.camera.CameraInputBase``) and, on a DAVIS, ``setFrameInterval``, ``setExposureDuration``,
  ``setAutoExposure`` and ``setUSBEarlyPacketDelay`` (dv-processing ``io.camera.DAVIS``; all
  durations as ``datetime.timedelta``).
"""

from __future__ import annotations

import datetime
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import numpy as np

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.sources import Frame, PausingStream, PollPause, SourceStatus, StatusKind, StreamItem
from neurotouch_hid.sources.dv import DV_ERRORS, dv_error_text, events_from_store
from neurotouch_hid.sources.recording import DAVIS346_RESOLUTION, grey_image, split_batches

#: Pause between polls when the camera has nothing new, s (well under one 1 ms batch).
_IDLE_SLEEP_S = 0.0002
#: Event batches read in one poll at most: everything the camera has queued, so that a slow
#: consumer catches up instead of letting dv-processing's queue overflow, bounded so that APS
#: frames are still looked at in between.
_MAX_BATCHES_PER_POLL = 64
#: APS frames read in one poll at most: every frame the camera has queued (a third of a second at
#: 25 Hz), so that frames do not fall behind the events when the consumer is slow: read one a poll,
#: they did, and a frame at rest from before a push reached the pipeline in the middle of it.
_MAX_FRAMES_PER_POLL = 8
#: The USB early packet delay (us) dv-processing writes when it opens a DAVIS (libcaer's default:
#: its FX3 sends data that does not fill a transfer after at most 1 ms).
EARLY_PACKET_DELAY_US = 1000
#: The longest early packet delay (us) while the gel rests: one 10 ms window. A touch's first events
#: wait in the camera at most this long; on the families' game sessions that moves no family's
#: dead-zone latency median or p90 (docs/performance.md, "At rest").
REST_EARLY_PACKET_DELAY_US = 10_000
#: dv-processing's data commit interval (us) outside rest, set when the camera is opened (it opens
#: a DAVIS with 10 ms): events reach the source's polls at most this long after the USB transfer
#: that brought them, as the early packet delay lets a transfer wait in the camera.
COMMIT_INTERVAL_US = 1000
#: The longest data commit interval (us) while the gel rests: one 10 ms window, dv-processing's own
#: default, so that a resting gel's data reach the host's queue as before, one batch a window.
REST_COMMIT_INTERVAL_US = 10_000
#: While the gel rests, a poll that brings nothing waits at least until the camera's next transfer
#: is due: the last data's arrival + the early packet delay in force + this much (s). The FX3 sends
#: a short transfer once its oldest data waited the delay, and that wait starts with the first event
#: after the previous transfer, so transfers come a little more than a delay apart: waking at the
#: delay itself polls too early about every time, then again (docs/performance.md, "At rest").
_TRANSFER_MARGIN_S = 0.001
#: dv-processing camera models that are DAVIS cameras (events + APS frames).
_DAVIS_MODELS = ("DAVIS", "DAVIS_GEN2")


def in_time_order(frames: list[Frame], batches: list[np.ndarray]) -> list[StreamItem]:
    """One poll's items in camera time: each frame before the events at or after its timestamp,
    as a recording's stream has it (:meth:`~neurotouch_hid.sources.recording.RecordingReader.stream`).

    Args:
        frames: the poll's APS frames, in the order the camera delivered them (``t_us`` increasing).
        batches: its event batches (EVENT_DTYPE, each and all time-ordered), possibly empty.
    Returns:
        The frames and the events cut at the frames' timestamps (views, no copy; empty batches
        left out); without frames, ``batches`` as given (an empty batch still says the camera is
        alive to the stall timer).
    """
    if not frames:
        return list(batches)
    items: list[StreamItem] = []
    k = 0  # the next frame
    for batch in batches:  # cut where a frame falls, views only (no copy of the events)
        ts = batch["timestamp"]
        start = 0
        while k < len(frames) and len(ts) and frames[k].t_us <= ts[-1]:
            cut = int(np.searchsorted(ts, frames[k].t_us, side="left"))
            if cut > start:
                items.append(batch[start:cut])
                start = cut
            items.append(frames[k])
            k += 1
        if start < len(ts):
            items.append(batch[start:])
    items.extend(frames[k:])
    return items


@dataclass(frozen=True)
class DavisConfig:
    """How the live camera is opened, set up and watched.

    Attributes:
        serial: the camera's serial number, or None for the first DAVIS-346 found.
        frame_interval_us: APS frame interval (us); 40,000 = 25 Hz, the paper's frame rate
            (section "System Overview").
        exposure_us: APS exposure (us), fixed so that every frame is thresholded alike (resting
            detection compares frames with the rest reference, paper section "Resting Position
            Detection"); None = the camera's auto-exposure.
        stall_timeout_s: no data (events or frames) for this long (s) counts as a lost camera. A
            DAVIS-346 watching the gel sends APS frames every ``frame_interval_us`` and noise
            events even at rest, so silence means a fault.
        retry_initial_s, retry_max_s: back-off between attempts to open the camera again (s):
            the first wait, doubled after each failure up to the maximum.
        commit_interval_us: dv-processing's data commit interval outside rest (us): events wait
            on the host at most about this long after the USB transfer that brought them. The
            driver's queue holds a number of batches (about 256 in the test kernel), so a longer
            interval holds more camera time for a reader that falls behind: 1 ms (the default,
            :data:`COMMIT_INTERVAL_US`) about 0.3 s, 10 ms about 2.5 s (``record``'s, for which
            latency does not count; docs/performance.md, "Runtime latency").
    """

    serial: str | None = None
    frame_interval_us: int = 40_000
    exposure_us: int | None = 4_000
    stall_timeout_s: float = 1.0
    retry_initial_s: float = 0.25
    retry_max_s: float = 4.0
    commit_interval_us: int = COMMIT_INTERVAL_US

    def __post_init__(self) -> None:
        if not COMMIT_INTERVAL_US <= self.commit_interval_us <= REST_COMMIT_INTERVAL_US:
            raise ValueError(
                f"data commit interval must be {COMMIT_INTERVAL_US}-{REST_COMMIT_INTERVAL_US} us, "
                f"got {self.commit_interval_us} us"
            )
        if self.frame_interval_us <= 0:
            raise ValueError(f"frame interval must be positive, got {self.frame_interval_us} us")
        if self.exposure_us is not None and not 0 < self.exposure_us <= self.frame_interval_us:
            raise ValueError(
                f"exposure must be positive and at most the frame interval "
                f"({self.frame_interval_us} us), got {self.exposure_us} us"
            )
        if self.stall_timeout_s <= 0:
            raise ValueError(f"stall timeout must be positive, got {self.stall_timeout_s} s")
        if not 0 < self.retry_initial_s <= self.retry_max_s:
            raise ValueError(
                f"retry back-off needs 0 < initial <= maximum, got {self.retry_initial_s} s and {self.retry_max_s} s"
            )


def _set_us(camera: Any, setter: str, value_us: int) -> None:
    """``camera.SETTER(timedelta(value_us))`` when the camera has that setter (a DAVIS has them
    all; the capture interface's other cameras may lack one). Raises what dv-processing raises."""
    method = getattr(camera, setter, None)
    if method is not None:
        method(datetime.timedelta(microseconds=value_us))


def _try_set_us(camera: Any, setter: str, value_us: int) -> None:
    """:func:`_set_us`, a failure left for the next poll to find (an unplug shows there; until then
    the camera sends as it did)."""
    try:
        _set_us(camera, setter, value_us)
    except DV_ERRORS:
        pass


def backoff_delays(initial_s: float, maximum_s: float) -> Iterator[float]:
    """The waits (s) between reconnection attempts: ``initial_s``, doubled each time, capped at
    ``maximum_s``; endless."""
    delay = initial_s
    while True:
        yield delay
        delay = min(delay * 2.0, maximum_s)


def _fix_hint(serial: str | None, problems: str | None = None) -> str:
    """What to do when no usable camera is found (sources/discovery.py looks at the USB bus):
    one line that also carries ``problems`` (why the cameras that were tried could not be used)."""
    from neurotouch_hid.sources.discovery import explain_no_camera

    hint = explain_no_camera(serial, error=problems)
    if problems and problems not in hint:
        hint = f"{problems}: {hint}"
    return f"{hint}; `neurotouch-hid devices` lists what is plugged in"


def require_camera_listed(config: "DavisConfig | None" = None, backend: Any = None) -> None:
    """Fail now, before a first run's compile (about 30 s), when dv-processing lists no DAVIS-346
    (with ``config.serial``, that one): only a look at what is plugged in, nothing opened
    (:class:`DavisSource` opens it later and says what else can be wrong).

    Raises:
        DeviceError: none listed, with the fix (sources/discovery.py looks at the USB bus).
    """
    if backend is None:
        import dv_processing as dv

        backend = dv.io.camera
    serial = config.serial if config is not None else None
    found = _listed(backend, serial)
    if isinstance(found, str):
        raise DeviceError(_fix_hint(serial, found))
    if not found:
        raise DeviceError(_fix_hint(serial))


def _listed(backend: Any, serial: str | None) -> list | str:
    """The DAVIS-346 descriptors dv-processing lists (``backend.discover()``; with ``serial``,
    that one only), or why it could not search."""
    try:
        found = backend.discover()
    except DV_ERRORS as exc:
        return f"cannot search for a DAVIS camera ({dv_error_text(str(exc))})"
    found = [d for d in found if getattr(d.cameraModel, "name", "") in _DAVIS_MODELS]
    return [d for d in found if serial is None or d.serialNumber == serial]


class DavisSource:
    """A live DAVIS-346: events and APS frames as they arrive, through unplugs and stalls.

    Args:
        config: which camera, its frame interval and exposure, the stall timeout and back-off.
        wait: do not fail when no camera can be opened now: :meth:`stream` (with
            ``reconnect=True``) waits for one.
        backend: the capture backend (module docstring); None = ``dv_processing.io.camera``.
        noise_filter: an :class:`~neurotouch_hid.pipeline.noise.EventNoiseFilter` run on the
            camera's own event stores before they become numpy batches (no copy: the pipeline's
            noise filter then stays off, ``engine.assembly.build_pipeline``), or None.
        clock, sleep: the monotonic clock (s) that times the stream, stalls and outages, and how
            to wait on it; ``time.monotonic`` and ``time.sleep``, or a clock a test controls
            together with ``backend``.

    Raises:
        DeviceError: (unless ``wait``) no DAVIS camera can be opened: none on USB, no permission
            (the udev rule), another resolution than 346x260. The message says how to fix it.

    Use as a context manager (or call :meth:`close`) to release the camera.
    """

    def __init__(
        self,
        config: DavisConfig | None = None,
        *,
        wait: bool = False,
        backend: Any = None,
        noise_filter: Any = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if backend is None:
            import dv_processing as dv

            backend = dv.io.camera
        self.config = config or DavisConfig()
        self._backend = backend
        self._noise = noise_filter
        self._clock, self._sleep = clock, sleep
        self._camera: Any = None
        self._early_packet_delay_us = EARLY_PACKET_DELAY_US  # as the open camera has it
        self._commit_interval_us = self.config.commit_interval_us  # likewise
        self.camera_name: str | None = None
        self.has_frames = False
        if not wait:
            self._open_or_raise()

    def __enter__(self) -> "DavisSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the camera and release its USB device (dv-processing does so when it is dropped)."""
        self._camera = None

    # --- opening ------------------------------------------------------------------------------
    def _open_or_raise(self) -> None:
        """Open the first usable DAVIS-346 (or the one with ``config.serial``) and set it up.

        Raises DeviceError (with the fix, from a look at the USB bus) when none can be opened."""
        problems = self._try_open()
        if problems is not None:
            raise DeviceError(_fix_hint(self.config.serial, "; ".join(problems) or None))

    def _try_open(self) -> list[str] | None:
        """Open and set up the first usable DAVIS-346: None on success, else why each camera
        dv-processing listed could not be used (empty: none was listed). Cheap enough to retry
        in a loop: it explains nothing (:meth:`_open_or_raise` does, for the user)."""
        found = _listed(self._backend, self.config.serial)
        if isinstance(found, str):
            return [found]
        problems = []
        for descriptor in found:
            try:
                camera = self._backend.open(descriptor)
            except DV_ERRORS as exc:
                problems.append(f"cannot open {descriptor.serialNumber} ({dv_error_text(str(exc))})")
                continue
            resolution = camera.getEventResolution()
            size = (int(resolution[0]), int(resolution[1])) if resolution else (0, 0)
            if size != DAVIS346_RESOLUTION:
                problems.append(
                    f"{camera.getCameraName()} is {size[0]}x{size[1]} px, not a DAVIS-346 "
                    f"({DAVIS346_RESOLUTION[0]}x{DAVIS346_RESOLUTION[1]})"
                )
                continue
            self._configure(camera)
            self._camera = camera
            self._early_packet_delay_us = EARLY_PACKET_DELAY_US
            self._commit_interval_us = self.config.commit_interval_us
            self.camera_name = camera.getCameraName()
            self.has_frames = bool(camera.isFrameStreamAvailable())
            return None
        return problems

    def _configure(self, camera: Any) -> None:
        """The data commit interval (``config.commit_interval_us``), APS frame interval and
        exposure (dv-processing ``io.camera.DAVIS`` setters). Raises what dv-processing raises
        (the camera is then not used)."""
        cfg = self.config
        _set_us(camera, "setTimeInterval", cfg.commit_interval_us)
        if not hasattr(camera, "setFrameInterval"):
            return
        camera.setFrameInterval(datetime.timedelta(microseconds=cfg.frame_interval_us))
        if cfg.exposure_us is None:
            camera.setAutoExposure(True)
        else:
            camera.setAutoExposure(False)
            camera.setExposureDuration(datetime.timedelta(microseconds=cfg.exposure_us))

    def _follow_rest(self, pause: PollPause) -> None:
        """The open camera's USB early packet delay and data commit interval as the gel rests or
        not (module docstring): the resting windows' length, at most
        :data:`REST_EARLY_PACKET_DELAY_US` and :data:`REST_COMMIT_INTERVAL_US`, while ``pause``
        says the gel rests, else :data:`EARLY_PACKET_DELAY_US` and ``config.commit_interval_us``.
        A camera that refuses is left as it is (it then sends and commits as before)."""
        window_us = pause.resting_window_us()
        camera = self._camera
        if camera is None:
            return
        commit = self.config.commit_interval_us
        if window_us is None:
            delay = EARLY_PACKET_DELAY_US
        else:
            delay = max(EARLY_PACKET_DELAY_US, min(window_us, REST_EARLY_PACKET_DELAY_US))
            commit = max(commit, min(window_us, REST_COMMIT_INTERVAL_US))
        if delay != self._early_packet_delay_us:
            self._early_packet_delay_us = delay
            _try_set_us(camera, "setUSBEarlyPacketDelay", delay)
        if commit != self._commit_interval_us:
            self._commit_interval_us = commit
            _try_set_us(camera, "setTimeInterval", commit)

    def _poll_wait(self, pause: PollPause, last_data: float, now: float) -> float:
        """How long (s) a poll that brought nothing waits: ``pause()`` (its consumer's decision,
        which also hands on what it held), and while the gel still rests with the early packet
        delay lengthened, at least until the camera's next transfer is due (the last data's
        arrival ``last_data`` + that delay + :data:`_TRANSFER_MARGIN_S`, clock seconds): a resting
        gel's data come one transfer a delay, not at a window's end, so polls before it find
        nothing. A transfer later than that is polled for as ``pause()`` says. Not once the rest
        ends: the delay is then set back at the next poll."""
        wait = pause()
        delay_us = self._early_packet_delay_us
        if delay_us > EARLY_PACKET_DELAY_US and pause.resting_window_us() is not None:
            wait = max(wait, last_data + delay_us / 1e6 + _TRANSFER_MARGIN_S - now)
        return wait

    # --- reading ------------------------------------------------------------------------------
    def _read(self) -> tuple[list[StreamItem], str | None]:
        """One poll of the camera: ``(items, failure)``; ``failure`` says why the camera is lost."""
        camera = self._camera
        try:
            if not camera.isRunning():
                return [], "stopped (unplugged?)"
            frames: list[Frame] = []
            for _ in range(_MAX_FRAMES_PER_POLL if self.has_frames else 0):  # all, as for the events
                frame = camera.getNextFrame()
                if frame is None:
                    break
                frames.append(Frame(int(frame.timestamp), grey_image(frame.image)))
            stores = []
            for _ in range(_MAX_BATCHES_PER_POLL):  # all the camera has: one a poll falls behind
                store = camera.getNextEventBatch()
                if store is None or not len(store):
                    break
                stores.append(store)
        except DV_ERRORS as exc:
            return [], f"failed ({dv_error_text(str(exc))})"
        batches = []
        for store in stores:
            if self._noise is not None:
                store = self._noise.filter_store(store)
            # a batch of noise only still tells the stream is alive (the stall timer), but none is
            # yielded: nothing would change downstream
            batches.append(events_from_store(store))
        return in_time_order(frames, batches), None

    def stream(self, seconds: float | None = None, batch_us: int = 1000, *, reconnect: bool = False) -> PausingStream:
        """Event batches and APS frames as the camera delivers them, until ``seconds`` have passed.

        Yields the same kinds of items as :meth:`RecordingReader.stream`: event batches (EVENT_DTYPE,
        time-ordered, cut at every multiple of ``batch_us`` us, never empty) and :class:`Frame`
        values (uint8 (260, 346), ``t_us`` as the camera stamps it). Unlike a recording, nothing is
        held back to keep latency low: a frame is yielded when its readout completes, so events
        stamped during its exposure may have been yielded before it.

        With ``reconnect``, faults do not end the stream: it yields
        :class:`~neurotouch_hid.sources.SourceStatus` items (``"waiting"`` when started without a
        camera, ``"lost"`` as soon as the camera stops, fails or stalls, ``"resumed"`` before the
        first data of a camera that is back), retrying with :func:`backoff_delays` in between.

        A poll that brings nothing new waits ``poll_pause()`` (the returned stream's
        :class:`~neurotouch_hid.sources.PollPause`: :data:`_IDLE_SLEEP_S` unless its consumer
        decides; the runtime, while the gel rests, until the next window's end), and while the gel
        rests at least until the camera's next transfer is due (:meth:`_poll_wait`).

        Raises:
            DeviceError: without ``reconnect``, the camera is missing, stops (unplugged), fails or
                stalls before ``seconds`` are over.
        """
        pause = PollPause(_IDLE_SLEEP_S)
        return PausingStream(self._items(seconds, batch_us, reconnect, pause), pause)

    def _items(self, seconds: float | None, batch_us: int, reconnect: bool, pause: PollPause) -> Iterator[StreamItem]:
        """:meth:`stream`'s items."""
        cfg = self.config
        deadline = None if seconds is None else self._clock() + seconds

        def remaining() -> float:
            return float("inf") if deadline is None else deadline - self._clock()

        delays = backoff_delays(cfg.retry_initial_s, cfg.retry_max_s)
        lost_since: float | None = None  # monotonic time the current outage began
        never_opened = self._camera is None
        if self._camera is None:
            if not reconnect:
                self._open_or_raise()
            else:
                lost_since = self._clock()
                yield SourceStatus(
                    StatusKind.WAITING, f"waiting for a DAVIS-346 ({_fix_hint(cfg.serial)}); Ctrl-C stops"
                )
        last_data = self._clock()
        while remaining() > 0:
            if self._camera is None:  # in an outage: try again after the back-off
                if self._try_open() is not None:
                    self._sleep(max(0.0, min(next(delays), remaining())))
                    continue
                last_data = self._clock()
            self._follow_rest(pause)
            items, failure = self._read()
            now = self._clock()
            if items:
                if lost_since is not None:
                    what = "found" if never_opened else "is back"
                    yield SourceStatus(
                        StatusKind.RESUMED,
                        f"camera {self.camera_name} {what} after {now - lost_since:.1f} s; "
                        "the markers are initialised on the first APS frame at rest",
                    )
                    never_opened = False
                    lost_since = None
                    delays = backoff_delays(cfg.retry_initial_s, cfg.retry_max_s)
                last_data = now
                for item in items:
                    if isinstance(item, Frame):
                        yield item
                    else:
                        yield from split_batches(item, batch_us)
                continue
            if failure is None and now - last_data > cfg.stall_timeout_s:
                failure = f"sent no data for {now - last_data:.1f} s (stalled)"
            if failure is None:
                self._sleep(self._poll_wait(pause, last_data, now))
                continue
            name = self.camera_name
            self.close()
            if not reconnect:
                raise DeviceError(
                    f"the DAVIS camera {name} {failure}: check its USB cable, then `neurotouch-hid devices`"
                )
            if lost_since is None:  # a new outage (not a camera that stalled again right after reopening)
                lost_since = now
                yield SourceStatus(
                    StatusKind.LOST,
                    f"camera {name} {failure}: gamepad centred and released; "
                    f"trying to reopen it (back-off up to {cfg.retry_max_s:g} s)",
                )
            self._sleep(max(0.0, min(next(delays), remaining())))
