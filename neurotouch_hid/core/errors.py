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


def nearest(word: str, choices) -> str | None:
    """The choice closest to a mistyped ``word`` (difflib's ratio >= 0.6), or None."""
    import difflib

    found = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1)
    return found[0] if found else None


def did_you_mean(word: str, choices) -> str:
    """``"; did you mean 'X'?"`` for the choice closest to ``word`` (:func:`nearest`), else ``""``."""
    found = nearest(word, choices)
    return f"; did you mean '{found}'?" if found is not None and found != word else ""


#: pydantic's (and typer's, which validates through pydantic) wordings -> the project's.
_LIBRARY_WORDS: tuple[tuple[str, str], ...] = (
    ("Input should be a valid number, unable to parse string as a number", "expected a number"),
    ("Input should be a valid integer, unable to parse string as an integer", "expected a whole number"),
    ("Input should be a finite number", "expected a finite number"),
    ("Input should be a valid boolean, unable to interpret input", "expected true or false"),
)


def in_plain_words(message: str) -> str:
    """A validation message from pydantic in the project's words: no ``Value error,`` prefix,
    ``expected ...`` instead of ``Input should be ...``."""
    message = message.replace("Value error, ", "")
    for library, ours in _LIBRARY_WORDS:
        message = message.replace(library, ours).replace(library[0].lower() + library[1:], ours)
    return message.replace("Input should be ", "expected ").replace("input should be ", "expected ")
