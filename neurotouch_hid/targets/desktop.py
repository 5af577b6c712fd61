"""The profile's keyboard and mouse as uinput devices, as one :class:`~neurotouch_hid.stages.Target`
beside a HID output (``run --output hid``): the joystick goes to UHID, the keys and the pointer
stay on uinput, made as the uinput pad's output makes them
(:class:`~neurotouch_hid.output.desktop.UinputOutputs`, without a pad). Where uinput cannot be
used (no /dev/uinput, no permission, python-evdev not installed) the user is told once per
profile that uses them that its keyboard and mouse outputs are not sent, and why.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Callable, Iterable

from neurotouch_hid.controller import ControllerState
from neurotouch_hid.errors import DeviceError
from neurotouch_hid.extras import MissingExtraError, require

if TYPE_CHECKING:
    from neurotouch_hid.mapping.profile import Profile
    from neurotouch_hid.output.desktop import UinputOutputs
    from neurotouch_hid.stages import Feedback

log = logging.getLogger(__name__)


class UinputDesktop:
    """The uinput keyboard and mouse the profiles use, or a plain "not sent" when uinput cannot be used.

    Args:
        profile: the profile mapping now (its keyboard and mouse are made at once).
        known: every profile the run may switch to (the devices offer what they use from the
            start, so a switch keeps them).
        say: one line for the user (what is not sent, and why).
        devnode: the uinput node.
        phys: the camera's (``neurotouch-hid/SERIAL``): the keyboard's and mouse's prefix
            (None: their own, ``neurotouch-hid/keyboard`` and ``/mouse``).
    """

    what = "uinput keyboard and mouse"

    def __init__(
        self,
        profile: Profile,
        known: Iterable[Profile] = (),
        say: Callable[[str], None] = log.warning,
        devnode: str = "/dev/uinput",
        phys: str | None = None,
    ) -> None:
        self.say = say
        self._phys = phys
        self.outputs: UinputOutputs | None = None
        self.unavailable: str | None = None  # why uinput cannot be used, once found
        self._known = list(known)
        self._devnode = devnode
        self._told: set[str] = set()
        self.prepare(profile)

    def prepare(self, profile: Profile) -> None:
        """Make the keyboard and mouse ``profile`` uses (on the first profile that uses one), or
        say once per such profile that they are not sent."""
        if not (profile.keyboard_keys or profile.mouse_outputs):
            return
        if self.outputs is None and self.unavailable is None:
            try:
                require("uinput", "the uinput keyboard and mouse")
            except MissingExtraError as exc:
                self.unavailable = str(exc)
            else:
                from neurotouch_hid.output.desktop import UinputOutputs

                # no pad: the joystick is another target's (UinputOutputs skips a missing device)
                self.outputs = UinputOutputs(None, None, self._devnode, known=self._known, phys=self._phys)  # type: ignore[arg-type]
        if self.outputs is not None:
            try:
                self.outputs.prepare(profile)
                return
            except DeviceError as exc:
                self.unavailable = str(exc).splitlines()[0]
        what = " and ".join(
            n for n, used in (("keyboard", profile.keyboard_keys), ("mouse", profile.mouse_outputs)) if used
        )
        line = f"the profile's {what} outputs are not sent: {self.unavailable} (see `neurotouch-hid doctor`)"
        if line not in self._told:
            self._told.add(line)
            self.say(line)

    def write(self, state: ControllerState) -> None:
        """The keys and mouse motion of ``state`` to the devices there are."""
        if self.outputs is not None:
            self.outputs.write(state)

    def neutralise(self) -> None:
        """Release every key and button."""
        if self.outputs is not None:
            self.outputs.neutralise()

    def fileno(self) -> int | None:
        """None: a keyboard and a mouse get nothing back."""
        return None

    def feedback(self) -> list[Feedback]:
        """Nothing (never called: :meth:`fileno` is None)."""
        return []

    def close(self) -> None:
        """Release and remove the devices."""
        if self.outputs is not None:
            self.outputs.close()
