"""neurotouch-hid doctor: each check's verdict and fix, the table, the exit code (real USB scan; the
camera checks also on small records of sources/discovery.py)."""

from __future__ import annotations

import importlib.metadata
import io
import os
from pathlib import Path

from helpers import run_cli
from rich.console import Console

from neurotouch_hid.service import doctor
from neurotouch_hid.service.doctor import FAIL, OK, SKIP, WARN, Check
from neurotouch_hid.sources.discovery import DvCamera, discover, merge
from neurotouch_hid.sources.usb_probe import UsbAccess, UsbCamera


def test_no_camera_on_this_machine_is_a_failure_with_a_fix():
    found = discover()  # the real pyusb + libusb-package scan and dv-processing's discover()
    assert found.cameras == () and found.usb_error is None and found.dv_error is None
    check = doctor.check_camera(found)
    assert check.status == FAIL and "152a:841a" in check.detail and "plug" in check.fix
    assert doctor.check_camera_access(found).status == SKIP
    assert doctor.check_camera_dv(found).status == SKIP


def _camera(access: str = UsbAccess.OK, dv: bool = True):
    usb = UsbCamera(
        bus=2,
        address=7,
        node="/dev/bus/usb/002/007",
        serial="00000042",
        access=access,
        reason="" if access == UsbAccess.OK else "permission denied: ...",
    )
    listed = [DvCamera("00000042", "DAVIS", "FX3_MB", 6, 2, 7)] if dv else []
    return merge([usb], listed)


def test_camera_checks_share_the_discovery_verdicts():
    ready = _camera()
    assert [
        c.status for c in (doctor.check_camera(ready), doctor.check_camera_access(ready), doctor.check_camera_dv(ready))
    ] == [OK, OK, OK]
    assert "serial 00000042" in doctor.check_camera(ready).detail
    assert "firmware 6" in doctor.check_camera_dv(ready).detail
    denied = _camera(UsbAccess.DENIED)
    access = doctor.check_camera_access(denied)
    assert access.status == FAIL and "bus 2 device 7" in access.detail and "60-neurotouch.rules" in access.fix
    assert doctor.check_camera_dv(denied).status == SKIP
    unlisted = _camera(dv=False)
    dv = doctor.check_camera_dv(unlisted)
    assert doctor.check_camera_access(unlisted).status == OK
    assert dv.status == FAIL and "dv-processing does not list it" in dv.detail and "firmware" in dv.fix


def test_uinput_missing(tmp_path):
    check = doctor.check_uinput(str(tmp_path / "uinput"))
    assert check.status == FAIL and "does not exist" in check.detail
    assert doctor.RULES_INSTALL in check.fix.splitlines()


def test_uinput_ok_for_a_writable_character_device():
    assert doctor.check_uinput("/dev/null").status == OK  # the check only looks at the node


def test_rules_found_only_where_udev_reads_them(tmp_path):
    assert doctor.check_rules((str(tmp_path),)).status == FAIL
    (tmp_path / doctor.RULES_NAME).write_text("# rules\n")
    check = doctor.check_rules((str(tmp_path),))
    assert check.status == OK and str(tmp_path) in check.detail


def test_libraries_report_versions_or_the_pip_command():
    ok = doctor.check_library("numba", "numba")
    assert ok.status == OK and ok.detail == importlib.metadata.version("numba")
    bad = doctor.check_library("neurotouch_no_such_module", "no-such-dist")
    assert bad.status == FAIL and "pip install --upgrade no-such-dist" in bad.fix


def test_evdev_is_checked_under_the_distribution_pyproject_installs_here():
    import tomllib

    from packaging.requirements import Requirement

    project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
    wanted = [Requirement(r) for r in project["dependencies"]]
    here = {r.name for r in wanted if r.marker is None or r.marker.evaluate()}
    assert doctor.EVDEV_DIST in here and here & {"evdev", "evdev-binary"} == {doctor.EVDEV_DIST}
    check = doctor.check_library("evdev", doctor.EVDEV_DIST)
    assert check.status == OK and check.detail[0].isdigit()  # a version, also from an older venv's evdev


def test_missing_service_is_only_a_warning(tmp_path):
    assert doctor.check_service(tmp_path / ".config").status == WARN
    unit = tmp_path / ".config/systemd/user" / doctor.SERVICE_NAME
    unit.parent.mkdir(parents=True)
    unit.write_text("[Service]\n")
    assert doctor.check_service(tmp_path / ".config").status == OK


def test_exit_code_counts_failures_only():
    console = Console(record=True, width=200)
    assert doctor.report([Check("a", OK, ""), Check("b", WARN, ""), Check("c", SKIP, "")], console) == 0
    assert doctor.report([Check("a", OK, ""), Check("d", FAIL, "broken", "do this")], console) == 1
    text = console.export_text()
    assert "do this" in text and "1 problem(s): d" in text


def test_cli_doctor_on_this_machine_reports_no_camera_and_exits_1():
    proc = run_cli("doctor", columns=200)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "no DAVIS-346 (152a:841a) on USB" in proc.stdout
    if not os.path.exists("/dev/uinput"):
        assert "/dev/uinput does not exist" in proc.stdout and doctor.RULES_INSTALL in proc.stdout


def test_evdev_missing_is_a_warning_naming_the_uinput_extra(monkeypatch):
    import sys

    # as on aarch64 without the [uinput] extra: `import evdev` finds no module
    monkeypatch.setitem(sys.modules, "evdev", None)
    check = doctor.check_library("evdev", doctor.EVDEV_DIST)
    assert check.status == WARN and "[uinput]" in check.detail and "--output hid" in check.detail
    assert "pipx inject neurotouch-hid evdev" in check.fix.splitlines()
    assert doctor.report([check], Console(file=io.StringIO())) == 0
    # a module of no extra that is missing is still a failure
    monkeypatch.setitem(sys.modules, "numba", None)
    assert doctor.check_library("numba", "numba").status == FAIL


def test_doctor_says_whether_the_first_run_still_has_to_compile(monkeypatch, tmp_path):
    """A cache with nothing compiled in it (a fresh install) is fine but says the first run
    compiles, so a slow first start is expected; a compiled one says runs start at once."""
    from neurotouch_hid.service import warmup

    monkeypatch.setattr(warmup, "is_cold", lambda group: True)
    cold = doctor.check_jit_cache()
    assert cold.status == OK and "empty yet: the first run compiles the pipeline" in cold.detail
    monkeypatch.setattr(warmup, "is_cold", lambda group: False)
    assert "the pipeline is compiled" in doctor.check_jit_cache().detail
