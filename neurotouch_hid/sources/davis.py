"""The live DAVIS-346 event camera inside the NeuroTouch gel, through dv-processing.

dv-processing 2.0.4 opens cameras with ``dv_processing.io.camera.discover()`` and
``dv_processing.io.camera.open()`` (its libusb-based DAVIS driver; the ``CameraCapture`` class of
older releases became this module). This module turns the camera's event batches and APS frames
into the stream every source yields (ARCHITECTURE.md, sources).
"""

from __future__ import annotations

import time
from typing import Iterator

from neurotouch_hid.errors import DeviceError
from neurotouch_hid.sources import Frame, StreamItem
from neurotouch_hid.sources.recording import (
    DAVIS346_RESOLUTION,
    DV_ERRORS,
    dv_error_text,
    events_from_store,
    grey_image,
    split_batches,
)

#: USB vendor:product of a DAVIS-346 (iniVation FX3 boards).
DAVIS_USB_ID = "152a:841a"
_FIX = (f"plug the DAVIS-346 in, check that `lsusb` lists {DAVIS_USB_ID}, and see "
        f"`neurotouch-hid doctor` for the udev rule that gives your user access to it")
#: Pause between polls when the camera has nothing new, s (well under one 1 ms batch).
_IDLE_SLEEP_S = 0.0002


class DavisSource:
    """A live DAVIS-346: events and APS frames as they arrive.

    Args:
        serial: the camera's serial number, or None for the first DAVIS found.
        require_resolution: (width, height) px the camera must have (a DAVIS-346: 346x260).

    Raises:
        DeviceError: no camera found, the camera cannot be opened (permissions: the udev rule),
            or it has another resolution. The message says how to fix it.

    Use as a context manager (or call :meth:`close`) to release the camera.
    """

    def __init__(self, serial: str | None = None,
                 require_resolution: tuple[int, int] | None = DAVIS346_RESOLUTION) -> None:
        import dv_processing as dv

        try:
            found = dv.io.camera.discover()
        except DV_ERRORS as exc:
            raise DeviceError(f"cannot search for a DAVIS camera ({dv_error_text(str(exc))}): {_FIX}") from None
        if serial is not None:
            found = [d for d in found if d.serialNumber == serial]
        if not found:
            which = f"with serial number {serial} " if serial is not None else ""
            raise DeviceError(f"no DAVIS camera {which}found: {_FIX}")
        try:
            self._camera = dv.io.camera.open(found[0])
        except DV_ERRORS as exc:
            raise DeviceError(f"cannot open the DAVIS camera {found[0].serialNumber} "
                              f"({dv_error_text(str(exc))}): {_FIX}") from None
        self.camera_name: str = self._camera.getCameraName()
        resolution = self._camera.getEventResolution()
        self.width, self.height = (int(resolution[0]), int(resolution[1])) if resolution else (0, 0)
        if require_resolution is not None and (self.width, self.height) != tuple(require_resolution):
            raise DeviceError(f"camera {self.camera_name} is {self.width}x{self.height} px, but NeuroTouch "
                              f"needs a DAVIS-346 ({require_resolution[0]}x{require_resolution[1]})")
        self.has_frames: bool = bool(self._camera.isFrameStreamAvailable())

    def __enter__(self) -> "DavisSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the camera and release its USB device (dv-processing does so when it is dropped)."""
        self._camera = None

    def stream(self, seconds: float | None = None, batch_us: int = 1000) -> Iterator[StreamItem]:
        """Event batches and APS frames as the camera delivers them, until ``seconds`` have passed.

        Yields the same kinds of items as :meth:`RecordingReader.stream`: event batches (EVENT_DTYPE,
        time-ordered, cut at every multiple of ``batch_us`` us, never empty) and :class:`Frame`
        values (uint8 (260, 346), ``t_us`` as the camera stamps it). Unlike a recording, nothing is
        held back to keep latency low: a frame is yielded when its readout completes, so events
        stamped during its exposure may have been yielded before it.

        Raises:
            DeviceError: the camera stops (unplugged) before ``seconds`` are over.
        """
        camera = self._camera
        if camera is None:
            raise DeviceError(f"the DAVIS camera {self.camera_name} was closed")
        deadline = None if seconds is None else time.monotonic() + seconds
        while deadline is None or time.monotonic() < deadline:
            if not camera.isRunning():
                raise DeviceError(f"the DAVIS camera {self.camera_name} stopped (unplugged?): {_FIX}")
            idle = True
            frame = camera.getNextFrame() if self.has_frames else None
            if frame is not None:
                idle = False
                yield Frame(int(frame.timestamp), grey_image(frame.image))
            store = camera.getNextEventBatch()
            if store is not None and len(store):
                idle = False
                yield from split_batches(events_from_store(store), batch_us)
            if idle:
                time.sleep(_IDLE_SLEEP_S)
