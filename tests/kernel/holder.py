"""Guest helper: hold a virtual gamepad with a button pressed until SIGTERM.

Prints ``ready /dev/input/eventN`` once the press is written. On SIGTERM its handler calls
VirtualGamepad.close() (what the runtime's handler calls) and exits 0.
"""

import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from neurotouch_hid.core.controller import ControllerState  # noqa: E402
from neurotouch_hid.targets.uinput.gamepad import GamepadIdentity, VirtualGamepad  # noqa: E402

pad = VirtualGamepad(GamepadIdentity(name="neurotouch holder"))


def _stop(signum, frame):
    pad.close()
    sys.exit(0)


signal.signal(signal.SIGTERM, _stop)
state = ControllerState.neutral()
state.buttons["BTN_SOUTH"] = True
state.axes["ABS_X"] = 30000
pad.write(state)
print("ready", pad.device_path, flush=True)
while True:
    time.sleep(1)
