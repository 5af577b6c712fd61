"""The USB boot keyboard: a modifier byte, a reserved byte and six key codes, 8 bytes.

The report is the boot protocol's (HID 1.11, Appendix B.1), so BIOSes, consoles and tablets that
only speak boot protocol read it too; the descriptor is B.1's (with the LED output report),
its key array widened to the Keyboard/Keypad page's usages up to Volume Down (0x81). The layout
is docs/reports.md, "keyboard: the boot keyboard".

Keys come from :attr:`ControllerState.keys` (evdev ``KEY_*`` names), translated by
:data:`USAGES` (HID Usage Tables 1.4, 10 "Keyboard/Keypad Page (0x07)"; the names are the kernel's,
Documentation/input/event-codes.rst). The rule for what a report cannot carry:

* a key with no usage in :data:`USAGES` (media keys beyond volume, ``BTN_*`` mouse buttons) is
  dropped; :func:`unrepresentable` names them, so a target can say so once per profile;
  KEY_SYSRQ and KEY_POWER are left out of :data:`USAGES` on purpose (a host may act on them);
* more than six keys down at once besides the modifiers: every key slot reports ErrorRollOver
  (0x01), the phantom state of HID 1.11 Appendix C, and the modifiers stay as they are.

Sources: Device Class Definition for HID 1.11 (usb.org), Appendix B.1 and C; HID Usage Tables
1.4 (usb.org), 10.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from neurotouch_hid.core.controller import ControllerState, Feedback

if TYPE_CHECKING:
    from neurotouch_hid.targets.identity import Identity

#: The modifier keys, bit 0 .. bit 7 of byte 0 (usages 0xE0..0xE7).
MODIFIER_BITS: tuple[str, ...] = (
    "KEY_LEFTCTRL",
    "KEY_LEFTSHIFT",
    "KEY_LEFTALT",
    "KEY_LEFTMETA",
    "KEY_RIGHTCTRL",
    "KEY_RIGHTSHIFT",
    "KEY_RIGHTALT",
    "KEY_RIGHTMETA",
)
#: Key codes in one report (the boot protocol's six).
KEY_SLOTS = 6
#: ErrorRollOver (usage 0x01): every slot, when more keys are down than there are slots.
ERROR_ROLL_OVER = 0x01
#: The highest usage the key array carries (Keyboard Volume Down).
MAX_USAGE = 0x81


def _usages() -> dict[str, int]:
    table = {f"KEY_{chr(ord('A') + i)}": 0x04 + i for i in range(26)}
    table |= {f"KEY_{d}": 0x1E + i for i, d in enumerate("123456789")} | {"KEY_0": 0x27}
    table |= {f"KEY_F{n}": 0x3A + n - 1 for n in range(1, 13)} | {f"KEY_F{n}": 0x68 + n - 13 for n in range(13, 25)}
    table |= {f"KEY_KP{d}": 0x59 + i for i, d in enumerate("123456789")} | {"KEY_KP0": 0x62}
    named = (
        (0x28, "ENTER"), (0x29, "ESC"), (0x2A, "BACKSPACE"), (0x2B, "TAB"), (0x2C, "SPACE"),
        (0x2D, "MINUS"), (0x2E, "EQUAL"), (0x2F, "LEFTBRACE"), (0x30, "RIGHTBRACE"),
        (0x31, "BACKSLASH"), (0x33, "SEMICOLON"), (0x34, "APOSTROPHE"), (0x35, "GRAVE"),
        (0x36, "COMMA"), (0x37, "DOT"), (0x38, "SLASH"), (0x39, "CAPSLOCK"),
        (0x47, "SCROLLLOCK"), (0x48, "PAUSE"), (0x49, "INSERT"), (0x4A, "HOME"), (0x4B, "PAGEUP"),
        (0x4C, "DELETE"), (0x4D, "END"), (0x4E, "PAGEDOWN"), (0x4F, "RIGHT"), (0x50, "LEFT"),
        (0x51, "DOWN"), (0x52, "UP"), (0x53, "NUMLOCK"), (0x54, "KPSLASH"), (0x55, "KPASTERISK"),
        (0x56, "KPMINUS"), (0x57, "KPPLUS"), (0x58, "KPENTER"), (0x63, "KPDOT"), (0x64, "102ND"),
        (0x65, "COMPOSE"), (0x67, "KPEQUAL"), (0x74, "OPEN"), (0x75, "HELP"), (0x76, "PROPS"),
        (0x77, "FRONT"), (0x78, "STOP"), (0x79, "AGAIN"), (0x7A, "UNDO"), (0x7B, "CUT"),
        (0x7C, "COPY"), (0x7D, "PASTE"), (0x7E, "FIND"), (0x7F, "MUTE"), (0x80, "VOLUMEUP"),
        (0x81, "VOLUMEDOWN"),
    )  # fmt: skip
    table |= {f"KEY_{name}": usage for usage, name in named}
    table |= {name: 0xE0 + bit for bit, name in enumerate(MODIFIER_BITS)}
    return table


#: evdev key name -> Keyboard/Keypad page usage (HID Usage Tables 1.4, 10), for the keys a report
#: carries: letters, digits, Enter .. Caps Lock, F1..F24, the navigation block and the keypad,
#: the editing keys (Undo .. Find), the volume keys and the eight modifiers (0xE0..0xE7).
USAGES: dict[str, int] = _usages()

# HID 1.11 Appendix B.1 (the boot keyboard), with the key array's maximum raised to MAX_USAGE.
DESCRIPTOR = bytes(
    [
        0x05, 0x01,  # Usage Page (Generic Desktop)
        0x09, 0x06,  # Usage (Keyboard)
        0xA1, 0x01,  # Collection (Application)
        0x05, 0x07,  #   Usage Page (Keyboard/Keypad)
        0x19, 0xE0,  #   Usage Minimum (Left Control)
        0x29, 0xE7,  #   Usage Maximum (Right GUI)
        0x15, 0x00,  #   Logical Minimum (0)
        0x25, 0x01,  #   Logical Maximum (1)
        0x75, 0x01,  #   Report Size (1)
        0x95, 0x08,  #   Report Count (8)
        0x81, 0x02,  #   Input (Data, Variable, Absolute): the modifier byte
        0x95, 0x01,  #   Report Count (1)
        0x75, 0x08,  #   Report Size (8)
        0x81, 0x01,  #   Input (Constant): the reserved byte
        0x95, 0x05,  #   Report Count (5)
        0x75, 0x01,  #   Report Size (1)
        0x05, 0x08,  #   Usage Page (LEDs)
        0x19, 0x01,  #   Usage Minimum (Num Lock)
        0x29, 0x05,  #   Usage Maximum (Kana)
        0x91, 0x02,  #   Output (Data, Variable, Absolute): the LED report
        0x95, 0x01,  #   Report Count (1)
        0x75, 0x03,  #   Report Size (3)
        0x91, 0x01,  #   Output (Constant): LED report padding
        0x95, KEY_SLOTS,  # Report Count (6)
        0x75, 0x08,  #   Report Size (8)
        0x15, 0x00,  #   Logical Minimum (0)
        0x26, MAX_USAGE, 0x00,  # Logical Maximum (0x81)
        0x05, 0x07,  #   Usage Page (Keyboard/Keypad)
        0x19, 0x00,  #   Usage Minimum (0)
        0x29, MAX_USAGE,  # Usage Maximum (0x81)
        0x81, 0x00,  #   Input (Data, Array): the key codes
        0xC0,  # End Collection
    ]
)  # fmt: skip


def unrepresentable(keys: Iterable[str]) -> list[str]:
    """The ``KEY_*`` names among ``keys`` that the report cannot carry (not in :data:`USAGES`),
    sorted; other names (``BTN_*``, ``REL_*``) are not keys and are not listed."""
    return sorted(k for k in keys if k.startswith("KEY_") and k not in USAGES)


class BootKeyboard:
    """The boot keyboard's report format (:class:`~neurotouch_hid.targets.reports.ReportFormat`)."""

    name = "keyboard"
    descriptor = DESCRIPTOR
    report_length = 2 + KEY_SLOTS
    feature_ids: tuple[int, ...] = ()

    def feature(self, report_id: int, identity: Identity) -> bytes:
        """Raises KeyError: the boot keyboard has no feature report."""
        raise KeyError(report_id)

    def parse_output(self, data: bytes) -> list[Feedback]:
        """The host's LED report (its first byte: Num Lock, Caps Lock, Scroll Lock, Compose, Kana in
        bits 0..4; HID 1.11 appendix B.1) as one ``"keyboard_leds"`` :class:`Feedback`; ``[]``
        for an empty report."""
        return [Feedback("keyboard_leds", led=data[0] & 0x1F)] if data else []

    def pack(self, state: ControllerState) -> bytes:
        """The 8-byte input report for ``state.keys`` (docs/reports.md, "keyboard: the boot keyboard"): modifier
        bits, 0, then the other keys' usages in ascending order, zero-filled; keys without a
        usage are dropped; more than six: all six slots ErrorRollOver."""
        modifiers = 0
        for bit, name in enumerate(MODIFIER_BITS):
            if name in state.keys:
                modifiers |= 1 << bit
        codes = sorted(USAGES[k] for k in state.keys if k in USAGES and USAGES[k] < 0xE0)
        if len(codes) > KEY_SLOTS:
            codes = [ERROR_ROLL_OVER] * KEY_SLOTS
        return bytes([modifiers, 0, *codes, *([0] * (KEY_SLOTS - len(codes)))])

    def neutral(self) -> bytes:
        """Eight zero bytes: nothing pressed."""
        return self.pack(ControllerState.neutral())


#: The one instance (the format keeps no state).
BOOT_KEYBOARD = BootKeyboard()
