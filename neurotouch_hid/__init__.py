"""neurotouch-hid: the NeuroTouch soft tactile sensor as a standard Linux game controller.

The method is Hoffmann et al., "From Soft Materials to Controllers with NeuroTouch: A Neuromorphic
Tactile Sensor for Real-Time Gesture Recognition" (the paper); section names cited in docstrings
refer to it, and docs/architecture.md sums up what the code takes from each section.
"""

__version__ = "0.1.0"

# Before any module with numba-compiled code is imported: where numba may cache it (a read-only
# install or home must not stop the driver; see service/jit_cache.py).
from neurotouch_hid.service import jit_cache as _jit_cache  # noqa: E402

_jit_cache.configure()
