"""Other input devices merged into the gel's pad (a profile's ``copilot:``): a helper's gamepad,
a switch box, a foot pedal.

:mod:`~neurotouch_hid.inputs.match` finds the devices a profile names (by name, USB ids or a
stable ``/dev/input/by-id/`` path, never the driver's own); :mod:`~neurotouch_hid.inputs.device`
opens, grabs and reads one within bounds; :mod:`~neurotouch_hid.inputs.copilot` is the
:class:`~neurotouch_hid.core.stages.Merge` the runtime uses: the devices' thread, hot-plug, rumble.
The arithmetic (what a device's controls become, and the policies) is
:mod:`neurotouch_hid.mapping.merge`.
"""
