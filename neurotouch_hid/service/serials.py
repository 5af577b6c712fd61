"""Camera serials, and each camera's own config folder.

A camera (a DAVIS-346, or the simulated one given ``--serial``) is known by its serial. With two
gels on one machine (two players, or one gel per hand), each camera may have a folder of its own
in the user's config folder (docs/several-sensors.md)::

    ~/.config/neurotouch-hid/                 (platformdirs.user_config_dir("neurotouch-hid"))
        sensor.yaml  games.yaml  profiles/    shared by every camera
        sensors/SERIAL/sensor.yaml            that camera's calibration
        sensors/SERIAL/profile.yaml           the profile it starts with (a profile file)
        sensors/SERIAL/games.yaml             its per-game table

Each file there replaces the shared one for that camera only; a file it does not have is the
shared one (:func:`sensor_file`). Nothing here creates a file.

A serial names a device link (``/dev/neurotouch-SERIAL``), a systemd instance
(``neurotouch-hid@SERIAL.service``), a folder and a socket, so it is made of letters, digits
and ``_`` (:func:`check_serial`).
"""

from __future__ import annotations

import re
from pathlib import Path

#: Longest serial taken (characters). A DAVIS camera's is 8 (libcaer's
#: ``SERIAL_NUMBER_MAX_LENGTH``); 32 keeps ``phys`` ("neurotouch-hid/SERIAL/keyboard") under the
#: kernel's 64 bytes and the USB serial string short.
MAX_SERIAL_CHARS = 32
#: A serial: ASCII letters, digits and ``_``. No ``-``: systemd escapes it in a device unit's
#: name (``/dev/neurotouch-A-1`` is ``dev-neurotouch\x2dA\x2d1.device``) but not in an instance
#: name, so the templated unit could not bind to its camera; and it never reads as an option.
SERIAL_PATTERN = re.compile(r"[A-Za-z0-9_]+")
#: The folder of per-camera folders, in the user's config folder.
SENSORS_FOLDER = "sensors"
#: The files a camera's folder may hold, each replacing the shared one of the same role:
#: role -> file name in ``sensors/SERIAL/``.
SENSOR_FILES = {"sensor": "sensor.yaml", "profile": "profile.yaml", "games": "games.yaml"}


def check_serial(serial: str) -> str:
    """``serial`` if it can name a camera's devices, links, service instance and config folder.

    Args:
        serial: a camera serial (``str``), e.g. ``"00000499"``.

    Returns:
        ``serial`` unchanged.

    Raises:
        ValueError: empty, longer than :data:`MAX_SERIAL_CHARS`, or with a character other
            than ASCII letters, digits and ``_``; the message quotes it.
    """
    if not isinstance(serial, str):
        raise ValueError(f"a camera serial is text, got {type(serial).__name__}")
    if not serial:
        raise ValueError("a camera serial is empty; expected letters, digits or '_'")
    if len(serial) > MAX_SERIAL_CHARS:
        raise ValueError(f"camera serial {serial[:40]!r}... has {len(serial)} characters; at most {MAX_SERIAL_CHARS}")
    if not SERIAL_PATTERN.fullmatch(serial):
        raise ValueError(
            f"camera serial {serial!r} has a character other than letters, digits and '_'; "
            "it names a device link, a service and a folder"
        )
    return serial


def config_dir() -> Path:
    """The user's config folder: ``platformdirs.user_config_dir("neurotouch-hid")``
    (``$XDG_CONFIG_HOME/neurotouch-hid`` on Linux)."""
    import platformdirs

    return Path(platformdirs.user_config_dir("neurotouch-hid"))


def sensor_dir(serial: str) -> Path:
    """The folder of the camera ``serial``'s own config: ``config_dir()/sensors/SERIAL`` (it may
    not exist). Raises ValueError for an invalid serial (:func:`check_serial`)."""
    return config_dir() / SENSORS_FOLDER / check_serial(serial)


def own_file(serial: str | None, role: str) -> Path | None:
    """The camera's own file for ``role`` (``"sensor"``, ``"profile"``, ``"games"``:
    :data:`SENSOR_FILES`) when ``serial`` is given and the file exists, else None (the shared one
    applies). Raises ValueError for an invalid serial, KeyError for an unknown role."""
    name = SENSOR_FILES[role]
    if serial is None:
        return None
    path = sensor_dir(serial) / name
    return path if path.exists() else None


def sensor_file(serial: str | None, role: str, shared: Path) -> Path:
    """The file a camera uses for ``role``: its own (:func:`own_file`) if it has one, else
    ``shared`` (the file every camera uses)."""
    own = own_file(serial, role)
    return own if own is not None else shared


def own_path(serial: str, role: str) -> Path:
    """Where the camera ``serial``'s own file for ``role`` goes (a command that writes it:
    ``calibrate --serial``, ``profile auto add --serial``), its folder made. Raises ValueError for
    an invalid serial, KeyError for an unknown role, OSError when the folder cannot be made."""
    folder = sensor_dir(serial)
    folder.mkdir(parents=True, exist_ok=True)
    return folder / SENSOR_FILES[role]


def configured_serials() -> list[str]:
    """The serials that have a folder of their own under ``config_dir()/sensors`` (folders whose
    name is no valid serial are left out), sorted."""
    folder = config_dir() / SENSORS_FOLDER
    if not folder.is_dir():
        return []
    found = []
    for entry in folder.iterdir():
        if entry.is_dir() and len(entry.name) <= MAX_SERIAL_CHARS and SERIAL_PATTERN.fullmatch(entry.name):
            found.append(entry.name)
    return sorted(found)
