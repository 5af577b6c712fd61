"""The optional extras: what the commands outside the driver need, and what to install when it is missing.

The driver (``run``, ``track``, ``eval`` without ``--report``) needs neither plots nor video:

* ``plots``: matplotlib, for ``eval --report`` and ``profile test --plot``;
* ``video``: Pillow (gif) and imageio with imageio-ffmpeg (mp4, through an ffmpeg program:
  its own, or the system's ``ffmpeg`` when the package carries none, as the .deb's), for
  ``view --out FILE.gif`` / ``FILE.mp4``;
* ``uinput``: python-evdev where its precompiled twin evdev-binary has no wheel (aarch64), for the
  uinput devices (``run --output gamepad``, the keyboard and mouse beside ``--output hid``).

:func:`require` is called before the work starts, so a missing extra costs nothing but one line.
"""

from __future__ import annotations

import importlib

from neurotouch_hid.core.errors import NeurotouchError

#: Each extra's import names and their distributions (``pyproject.toml``'s optional dependencies).
EXTRAS: dict[str, dict[str, str]] = {
    "plots": {"matplotlib": "matplotlib"},
    "video": {"imageio": "imageio", "imageio_ffmpeg": "imageio-ffmpeg", "PIL": "pillow"},
    "uinput": {"evdev": "evdev"},
}

#: Debian's package for each import name, for a system Python.
DEBIAN: dict[str, str] = {
    "matplotlib": "python3-matplotlib",
    "imageio": "python3-imageio",
    "PIL": "python3-pil",
    "evdev": "python3-evdev",
}


class MissingExtraError(NeurotouchError):
    """An optional extra (or the ffmpeg program) that a command needs is not installed; the message
    says which and the install command for pipx, pip and Debian."""


def missing_message(extra: str, what: str, module: str) -> str:
    """The one line naming what ``what`` needs and how to install it (pipx, pip, Debian)."""
    dists = " ".join(EXTRAS[extra].values())
    line = (
        f"{what} needs {EXTRAS[extra][module]}, which is not installed (the optional extra [{extra}]): "
        f"pipx inject neurotouch-hid {dists}, or pip install 'neurotouch-hid[{extra}]'"
    )
    if module in DEBIAN:
        line += f" (for Debian's own python3: sudo apt install {DEBIAN[module]})"
    return line


def require(extra: str, what: str, modules: tuple[str, ...] | None = None) -> None:
    """Import the modules of ``extra`` (all of them, or only ``modules``) or say what to install.

    Args:
        extra: a key of :data:`EXTRAS` (``plots``, ``video``).
        what: what needs it, as the user typed it (``eval --report``), for the message.
        modules: import names of the extra to check; None = all of the extra's.
    Raises:
        MissingExtraError: a module cannot be imported; the message names the extra and the
            commands that install it.
    """
    for module in modules if modules is not None else tuple(EXTRAS[extra]):
        try:
            importlib.import_module(module)
        except ImportError:
            raise MissingExtraError(missing_message(extra, what, module)) from None


def require_ffmpeg(what: str) -> None:
    """The ``video`` extra and an ffmpeg program it can run (imageio-ffmpeg's own, else ``ffmpeg`` on PATH).

    Raises:
        MissingExtraError: the extra is missing, or no ffmpeg program runs (the .deb carries
            imageio-ffmpeg without its own ffmpeg and recommends Debian's).
    """
    require("video", what)
    import imageio_ffmpeg

    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError:
        raise MissingExtraError(
            f"{what} needs an ffmpeg program, and none runs: sudo apt install ffmpeg (Debian, Ubuntu), "
            "or set IMAGEIO_FFMPEG_EXE to one"
        ) from None
