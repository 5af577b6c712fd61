"""Guest helper: create the virtual gamepad, open it with SDL2 (pygame) as a GameController.

Prints one JSON line: is_controller, SDL's name/GUID/mapping for it, and the values SDL reads
after a press (button A, START, left stick right, right trigger) and after neutralise().
Run with SDL_VIDEODRIVER=dummy.
"""

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from neurotouch_hid.controller import ControllerState  # noqa: E402
from neurotouch_hid.output.gamepad import VirtualGamepad  # noqa: E402


def poll(pygame, pad_ctl, wanted, timeout_s=10.0):
    end = time.monotonic() + timeout_s
    while True:
        pygame.event.pump()
        values = {
            "a": pad_ctl.get_button(pygame.CONTROLLER_BUTTON_A),
            "start": pad_ctl.get_button(pygame.CONTROLLER_BUTTON_START),
            "leftx": pad_ctl.get_axis(pygame.CONTROLLER_AXIS_LEFTX),
            "triggerright": pad_ctl.get_axis(pygame.CONTROLLER_AXIS_TRIGGERRIGHT),
        }
        if wanted(values) or time.monotonic() > end:
            return values
        time.sleep(0.02)


def main() -> dict:
    import subprocess

    with VirtualGamepad() as pad:
        subprocess.run(["udevadm", "settle", "--timeout=10"])
        t0 = time.monotonic()
        # pygame imports numpy (surfarray) and pkg_resources when present; the probe needs
        # neither, and under software emulation they cost ~40 s. Blocked, pygame skips them.
        sys.modules["numpy"] = sys.modules["pkg_resources"] = None
        import pygame
        from pygame._sdl2 import controller

        pygame.display.init()
        controller.init()
        result = {"sdl": ".".join(map(str, pygame.get_sdl_version())), "pygame": pygame.version.ver}
        count = controller.get_count()
        found = [i for i in range(count) if controller.is_controller(i)]
        result.update(count=count, is_controller=bool(found), init_seconds=round(time.monotonic() - t0, 1))
        if not found:
            return result
        ctl = controller.Controller(found[0])
        pygame.joystick.init()
        result["guid"] = pygame.joystick.Joystick(found[0]).get_guid()
        result["name"] = controller.name_forindex(found[0])
        result["mapping"] = ctl.get_mapping()
        state = ControllerState.neutral()
        state.buttons.update(BTN_SOUTH=True, BTN_START=True)
        state.axes.update(ABS_X=32767, ABS_RZ=255)
        pad.write(state)
        result["pressed"] = poll(pygame, ctl, lambda v: v["a"] and v["start"] and v["leftx"] > 30000
                                 and v["triggerright"] > 30000)
        pad.neutralise()
        result["released"] = poll(pygame, ctl, lambda v: not v["a"] and abs(v["leftx"]) < 2)
        ctl.quit()
        return result


if __name__ == "__main__":
    try:
        out = main()
        out.setdefault("error", None)
    except Exception as exc:
        out = {"error": f"{type(exc).__name__}: {exc}"}
    print(json.dumps(out, default=str), flush=True)
