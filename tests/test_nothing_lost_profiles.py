"""Nothing lost in the profiles (docs/limits.md): edits on a full or read-only config folder end in
one line and exit 2 with the profile byte-identical; edits and ``profile use`` run side by side all
land; a symlinked profile keeps its link.

A full disk is a real one: a small tmpfs mounted for the test (root and ``mount`` are needed: CI
runs as root; elsewhere those tests are skipped, saying why). A read-only folder is a read-only
bind mount: ``chmod`` does not stop root."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from pathlib import Path

import pytest
from hostile_helpers import ROOT, assert_refused, cli
from nothing_lost_helpers import _env, _mount, _snapshot, full_disk

PROFILE = [sys.executable, "-m", "neurotouch_hid.cli", "profile"]


@contextlib.contextmanager
def read_only(folder: Path):
    """``folder`` bind-mounted read-only over itself (root writes through a chmod)."""
    _mount("--bind", str(folder), str(folder))
    try:
        _mount("-o", "remount,bind,ro", str(folder))
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


# --- profiles: a full or read-only config folder, side by side edits ---------------------------
def test_profile_edits_on_a_full_or_read_only_config_folder_are_one_line_and_keep_the_profile(tmp_path):
    config = tmp_path / "config"
    env = _env(config)
    assert cli("profile", "new", "mine", "--from", "default", env=env)[0] == 0
    profiles = config / "neurotouch-hid"
    before = _snapshot(profiles)
    set_push = ("profile", "set", "mine", "mappings.push.deadzone_mm", "1.25")
    with read_only(profiles):
        for args in (set_push, ("profile", "new", "other"), ("profile", "auto", "add", "4242", "mine")):
            assert_refused(cli(*args, env=env), "nothing was changed")
        assert _snapshot(profiles) == before
    work = tmp_path / "full"
    env = _env(work)
    with full_disk(work, 512, lambda _: cli("profile", "new", "mine", "--from", "default", env=env)) as full:
        before = _snapshot(full / "neurotouch-hid")
        for args in (set_push, ("profile", "new", "other"), ("profile", "auto", "add", "4242", "default")):
            assert_refused(cli(*args, env=env), "No space left on device")
        assert _snapshot(full / "neurotouch-hid") == before
    flat = tmp_path / "flat"
    flat.write_text("a file where the config folder should be\n")
    assert_refused(cli(*set_push[:2], "default", *set_push[3:], env=_env(flat)), "nothing was changed")
    assert flat.read_text() == "a file where the config folder should be\n"


def test_parallel_profile_edits_all_land(tmp_path):
    """8 ``profile set`` of different keys and 10 ``profile auto add`` at once: every change is in
    the files afterwards (they kept 2 and 7)."""
    env = _env(tmp_path / "config")
    assert subprocess.run([*PROFILE, "new", "mine", "--from", "default"], env=env, cwd=ROOT).returncode == 0
    keys = [f"mappings.{m}.{f}" for m in ("push", "twist", "zoom", "pinch") for f in ("deadzone_mm", "saturation_mm")]
    values = {key: f"{(9 + i) if 'saturation' in key else 0.1 + 0.01 * i:.2f}" for i, key in enumerate(keys)}
    runs = [subprocess.Popen([*PROFILE, "set", "mine", key, value], env=env, cwd=ROOT) for key, value in values.items()]
    runs += [
        subprocess.Popen(
            [*PROFILE, "auto", "add", str(4000 + i), "mouse"], env=env, cwd=ROOT, stdout=subprocess.DEVNULL
        )
        for i in range(10)
    ]
    assert [p.wait(timeout=300) for p in runs] == [0] * len(runs)
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.service.games import load_game_map

    profile = load_profile(tmp_path / "config" / "neurotouch-hid" / "profiles" / "mine.yaml")
    for key, value in values.items():
        _, name, field = key.split(".")
        assert getattr(profile.mappings[name], field) == pytest.approx(float(value)), key
    assert sorted(load_game_map(tmp_path / "config" / "neurotouch-hid" / "games.yaml").steam) == list(range(4000, 4010))


def test_a_profile_name_ending_in_a_newline_is_refused(cli):
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.mapping.editor import user_profile_path

    with pytest.raises(ProfileError, match="not allowed"):
        user_profile_path("evil\n")
    done = cli("new", "evil\n")
    assert done.returncode == 2 and "not allowed" in done.stderr, done.stderr
    assert not cli.user_dir.exists() or not list(cli.user_dir.glob("evil*"))


def test_profile_set_writes_through_a_symlinked_profile_and_keeps_the_link(cli, tmp_path):
    kept = tmp_path / "kept" / "mine.yaml"
    kept.parent.mkdir()
    assert cli("new", "mine").returncode == 0
    (cli.user_dir / "mine.yaml").rename(kept)
    (cli.user_dir / "mine.yaml").symlink_to(kept)
    done = cli("set", "mine", "mappings.push.deadzone_mm", "1.5")
    assert done.returncode == 0, done.stderr
    assert (cli.user_dir / "mine.yaml").is_symlink()
    assert "deadzone_mm: 1.5" in kept.read_text()


# --- the control socket: many `profile use` at once --------------------------------------------
def test_parallel_profile_use_all_get_their_answer(tmp_path):
    """The backlog of 4 made ten `profile use` at once fail with "Resource temporarily
    unavailable"; over the clients served at once they were answered busy."""
    import threading
    import time

    from neurotouch_hid.service.control import ControlServer, request_use

    folder = tmp_path / "run"
    folder.mkdir(mode=0o700)
    (folder / "neurotouch-hid").mkdir(mode=0o700)
    gate = threading.Event()

    def use(ref: str) -> str:
        gate.wait(5)  # every client waits here: the backlog and the served ones fill up
        time.sleep(0.01)
        return f"switched to {ref}"

    server = ControlServer(use, path=folder / "neurotouch-hid" / "control.sock")
    assert server.start()
    answers, errors = [], []

    def ask(i: int) -> None:
        try:
            answers.append(request_use(f"p{i}", path=server.path, timeout_s=20))
        except Exception as exc:  # noqa: BLE001 (each failure is collected and shown)
            errors.append(repr(exc))

    try:
        threads = [threading.Thread(target=ask, args=(i,)) for i in range(40)]
        for t in threads:
            t.start()
        time.sleep(0.5)
        gate.set()
        for t in threads:
            t.join(60)
    finally:
        server.stop()
    assert not errors, errors[:3]
    assert sorted(answers) == sorted(f"switched to p{i}" for i in range(40))
