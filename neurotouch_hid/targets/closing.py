"""What every device of this machine does when it goes: its neutral report first, then a pause
for readers to take it, then the device removed (the uinput pad, keyboard and mouse, the UHID
device).

Source: Documentation/input/uinput.rst and Documentation/hid/uhid.rst (destroying a device drops
what its readers had not read yet: evdev answers a reader's read() with ENODEV).
"""

from __future__ import annotations

import threading
import time

#: Pause between the neutral report and destroying the device (s): once a device is gone, evdev
#: answers a reader's read() with ENODEV and drops what it had not read yet, so a game polling
#: every frame must get the chance to read the release.
RELEASE_GRACE_S = 0.05


class NeutralOnClose:
    """``close()`` for a device: neutralise it, wait :data:`RELEASE_GRACE_S` so readers see the
    release, then ``_destroy()`` it. Idempotent; never leaves a key, button or axis held, even if
    neutralising fails. Subclasses set ``_lock`` (an RLock) and ``_closed`` and define
    ``neutralise()`` and ``_destroy()``."""

    _lock: threading.RLock
    _closed: bool

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            try:
                self.neutralise()
                time.sleep(RELEASE_GRACE_S)
            finally:
                self._closed = True
                self._destroy()
