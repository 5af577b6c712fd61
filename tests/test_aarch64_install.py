"""``pipx install .`` on a 64-bit ARM board (a Raspberry Pi 4 or 5) takes every dependency as a
wheel: no compiler, no headers. pip resolves the install for aarch64 here, wheels only
(``--only-binary=:all: --platform manylinux_2_28_aarch64`` and the older manylinux tags,
``--python-version 3.11 --implementation cp``), and every package it picks must be a wheel.
python-evdev, which has no aarch64 wheel, is the ``uinput`` extra there; without it the driver
loads profiles (``key_names.KEY_NAMES``) and says what to install when a uinput output is asked for.

pip evaluates environment markers for the machine it runs on, whatever ``--platform`` says, so
the project's own dependencies are taken from pyproject.toml with their markers evaluated for
aarch64 Linux (``packaging``) and handed to pip as plain requirements; the dependencies' own
dependencies are resolved by pip with this machine's markers (Linux, CPython 3.11: only
``platform_machine`` differs, and no dependency of theirs uses it today).

Needs PyPI: skipped, with the reason, where it cannot be reached at all, except in CI (``CI`` set),
where that fails. The resolution reads only metadata (PEP 658), about 30 s.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request

import pytest
from helpers import project_requirements
from packaging.requirements import Requirement
from test_extras import assert_names_the_extra, cli_without

#: The environment markers of a Raspberry Pi OS (Debian 12) board with CPython 3.11.
AARCH64 = {
    "sys_platform": "linux",
    "platform_system": "Linux",
    "platform_machine": "aarch64",
    "os_name": "posix",
    "python_version": "3.11",
    "python_full_version": "3.11.2",
    "implementation_name": "cpython",
    "platform_python_implementation": "CPython",
}


#: ``--platform`` for glibc 2.28 on aarch64 and every older manylinux tag it runs (pip before 24
#: does not expand ``manylinux_2_28`` to the tags below it; most aarch64 wheels are ``2_17``).
PLATFORMS = [
    arg
    for tag in [f"manylinux_2_{minor}_aarch64" for minor in range(28, 16, -1)] + ["manylinux2014_aarch64"]
    for arg in ("--platform", tag)
]


def _pypi_reachable() -> str | None:
    try:
        urllib.request.urlopen("https://pypi.org/simple/pip/", timeout=15).close()
        return None
    except OSError as exc:
        return str(exc)


def test_every_dependency_installs_as_a_wheel_on_aarch64(tmp_path):
    problem = _pypi_reachable()
    if problem and not os.environ.get("CI"):
        pytest.skip(f"PyPI cannot be reached from here: {problem}")
    reqs = project_requirements(environment=AARCH64)
    names = {r.name for r in reqs}
    assert "evdev" not in names and "evdev-binary" not in names  # the uinput extra's, there
    plain = [str(Requirement(f"{r.name}{r.specifier}")) for r in reqs]
    report = tmp_path / "report.json"
    result = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
         "--only-binary=:all:", *PLATFORMS, "--python-version", "3.11",
         "--implementation", "cp", "--target", str(tmp_path / "target"), "--report", str(report), *plain],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, f"pip cannot install every dependency as an aarch64 wheel:\n{result.stderr[-3000:]}"
    picked = json.loads(report.read_text())["install"]
    not_wheels = [p["download_info"]["url"] for p in picked if not p["download_info"]["url"].endswith(".whl")]
    assert not_wheels == []
    got = {p["metadata"]["name"].lower().replace("_", "-") for p in picked}
    assert {"numba", "llvmlite", "opencv-contrib-python-headless", "dv-processing", "numpy"} <= got
    assert not any("aarch64" not in p["download_info"]["url"] and "-none-any" not in p["download_info"]["url"]
                   for p in picked), "a platform wheel that is not aarch64's"  # fmt: skip


def test_the_uinput_extra_brings_python_evdev_on_aarch64_only():
    assert [r.name for r in project_requirements(("uinput",), AARCH64) if r.name.startswith("evdev")] == ["evdev"]
    x86 = AARCH64 | {"platform_machine": "x86_64"}
    assert [r.name for r in project_requirements(("uinput",), x86) if r.name.startswith("evdev")] == ["evdev-binary"]


def test_the_key_names_are_python_evdevs():
    from evdev import ecodes

    from neurotouch_hid.core.key_names import KEY_NAMES

    assert KEY_NAMES <= set(ecodes.ecodes)
    assert {"KEY_A", "KEY_SPACE", "KEY_LEFTSHIFT", "KEY_TAB", "KEY_VOLUMEUP"} <= KEY_NAMES


def test_without_python_evdev_profiles_load_and_the_gamepad_names_the_uinput_extra(tmp_path):
    code = (
        "import sys; sys.modules['evdev'] = None\n"
        "from neurotouch_hid.mapping.profile import load_profile\n"
        "print(sorted(load_profile('switch-access').keyboard_keys))\n"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert loaded.returncode == 0 and "KEY_" in loaded.stdout, loaded.stderr
    result = cli_without(["evdev"], "run", "--source", "sim", "--output", "gamepad", "--seconds", "0.1")
    assert_names_the_extra(result, "uinput", "evdev")
    assert "the virtual gamepad (--output gamepad) needs evdev" in result.stderr
