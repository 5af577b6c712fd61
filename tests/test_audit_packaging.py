"""install.sh run in a temporary HOME and DESTDIR, and doctor's fixes: what a user who follows them gets."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from neurotouch_hid.service import doctor
from neurotouch_hid.service.doctor import WARN
from neurotouch_hid.service.udev import RULES_INSTALL

ROOT = Path(__file__).resolve().parent.parent
INSTALL = ROOT / "packaging" / "install.sh"


def _shim(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    shim = folder / "neurotouch-hid"
    shim.write_text("#!/bin/sh\nexit 0\n")
    shim.chmod(0o755)
    return shim


def _run(args: list[str], env: dict, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(["sh", str(INSTALL), *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=60)


def test_gadget_without_a_user_is_refused(tmp_path):
    """`--gadget hid` (no :USER) would hand the gadget's nodes to a user named "hid" at every boot."""
    env = dict(os.environ, DESTDIR=str(tmp_path / "dest"), PATH=f"{_shim(tmp_path / 'bin').parent}:/usr/bin:/bin")
    for wrong in ("hid", "hid:"):
        proc = _run(["--gadget", wrong], env)
        assert proc.returncode == 2, (wrong, proc.stdout, proc.stderr)
        assert not (tmp_path / "dest/etc/systemd/system/neurotouch-hid-gadget.service").exists()
    (tmp_path / "dest/etc").mkdir(parents=True)
    (tmp_path / "dest/etc/passwd").write_text("alice:x:1000:1000::/home/alice:/bin/sh\n")  # the staged system's
    proc = _run(["--gadget", "switch:alice"], env)
    assert proc.returncode == 0, proc.stderr
    unit = (tmp_path / "dest/etc/systemd/system/neurotouch-hid-gadget.service").read_text()
    assert "--protocol switch --user alice" in unit


def test_install_user_takes_a_relative_bin(tmp_path):
    """`--bin .venv/bin/neurotouch-hid` from a checkout: the unit gets the absolute path."""
    shim = _shim(tmp_path / "checkout/.venv/bin")
    env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CONFIG_HOME="", PATH="/usr/bin:/bin")
    proc = _run(["--user", "--bin", ".venv/bin/neurotouch-hid"], env, cwd=tmp_path / "checkout")
    assert proc.returncode == 0, proc.stderr
    unit = (tmp_path / "home/.config/systemd/user/neurotouch-hid.service").read_text()
    assert f"ExecStart={shim} run --source davis" in unit


def test_install_user_with_a_space_in_the_path_writes_a_unit_systemd_accepts(tmp_path):
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip(reason="systemd-analyze not found")
    shim = _shim(tmp_path / "my tools/bin")
    env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CONFIG_HOME="", PATH="/usr/bin:/bin")
    proc = _run(["--user", "--bin", str(shim)], env)
    assert proc.returncode == 0, proc.stderr
    unit = tmp_path / "home/.config/systemd/user/neurotouch-hid.service"
    verify = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0 and not verify.stderr.strip(), verify.stderr


def test_default_install_checks_the_user_part_before_asking_sudo(tmp_path):
    """`sh install.sh` with no neurotouch-hid to point the unit at: it stops before the system part,
    rather than installing the udev rule through sudo and then failing."""
    fake = _as_a_user_with_a_fake_sudo(tmp_path)
    env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CONFIG_HOME="", PATH=f"{fake}:/usr/bin:/bin")
    proc = _run([], env)
    assert proc.returncode == 1 and "not on PATH" in proc.stderr
    assert not (tmp_path / "sudo.log").exists()


def test_install_user_twice_keeps_the_users_service_env(tmp_path):
    shim = _shim(tmp_path / "bin")
    env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CONFIG_HOME="", PATH="/usr/bin:/bin")
    assert _run(["--user", "--bin", str(shim)], env).returncode == 0
    service_env = tmp_path / "home/.config/neurotouch-hid/service.env"
    service_env.write_text("NEUROTOUCH_PROFILE=accessibility\n")
    assert _run(["--user", "--bin", str(shim)], env).returncode == 0
    assert service_env.read_text() == "NEUROTOUCH_PROFILE=accessibility\n"


def test_uhid_without_permission_gets_the_udev_rule_not_only_modprobe(monkeypatch):
    """/dev/uhid there but not writable: loading the module again does not help; the rule does."""
    from neurotouch_hid.targets.gadget import support

    monkeypatch.setattr(support, "uhid_problem", lambda: "no permission to open /dev/uhid for reading and writing")
    check = doctor.check_uhid()
    assert check.status == doctor.WARN and RULES_INSTALL in check.fix.splitlines()


def _as_a_user_with_a_fake_sudo(tmp_path: Path) -> Path:
    """A folder for PATH whose id says uid 1000 and whose sudo only logs its arguments."""
    fake = tmp_path / "fake"
    fake.mkdir(exist_ok=True)
    (fake / "id").write_text("#!/bin/sh\necho 1000\n")
    (fake / "sudo").write_text(f'#!/bin/sh\necho "$@" >> {tmp_path}/sudo.log\n')
    for tool in ("id", "sudo"):
        (fake / tool).chmod(0o755)
    return fake


def test_destdir_without_options_stages_and_never_asks_sudo(tmp_path):
    """DESTDIR touches nothing live: not through sudo either (which would drop DESTDIR and install for real)."""
    fake = _as_a_user_with_a_fake_sudo(tmp_path)
    shim = _shim(tmp_path / "bin")
    env = dict(
        os.environ,
        DESTDIR=str(tmp_path / "dest"),
        HOME=str(tmp_path / "home"),
        XDG_CONFIG_HOME="",
        PATH=f"{fake}:{shim.parent}:/usr/bin:/bin",
    )
    proc = _run([], env)
    assert proc.returncode == 0, proc.stderr
    assert not (tmp_path / "sudo.log").exists()
    assert (tmp_path / "dest/etc/udev/rules.d/60-neurotouch.rules").is_file()


def test_headless_camera_fix_says_how_to_join_the_group_and_to_log_in_again():
    from neurotouch_hid.service.udev import GROUP_RULE, camera_access_fix

    lines = camera_access_fix("/etc/udev/rules.d/60-neurotouch.rules").splitlines()
    assert "sudo usermod -aG plugdev $USER" in lines
    rule_line = next(line for line in lines if GROUP_RULE in line)
    assert rule_line.startswith("echo '") and "sudo tee /etc/udev/rules.d/" in rule_line
    after = "\n".join(lines[lines.index("sudo usermod -aG plugdev $USER") :])
    assert "log out and in" in after and "replug" in after


def test_fixes_quote_an_install_script_path_with_a_space(tmp_path, monkeypatch):
    """A checkout or venv under "My Projects": the printed commands still run when copied."""
    import importlib.util
    import shlex

    copy = tmp_path / "My Projects" / "neurotouch_hid" / "service" / "udev.py"
    copy.parent.mkdir(parents=True)
    copy.write_text((ROOT / "neurotouch_hid" / "service" / "udev.py").read_text())
    spec = importlib.util.spec_from_file_location("udev_copy", copy)
    udev_copy = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(udev_copy)
    assert " " in str(udev_copy.INSTALL_SCRIPT)
    assert shlex.split(udev_copy.RULES_INSTALL) == ["sudo", "sh", str(udev_copy.INSTALL_SCRIPT), "--system"]

    script = tmp_path / "My Projects" / "install.sh"
    command = tmp_path / "my venv" / "bin" / "neurotouch-hid"
    monkeypatch.setattr(doctor, "INSTALL_SCRIPT", script)
    monkeypatch.setattr(doctor, "this_command", lambda: str(command))
    fix = doctor.check_service(tmp_path / ".config").fix
    assert shlex.split(fix) == ["sh", str(script), "--user", "--bin", str(command)]


def test_service_whose_command_is_gone_is_not_ok(tmp_path, monkeypatch):
    """The unit install.sh --user wrote names a neurotouch-hid since removed (a deleted venv): the
    service fails at every plug-in, so doctor does not say ok, and prints the reinstall."""
    monkeypatch.setattr(doctor, "this_command", lambda: "/usr/bin/neurotouch-hid")
    unit = tmp_path / ".config/systemd/user" / doctor.SERVICE_NAME
    unit.parent.mkdir(parents=True)
    unit.write_text("[Service]\nExecStart=/gone/venv/bin/neurotouch-hid run --source davis\n")
    check = doctor.check_service(tmp_path / ".config")
    assert check.status == WARN and "/gone/venv/bin/neurotouch-hid" in check.detail
    assert "--user --bin /usr/bin/neurotouch-hid" in check.fix
    shim = _shim(tmp_path / "my venv/bin")
    unit.write_text(f'[Service]\nExecStart="{shim}" run --source davis\n')
    assert doctor.check_service(tmp_path / ".config").status == doctor.OK
