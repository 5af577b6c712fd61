"""Several cameras on one machine: each run stands for one camera (its serial), whose outputs carry
an identity of their own and whose own config folder is used where it has one
(neurotouch_hid/serials.py, sources/serial.py, control.socket_path).
The two pads in a real kernel: tests/kernel/checks_sensors.py."""

from types import SimpleNamespace

import numpy as np
import pytest
from helpers import read_states, run_main

from neurotouch_hid.core.errors import NeurotouchError
from neurotouch_hid.core.estimate import GestureEstimate, GestureType
from neurotouch_hid.service.serials import config_dir, configured_serials, own_file, sensor_dir, sensor_file


def _own(serial: str, name: str, text: str = "") -> None:
    folder = sensor_dir(serial)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(text)


def test_a_camera_uses_its_own_file_where_it_has_one_else_the_shared_one(tmp_path):
    shared = tmp_path / "games.yaml"
    assert sensor_file("A1", "games", shared) == shared
    _own("A1", "games.yaml")
    assert sensor_file("A1", "games", shared) == config_dir() / "sensors" / "A1" / "games.yaml"
    assert sensor_file("B2", "games", shared) == shared  # another camera keeps the shared one
    assert sensor_file(None, "games", shared) == shared
    assert own_file("A1", "profile") is None
    with pytest.raises(KeyError):
        own_file("A1", "model")
    with pytest.raises(ValueError, match="character other than"):
        own_file("../A1", "games")


def test_configured_serials_lists_the_camera_folders_only():
    assert configured_serials() == []
    _own("B2", "profile.yaml")
    _own("A1", "sensor.yaml")
    (config_dir() / "sensors" / "not a serial").mkdir()
    (config_dir() / "sensors" / "file").write_text("")
    assert configured_serials() == ["A1", "B2"]


def _on_the_bus(monkeypatch, *serials):
    """pyusb's view of the bus (sources/discovery.py) as DAVIS-346 cameras with ``serials``."""
    from neurotouch_hid.sources import discovery

    cameras = [SimpleNamespace(serial=s or None) for s in serials]
    monkeypatch.setattr(discovery, "discover", lambda dv=True: SimpleNamespace(davis346=cameras))


def test_the_run_serial_is_the_given_one_else_the_only_camera_on_the_bus(monkeypatch):
    from neurotouch_hid.sources.davis import DavisConfig
    from neurotouch_hid.sources.serial import camera_serial

    said = []
    _on_the_bus(monkeypatch, "00000499")
    assert camera_serial("sim", "left_1", say=said.append) == "left_1"
    assert camera_serial("sim", None, say=said.append) is None  # the bus is the live camera's only
    assert camera_serial("davis", None, DavisConfig(serial="00000500"), say=said.append) == "00000500"
    assert camera_serial("davis", None, None, say=said.append) == "00000499"
    assert said == []
    _on_the_bus(monkeypatch, "")  # a serial string nobody could read
    assert camera_serial("davis", None, None, say=said.append) is None
    _on_the_bus(monkeypatch, "00000499", "00000500")
    assert camera_serial("davis", None, None, say=said.append) is None
    assert "00000499, 00000500" in said[-1] and "--serial" in said[-1]
    _on_the_bus(monkeypatch, "0000 499")
    assert camera_serial("davis", None, None, say=said.append) is None
    assert "not used for its controller's identity" in said[-1]
    with pytest.raises(NeurotouchError, match="--serial: camera serial 'a/b'"):
        camera_serial("sim", "a/b")


def test_own_config_takes_the_camera_profile_and_sensor_else_the_shared_ones():
    from neurotouch_hid.sources.serial import own_config

    assert own_config("sim", "A1", None, None) == ("default", None)
    _own("A1", "profile.yaml")
    _own("A1", "sensor.yaml")
    folder = config_dir() / "sensors" / "A1"
    assert own_config("sim", "A1", None, None) == (folder / "profile.yaml", folder / "sensor.yaml")
    assert own_config("davis", "A1", "mouse", "/x/sensor.yaml") == ("mouse", "/x/sensor.yaml")  # given wins
    assert own_config("rec.aedat4", "A1", None, None) == (folder / "profile.yaml", None)  # the recording's own
    assert own_config("sim", None, None, None) == ("default", None)


def _push_right(path):
    from neurotouch_hid.core.dataset import write_predictions

    estimates = [
        GestureEstimate(
            t_us=1_000_000 + 10_000 * k,
            gesture=GestureType.PUSH,
            resting=False,
            intensity_mm=6.0,
            translation_mm=np.array([3.0, 0.0]),
        )
        for k in range(40)
    ]
    estimates += [GestureEstimate(t_us=1_400_000 + 10_000 * k) for k in range(10)]
    write_predictions(path, estimates)


def test_a_run_with_a_serial_maps_with_that_camera_profile(tmp_path):
    """Two runs of the same push, one per camera: the camera with a profile.yaml of its own
    (the shipped ``mouse``) moves the pointer, the other one (no folder) the default's stick."""
    from neurotouch_hid.engine.driver import DriverOptions, run_driver
    from neurotouch_hid.mapping.profile import find_profile

    preds = tmp_path / "push.jsonl"
    _push_right(preds)
    _own("LEFT", "profile.yaml", find_profile("mouse").read_text())
    left, right = tmp_path / "left.jsonl", tmp_path / "right.jsonl"
    run_driver(str(preds), None, "jsonl", DriverOptions(fast=True, out=left, serial="LEFT"))
    run_driver(str(preds), None, "jsonl", DriverOptions(fast=True, out=right, serial="RIGHT"))
    left_states, right_states = read_states(left.read_text()), read_states(right.read_text())
    assert sum(d["rel"].get("REL_X", 0) for d in left_states) > 100
    assert all(d["axes"]["ABS_X"] == 0 for d in left_states)
    assert max(d["axes"]["ABS_X"] for d in right_states) > 16000
    assert all(not d["rel"] for d in right_states)


def test_run_refuses_a_serial_that_cannot_name_a_camera(monkeypatch, capsys, tmp_path):
    preds = tmp_path / "push.jsonl"
    _push_right(preds)
    done = run_main(monkeypatch, capsys, ["run", "--source", str(preds), "--output", "jsonl", "--serial", "a b"])
    assert done.returncode == 2
    assert "--serial: camera serial 'a b' has a character other than" in done.stderr


def test_each_camera_driver_has_its_own_control_socket(tmp_path, monkeypatch):
    from neurotouch_hid.service import control

    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    folder = tmp_path / "neurotouch-hid"
    assert control.socket_path() == folder / "control.sock"
    assert control.socket_path("A1") == folder / "control-A1.sock"
    with pytest.raises(ValueError):
        control.socket_path("../x")
    folder.mkdir(mode=0o700)
    assert control._chosen_socket(None) == folder / "control.sock"  # nobody runs: said on connecting
    (folder / "control-A1.sock").write_text("")
    assert control.running_serials() == ["A1"]
    assert control._chosen_socket(None) == folder / "control-A1.sock"  # the one camera's driver
    (folder / "control-B2.sock").write_text("")
    with pytest.raises(NeurotouchError, match="cameras A1, B2: say which with --serial"):
        control.request_use("default")
    assert control._chosen_socket("B2") == folder / "control-B2.sock"
    (folder / "control.sock").write_text("")
    assert control._chosen_socket(None) == folder / "control.sock"  # the driver without a serial


def test_outputs_carry_the_camera_identity():
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.targets.gadget import configfs
    from neurotouch_hid.targets.identity import identity_for
    from neurotouch_hid.targets.uhid import hid_identity
    from neurotouch_hid.targets.uhid_events import _CREATE2, create2_event
    from neurotouch_hid.targets.uhid_events import PHYS as UHID_PHYS
    from neurotouch_hid.targets.uinput.gamepad import PHYS, GamepadIdentity

    camera = identity_for("00000499")
    hid = hid_identity(load_profile("default").device, camera)
    assert (hid.phys, hid.uniq) == ("neurotouch-hid/00000499", camera.uniq)
    plain = hid_identity(load_profile("default").device)
    assert (plain.phys, plain.uniq) == (UHID_PHYS, "")
    event = create2_event(b"\x05\x01", hid.name, vendor=1, product=2, version=3, phys=hid.phys, uniq=hid.uniq)
    _, _, phys, uniq, *_ = _CREATE2.unpack_from(event)
    assert phys.rstrip(b"\0") == b"neurotouch-hid/00000499" and uniq.rstrip(b"\0") == camera.uniq.encode()
    assert GamepadIdentity().phys == PHYS
    assert configfs.plan("hid", serial=camera.usb_serial).serial == "00000499"
    assert configfs.plan("xinput").serial == "00000001"


def test_gadget_setup_refuses_a_bad_serial(monkeypatch, capsys):
    done = run_main(monkeypatch, capsys, ["gadget", "setup", "--serial", "x y"])
    assert done.returncode == 2
    assert "--serial: camera serial 'x y' has a character other than" in done.stderr


def test_devices_and_doctor_say_which_driver_runs_for_which_camera(tmp_path, monkeypatch):
    """A runtime for camera A1 (its control socket, real Unix sockets) answers ``status``: the
    camera on the bus with that serial shows its driver (this process) and its own config, the
    other camera shows none, and the doctor's line says both."""
    import os
    import threading

    from helpers import wait_until
    from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, endless

    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions
    from neurotouch_hid.service.control import running_drivers, socket_path
    from neurotouch_hid.service.doctor import OK, camera_drivers, check_drivers
    from neurotouch_hid.service.serve import served

    folder = tmp_path / "run"
    folder.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(folder))
    _own("A1", "profile.yaml")
    rt = Engine(
        RunParts(endless(), FakePipeline(push_batches=10**9)),
        {"sign": 1},
        [RecordingOutput()],
        RunOptions(mode=RunMode.PACED, mapper_factory=FakeMapper, profile_ref="left"),
    )
    seen: dict = {}

    def client():
        try:
            assert wait_until(lambda: socket_path("A1").exists(), 30.0)
            seen["drivers"] = running_drivers()
            found = SimpleNamespace(davis346=[_camera("A1", 3), _camera("B2", 4)])
            seen["rows"] = camera_drivers(found)
            seen["check"] = check_drivers(found)
        finally:
            rt.stop()

    thread = threading.Thread(target=client)
    thread.start()
    with served(rt, "left", serial="A1"):
        rt.run()
    thread.join(10)
    (driver,) = seen["drivers"]
    assert (driver.serial, driver.pid, driver.status) == ("A1", os.getpid(), "profile left")
    a1, b2 = seen["rows"]
    assert a1["serial"] == "A1" and a1["driver"]["pid"] == os.getpid() and a1["config"] == ["profile.yaml"]
    assert b2["serial"] == "B2" and b2["driver"] is None and b2["config"] == []
    check = seen["check"]
    assert check.status == OK
    assert "camera A1 (bus 1 device 3): driver pid" in check.detail and "profile left; own profile.yaml" in check.detail
    assert "camera B2 (bus 1 device 4): no driver runs for it; shared config" in check.detail
    assert running_drivers() == []  # the socket went with the run


def _camera(serial: str, address: int):
    return SimpleNamespace(serial=serial, bus=1, address=address)


def test_doctor_warns_when_several_cameras_share_the_single_service(monkeypatch):
    from neurotouch_hid.service.doctor import WARN, check_drivers

    found = SimpleNamespace(davis346=[_camera("A1", 3), _camera("B2", 4)])
    check = check_drivers(found, drivers=[])
    assert check.status == WARN and "2 cameras and none has a config folder" in check.detail
    assert f"mkdir -p {sensor_dir('A1')}" in check.fix.splitlines()
    _own("A1", "sensor.yaml")
    assert check_drivers(found, drivers=[]).status != WARN


def test_a_driver_of_no_camera_on_the_bus_is_listed_too():
    from neurotouch_hid.service.control import RunningDriver
    from neurotouch_hid.service.doctor import camera_drivers, describe_camera_driver

    sim = RunningDriver("SIM1", 42, "profile default", "neurotouch-hid@SIM1.service")
    (row,) = camera_drivers(SimpleNamespace(davis346=[]), drivers=[sim])
    assert describe_camera_driver(row) == (
        "camera SIM1 (not on the bus): driver pid 42 in neurotouch-hid@SIM1.service, profile default; shared config"
    )


def test_calibrate_with_a_serial_writes_that_camera_sensor_yaml(monkeypatch, capsys, sim_push_only_recording):
    """``calibrate --serial S1`` (here on a recording of the gel at rest first) writes
    sensors/S1/sensor.yaml, which a run of camera S1 then reads; the shared one is not made."""
    from neurotouch_hid.core.sensor import SensorGeometry, user_sensor_path
    from neurotouch_hid.sources.serial import own_config

    args = ["calibrate", "--source", str(sim_push_only_recording), "--serial", "S1", "--no-mirror", "--rotation", "0"]
    done = run_main(monkeypatch, capsys, args)
    assert done.returncode == 0, done.stderr
    written = sensor_dir("S1") / "sensor.yaml"
    assert SensorGeometry.load(written).mirror is False
    assert not user_sensor_path().exists()
    assert own_config("sim", "S1", None, None)[1] == written
    bad = run_main(monkeypatch, capsys, ["calibrate", "--source", str(sim_push_only_recording), "--serial", "S 1"])
    assert bad.returncode == 2 and "--serial: camera serial 'S 1'" in bad.stderr


def test_run_hands_the_serial_of_the_simulated_camera_to_the_driver(monkeypatch, capsys):
    """``run --source sim --serial S1`` without --profile: the driver gets the serial and no
    profile (the camera's own, else default: :func:`sources.serial.own_config`)."""
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.engine import driver

    seen = {}

    def fake_run(source, profile, output, options):
        seen.update(source=source, profile=profile, output=output, serial=options.serial)
        return RunStats()

    monkeypatch.setattr(driver, "run_driver", fake_run)
    done = run_main(monkeypatch, capsys, ["run", "--source", "sim", "--serial", "S1", "--output", "jsonl"])
    assert done.returncode == 0, done.stderr
    assert seen == {"source": "sim", "profile": None, "output": "jsonl", "serial": "S1"}
    run_main(monkeypatch, capsys, ["run", "--source", "sim", "--serial", "S1", "--profile", ""])
    assert seen["profile"] is None  # the templated unit's empty NEUROTOUCH_PROFILE


def test_profile_auto_with_a_serial_edits_that_camera_games_table(monkeypatch, capsys):
    """``profile auto add --serial S1`` writes sensors/S1/games.yaml (the table S1's driver then
    reads, :class:`~neurotouch_hid.engine.engine.Engine`'s games watcher); the shared one stays as it
    was, and ``list`` without a serial shows the shared one."""
    from neurotouch_hid.service.games import games_file, load_game_map

    done = run_main(monkeypatch, capsys, ["profile", "auto", "add", "4242", "mouse", "--serial", "S1"])
    assert done.returncode == 0, done.stderr
    own = sensor_dir("S1") / "games.yaml"
    assert load_game_map(own).steam == {4242: "mouse"} and not games_file().exists()
    assert sensor_file("S1", "games", games_file()) == own
    listed = run_main(monkeypatch, capsys, ["profile", "auto", "list", "--serial", "S1"])
    assert "Steam app 4242 -> mouse" in listed.stdout and str(own) in listed.stdout
    shared = run_main(monkeypatch, capsys, ["profile", "auto", "list"])
    assert "no game is mapped" in shared.stdout
    run_main(monkeypatch, capsys, ["profile", "auto", "remove", "4242", "--serial", "S1"])
    assert load_game_map(own).steam == {}
    bad = run_main(monkeypatch, capsys, ["profile", "auto", "list", "--serial", "../x"])
    assert bad.returncode == 2 and "--serial: camera serial '../x'" in bad.stderr


def test_the_keyboard_and_mouse_of_a_camera_carry_its_phys(monkeypatch):
    """The uinput keyboard and mouse a profile uses: ``neurotouch-hid/SERIAL/keyboard`` and
    ``/mouse`` for a camera's run, their own phys without one (the devices themselves need
    /dev/uinput: here stand-ins record what they are made with)."""
    from neurotouch_hid.mapping.profile import parse_profile
    from neurotouch_hid.targets.uinput import desktop

    made = []

    class Stand:
        def __init__(self, keys, devnode, phys="own"):
            self.offers, self.phys = frozenset(keys), phys
            made.append(phys)

        def close(self):
            pass

    monkeypatch.setattr(desktop, "VirtualKeyboard", type("Kb", (Stand,), {}))
    monkeypatch.setattr(desktop, "VirtualMouse", type("Mouse", (Stand,), {}))
    both = parse_profile(
        "description: keys and clicks\nmappings:\n"
        "  enter: {input: push_intensity, output: KEY_ENTER, press_mm: 2.0, release_mm: 1.0}\n"
        "  click: {input: push_intensity, output: BTN_RIGHT, press_mm: 2.0, release_mm: 1.0}\n",
        "both.yaml",
    )
    desktop.UinputOutputs(None, both, phys="neurotouch-hid/S1")
    assert made == ["neurotouch-hid/S1/keyboard", "neurotouch-hid/S1/mouse"]
    made.clear()
    desktop.UinputOutputs(None, both)
    assert made == ["own", "own"]


def test_the_unit_of_a_driver_is_its_own_service_only(monkeypatch):
    """``/proc/PID/cgroup``'s last part names the service a driver runs in; a driver started in a
    terminal (a scope under the user's manager, ``user@1000.service``) has none."""
    from neurotouch_hid.core import limits
    from neurotouch_hid.service import control

    cgroups = {
        1: b"0::/user.slice/user-1000.slice/user@1000.service/app.slice/neurotouch-hid@00000499.service\n",
        2: b"0::/user.slice/user-1000.slice/user@1000.service/app.slice/app-gnome-term.slice/vte-spawn-1.scope\n",
        3: b"0::/\n",
    }
    monkeypatch.setattr(limits, "read_proc_file", lambda path, n: (cgroups[int(str(path).split("/")[2])], False))
    assert control._unit_of(1) == "neurotouch-hid@00000499.service"
    assert control._unit_of(2) is None and control._unit_of(3) is None


def test_doctor_says_when_camera_folders_need_the_unit_template():
    """Once cameras have folders of their own the single unit steps aside: doctor warns while
    the per-camera template is not installed (nothing would start on plug-in), and names each
    camera's instance once it is."""
    from neurotouch_hid.service.doctor import OK, WARN, check_service, user_config_dir

    units = user_config_dir() / "systemd" / "user"
    units.mkdir(parents=True)
    (units / "neurotouch-hid.service").write_text("[Service]\nExecStart=/bin/sh -c true\n")
    assert check_service().status == OK
    _own("A1", "sensor.yaml")
    warned = check_service()
    assert warned.status == WARN and "neurotouch-hid@.service" in warned.detail and "(A1)" in warned.detail
    assert "install.sh" in warned.fix
    (units / "neurotouch-hid@.service").write_text("[Service]\nExecStart=/bin/sh -c true\n")
    ok = check_service()
    assert ok.status == OK and ok.detail == "one driver per camera with a config folder: neurotouch-hid@A1.service"
