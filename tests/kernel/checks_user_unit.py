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
under /root (mode 0700): the user's manager runs in a mount namespace where /root is a readable
folder with that Python in it.
Run by tests/kernel/guest.py; asserted on by tests/test_user_unit_kernel.py.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import guestlib
from checks_gadget import _systemd_runtime, stop_unit_and_manager
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
#: What the user's manager runs in: /root made readable, with this machine's Python in it.
MANAGER_MOUNTS = (
    "set -e; mount --make-rprivate /; mkdir -p {folder}/python; mount --bind /root/.pyenv {folder}/python; "
    "mount -t tmpfs -o mode=755 tmpfs /root; mkdir /root/.pyenv; mount --bind {folder}/python /root/.pyenv; "
    "exec setpriv --reuid {uid} --regid {uid} --clear-groups {systemd} --user"
)


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


def _unit_as_a_user(systemd: Path, systemctl_path: Path, libs: Path | None) -> dict:
    """The user unit under ``systemd`` run by the user: see the module docstring."""
    t0 = time.monotonic()
    _systemd_runtime()
    cgroup = _the_user()
    home = FOLDER / "home"
    shutil.rmtree(home, ignore_errors=True)
    home.mkdir(parents=True)
    data = FOLDER / "data"
    data.mkdir(exist_ok=True)
    preds = _write_preds(data, sequence((G.PUSH, 4.0, 600.0), lead_in_s=2.0))
    base = data / "base.yaml"
    base.write_text(BASE)
    for path in (data, preds, base):
        os.chmod(path, 0o755 if path.is_dir() else 0o644)
    runtime = Path(f"/run/user/{UID}")
    env = {"HOME": str(home), "USER": NAME, "LOGNAME": NAME, "XDG_RUNTIME_DIR": str(runtime), "PATH": "/usr/bin:/bin"}
    if libs is not None:
        env["LD_LIBRARY_PATH"] = str(libs)
    os.chown(home, UID, UID)
    command = Path(sys.executable).with_name("neurotouch-hid")
    install = subprocess.run(
        ["sh", str(REPO / "packaging/install.sh"), "--user", "--bin", str(command)],
        env=env, capture_output=True, text=True, timeout=60, preexec_fn=_as_user,
    )  # fmt: skip
    assert install.returncode == 0, f"install.sh --user as {NAME}: {install.stderr}"
    config = home / ".config"
    unit = config / "systemd" / "user" / "neurotouch-hid.service"
    text = "\n".join(line for line in unit.read_text().splitlines() if not line.startswith(("BindsTo=", "After=")))
    unit.write_text(text.replace(" run --source davis ", f" run --source {preds} ") + "\n")
    said = home / "run.err"
    drop_in = unit.with_name("neurotouch-hid.service.d")
    drop_in.mkdir()
    (drop_in / "guest.conf").write_text(f"[Service]\nStandardOutput=file:{said}\nStandardError=file:{said}\n")
    (config / "neurotouch-hid" / "profiles").mkdir(parents=True)
    (config / "neurotouch-hid" / "profiles" / "everything.yaml").write_text(EVERYTHING)
    (config / "neurotouch-hid" / "games.yaml").write_text("steam:\n  4242: everything\n")
    env_file = config / "neurotouch-hid" / "service.env"
    env_file.write_text(env_file.read_text() + f"NEUROTOUCH_PROFILE={base}\n")
    subprocess.run(["chown", "-R", f"{UID}:{UID}", str(home)], check=True)
    script = MANAGER_MOUNTS.format(folder=FOLDER, uid=UID, systemd=systemd)
    manager = subprocess.Popen(
        ["unshare", "-m", "sh", "-c", script], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        preexec_fn=lambda: (cgroup / "cgroup.procs").write_text(f"{os.getpid()}\n"),
    )  # fmt: skip

    def systemctl(*args: str) -> str:
        done = subprocess.run(
            [str(systemctl_path), "--user", *args],
            env=env, capture_output=True, text=True, timeout=120, preexec_fn=_as_user,
        )  # fmt: skip
        return (done.stdout + done.stderr).strip()

    def log() -> str:
        return said.read_text() if said.exists() else ""

    seen: dict = {}
    game = None
    try:
        assert guestlib.wait_for(lambda: (runtime / "systemd" / "private").exists(), 60.0), "no systemd --user"
        seen["version"] = systemctl("--version").splitlines()[0]
        seen["start"] = systemctl("start", "neurotouch-hid.service")
        seen["running"] = bool(
            guestlib.wait_for(
                lambda: (
                    (runtime / "neurotouch-hid" / "control.sock").exists()
                    or systemctl("is-failed", "neurotouch-hid.service") == "failed"
                ),
                240.0,
                interval_s=0.5,
            )
            and (runtime / "neurotouch-hid" / "control.sock").exists()
        )
        pid = systemctl("show", "-p", "MainPID", "--value", "neurotouch-hid.service")
        seen["status"] = systemctl("show", "-p", "ExecMainStatus", "-p", "Result", "neurotouch-hid.service")
        assert seen["running"], f"the unit did not run: {seen}, its log: {log()[-1500:]}"
        seen["own_user_namespace"] = os.readlink(f"/proc/{pid}/ns/user") != os.readlink("/proc/1/ns/user")
        game = subprocess.Popen(["sleep", "600"], env=dict(env, SteamAppId="4242"), preexec_fn=_as_user)
        seen["to_game"] = bool(guestlib.wait_for(lambda: "switched to profile everything" in log(), 90.0, 0.2))
        game.kill()
        game.wait()
        seen["back"] = bool(guestlib.wait_for(lambda: f"switched to profile {base}" in log(), 60.0, 0.2))
        seen["stop"] = systemctl("stop", "neurotouch-hid.service")
        seen["result"] = systemctl("show", "-p", "Result", "-p", "ExecMainStatus", "neurotouch-hid.service")
    finally:
        if game is not None and game.poll() is None:
            game.kill()
            game.wait()
        stop_unit_and_manager(systemctl, manager)
    lines = [line for line in log().splitlines() if line.startswith("switched to profile")]
    assert seen["to_game"] and seen["back"], f"the game's profile: {seen}, the run said: {log()[-1500:]}"
    assert "Result=success" in seen["result"] and "ExecMainStatus=0" in seen["result"], f"{seen}: {log()[-1500:]}"
    return {**seen, "said": lines, "seconds": round(time.monotonic() - t0, 1)}


def check_the_user_unit_of_a_user_under_this_systemd() -> dict:
    """Debian 12's systemd (252)."""
    return _unit_as_a_user(Path("/usr/lib/systemd/systemd"), Path(shutil.which("systemctl") or "systemctl"), None)


def check_the_user_unit_of_a_user_under_a_newer_systemd() -> dict:
    """systemd 254 (Debian 12's backports, the boot's shared folder; copied to /run, which the user can
    read: the shared folder is under /root)."""
    shared = Path(sys.argv[1]).resolve().parent / NEWER_SYSTEMD
    newer = FOLDER / NEWER_SYSTEMD
    if not newer.exists():
        FOLDER.mkdir(parents=True, exist_ok=True)
        shutil.copytree(shared, newer, symlinks=True)
    libs = newer / "usr" / "lib" / "x86_64-linux-gnu" / "systemd"
    return _unit_as_a_user(newer / "lib" / "systemd" / "systemd", newer / "bin" / "systemctl", libs)


def check_plugging_the_camera_in_starts_a_users_unit() -> dict:
    """The unit as ``install.sh --user`` installs it, nothing taken out, under the user's own
    ``systemd --user`` (252): the emulated camera plugged in (checks_packaging.py's 152a:841a
    gadget on dummy_hcd, tagged by the udev rule with SYSTEMD_USER_WANTS) starts it, and
    unplugging it stops it (``BindsTo=dev-neurotouch.device``). The emulated camera is no DAVIS,
    so the run itself does not stream; what is checked is that the camera starts and stops it."""
    from checks_packaging import _plug_camera, _unplug_camera

    t0 = time.monotonic()
    _systemd_runtime()
    cgroup = _the_user()
    home = FOLDER / "home"
    shutil.rmtree(home, ignore_errors=True)
    home.mkdir(parents=True)
    runtime = Path(f"/run/user/{UID}")
    env = {"HOME": str(home), "USER": NAME, "LOGNAME": NAME, "XDG_RUNTIME_DIR": str(runtime), "PATH": "/usr/bin:/bin"}
    os.chown(home, UID, UID)
    command = Path(sys.executable).with_name("neurotouch-hid")
    install = subprocess.run(
        ["sh", str(REPO / "packaging/install.sh"), "--user", "--bin", str(command)],
        env=env, capture_output=True, text=True, timeout=60, preexec_fn=_as_user,
    )  # fmt: skip
    assert install.returncode == 0, f"install.sh --user as {NAME}: {install.stderr}"
    unit = home / ".config" / "systemd" / "user" / "neurotouch-hid.service"
    said = home / "run.err"
    drop_in = unit.with_name("neurotouch-hid.service.d")
    drop_in.mkdir()
    (drop_in / "guest.conf").write_text(f"[Service]\nStandardOutput=file:{said}\nStandardError=file:{said}\n")
    subprocess.run(["chown", "-R", f"{UID}:{UID}", str(home)], check=True)
    script = MANAGER_MOUNTS.format(folder=FOLDER, uid=UID, systemd="/usr/lib/systemd/systemd")
    manager = subprocess.Popen(
        ["unshare", "-m", "sh", "-c", script], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        preexec_fn=lambda: (cgroup / "cgroup.procs").write_text(f"{os.getpid()}\n"),
    )  # fmt: skip

    def systemctl(*args: str) -> str:
        done = subprocess.run(
            ["systemctl", "--user", *args], env=env, capture_output=True, text=True, timeout=120, preexec_fn=_as_user
        )
        return (done.stdout + done.stderr).strip()

    def invocation() -> str:
        return systemctl("show", "-p", "InvocationID", "--value", "neurotouch-hid.service")

    seen: dict = {}
    plugged = False
    try:
        assert guestlib.wait_for(lambda: (runtime / "systemd" / "private").exists(), 60.0), "no systemd --user"
        time.sleep(1.0)  # the manager's first enumeration of udev's devices
        seen["before"] = systemctl("is-active", "neurotouch-hid.service")
        seen["invocation_before"] = invocation()
        _plug_camera()
        plugged = True
        seen["device"] = bool(
            guestlib.wait_for(lambda: systemctl("is-active", "dev-neurotouch.device") == "active", 60.0, 0.2)
        )
        seen["started"] = bool(guestlib.wait_for(invocation, 60.0, 0.2))
        seen["after_plug"] = systemctl("show", "-p", "ActiveState", "-p", "ExecMainStartTimestampMonotonic",
                                       "neurotouch-hid.service")  # fmt: skip
        _unplug_camera()
        plugged = False
        seen["stopped"] = bool(
            guestlib.wait_for(
                lambda: systemctl("is-active", "neurotouch-hid.service") in ("inactive", "failed"), 60.0, 0.2
            )
        )
        seen["after_unplug"] = systemctl("is-active", "neurotouch-hid.service")
    finally:
        if plugged:
            _unplug_camera()
        stop_unit_and_manager(systemctl, manager)
    log = said.read_text()[-1500:] if said.exists() else ""
    assert seen["before"] == "inactive" and not seen["invocation_before"], f"running before the plug: {seen}"
    assert seen["device"] and seen["started"], f"plugging the camera in did not start the unit: {seen}, {log}"
    assert seen["stopped"], f"unplugging the camera left the unit running: {seen}, {log}"
    return {**seen, "said": log.splitlines()[-5:], "seconds": round(time.monotonic() - t0, 1)}
