"""``python -m neurotouch_hid.cli``: the ``neurotouch-hid`` command."""

from neurotouch_hid.cli import main

main()
