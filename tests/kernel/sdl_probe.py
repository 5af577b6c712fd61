"""Guest helper: open a gamepad with SDL2 (pygame) as a GameController, like a game does.

Without arguments: create the virtual gamepad itself and print one JSON line: is_controller,
SDL's name/GUID/mapping for it, and the values SDL reads after a press (button A, START, left
stick right, right trigger) and after neutralise().

``--watch SECONDS``: start SDL with no gamepad, print ``{"ready": ...}``, wait for a GameController
to be plugged in (another process creates it, e.g. ``neurotouch-hid run --output gamepad``), print
``{"opened": ...}`` (names, GUID, mapping), then one ``{"t": s, "v": {...}}`` line per change of
what SDL reads (every controller axis and button, SDL's scale), until the controller is unplugged
or SECONDS pass; last ``{"done": ...}``. ``--watch SECONDS --rumble-on-push``: the same, and the
first time the left stick is past half way, play a rumble (as ``--rumble``) and print
``{"rumble": True/False, "sdl_error": ...}``.

``--rumble SECONDS``: like ``--watch``, but once the GameController is open, ask SDL whether it
has rumble and play a rumble (SDL_GameControllerRumble: uploads an FF_RUMBLE effect and plays
it); print one ``{"done": ...}`` line with ``has_rumble`` and ``rumble`` (True = SDL accepted
it), SDL's error otherwise.

``--joystick SECONDS``: like ``--watch``, for a plain joystick (one SDL has no GameController
mapping for, e.g. the generic HID joystick of ``run --output hid``): print ``{"opened": ...}``
(name, GUID, how many axes, buttons and hats), then one ``{"t": s, "axes": [...], "buttons":
[...], "hats": [...]}`` line per change of what SDL's joystick API reads, until it is unplugged or
SECONDS pass; last ``{"done": ...}``.

``--serve SECONDS PRODUCT``: wait for the GameController whose USB product id (the joystick GUID's,
4 hex digits as written: ``028e``) is PRODUCT, print ``{"opened": ...}`` (with every controller's
GUID), then answer one line per command read on stdin: ``state`` -> ``{"v": {...}}`` (what SDL
reads now, as ``--watch``), ``rumble`` -> ``{"rumble": bool, ...}`` (a 300 ms rumble played),
``relist`` -> ``{"relisted": {"count": N, "guids": [...]}}`` (SDL's joystick and game controller
subsystems quit and started again: SDL forgets every device and enumerates afresh, as a game
started now would; PRODUCT's controller is then opened again), ``quit`` (or the end of stdin) ->
the ``{"done": ...}`` line.

Run with SDL_VIDEODRIVER=dummy.
"""

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from neurotouch_hid.core.controller import ControllerState  # noqa: E402
from neurotouch_hid.targets.uinput.gamepad import VirtualGamepad  # noqa: E402


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


def start_sdl():
    """Import pygame and start SDL's video (dummy), joystick and game controller subsystems;
    returns (pygame, pygame._sdl2.controller)."""
    # pygame imports numpy (surfarray) and pkg_resources when present; the probe needs
    # neither, and under software emulation they cost ~40 s. Blocked, pygame skips them.
    sys.modules["numpy"] = sys.modules["pkg_resources"] = None
    import pygame
    from pygame._sdl2 import controller

    pygame.display.init()
    controller.init()
    return pygame, controller


def main() -> dict:
    import subprocess

    with VirtualGamepad() as pad:
        subprocess.run(["udevadm", "settle", "--timeout=10"])
        t0 = time.monotonic()
        pygame, controller = start_sdl()
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
        result["pressed"] = poll(
            pygame, ctl, lambda v: v["a"] and v["start"] and v["leftx"] > 30000 and v["triggerright"] > 30000
        )
        pad.neutralise()
        result["released"] = poll(pygame, ctl, lambda v: not v["a"] and abs(v["leftx"]) < 2)
        ctl.quit()
        return result


#: SDL GameController axis and button names (pygame constant suffixes) read by ``--watch``.
WATCH_AXES = ("LEFTX", "LEFTY", "RIGHTX", "RIGHTY", "TRIGGERLEFT", "TRIGGERRIGHT")
WATCH_BUTTONS = (
    "A",
    "B",
    "X",
    "Y",
    "BACK",
    "GUIDE",
    "START",
    "LEFTSTICK",
    "RIGHTSTICK",
    "LEFTSHOULDER",
    "RIGHTSHOULDER",
    "DPAD_UP",
    "DPAD_DOWN",
    "DPAD_LEFT",
    "DPAD_RIGHT",
)


def say(line: dict) -> None:
    print(json.dumps(line, default=str), flush=True)


def watch(seconds: float, rumble_on_push: bool = False) -> dict:
    """``--watch``: see the module docstring. Returns the ``done`` line."""
    t0 = time.monotonic()
    pygame, controller = start_sdl()
    pygame.joystick.init()
    say(
        {
            "ready": True,
            "init_seconds": round(time.monotonic() - t0, 1),
            "sdl": ".".join(map(str, pygame.get_sdl_version())),
            "pygame": pygame.version.ver,
        }
    )
    end = time.monotonic() + seconds
    index = None
    while index is None and time.monotonic() < end:
        pygame.event.pump()
        index = next((i for i in range(controller.get_count()) if controller.is_controller(i)), None)
        time.sleep(0.01)
    if index is None:
        return {"done": True, "error": f"no GameController appeared within {seconds} s"}
    ctl = controller.Controller(index)
    joy = pygame.joystick.Joystick(index)
    say(
        {
            "opened": round(time.monotonic(), 3),
            "controller_name": controller.name_forindex(index),
            "joystick_name": joy.get_name(),
            "guid": joy.get_guid(),
            "mapping": ctl.get_mapping(),
        }
    )
    axes = [(name.lower(), getattr(pygame, "CONTROLLER_AXIS_" + name)) for name in WATCH_AXES]
    buttons = [(name.lower(), getattr(pygame, "CONTROLLER_BUTTON_" + name)) for name in WATCH_BUTTONS]
    last, samples, removed = None, 0, False
    while time.monotonic() < end:
        events = pygame.event.get()  # pumps; SDL updates the controller's values from evdev
        removed = removed or any(e.type == pygame.CONTROLLERDEVICEREMOVED for e in events)
        if removed or not ctl.attached():
            removed = True
            break
        values = {name: ctl.get_axis(code) for name, code in axes}
        values.update((name, ctl.get_button(code)) for name, code in buttons)
        if values != last:
            say({"t": round(time.monotonic(), 3), "v": values})
            last, samples = values, samples + 1
        if rumble_on_push and abs(values["leftx"]) > 16384:
            played = ctl.rumble(0.5, 1.0, 300)
            say({"rumble": bool(played), "sdl_error": None if played else pygame.get_error()})
            rumble_on_push = False
        time.sleep(0.005)
    return {"done": True, "removed": removed, "changes": samples, "error": None}


def rumble(seconds: float) -> dict:
    """``--rumble``: see the module docstring. Returns the ``done`` line."""
    pygame, controller = start_sdl()
    pygame.joystick.init()
    say({"ready": True})
    end = time.monotonic() + seconds
    index = None
    while index is None and time.monotonic() < end:
        pygame.event.pump()
        index = next((i for i in range(controller.get_count()) if controller.is_controller(i)), None)
        time.sleep(0.01)
    if index is None:
        return {"done": True, "error": f"no GameController appeared within {seconds} s"}
    ctl = controller.Controller(index)
    joy = pygame.joystick.Joystick(index)
    t0 = time.monotonic()
    played = ctl.rumble(0.5, 1.0, 300)  # SDL_GameControllerRumble(ctl, 32767, 65535, 300 ms)
    seconds_taken = round(time.monotonic() - t0, 2)
    error = None if played else pygame.get_error()
    ctl.stop_rumble()
    return {
        "done": True,
        "is_controller": True,
        "controller_name": controller.name_forindex(index),
        "joystick_name": joy.get_name(),
        "rumble": bool(played),
        "rumble_seconds": seconds_taken,
        "sdl_error": error,
        "error": None,
    }


def joystick(seconds: float) -> dict:
    """``--joystick``: see the module docstring. Returns the ``done`` line."""
    pygame, _ = start_sdl()
    pygame.joystick.init()
    say({"ready": True, "sdl": ".".join(map(str, pygame.get_sdl_version()))})
    end = time.monotonic() + seconds
    joy = None
    while joy is None and time.monotonic() < end:
        for event in pygame.event.get():
            if event.type == pygame.JOYDEVICEADDED:
                joy = pygame.joystick.Joystick(event.device_index)
        time.sleep(0.01)
    if joy is None:
        return {"done": True, "error": f"no joystick appeared within {seconds} s"}
    say(
        {
            "opened": round(time.monotonic(), 3),
            "name": joy.get_name(),
            "guid": joy.get_guid(),
            "axes": joy.get_numaxes(),
            "buttons": joy.get_numbuttons(),
            "hats": joy.get_numhats(),
        }
    )
    last, samples, removed = None, 0, False
    while time.monotonic() < end:
        events = pygame.event.get()
        if any(e.type == pygame.JOYDEVICEREMOVED for e in events):
            removed = True
            break
        values = {
            "axes": [joy.get_axis(i) for i in range(joy.get_numaxes())],
            "buttons": [joy.get_button(i) for i in range(joy.get_numbuttons())],
            "hats": [list(joy.get_hat(i)) for i in range(joy.get_numhats())],
        }
        if values != last:
            say({"t": round(time.monotonic(), 3), **values})
            last, samples = values, samples + 1
        time.sleep(0.005)
    return {"done": True, "removed": removed, "changes": samples, "error": None}


def _guid(pygame, index: int) -> str | None:
    """The GUID of SDL's device ``index``, or None when its node went after SDL listed it (the
    driver hid a merged device's node meanwhile): opening it fails, and a game skips it."""
    try:
        return pygame.joystick.Joystick(index).get_guid()
    except pygame.error:
        return None


def _guids(pygame, count: int) -> list[str]:
    """The GUIDs of SDL's devices 0..count-1 that could be opened."""
    return [guid for guid in (_guid(pygame, i) for i in range(count)) if guid is not None]


def serve(seconds: float, product: str) -> dict:
    """``--serve``: see the module docstring. Returns the ``done`` line."""
    pygame, controller = start_sdl()
    pygame.joystick.init()
    say({"ready": True})
    # the GUID's bytes 8..9 are the product id, little-endian: 028e -> "8e02"
    wanted = product[2:4] + product[0:2]

    def find(seconds: float):
        end, index = time.monotonic() + seconds, None
        while index is None and time.monotonic() < end:
            pygame.event.pump()
            index = next(
                (
                    i
                    for i in range(controller.get_count())
                    if controller.is_controller(i) and (_guid(pygame, i) or "")[16:20] == wanted
                ),
                None,
            )
            time.sleep(0.01)
        return index

    def open_wanted(seconds: float):
        """PRODUCT's controller opened, or None: found again when SDL listed a device whose node
        went before it was opened (another process made and removed devices meanwhile), as a
        game waits for the next device added."""
        end = time.monotonic() + seconds
        while True:
            index = find(max(0.0, end - time.monotonic()))
            if index is None:
                return None
            try:
                return controller.Controller(index)
            except pygame.error:
                if time.monotonic() >= end:
                    raise
                time.sleep(0.1)

    ctl = open_wanted(seconds)
    if ctl is None:
        return {"done": True, "error": f"no GameController with product {product} within {seconds} s"}
    count = controller.get_count()
    say({"opened": True, "name": getattr(ctl, "name", None), "count": count, "guids": _guids(pygame, count)})
    axes = [(name.lower(), getattr(pygame, "CONTROLLER_AXIS_" + name)) for name in WATCH_AXES]
    buttons = [(name.lower(), getattr(pygame, "CONTROLLER_BUTTON_" + name)) for name in WATCH_BUTTONS]
    for line in sys.stdin:
        command = line.strip()
        pygame.event.pump()
        if command == "state":
            values = {name: ctl.get_axis(code) for name, code in axes}
            values.update((name, ctl.get_button(code)) for name, code in buttons)
            say({"v": values})
        elif command == "relist":
            ctl.quit()
            controller.quit()
            pygame.joystick.quit()
            pygame.joystick.init()
            controller.init()
            found = open_wanted(10.0)
            count = controller.get_count()
            guids = _guids(pygame, count)
            if found is not None:
                ctl = found
            say({"relisted": {"count": count, "guids": guids, "found": found is not None}})
        elif command == "rumble":
            played = ctl.rumble(0.5, 1.0, 300)
            say({"rumble": bool(played), "sdl_error": None if played else pygame.get_error()})
        else:
            break
    return {"done": True, "error": None}


#: The modes that watch a device another process makes: each returns its ``done`` line.
MODES = {"--joystick": joystick, "--rumble": rumble, "--watch": watch}


if __name__ == "__main__":
    if sys.argv[1:2] == ["--serve"]:
        try:
            out = serve(float(sys.argv[2]), sys.argv[3])
        except Exception as exc:
            out = {"done": True, "error": f"{type(exc).__name__}: {exc}"}
        say(out)
        sys.exit(0)
    if sys.argv[1:2] and sys.argv[1] in MODES:
        try:
            extra = {"rumble_on_push": True} if "--rumble-on-push" in sys.argv[3:] else {}  # --watch only
            out = MODES[sys.argv[1]](float(sys.argv[2]), **extra)
        except Exception as exc:
            out = {"done": True, "error": f"{type(exc).__name__}: {exc}"}
        say(out)
        sys.exit(0)
    try:
        out = main()
        out.setdefault("error", None)
    except Exception as exc:
        out = {"error": f"{type(exc).__name__}: {exc}"}
    print(json.dumps(out, default=str), flush=True)
