"""udev rules, the systemd user unit and install.sh, checked with udev's and systemd's own tools."""

from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
from pathlib import Path

import pytest
from kernel.vm import installed

from neurotouch_hid.service.udev import UINPUT_RULE
from neurotouch_hid.targets.uinput.gamepad import PHYS

ROOT = Path(__file__).resolve().parent.parent
RULES = ROOT / "udev" / "60-neurotouch.rules"
UNIT = ROOT / "packaging" / "neurotouch-hid.service"
INSTALL = ROOT / "packaging" / "install.sh"


def _rule_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]


@pytest.fixture(scope="module")
def systemd_analyze() -> str:
    found = installed("systemd-analyze", "systemd")
    if found is None:
        pytest.skip(reason="systemd-analyze not found and systemd cannot be apt-installed here")
    return found


def _verify(tool: str, unit: Path) -> subprocess.CompletedProcess:
    return subprocess.run([tool, "verify", str(unit)], capture_output=True, text=True, timeout=60)


def test_shipped_unit_verifies_cleanly(systemd_analyze):
    proc = _verify(systemd_analyze, UNIT)
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr


def test_verify_catches_a_broken_unit(systemd_analyze, tmp_path):
    broken = tmp_path / "neurotouch-hid.service"
    broken.write_text(UNIT.read_text().replace("/usr/bin/env neurotouch-hid", "/nonexistent/neurotouch-hid"))
    assert _verify(systemd_analyze, broken).returncode != 0


def test_unit_binds_to_the_device_unit_the_rules_create():
    unit = UNIT.read_text()
    symlink = re.search(r'SYMLINK\+="([^"]+)"', RULES.read_text()).group(1)
    escape = shutil.which("systemd-escape")
    device_unit = (
        subprocess.run(
            [escape, "--path", "--suffix=device", f"/dev/{symlink}"], capture_output=True, text=True
        ).stdout.strip()
        if escape
        else f"dev-{symlink}.device"
    )
    assert f"BindsTo={device_unit}" in unit and f"After={device_unit}" in unit
    assert "Restart=on-failure" in unit and re.search(r"^ExecStart=.* run --source davis", unit, re.M)


HARDENING = (
    "NoNewPrivileges=yes",
    "DevicePolicy=closed",
    "DeviceAllow=/dev/uinput rw",
    "DeviceAllow=/dev/neurotouch rw",
    "SystemCallFilter=@system-service",
    "RestrictAddressFamilies=AF_UNIX AF_NETLINK",
    "StateDirectory=neurotouch-hid",
    "CacheDirectory=neurotouch-hid",
)


def test_unit_is_hardened():
    """The sandbox a user's own process can be held to: no new privileges, seccomp's system
    calls and socket families, only the camera and the outputs' devices (uinput, uhid, the USB
    gadget's) where the manager can filter devices, its own state and cache folders."""
    lines = set(_rule_lines(UNIT.read_text()))
    assert set(HARDENING) <= lines
    assert {line for line in lines if line.startswith("DeviceAllow=")} == {
        "DeviceAllow=/dev/uinput rw",
        "DeviceAllow=/dev/neurotouch rw",
        "DeviceAllow=/dev/uhid rw",  # --output hid
        "DeviceAllow=char-hidg rw",  # --output usb: the gadget's /dev/hidgN
    }


#: The options that need a mount, UTS or user namespace, which a user's manager (not root) cannot
#: make by itself: systemd 252 skips them, from 253 it runs the unit in a user namespace of its own
#: to make them (systemd.exec(5), PrivateUsers=). Measured in the test kernel under systemd 254 as a
#: user: each mount option kept the unit from starting (226/NAMESPACE); PrivateUsers= and
#: ProtectHostname= ran it where a game's /proc/PID/environ is refused (EACCES).
NAMESPACE_OPTIONS = {
    "ProtectSystem",
    "ProtectHome",
    "PrivateTmp",
    "PrivateMounts",
    "PrivateDevices",
    "PrivateNetwork",
    "PrivateIPC",
    "PrivateUsers",
    "ProtectKernelTunables",
    "ProtectControlGroups",
    "ProtectHostname",
    "ProtectProc",
    "ProcSubset",
    "ReadWritePaths",
    "ReadOnlyPaths",
    "InaccessiblePaths",
    "ExecPaths",
    "NoExecPaths",
    "BindPaths",
    "BindReadOnlyPaths",
    "TemporaryFileSystem",
    "MountAPIVFS",
    "RootDirectory",
    "RootImage",
}


def test_the_user_unit_asks_for_no_namespace():
    """In a user namespace of its own the driver cannot read a game's environment, and per-game
    profiles never switch: the user unit asks for nothing that makes a user's systemd (253 and
    later) put it in one (tests/kernel/checks_user_unit.py runs it as a user under 252 and 254)."""
    keys = {line.split("=", 1)[0] for line in _rule_lines(UNIT.read_text())}
    assert keys & NAMESPACE_OPTIONS == set()


def test_the_user_unit_drops_no_capability_an_unprivileged_manager_cannot():
    """A user manager runs without CAP_SETPCAP: a unit that drops capabilities from the bounding
    set never starts (status 218/CAPABILITIES under a real ``systemd --user`` 252, in a qemu guest;
    packaging/README.md)."""
    keys = {line.split("=", 1)[0] for line in _rule_lines(UNIT.read_text())}
    dropping = {
        "CapabilityBoundingSet",
        "AmbientCapabilities",
        "ProtectKernelModules",
        "ProtectKernelLogs",
        "ProtectClock",
    }
    assert keys & dropping == set()
    assert "NoNewPrivileges=yes" in set(_rule_lines(UNIT.read_text()))


def test_security_exposure_is_low_and_documented(systemd_analyze, tmp_path):
    """`systemd-analyze security` rates the user unit as it would a system service: it counts the
    bounding-set capabilities a user manager cannot drop and the namespace options a user unit must
    not ask for (packaging/README.md). The figure is the one the README gives, and does not grow."""
    runtime = tmp_path / "runtime"
    runtime.mkdir(mode=0o700)
    proc = subprocess.run(
        [systemd_analyze, "--user", "security", "--offline=yes", str(UNIT)],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ, XDG_RUNTIME_DIR=str(runtime)),
    )
    found = re.search(r"Overall exposure level for neurotouch-hid.service: (\d+\.\d) (\w+)", proc.stdout)
    assert found, proc.stdout + proc.stderr
    level = float(found.group(1))
    assert level <= 6.1, proc.stdout
    readme = (ROOT / "packaging" / "README.md").read_text()
    assert f"overall exposure level {found.group(1)} {found.group(2)}" in readme


def test_install_user_writes_a_verifiable_unit_with_an_absolute_execstart(systemd_analyze, tmp_path):
    shim = tmp_path / "bin" / "neurotouch-hid"
    shim.parent.mkdir()
    shim.write_text("#!/bin/sh\nexit 0\n")
    shim.chmod(0o755)
    env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CONFIG_HOME="", PATH=f"{shim.parent}:{os.environ['PATH']}")
    proc = subprocess.run(["sh", str(INSTALL), "--user"], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    unit = tmp_path / "home/.config/systemd/user/neurotouch-hid.service"
    assert f"ExecStart={shim} run --source davis" in unit.read_text()
    assert f"ExecReload={shim} profile use " in unit.read_text()  # systemctl reload switches the profile
    assert "NEUROTOUCH_PROFILE=default" in (tmp_path / "home/.config/neurotouch-hid/service.env").read_text()
    verify = _verify(systemd_analyze, unit)
    assert verify.returncode == 0 and not verify.stderr.strip(), verify.stderr


def test_install_user_without_neurotouch_hid_on_path_fails_clearly(tmp_path):
    env = dict(os.environ, HOME=str(tmp_path), XDG_CONFIG_HOME="", PATH="/usr/bin:/bin")
    proc = subprocess.run(["sh", str(INSTALL), "--user"], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 1 and "not on PATH" in proc.stderr


def test_install_system_into_destdir(tmp_path):
    env = dict(os.environ, DESTDIR=str(tmp_path))
    proc = subprocess.run(["sh", str(INSTALL), "--system"], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    rules = tmp_path / "etc/udev/rules.d/60-neurotouch.rules"
    assert rules.read_text() == RULES.read_text()
    assert stat.S_IMODE(rules.stat().st_mode) == 0o644
    assert (tmp_path / "etc/modules-load.d/neurotouch-hid.conf").read_text().split() == ["uinput"]


def test_rules_give_access_only_to_the_seated_user():
    text = RULES.read_text()
    lines = _rule_lines(text)
    assert UINPUT_RULE in lines  # the line gamepad.py's DeviceError tells users about
    for line in lines:
        for mode in re.findall(r'MODE\s*[:+]?=\s*"(\d+)"', line):
            assert not int(mode, 8) & 0o002, f"world-writable: {line}"
    camera = [line for line in lines if 'ATTR{idVendor}=="152a"' in line]
    assert len(camera) == 2 and all('ATTR{idProduct}=="841a"' in line for line in camera)
    for needed in ('TAG+="uaccess"', 'TAG+="systemd"', f'ENV{{SYSTEMD_USER_WANTS}}+="{UNIT.name}"'):
        assert needed in camera[0]
    # each camera by its serial too (tests/test_sensor_units.py): no access given there
    assert 'SYMLINK+="neurotouch-$attr{serial}"' in camera[1] and "uaccess" not in camera[1]
    virtual = [line for line in lines if "ID_NEUROTOUCH_VIRTUAL" in line]
    assert len(virtual) == 1
    pattern = re.search(r'ATTRS\{phys\}=="([^"]+)"', virtual[0]).group(1)
    assert re.fullmatch(pattern.replace("*", ".*"), PHYS)  # matches the phys VirtualGamepad sets
    # the DualSense's hidraw node (054c:0ce6: the HID device's name in sysfs is 0003:054C:0CE6.NNNN)
    dualsense = [line for line in lines if "054C:0CE6" in line]
    assert len(dualsense) == 1 and 'KERNEL=="hidraw*"' in dualsense[0] and 'TAG+="uaccess"' in dualsense[0]
    assert re.fullmatch(
        re.search(r'KERNELS=="([^"]+)"', dualsense[0]).group(1).replace("*", ".*"), "0003:054C:0CE6.0001"
    )


def _udevadm_test(rules_text: str, tmp_path: Path) -> str:
    """Run the real udev rules parser (`udevadm test`) on ``rules_text`` in a private mount namespace
    whose /run is a fresh tmpfs, so nothing on this machine changes. Returns the lines about it."""
    src = tmp_path / "60-neurotouch.rules"
    src.write_text(rules_text)
    script = (
        f"mount -t tmpfs tmpfs /run && mkdir -p /run/udev/rules.d && cp {src} /run/udev/rules.d/ && "
        "udevadm test --action=add /sys/class/mem/null 2>&1"
    )
    proc = subprocess.run(
        ["unshare", "--mount", "--propagation", "private", "sh", "-c", script],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if "Reading rules file: /run/udev/rules.d/60-neurotouch.rules" not in proc.stdout:
        pytest.skip(reason=f"cannot run udevadm test in a private mount namespace here: {proc.stderr.strip()[:200]}")
    return "\n".join(line for line in proc.stdout.splitlines() if "60-neurotouch.rules" in line)


@pytest.fixture(scope="module")
def udevadm() -> str:
    """udevadm, apt-installed (udev) when missing: looked for when the test runs, not when it is
    collected, so that a new machine installs it rather than skipping."""
    if os.geteuid() != 0 or not shutil.which("unshare") or not os.path.exists("/sys/class/mem/null"):
        pytest.skip(reason="needs root and unshare to run udev's parser in a private namespace")
    found = installed("udevadm", "udev")
    if found is None:
        pytest.skip(reason="udevadm not found and udev cannot be apt-installed here")
    return found


def test_udev_parses_the_rules_without_complaint(udevadm, tmp_path):
    said = _udevadm_test(RULES.read_text(), tmp_path)
    assert said.strip() == "Reading rules file: /run/udev/rules.d/60-neurotouch.rules", said
    broken = _udevadm_test(RULES.read_text() + 'SUBSYSTEM=="usb", ATTRR{x}=="1", TAG+="uaccess"\n', tmp_path)
    assert "Invalid key 'ATTRR'" in broken  # the same check does catch a bad line
