"""The dv-processing layer: what the project needs to talk to iniVation's library.

dv-processing (import ``dv_processing``) is the live camera's driver (libcaer inside) and the
AEDAT4 writer; its event container is the ``EventStore``, ours a numpy array of
:data:`~neurotouch_hid.sources.EVENT_DTYPE`. This module converts between the two and turns the
library's C++ exceptions into one line, for the recording writer (``recording_writer.py``), the live
camera (``davis.py``), discovery (``discovery.py``) and the noise filter (``pipeline/noise.py``).
"""

from __future__ import annotations

import collections
from typing import TYPE_CHECKING

import numpy as np

from neurotouch_hid.sources import EVENT_DTYPE

if TYPE_CHECKING:
    import dv_processing as dv

#: What pybind11 turns dv-processing's C++ exceptions into (std::exception and its kinds).
DV_ERRORS = (RuntimeError, ValueError, IndexError, MemoryError)


def dv_error_text(message: str) -> str:
    """The useful line of a dv-processing exception text (it carries source paths and a stack)."""
    lines = [line for line in message.splitlines() if line.strip() and not line.startswith("/")]
    text = lines[0] if lines else message.splitlines()[0] if message else "unknown error"
    return text.split(" - Error info")[0].strip()


def events_from_store(store: "dv.EventStore") -> np.ndarray:
    """A dv-processing ``EventStore`` as an array of :data:`EVENT_DTYPE` (a copy).

    dv-processing's ``EventStore.numpy()`` has the same fields, padded to 16 bytes per event;
    this packs them into EVENT_DTYPE.
    """
    return store.numpy().astype(EVENT_DTYPE, copy=False)


def store_from_events(events: np.ndarray) -> "dv.EventStore":
    """Build a dv-processing ``EventStore`` from time-ordered events (fields of EVENT_DTYPE).

    dv-processing 2.0.4 has no constructor from numpy, and ``EventStore.numpy()`` returns a
    copy (no writable view), so events go in one ``push_back`` call each, driven by ``map`` over
    column lists: about 3 M events/s (docs/performance.md, "Recording I/O").
    """
    import dv_processing as dv

    store = dv.EventStore()
    columns = (
        events["timestamp"].tolist(),
        events["x"].tolist(),
        events["y"].tolist(),
        events["polarity"].astype(bool).tolist(),
    )
    collections.deque(map(store.push_back, zip(*columns)), maxlen=0)  # consume in C
    return store
