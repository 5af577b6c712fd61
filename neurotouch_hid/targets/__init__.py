"""The devices the system sees, fed from the controller state: :class:`~neurotouch_hid.stages.Target` s."""
