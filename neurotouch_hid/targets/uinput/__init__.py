"""The devices made with the kernel's uinput (Documentation/input/uinput.rst) through
python-evdev: the virtual gamepad (:mod:`~neurotouch_hid.targets.uinput.gamepad`, Xbox 360
layout, force feedback) and the keyboard and mouse (:mod:`~neurotouch_hid.targets.uinput.desktop`),
each a :class:`~neurotouch_hid.core.stages.Target` on the run's one output path
(:class:`~neurotouch_hid.targets.TargetOutputs`)."""
