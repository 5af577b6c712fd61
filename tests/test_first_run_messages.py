"""What a new user reads when a step cannot be done: every problem at once, and the way around."""

from __future__ import annotations

import pytest

from neurotouch_hid import driver
from neurotouch_hid.errors import DeviceError

UINPUT = "/dev/uinput does not exist (the kernel's uinput module is not loaded)"


@pytest.fixture()
def no_uinput(monkeypatch):
    def refuse(kind, *args, **kwargs):
        raise DeviceError(UINPUT)

    monkeypatch.setattr(driver, "open_output", refuse)


def test_run_sim_without_uinput_mentions_the_terminal_view(no_uinput):
    with pytest.raises(DeviceError) as err:
        driver.run_driver("sim", "default", "gamepad", seconds=1)
    lines = str(err.value).splitlines()
    assert lines[0] == UINPUT and lines[-1].endswith("--output term")


def test_run_davis_with_neither_camera_nor_uinput_says_both(no_uinput, monkeypatch):
    """The camera's problem used to come only after the uinput one was fixed."""
    from neurotouch_hid.sources import discovery

    monkeypatch.setattr(discovery, "discover", lambda dv=True: discovery.Discovery())
    with pytest.raises(DeviceError) as err:
        driver.run_driver("davis", "default", "gamepad", seconds=1)
    message = str(err.value)
    assert message.startswith(UINPUT)
    assert "and the camera: no DAVIS-346 (USB 152a:841a) found: plug the NeuroTouch's USB cable in" in message
    assert "--output term" not in message
