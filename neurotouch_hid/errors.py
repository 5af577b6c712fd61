"""The errors neurotouch-hid raises on bad input.

Every error a user can cause (a broken recording, a bad profile, a missing camera or
/dev/uinput) is a :class:`NeurotouchError` whose message says what is wrong, where, and what
to do. The CLI prints the message and exits with code 2; it never shows a traceback for them.
"""


class NeurotouchError(Exception):
    """Base class of the errors a user can cause and fix; the message is for the user."""


class RecordingError(NeurotouchError):
    """An AEDAT4 recording cannot be read or written (names the file and what is wrong)."""


class SensorError(NeurotouchError):
    """A sensor.yaml is missing or invalid, or no gel is in view."""


class DatasetError(NeurotouchError):
    """A dataset folder does not follow docs/dataset.md."""


class ProfileError(NeurotouchError):
    """A gamepad profile is invalid (names file, line, field, value found, what was expected)."""


class DeviceError(NeurotouchError):
    """The camera or /dev/uinput cannot be opened (says how to fix it, e.g. the udev rule)."""
