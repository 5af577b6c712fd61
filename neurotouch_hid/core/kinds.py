"""The closed sets of choices the command line offers, as ``str`` enums (typer makes its choices
from them; the driver compares against them). A module of its own, with nothing to import, so
that the CLI can name them without loading the driver's stages.
"""

from __future__ import annotations

from enum import StrEnum


class OutputKind(StrEnum):
    """Where ``run`` sends the controller states (``--output``)."""

    GAMEPAD = "gamepad"  #: the uinput pad (and the keyboard and mouse a profile uses)
    HID = "hid"  #: the generic HID joystick on UHID (the keyboard and mouse stay on uinput)
    USB = "usb"  #: a USB gadget for the host at the other end of the cable (``--protocol``)
    JSONL = "jsonl"  #: one JSON line per state change (``--out`` or stdout)
    TERM = "term"  #: the terminal view


class SourceKind(StrEnum):
    """The named sources of ``--source``; any other value is a file (AEDAT4 or predictions)."""

    DAVIS = "davis"  #: the live DAVIS-346
    SIM = "sim"  #: the simulated gel


class MethodKind(StrEnum):
    """The gesture pipeline's methods (``--method``; ``pipeline.methods`` maps each to its code)."""

    DEFAULT = "default"  #: the product (docs/method.md, "Overview")
    PAPER = "paper"  #: the paper's method exactly (docs/method.md, "The paper's method")
