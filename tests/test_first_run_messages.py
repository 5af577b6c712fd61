"""What a new user reads when a step cannot be done: every problem at once, and the way around."""

from __future__ import annotations

import os
import sys

import pytest

from neurotouch_hid.core.errors import DeviceError
from neurotouch_hid.engine import driver

UINPUT = "/dev/uinput does not exist (the kernel's uinput module is not loaded)"


@pytest.fixture()
def no_uinput(monkeypatch):
    def refuse(kind, *args, **kwargs):
        raise DeviceError(UINPUT)

    monkeypatch.setattr(driver, "open_output", refuse)


def test_run_sim_without_uinput_mentions_the_terminal_view(no_uinput):
    with pytest.raises(DeviceError) as err:
        driver.run_driver("sim", "default", "gamepad", driver.DriverOptions(seconds=1))
    lines = str(err.value).splitlines()
    assert lines[0] == UINPUT and lines[-1].endswith("--output term")


def test_run_davis_with_neither_camera_nor_uinput_says_both(no_uinput, monkeypatch):
    """The camera's problem used to come only after the uinput one was fixed."""
    from neurotouch_hid.sources import discovery

    monkeypatch.setattr(discovery, "discover", lambda dv=True: discovery.Discovery())
    with pytest.raises(DeviceError) as err:
        driver.run_driver("davis", "default", "gamepad", driver.DriverOptions(seconds=1))
    message = str(err.value)
    assert message.startswith(UINPUT)
    assert "and the camera: no DAVIS-346 (USB 152a:841a) found: plug the NeuroTouch's USB cable in" in message
    assert "--output term" not in message


@pytest.mark.parametrize("content, says", [(None, "no such file"), (b"not a recording\n", "not an AEDAT4 recording")])
def test_calibrate_reads_the_press_file_before_needing_a_camera(tmp_path, content, says):
    """``calibrate --press FILE`` failed on the missing camera (after compiling) before it ever
    read the file: a wrong file is said first, whatever the camera."""
    from helpers import run_cli

    press = tmp_path / "press.aedat4"
    if content is not None:
        press.write_bytes(content)
    done = run_cli("calibrate", "--press", str(press), timeout=60)
    assert done.returncode == 2 and f"{press}: {says}" in done.stderr, done.stderr
    assert "DAVIS" not in done.stderr and "compiling" not in done.stderr


def test_build_deb_says_every_missing_tool_before_it_starts(tmp_path):
    """build-deb.sh stopped deep inside debian12-root.sh on a missing debootstrap: now every
    missing tool is said at once, before anything is built."""
    import os
    import shutil
    import subprocess
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "packaging" / "build-deb.sh"
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("sh", "dirname", "sed", "head", "dpkg", "id", "mount"):  # no debootstrap, dpkg-deb, chroot
        found = shutil.which(tool)
        assert found is not None, tool
        os.symlink(found, bin_dir / tool)
    env = {"PATH": str(bin_dir), "NEUROTOUCH_ROOTS": str(tmp_path / "roots"), "HOME": str(tmp_path)}
    done = subprocess.run([str(bin_dir / "sh"), str(script)], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert "missing: dpkg-deb chroot debootstrap (Debian: apt-get install debootstrap" in done.stderr, done.stderr
    assert not (tmp_path / "roots").exists() and "building" not in done.stderr


def test_install_user_says_the_services_first_start_compiles(tmp_path):
    """The service's first camera start compiled the pipeline again when the package's folder was
    not the user's (a system-wide install) for a minute, with nothing saying so: the pad just did
    not come. install.sh says when it shares the user's compiled code and when it compiles."""
    import os
    import subprocess
    from pathlib import Path

    install = Path(__file__).resolve().parents[1] / "packaging" / "install.sh"
    shim = tmp_path / "bin" / "neurotouch-hid"
    shim.parent.mkdir()
    shim.write_text("#!/bin/sh\nexit 0\n")
    shim.chmod(0o755)
    home = tmp_path / "home"
    env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME="", XDG_CACHE_HOME="", PATH=f"{shim.parent}:/usr/bin:/bin")
    done = subprocess.run(["sh", str(install), "--user"], capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 0, done.stderr
    said = done.stdout.splitlines()[-1]
    assert said.startswith("it shares the compiled pipeline your own runs cached")
    assert "first start compiles once more" in said
    assert f"{home}/.cache/neurotouch-hid" in said and "journalctl --user -u neurotouch-hid -f" in said


def test_eval_on_a_folder_without_recordings_says_so_not_the_sensor(tmp_path):
    from helpers import run_cli

    done = run_cli("eval", str(tmp_path), timeout=60)
    assert done.returncode == 2 and f"{tmp_path}: no recording in it" in done.stderr, done.stderr
    assert "sensor.yaml" not in done.stderr


def test_doctor_shows_the_calibration_in_use():
    from neurotouch_hid.core.sensor import SensorGeometry, user_sensor_path
    from neurotouch_hid.service import doctor

    none = doctor.check_calibration()
    assert (
        none.status == doctor.WARN and str(user_sensor_path()) in none.detail and none.fix == "neurotouch-hid calibrate"
    )
    user_sensor_path().parent.mkdir(parents=True, exist_ok=True)
    SensorGeometry(gel_center_px=(170.0, 128.0), rotation_deg=90.0, creep=(0.3, 0.8)).save(user_sensor_path())
    mine = doctor.check_calibration()
    assert mine.status == doctor.OK and mine.detail.startswith(f"{user_sensor_path()}: gel at (170, 128) px")
    assert "rotation 90 deg" in mine.detail and "creep q 0.30, tau 0.80 s" in mine.detail
    user_sensor_path().write_text("gel_radius_px: lots\n")
    broken = doctor.check_calibration()
    assert broken.status == doctor.FAIL and "calibrate" in broken.fix
    assert "calibration" in [c.name for c in doctor.run_checks()]


def test_ctrl_c_during_a_run_prints_its_summary_before_exit_130(monkeypatch, capsys):
    """Ctrl-C in a demo whose first compile is not done: the run stops, says how far the compile
    got (the summary), then exits 130. A real SIGINT, sent to the main thread once the run reads
    its source (as a terminal's Ctrl-C reaches it), not ``_thread.interrupt_main``: that sets a
    flag that another thread can clear from the main thread's check, so that an idle main
    thread never saw it; the runtime hands its stats on with the interrupt."""
    import signal
    import threading

    from helpers import run_main
    from runtime_fakes import EstimatesThrough

    from neurotouch_hid.core.estimate import GestureEstimate
    from neurotouch_hid.core.stages import CompileProgress
    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions
    from neurotouch_hid.mapping.profile import load_profile

    def source():
        yield GestureEstimate(t_us=10_000)
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)  # Ctrl-C
        threading.Event().wait(300)  # only ends a hang: the interrupt ends the run

    def demo(seconds, console, say):
        compiling = CompileProgress("compiling the pipeline", 0.49)  # until the run ends
        parts = RunParts(source(), EstimatesThrough(), compile_progress=lambda: compiling)
        runtime = Engine(parts, load_profile("default"), [], RunOptions(mode=RunMode.FAST))
        runtime.stats.interpreted_windows = 12
        return runtime.run(seconds)

    monkeypatch.setattr(driver, "run_demo", demo)
    # Python's own Ctrl-C, as in a terminal's foreground job (a test session started in the
    # background by a shell without job control inherits SIGINT ignored)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        done = run_main(monkeypatch, capsys, ["demo", "--seconds", "5"])
    finally:
        signal.signal(signal.SIGINT, previous)
    assert done.returncode == 130
    assert "the run ended with the compile 49 % done" in done.stderr


def test_calibrate_into_a_folder_that_does_not_exist_is_refused_before_the_session(tmp_path):
    """A typo in --out's folder: said at once (before the compile and the session), nothing made;
    the default, your config folder, is made on the first calibration."""
    from helpers import run_cli

    out = tmp_path / "typo" / "sensor.yaml"
    done = run_cli("calibrate", "--source", "sim", "--out", str(out), timeout=60)
    assert done.returncode == 2 and f"cannot write in {out.parent}: no such folder" in done.stderr, done.stderr
    assert not out.parent.exists() and "compiling" not in done.stderr


def test_ctrl_c_during_the_start_says_the_run_stopped_before_its_first_window(monkeypatch, capsys):
    """Ctrl-C while a first run still imports and compiles (the view already drawn) ended in
    silence: no summary, since the run had not begun. It says so, then exits 130."""
    from helpers import run_main

    def demo(seconds, console, say):
        raise KeyboardInterrupt  # before the runtime: no stats

    monkeypatch.setattr(driver, "run_demo", demo)
    done = run_main(monkeypatch, capsys, ["demo", "--seconds", "5"])
    assert done.returncode == 130
    assert "stopped during the start, before the first window: no output was sent" in done.stderr


@pytest.mark.parametrize("command", [["run", "--source", "sim", "--output", "term"], ["demo"]], ids=["run", "demo"])
def test_ctrl_c_typed_in_the_live_view_after_its_first_windows_prints_the_summary_then_exit_130(command):
    """The live view on a real terminal (a pty): once it has drawn some windows, Ctrl-C typed
    there (the byte 0x03, which the terminal's line discipline turns into SIGINT for the
    foreground job: the view's cbreak mode keeps ISIG) ends the run with its summary, then
    exit 130, as ``q`` gives it with exit 0."""
    import pty
    import re
    import select
    import signal
    import time

    from helpers import CLI

    pid, terminal = pty.fork()
    if pid == 0:  # the child: the CLI on the pty (stdin, stdout and stderr)
        # SIGINT's default action, as a terminal's foreground job has it (an ignored SIGINT, as a
        # shell without job control gives a background job, would be inherited through execv)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.execv(sys.executable, [*CLI, *command, "--seconds", "120"])
    out, typed, deadline = b"", False, time.monotonic() + 300  # the bound only ends a hang
    try:
        while time.monotonic() < deadline:
            if select.select([terminal], [], [], 0.2)[0]:
                try:
                    data = os.read(terminal, 65536)
                except OSError:  # EIO: the child closed the terminal
                    break
                if not data:
                    break
                out += data
            drawn = [int(n) for n in re.findall(rb"windows (\d+)", out)]
            if not typed and drawn and max(drawn) >= 20:  # the view shows windows: the steady state
                os.write(terminal, b"\x03")  # Ctrl-C, typed
                typed, out = True, b""
        _, status = os.waitpid(pid, 0)
    finally:
        os.close(terminal)
    said = out.decode("utf-8", "replace")
    assert typed and os.waitstatus_to_exitcode(status) == 130, said[-2000:]
    assert re.search(r"\d+ windows, \d+ events, \d+ frames in", said), said[-2000:]
    assert "Traceback" not in said


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--window-us", "500"], "--window-us 500: windows must be at least 1000 us"),
        (["--max-lag-ms", "0.5"], "--max-lag-ms 0.5: the lag allowed must be at least 1 ms"),
    ],
)
def test_run_options_out_of_range_are_refused_before_any_device(monkeypatch, capsys, no_uinput, args, said):
    """The run's options are one value the command line builds (``DriverOptions``): a value out
    of range is refused as it is built, naming the option, before the driver opens anything."""
    from helpers import run_main

    done = run_main(monkeypatch, capsys, ["run", "--source", "sim", "--output", "jsonl", *args])
    assert done.returncode != 0 and said in done.stderr
    with pytest.raises(Exception, match="cannot assign"):
        driver.DriverOptions().fast = True  # frozen: what the CLI built is what runs
