"""Shared fixtures: the one real-kernel boot per test session (tests/kernel/vm.py), and a user
config folder in tmp for every other test, and ``cli``: the profile commands run in this process.

The boot starts in the background as soon as the tests are collected, when any of them needs it,
and the tests that need it run last: the host's tests run while the guest boots and checks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kernel.vm import (  # noqa: E402
    KernelUnavailable,
    boot_summary,
    cancel_background_boot,
    guest_results,
    start_background_boot,
)


def _needs_guest(item: pytest.Item) -> bool:
    return "guest" in getattr(item, "fixturenames", ())


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests on the guest's results last (in their own order), so that the boot overlaps the
    host's tests."""
    items.sort(key=_needs_guest)  # stable: the order within each group is kept


def pytest_collection_finish(session: pytest.Session) -> None:
    if not session.config.option.collectonly and any(_needs_guest(item) for item in session.items):
        start_background_boot()


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    line = boot_summary()
    if line:
        terminalreporter.write_line(line)


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    cancel_background_boot()  # an interrupted or -x session leaves no qemu behind


@pytest.fixture(autouse=True)
def user_config_in_tmp(request, tmp_path, monkeypatch) -> Path | None:
    """Every test's user config folder (profiles, calibrated sensor.yaml) is an empty folder in
    tmp, so that tests never read or write the real one (platformdirs follows XDG_CONFIG_HOME).
    Not for the kernel tests: the guest boots with the environment it always had."""
    if request.node.get_closest_marker("kernel"):
        return None
    folder = tmp_path / "config"
    monkeypatch.setenv("XDG_CONFIG_HOME", str(folder))
    return folder


@pytest.fixture(scope="session")
def guest() -> dict:
    """The JSON results of every guest check (tests/kernel/checks_*.py), from one boot of Debian's
    kernel under qemu. Skips, with the reason, only where qemu cannot be installed at all."""
    try:
        return guest_results()
    except KernelUnavailable as exc:
        pytest.skip(reason=f"cannot boot a real kernel here: {exc}")


def passed(guest: dict, name: str) -> dict:
    """The details of guest check ``name``, failing the test with the guest's error if it failed."""
    entry = guest.get(name)
    assert entry is not None, f"the guest did not run {name} (setup: {guest.get('setup')})"
    assert entry["ok"], f"{name}: {entry.get('error')}\n{entry.get('traceback', '')}\nboot: {guest.get('_boot')}"
    return entry["details"]


@pytest.fixture()
def cli(tmp_path, monkeypatch, capsys):
    """``neurotouch-hid profile ARGS`` in this process (cli.main: errors -> exit 2), XDG in tmp;
    ``cli.user_dir``: the user's profiles folder."""
    from neurotouch_hid.cli import main

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("VISUAL", raising=False)

    def run(*args: str, editor: str | None = None) -> subprocess.CompletedProcess:
        if editor is not None:
            monkeypatch.setenv("EDITOR", editor)
        monkeypatch.setattr(sys, "argv", ["neurotouch-hid", "profile", *args])
        capsys.readouterr()
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = exc.code or 0
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(args, code, out, err)

    run.user_dir = tmp_path / "config" / "neurotouch-hid" / "profiles"
    return run
