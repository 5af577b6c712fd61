"""One driver per camera: the udev rule's per-serial link and the templated user unit
(packaging/neurotouch-hid@.service), checked with systemd's and udev's own tools."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from kernel.vm import installed

ROOT = Path(__file__).resolve().parent.parent
RULES = ROOT / "udev" / "60-neurotouch.rules"
UNIT = ROOT / "packaging" / "neurotouch-hid.service"
TEMPLATE = ROOT / "packaging" / "neurotouch-hid@.service"
INSTALL = ROOT / "packaging" / "install.sh"
SERIAL = "00000499"


@pytest.fixture(scope="module")
def systemd_analyze() -> str:
    found = installed("systemd-analyze", "systemd")
    if found is None:
        pytest.skip(reason="systemd-analyze not found and systemd cannot be apt-installed here")
    return found


def _instance(tmp_path: Path, text: str, serial: str = SERIAL) -> Path:
    unit = tmp_path / f"neurotouch-hid@{serial}.service"
    unit.write_text(text)
    return unit


def _verify(tool: str, unit: Path) -> subprocess.CompletedProcess:
    return subprocess.run([tool, "verify", str(unit)], capture_output=True, text=True, timeout=60)


def test_an_instance_of_the_template_verifies_and_a_broken_one_does_not(systemd_analyze, tmp_path):
    proc = _verify(systemd_analyze, _instance(tmp_path, TEMPLATE.read_text()))
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr
    broken = TEMPLATE.read_text().replace("/usr/bin/env neurotouch-hid", "/nonexistent/neurotouch-hid")
    assert _verify(systemd_analyze, _instance(tmp_path, broken, "00000500")).returncode != 0


def test_an_instance_binds_to_its_camera_link_and_runs_that_camera():
    escape = shutil.which("systemd-escape")
    if escape is None:
        pytest.skip(reason="no systemd-escape")
    device = subprocess.run(
        [escape, "--path", "--suffix=device", f"/dev/neurotouch-{SERIAL}"], capture_output=True, text=True
    ).stdout.strip()
    text = TEMPLATE.read_text()
    # what the unit says with %i = SERIAL is the device unit systemd makes of the link
    assert device == "dev-neurotouch\\x2d00000499.device"
    assert f"BindsTo={device.replace(SERIAL, '%i')}" in text and f"After={device.replace(SERIAL, '%i')}" in text
    assert re.search(r"^ExecStart=.* run --source davis --serial %i ", text, re.M)
    assert "ConditionPathIsDirectory=%E/neurotouch-hid/sensors/%i" in text
    assert "EnvironmentFile=-%E/neurotouch-hid/sensors/%i/service.env" in text
    assert "DeviceAllow=/dev/neurotouch-%i rw" in text
    # the single unit steps aside once per-camera folders exist: no camera gets two drivers
    assert "ConditionPathExists=!%E/neurotouch-hid/sensors" in UNIT.read_text()


def test_the_template_keeps_the_single_unit_hardening():
    """Every sandboxing line of neurotouch-hid.service is in the template (tests/test_packaging.py
    checks the single unit's)."""
    ours = set(TEMPLATE.read_text().splitlines())
    keys = ("NoNewPrivileges", "DevicePolicy", "DeviceAllow", "Restrict", "SystemCall", "UMask", "Keyring", "Lock")
    for line in UNIT.read_text().splitlines():
        if line.startswith(keys):
            assert line in ours, line


def test_the_rule_wants_the_instance_of_each_camera_serial():
    lines = [line for line in RULES.read_text().splitlines() if "$attr{serial}" in line]
    assert len(lines) == 1
    line = lines[0]
    assert 'ATTR{idVendor}=="152a"' in line and 'ATTR{idProduct}=="841a"' in line
    assert 'ENV{SYSTEMD_USER_WANTS}+="neurotouch-hid@$attr{serial}.service"' in line
    assert 'ATTR{serial}!="*[!A-Za-z0-9_]*"' in line  # the serials neurotouch_hid.service.serials takes


def test_install_user_installs_the_template_with_an_absolute_execstart(systemd_analyze, tmp_path):
    shim = tmp_path / "bin" / "neurotouch-hid"
    shim.parent.mkdir()
    shim.write_text("#!/bin/sh\nexit 0\n")
    shim.chmod(0o755)
    env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CONFIG_HOME="", PATH=f"{shim.parent}:{os.environ['PATH']}")
    proc = subprocess.run(["sh", str(INSTALL), "--user"], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    template = tmp_path / "home/.config/systemd/user/neurotouch-hid@.service"
    assert f"ExecStart={shim} run --source davis --serial %i" in template.read_text()
    verify = _verify(systemd_analyze, _instance(tmp_path, template.read_text()))
    assert verify.returncode == 0 and not verify.stderr.strip(), verify.stderr
