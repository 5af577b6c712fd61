"""Guest check of the packaged user unit as a user (not root) runs it: the user's own
``systemd --user``, under this system's systemd (Debian 12's 252) and under a newer one (254,
Debian 12's backports, which the host puts in the boot's shared folder: ``vm.ensure_newer_systemd``).

From systemd 253 a user's manager that is asked for a namespace (``ProtectSystem=``,
``PrivateTmp=``, ``ProtectHostname=``, ...) runs the unit in a user namespace of its own, where the
kernel refuses the driver the environment of every process outside it: a Steam game's
``SteamAppId`` is never seen and its profile never switches; 252 skips those options silently. So
the unit is checked under both, the way a player has it: ``install.sh --user`` as the user, a game
started by the user beside it, the switch to the game's profile and back said on the run's log, and
``systemctl --user stop`` ending it in order.

What this guest lacks is stood in for: no camera (the device unit's ``BindsTo=``/``After=`` are taken
out and the source is a predictions file), no journald (the run's output goes to a file), no login
(the check makes the user, ``/run/user/UID`` and the user's delegated cgroup as logind would, and
gives the user ``/dev/uinput`` as the udev rule's uaccess would). This test machine's Python lives
under /root (mode 0700): /root is made traversable while the user's manager runs
(``guestlib.python_readable_by_all``).
Run by tests/kernel/guest.py; asserted on by tests/test_user_unit_kernel.py.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import guestlib
from checks_gadget import _systemd_runtime, stop_unit_and_manager, unit_in_this_guest
from checks_runtime_remap import EVERYTHING, G, _write_preds, sequence
from vm import NEWER_SYSTEMD

TIMEOUT_S = 400
REPO = Path(__file__).resolve().parents[2]
#: The user: a uid no account of the host's root file system has.
UID = 1000
NAME = "player"
FOLDER = Path("/run/neurotouch-user-unit")
#: The profile the unit starts with (service.env's NEUROTOUCH_PROFILE): a held push holds B.
BASE = "description: base\nmappings:\n  pad: {input: push_intensity, output: B, press_mm: 2.0, release_mm: 1.0}\n"


def _as_user() -> None:
    os.setgroups([])
    os.setgid(UID)
    os.setuid(UID)


def _cgroup2() -> Path:
    for line in Path("/proc/self/mounts").read_text().splitlines():
        _, where, kind = line.split()[:3]
        if kind == "cgroup2":
            return Path(where)
    raise AssertionError("no cgroup2 file system mounted")


def _the_user() -> Path:
    """The user's account (passwd and group bound over /etc's, which the read-only root has not),
    runtime folder, delegated cgroup and /dev/uinput; returns the cgroup."""
    FOLDER.mkdir(parents=True, exist_ok=True)
    passwd, group = FOLDER / "passwd", FOLDER / "group"
    if not passwd.exists():
        passwd.write_text(Path("/etc/passwd").read_text() + f"{NAME}:x:{UID}:{UID}::{FOLDER}/home:/bin/sh\n")
        group.write_text(Path("/etc/group").read_text() + f"{NAME}:x:{UID}:\n")
        for made, etc in ((passwd, "/etc/passwd"), (group, "/etc/group")):
            subprocess.run(["mount", "--bind", str(made), etc], check=True)
    runtime = Path(f"/run/user/{UID}")
    shutil.rmtree(runtime, ignore_errors=True)
    runtime.mkdir(parents=True, mode=0o700)
    os.chown(runtime, UID, UID)
    os.chmod("/dev/uinput", 0o666)
    cgroup = _cgroup2() / "user.slice" / f"user-{UID}.slice" / f"user@{UID}.service"
    for old in sorted(cgroup.rglob("*"), reverse=True) if cgroup.exists() else ():
        if old.is_dir():
            with contextlib.suppress(OSError):
                old.rmdir()
    cgroup.mkdir(parents=True, exist_ok=True)
    for path in (cgroup, *cgroup.iterdir()):
        with contextlib.suppress(OSError):
            os.chown(path, UID, UID)
    return cgroup


#: This system's systemd (Debian 12's 252).
THIS_SYSTEMD = (Path("/usr/lib/systemd/systemd"), Path("/usr/bin/systemctl"), None)


class UsersUnit:
    """The unit installed for the user, and the user's ``systemd --user`` running. (Not a
    dataclass: guest.py loads check modules outside ``sys.modules``.)"""

    def __init__(self, env: dict[str, str], config: Path, said: Path, systemctl_path: Path):
        self.env, self.config, self.said, self.systemctl_path = env, config, said, systemctl_path

    def systemctl(self, *args: str) -> str:
        """``systemctl --user ARGS`` as the user: what it printed."""
        done = subprocess.run(
            [str(self.systemctl_path), "--user", *args],
            env=self.env, capture_output=True, text=True, timeout=120, preexec_fn=_as_user,
        )  # fmt: skip
        return (done.stdout + done.stderr).strip()

    def log(self) -> str:
        """What the run said (its output and error)."""
        return self.said.read_text() if self.said.exists() else ""


@contextlib.contextmanager
def _users_unit(
    systemd: tuple[Path, Path, Path | None], edit: Callable[[UsersUnit, Path], None]
) -> Iterator[UsersUnit]:
    """The unit installed by ``install.sh --user`` as the user, ``edit(unit, unit_file)`` applied
    (the user's files are the user's afterwards), then the user's own ``systemd --user``
    (``systemd``: the manager, its systemctl, the folder of its libraries or None) started in
    the user's cgroup; at the end the unit stopped and the manager ended."""
    manager_path, systemctl_path, libs = systemd
    _systemd_runtime()
    cgroup = _the_user()
    home = FOLDER / "home"
    shutil.rmtree(home, ignore_errors=True)
    home.mkdir(parents=True)
    os.chown(home, UID, UID)
    runtime = Path(f"/run/user/{UID}")
    env = {"HOME": str(home), "USER": NAME, "LOGNAME": NAME, "XDG_RUNTIME_DIR": str(runtime), "PATH": "/usr/bin:/bin"}
    if libs is not None:
        env["LD_LIBRARY_PATH"] = str(libs)
    command = Path(sys.executable).with_name("neurotouch-hid")
    install = subprocess.run(
        ["sh", str(REPO / "packaging/install.sh"), "--user", "--bin", str(command)],
        env=env, capture_output=True, text=True, timeout=60, preexec_fn=_as_user,
    )  # fmt: skip
    assert install.returncode == 0, f"install.sh --user as {NAME}: {install.stderr}"
    unit = UsersUnit(env, home / ".config", home / "run.err", systemctl_path)
    edit(unit, unit.config / "systemd" / "user" / "neurotouch-hid.service")
    subprocess.run(["chown", "-R", f"{UID}:{UID}", str(home)], check=True)

    def in_the_users_cgroup() -> None:
        (cgroup / "cgroup.procs").write_text(f"{os.getpid()}\n")
        _as_user()

    with guestlib.python_readable_by_all():
        manager = subprocess.Popen(
            [str(manager_path), "--user"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            preexec_fn=in_the_users_cgroup,
        )  # fmt: skip
        try:
            assert guestlib.wait_for(lambda: (runtime / "systemd" / "private").exists(), 60.0), "no systemd --user"
            yield unit
        finally:
            stop_unit_and_manager(unit.systemctl, manager)


def _a_game_switches_the_profile(systemd: tuple[Path, Path, Path | None]) -> dict:
    """The user unit under ``systemd`` run by the user: see the module docstring."""
    t0, busy0 = time.monotonic(), guestlib.busy_s()
    data = FOLDER / "data"
    data.mkdir(parents=True, exist_ok=True)
    preds = _write_preds(data, sequence((G.PUSH, 4.0, 600.0), lead_in_s=2.0))
    base = data / "base.yaml"
    base.write_text(BASE)
    for path in (data, preds, base):
        os.chmod(path, 0o755 if path.is_dir() else 0o644)

    def edit(unit: UsersUnit, unit_file: Path) -> None:
        unit_in_this_guest(unit_file, unit.said, source=preds)
        ours = unit.config / "neurotouch-hid"
        (ours / "profiles").mkdir(parents=True)
        (ours / "profiles" / "everything.yaml").write_text(EVERYTHING)
        (ours / "games.yaml").write_text("steam:\n  4242: everything\n")
        env_file = ours / "service.env"
        env_file.write_text(env_file.read_text() + f"NEUROTOUCH_PROFILE={base}\n")

    seen: dict = {}
    game = None
    with _users_unit(systemd, edit) as unit:
        socket = Path(unit.env["XDG_RUNTIME_DIR"]) / "neurotouch-hid" / "control.sock"
        try:
            seen["version"] = unit.systemctl("--version").splitlines()[0]
            seen["start"] = unit.systemctl("start", "neurotouch-hid.service")
            stamps = {"started": round(time.monotonic() - t0, 1)}
            busy = {"started": round(guestlib.busy_s() - busy0, 1)}  # the guest's CPU (s) since the check began
            seen["running"] = bool(
                guestlib.wait_for(
                    lambda: socket.exists() or unit.systemctl("is-failed", "neurotouch-hid.service") == "failed",
                    240.0,
                    interval_s=0.5,
                )
                and socket.exists()
            )
            pid = unit.systemctl("show", "-p", "MainPID", "--value", "neurotouch-hid.service")
            seen["status"] = unit.systemctl("show", "-p", "ExecMainStatus", "-p", "Result", "neurotouch-hid.service")
            assert seen["running"], f"the unit did not run: {seen}, its log: {unit.log()[-1500:]}"
            stamps["running"] = round(time.monotonic() - t0, 1)
            busy["running"] = round(guestlib.busy_s() - busy0, 1)
            seen["own_user_namespace"] = os.readlink(f"/proc/{pid}/ns/user") != os.readlink("/proc/1/ns/user")
            game = subprocess.Popen(["sleep", "600"], env=dict(unit.env, SteamAppId="4242"), preexec_fn=_as_user)
            seen["to_game"] = bool(guestlib.wait_for(lambda: "switched to profile everything" in unit.log(), 90.0, 0.2))
            stamps["to_game"] = round(time.monotonic() - t0, 1)
            game.kill()
            game.wait()
            seen["back"] = bool(guestlib.wait_for(lambda: f"switched to profile {base}" in unit.log(), 60.0, 0.2))
            stamps["back"] = round(time.monotonic() - t0, 1)
            seen["stop"] = unit.systemctl("stop", "neurotouch-hid.service")
            stamps["stopped"] = round(time.monotonic() - t0, 1)
            busy["stopped"] = round(guestlib.busy_s() - busy0, 1)
            seen["stamps_s"], seen["cpu_s"] = stamps, busy
            seen["result"] = unit.systemctl("show", "-p", "Result", "-p", "ExecMainStatus", "neurotouch-hid.service")
        finally:
            if game is not None and game.poll() is None:
                game.kill()
                game.wait()
    log = unit.log()
    lines = [line for line in log.splitlines() if line.startswith("switched to profile")]
    assert seen["to_game"] and seen["back"], f"the game's profile: {seen}, the run said: {log[-1500:]}"
    assert "Result=success" in seen["result"] and "ExecMainStatus=0" in seen["result"], f"{seen}: {log[-1500:]}"
    return {**seen, "said": lines, "seconds": round(time.monotonic() - t0, 1)}


def check_the_user_unit_of_a_user_under_this_systemd() -> dict:
    """Debian 12's systemd (252)."""
    return _a_game_switches_the_profile(THIS_SYSTEMD)


def check_the_user_unit_of_a_user_under_a_newer_systemd() -> dict:
    """systemd 254 (Debian 12's backports, the boot's shared folder; bound onto a folder under /run,
    which the user can reach: the shared folder is under /root. A copy took 56 s under emulation)."""
    shared = Path(sys.argv[1]).resolve().parent / NEWER_SYSTEMD
    newer = FOLDER / NEWER_SYSTEMD
    newer.mkdir(parents=True, exist_ok=True)
    bound = guestlib.sh(["mount", "--bind", str(shared), str(newer)])
    assert bound.returncode == 0, f"mount --bind {shared} {newer}: {bound.stderr}"
    try:
        libs = newer / "usr" / "lib" / "x86_64-linux-gnu" / "systemd"
        return _a_game_switches_the_profile((newer / "lib" / "systemd" / "systemd", newer / "bin" / "systemctl", libs))
    finally:
        guestlib.sh(["umount", str(newer)])


def check_plugging_the_camera_in_starts_a_users_unit() -> dict:
    """The unit as ``install.sh --user`` installs it, nothing taken out, under the user's own
    ``systemd --user`` (252): the emulated camera plugged in (checks_packaging.py's 152a:841a
    gadget on dummy_hcd, tagged by the udev rule with SYSTEMD_USER_WANTS) starts it, and
    unplugging it stops it (``BindsTo=dev-neurotouch.device``). The emulated camera is no DAVIS,
    so the run itself does not stream; what is checked is that the camera starts and stops it."""
    from checks_packaging import _plug_camera, _unplug_camera

    t0 = time.monotonic()
    seen: dict = {}
    with _users_unit(THIS_SYSTEMD, lambda unit, unit_file: unit_in_this_guest(unit_file, unit.said)) as unit:

        def invocation() -> str:
            return unit.systemctl("show", "-p", "InvocationID", "--value", "neurotouch-hid.service")

        plugged = False
        try:
            time.sleep(1.0)  # the manager's first enumeration of udev's devices
            seen["before"] = unit.systemctl("is-active", "neurotouch-hid.service")
            seen["invocation_before"] = invocation()
            _plug_camera()
            plugged = True
            seen["device"] = bool(
                guestlib.wait_for(lambda: unit.systemctl("is-active", "dev-neurotouch.device") == "active", 60.0, 0.2)
            )
            seen["started"] = bool(guestlib.wait_for(invocation, 60.0, 0.2))
            seen["after_plug"] = unit.systemctl(
                "show", "-p", "ActiveState", "-p", "ExecMainStartTimestampMonotonic", "neurotouch-hid.service"
            )
            _unplug_camera()
            plugged = False
            seen["stopped"] = bool(
                guestlib.wait_for(
                    lambda: unit.systemctl("is-active", "neurotouch-hid.service") in ("inactive", "failed"), 60.0, 0.2
                )
            )
            seen["after_unplug"] = unit.systemctl("is-active", "neurotouch-hid.service")
        finally:
            if plugged:
                _unplug_camera()
    log = unit.log()[-1500:]
    assert seen["before"] == "inactive" and not seen["invocation_before"], f"running before the plug: {seen}"
    assert seen["device"] and seen["started"], f"plugging the camera in did not start the unit: {seen}, {log}"
    assert seen["stopped"], f"unplugging the camera left the unit running: {seen}, {log}"
    return {**seen, "said": log.splitlines()[-5:], "seconds": round(time.monotonic() - t0, 1)}
