"""Merged devices hidden from games (neurotouch_hid/inputs/hide.py) on a folder standing in for
/dev, /sys and /run: which nodes belong to a device, the move out and back (a rename, or across
file systems a new node then the old one removed), a gone device's node removed, a node made
again while hidden removed, a dead driver's folder put back. The nodes here are regular files
(device number 0:0, which the fake sysfs gives them); real character devices are moved in the
real-kernel check (tests/kernel/checks_copilot.py)."""

from __future__ import annotations

import errno
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import exited, wait_until

from neurotouch_hid.inputs import hide
from neurotouch_hid.inputs.copilot import unhidden_note
from neurotouch_hid.inputs.hide import Hider, related_nodes, restore_stale
from neurotouch_hid.inputs.match import InputInfo

HID = "usb1/1-1/1-1:1.0/0003:045E:02EA.0001"
KEYBOARD_HID = "usb1/1-1/1-1:1.1/0003:045E:02EA.0002"


@pytest.fixture
def box(tmp_path: Path) -> dict[str, Path]:
    """/dev with input/event5, input/js0 and hidraw2 of one USB pad (and event6 of another
    device), /sys describing them, an empty /run hidden folder."""
    dev, sysfs, run = tmp_path / "dev", tmp_path / "sys", tmp_path / "run"
    (dev / "input").mkdir(parents=True)
    for name in ("input/event5", "input/js0", "hidraw2", "input/event6"):
        (dev / name).write_text(name)
        os.chmod(dev / name, 0o640)
    usb = sysfs / "devices" / HID
    input5 = usb / "input" / "input5"
    for child in ("event5", "js0"):
        (input5 / child).mkdir(parents=True)
    (usb / "hidraw" / "hidraw2").mkdir(parents=True)
    # the same USB device's keyboard interface (a chat pad): its own HID device, input and hidraw
    keyboard = sysfs / "devices" / KEYBOARD_HID
    (keyboard / "input" / "input6" / "event7").mkdir(parents=True)
    (keyboard / "hidraw" / "hidraw3").mkdir(parents=True)
    (sysfs / "devices/usb1/1-1/idVendor").write_text("045e\n")
    for subsystem, name in (("input", "event5"), ("input", "js0"), ("hidraw", "hidraw2"), ("input", "event6")):
        entry = sysfs / "class" / subsystem / name
        entry.mkdir(parents=True)
        (entry / "dev").write_text("0:0\n")  # a regular file's st_rdev
    (sysfs / "class/input/event5/device").symlink_to(input5)
    return {"dev": dev, "sys": sysfs, "run": run}


def hider(box: dict[str, Path], pid: int | None = None) -> Hider:
    return Hider(box["run"], box["dev"], box["sys"], pid=pid)


def test_a_devices_nodes_are_its_event_node_its_joystick_and_the_hidraw_of_its_hid_device(box):
    """Merging the joystick interface hid the keyboard interface's hidraw node too (every
    interface's of the USB device): a headset's keys or a security key would have gone with it."""
    assert related_nodes("/dev/input/event5", box["sys"]) == ["input/event5", "input/js0", "hidraw2"]
    # no sysfs link to follow: the event node alone
    assert related_nodes("/dev/input/event6", box["sys"]) == ["input/event6"]


def test_the_other_interfaces_hidraw_nodes_stay_whichever_interface_is_merged(box):
    sysfs = box["sys"]
    (sysfs / "class/input/event7").mkdir()
    (sysfs / "class/input/event7/device").symlink_to(sysfs / "devices" / KEYBOARD_HID / "input" / "input6")
    assert related_nodes("/dev/input/event7", sysfs) == ["input/event7", "hidraw3"]
    # an interface with no HID device (xpad's): its nodes, no interface's hidraw
    xpad = sysfs / "devices/usb1/1-1/1-1:1.2/input/input8"
    (xpad / "event8").mkdir(parents=True)
    (sysfs / "class/input/event8").mkdir()
    (sysfs / "class/input/event8/device").symlink_to(xpad)
    assert related_nodes("/dev/input/event8", sysfs) == ["input/event8"]


def test_hidden_nodes_leave_dev_and_come_back_as_they_were(box):
    h, dev = hider(box), box["dev"]
    before = {n: os.stat(dev / n) for n in ("input/event5", "input/js0", "hidraw2")}
    assert h.hide(str(dev / "input/event5")) == ["input/event5", "input/js0", "hidraw2"]
    assert sorted(p.name for p in (dev / "input").iterdir()) == ["event6"] and not (dev / "hidraw2").exists()
    assert (h.folder / "input/event5").read_text() == "input/event5"
    assert h.restore(str(dev / "input/event5")) == ["input/event5", "input/js0", "hidraw2"]
    for name, st in before.items():
        after = os.stat(dev / name)
        assert (after.st_ino, after.st_mode) == (st.st_ino, st.st_mode) and (dev / name).read_text() == name
    assert not (h.folder / "input/event5").exists()


def test_across_file_systems_the_node_is_made_again_before_the_old_one_goes(box, monkeypatch):
    def no_rename(src, dst):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(hide.os, "rename", no_rename)
    h, dev = hider(box), box["dev"]
    node = dev / "input/event5"
    os.chmod(node, 0o660)
    h.hide(str(node))
    hidden = os.stat(h.folder / "input/event5")
    assert not node.exists() and stat.S_IMODE(hidden.st_mode) == 0o660
    h.restore_all()
    assert stat.S_IMODE(os.stat(node).st_mode) == 0o660 and not h.folder.exists()


def test_a_node_that_cannot_be_made_is_left_where_it_was(box, monkeypatch):
    def refuse(*args):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    def across(src, dst):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(hide.os, "rename", across)
    monkeypatch.setattr(hide.os, "mknod", refuse)
    h, dev = hider(box), box["dev"]
    assert h.hide(str(dev / "input/event5")) == []
    assert (dev / "input/event5").read_text() == "input/event5" and (dev / "hidraw2").exists()


def test_a_gone_devices_hidden_node_is_removed_not_put_back(box):
    h, dev = hider(box), box["dev"]
    h.hide(str(dev / "input/event5"))
    (box["sys"] / "class/input/event5/dev").unlink()  # unplugged: sysfs forgets it
    (box["sys"] / "class/hidraw/hidraw2/dev").write_text("241:2\n")  # its number now another device's
    assert h.restore(str(dev / "input/event5")) == ["input/js0"]
    assert not (dev / "input/event5").exists() and not (dev / "hidraw2").exists()
    assert list(h.folder.rglob("*event5")) == [] and list(h.folder.rglob("hidraw2")) == []


def test_a_node_made_again_while_hidden_is_removed_and_never_doubled(box):
    h, dev = hider(box), box["dev"]
    h.hide(str(dev / "input/event5"))
    (dev / "input/event5").write_text("again")  # made again (a tool, a udev event): a second pad for games
    assert h.rehide() == ["input/event5"] and not (dev / "input/event5").exists()
    (dev / "input/js0").write_text("again")
    h.restore_all()  # the node there wins; the hidden copy is dropped, nothing is doubled
    assert (dev / "input/js0").read_text() == "again" and (dev / "input/event5").read_text() == "input/event5"
    assert not h.folder.exists()


def test_a_dead_drivers_hidden_nodes_are_put_back_at_the_next_start_and_a_live_ones_are_not(box):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        hider(box, pid=dead_pid).hide(str(box["dev"] / "input/event5"))
        hider(box, pid=live.pid).hide(str(box["dev"] / "input/event6"))
        assert restore_stale(box["run"], box["dev"], box["sys"]) == ["hidraw2", "input/event5", "input/js0"]
        assert (box["dev"] / "input/event5").exists() and not (box["dev"] / "input/event6").exists()
        assert sorted(p.name for p in box["run"].iterdir()) == [str(live.pid)]
    finally:
        live.kill()
        live.wait()
    assert restore_stale(box["run"], box["dev"], box["sys"]) == ["input/event6"]
    assert restore_stale(box["run"] / "absent", box["dev"], box["sys"]) == []


def test_the_note_for_a_user_who_cannot_hide_names_the_sdl_variable_with_the_devices_ids():
    note = unhidden_note(InputInfo(path="/dev/input/event5", name="Helper Pad", vendor=0x045E, product=0x02EA))
    assert "SDL_GAMECONTROLLER_IGNORE_DEVICES=0x045e/0x02ea" in note and "root" in note


def test_the_relay_hides_where_it_may_and_otherwise_says_once_why_a_game_may_list_the_helper():
    from neurotouch_hid.inputs.copilot import FeedbackRelay
    from neurotouch_hid.mapping.profile import parse_profile

    profile = parse_profile('copilot:\n  - device: "Helper Pad"\n', "p.yaml")
    assert isinstance(FeedbackRelay(hide=True).merge_for(profile)._hider, Hider)
    said: list[str] = []
    relay = FeedbackRelay(said.append, hide=False)
    copilot = relay.merge_for(profile)
    assert copilot._hider is None
    helper = InputInfo(path="/dev/input/event5", name="Helper Pad", vendor=0x045E, product=0x02EA)
    for _ in range(2):
        copilot._unhidden(helper)
        relay.merge_for(profile)._unhidden(helper)  # a profile switch: still said once
    assert said == [unhidden_note(helper)]


def test_a_driver_killed_with_devices_hidden_has_its_guard_put_them_back_at_once(box):
    """SIGKILL (the OOM killer, a crash in native code): nothing in the driver runs, its guard puts
    the helper's nodes back and says so on the driver's standard error, with no next start."""
    code = (
        "import sys\n"
        "from neurotouch_hid.inputs.hide import Hider\n"
        "h = Hider(sys.argv[1], sys.argv[2], sys.argv[3], guarded=True)\n"
        "print(h.hide(sys.argv[2] + '/input/event5'), h._guard.pid, flush=True)\n"
        "sys.stdin.read()\n"
    )
    driver = subprocess.Popen(
        [sys.executable, "-c", code, str(box["run"]), str(box["dev"]), str(box["sys"])],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = driver.stdout.readline()
        assert line.startswith("['input/event5', 'input/js0', 'hidraw2'] "), line
        guard_pid = int(line.split()[-1])
        assert not (box["dev"] / "input/event5").exists()
        driver.kill()
        driver.wait()
        assert wait_until(lambda: exited(guard_pid), 30.0), "the guard did not end"
    finally:
        driver.kill()
        driver.wait()
    for name in ("input/event5", "input/js0", "hidraw2"):
        assert (box["dev"] / name).read_text() == name
    assert list(box["run"].iterdir()) == []
    assert (
        driver.stderr.read()
        .strip()
        .endswith(
            "the driver died with merged devices hidden; put back /dev/hidraw2, /dev/input/event5, /dev/input/js0"
        )
    )


def test_a_driver_that_puts_its_nodes_back_ends_its_guard_which_does_nothing(box, monkeypatch):
    h = Hider(box["run"], box["dev"], box["sys"], guarded=True)
    h.hide(str(box["dev"] / "input/event5"))
    guard = h._guard
    assert guard is not None and not exited(guard.pid)
    h.hide(str(box["dev"] / "input/event6"))
    assert h._guard is guard  # one guard for the process's folder
    assert h.restore_all() == ["hidraw2", "input/event5", "input/event6", "input/js0"]
    assert h._guard is None and guard._proc.returncode == 0
    unguarded = hider(box)
    unguarded.hide(str(box["dev"] / "input/event5"))
    assert unguarded._guard is None  # only the driver's own Hider is guarded
    unguarded.restore_all()


def _waiting_on_its_pipe(pid: int) -> bool:
    """Whether guard ``pid`` is ready: its main thread sleeps in a read of its pipe (the kernel's
    wait channel), started after its preparing thread, and that thread has ended."""
    try:
        return "pipe_read" in Path(f"/proc/{pid}/wchan").read_text() and len(os.listdir(f"/proc/{pid}/task")) == 1
    except OSError:
        return False


def test_the_guard_has_what_puts_the_nodes_back_ready_before_the_driver_dies(box, tmp_path):
    """After a SIGKILL the guard started a new Python and imported the package to put the nodes
    back: 9.4 s in an emulated machine under load. Now that work is done while the driver lives,
    so the nodes come back even when neither the interpreter nor the package can be started by
    then (here: both moved away, as an upgrade may while the driver runs)."""
    import shutil

    package = Path(hide.__file__).resolve().parents[1]
    copy = tmp_path / "pkg"
    shutil.copytree(package, copy / "neurotouch_hid", ignore=shutil.ignore_patterns("__pycache__", "data"))
    code = (
        "import sys\n"
        "from neurotouch_hid.inputs.hide import Hider\n"
        "h = Hider(sys.argv[1], sys.argv[2], sys.argv[3], guarded=True)\n"
        "print(h.hide(sys.argv[2] + '/input/event5'), h._guard.pid, flush=True)\n"
        "sys.stdin.read()\n"
    )
    env = {**os.environ, "PYTHONPATH": str(copy)}
    python = tmp_path / "bin" / "python3"  # the interpreter outside any venv: only the package copy
    python.parent.mkdir()
    python.symlink_to(os.path.realpath(sys.executable))
    driver = subprocess.Popen(
        [str(python), "-c", code, str(box["run"]), str(box["dev"]), str(box["sys"])],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    try:
        line = driver.stdout.readline()
        assert line.startswith("['input/event5', 'input/js0', 'hidraw2'] "), line
        guard_pid = int(line.split()[-1])
        assert wait_until(lambda: _waiting_on_its_pipe(guard_pid), 60.0), "the guard never waited on its pipe"
        (copy / "neurotouch_hid").rename(copy / "moved_away")
        python.unlink()
        driver.kill()
        driver.wait()
        assert wait_until(lambda: exited(guard_pid), 30.0), "the guard did not end"
    finally:
        driver.kill()
        driver.wait()
    for name in ("input/event5", "input/js0", "hidraw2"):
        assert (box["dev"] / name).read_text() == name, driver.stderr.read()
    assert "put back /dev/hidraw2, /dev/input/event5, /dev/input/js0" in driver.stderr.read()
