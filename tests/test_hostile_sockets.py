"""The running driver and its control socket against hostile clients (docs/limits.md): malformed and
slow requests, ctrl-z, a control folder open to others or another user's socket, a profile path
naming a file that is no profile. The driver refuses them and keeps going."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from helpers import wait_until
from hostile_helpers import ROOT, _env, _predictions
from hostile_inputs import ALIAS_BOMB, DEEP_YAML
from test_control import runtime_dir  # noqa: F401 (a fixture)


# --- the control socket -------------------------------------------------------------------------
def _send(path: Path, data: bytes) -> bytes:
    """Send ``data`` and read the answer. The driver answers a request over its size bound and
    closes at once, so sending the rest of it may meet a closed socket (EPIPE): the answer is
    already queued for us then, and is read all the same."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(10)
        sock.connect(str(path))
        try:
            sock.sendall(data)
            sock.shutdown(socket.SHUT_WR)
        except (BrokenPipeError, ConnectionResetError):
            pass
        return sock.makefile("rb").readline()


@pytest.mark.usefixtures("runtime_dir")
def test_control_socket_refuses_malformed_requests_and_keeps_answering():
    from neurotouch_hid.service.control import ControlServer, request_use, socket_path

    server = ControlServer(lambda ref: f"switched to {ref}")
    assert server.start()
    try:
        path = socket_path()
        for crafted in (b"[" * 8192 + b"\n", b"[" * 100_000, b'{"command": "use", "profile": [[[[["x"]]]]]}\n'):
            answer = json.loads(_send(path, crafted))
            assert answer["ok"] is False and len(answer["message"]) < 200
        silent = [socket.socket(socket.AF_UNIX) for _ in range(3)]
        for sock in silent:
            sock.connect(str(path))
        assert request_use("mouse", timeout_s=5.0) == "switched to mouse"  # beside the silent ones
        for sock in silent:  # the driver drops them after its request timeout
            assert sock.recv(100) == b""
            sock.close()
        assert request_use("default", timeout_s=5.0) == "switched to default"
    finally:
        server.stop()


def _lines(path: Path) -> list[dict]:
    text = path.read_text() if path.exists() else ""
    complete = text[: text.rfind("\n") + 1]  # a line being written is left out
    return [json.loads(line) for line in complete.splitlines() if line.strip()]


def _process_state(pid: int) -> str:
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


def test_the_running_driver_survives_every_attack_and_ctrl_z_releases_everything(tmp_path):
    """``run --output jsonl`` with the control socket: an 8 KB line of '[', a silent client, the
    alias-bomb profile through ``profile use``, a deeply nested profile on SIGHUP: each is refused
    and logged, the driver keeps writing states and then switches profile on request. SIGTSTP
    writes the neutral state before the process stops; SIGCONT resumes; SIGTERM exits 0."""
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.service.control import SOCKET_NAME, request_use

    xdg = tmp_path / "xdg"
    xdg.mkdir(mode=0o700)
    sock_path = xdg / SOCKET_NAME
    profile, good, bomb = tmp_path / "mine.yaml", tmp_path / "good.yaml", tmp_path / "bomb.yaml"
    states = tmp_path / "states.jsonl"
    good.write_text(
        "mappings:\n  stick: {input: push, output: left_stick}\n  fire: {input: push_intensity, output: A}\n"
    )
    profile.write_text(good.read_text())
    bomb.write_text(ALIAS_BOMB)
    env = _env(XDG_RUNTIME_DIR=str(xdg), XDG_CONFIG_HOME=str(tmp_path / "config"))
    preds = _predictions(tmp_path, 120.0)
    args = ["run", "--source", str(preds), "--profile", str(profile), "--output", "jsonl", "--out", str(states)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "neurotouch_hid.cli", *args],
        env=env,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        process_group=0,  # a group of its own that is not orphaned: the kernel honours its SIGTSTP
    )
    try:
        assert wait_until(lambda: sock_path.exists() and len(_lines(states)) >= 2), "the driver did not start"
        answer = json.loads(_send(sock_path, b"[" * 8192 + b"\n"))
        assert answer["ok"] is False
        silent = socket.socket(socket.AF_UNIX)
        silent.connect(str(sock_path))
        with pytest.raises(NeurotouchError, match="aliases"):
            request_use(str(bomb), path=sock_path, timeout_s=10.0)
        profile.write_text(DEEP_YAML)
        proc.send_signal(signal.SIGHUP)
        seen = len(_lines(states))
        assert wait_until(lambda: len(_lines(states)) >= seen + 4), "the driver stopped writing states"
        assert request_use(str(good), path=sock_path, timeout_s=10.0) == f"switched to profile {good}"
        silent.close()
        # Ctrl-Z while A is held: the outputs are released (a neutral line at the held state's
        # time, not a later window's release), then the process stops
        assert wait_until(lambda: _lines(states)[-1]["buttons"]["BTN_SOUTH"]), "A never held"
        proc.send_signal(signal.SIGTSTP)
        assert wait_until(lambda: _process_state(proc.pid) == "T", 30.0)
        stopped = _lines(states)
        held, last = stopped[-2], stopped[-1]
        assert not any(last["buttons"].values()) and last["axes"]["ABS_X"] == 0, last
        assert held["buttons"]["BTN_SOUTH"] and last["t_us"] == held["t_us"], stopped[-3:]
        proc.send_signal(signal.SIGCONT)
        assert wait_until(lambda: len(_lines(states)) > len(stopped) + 2), "nothing after SIGCONT"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    assert "Traceback" not in err and len(err) < 8192, err[-3000:]
    assert "profile not reloaded" in err and "request refused" in err


@pytest.mark.usefixtures("runtime_dir")
def test_a_client_sending_a_byte_now_and_then_is_dropped_at_the_request_deadline():
    """The request timeout is for the whole line: a byte every second does not keep a slot."""
    from neurotouch_hid.service.control import REQUEST_TIMEOUT_S, ControlServer, socket_path

    server = ControlServer(lambda ref: "switched")
    assert server.start()
    try:
        with socket.socket(socket.AF_UNIX) as slow:
            slow.connect(str(socket_path()))
            start = time.monotonic()
            closed = False
            for _ in range(int(REQUEST_TIMEOUT_S * 20)):  # 10x the deadline: a loaded machine is late
                try:
                    slow.sendall(b"[")
                except OSError:  # the driver closed it
                    closed = True
                    break
                slow.settimeout(0.5)
                try:
                    if slow.recv(100) == b"":
                        closed = True
                        break
                except TimeoutError:
                    pass
                except ConnectionResetError:  # closed with our unread byte in its buffer: a reset
                    closed = True
                    break
            assert closed, f"still connected after {time.monotonic() - start:.1f} s of a byte every 0.5 s"
    finally:
        server.stop()


# --- the control socket's folder and peers ------------------------------------------------------
NOBODY = 65534


def _as_nobody(work) -> int:
    """Fork a child that drops to uid/gid 65534 and runs ``work()``; returns its pid (needs root,
    as the suite runs: only root can make a process of another user)."""
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            work()
        finally:
            os._exit(0)
    return pid


def _forged_driver(folder: Path, ready: int) -> None:
    """Another user's socket that answers every request "ok" (bound as root in ``folder``, then
    listening as uid 65534: SO_PEERCRED reports the listener's credentials)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(folder / "control.sock"))
    os.chmod(folder / "control.sock", 0o777)
    os.setgid(NOBODY)
    os.setuid(NOBODY)
    sock.listen(4)
    os.write(ready, b"x")
    sock.settimeout(60)
    conn, _ = sock.accept()
    conn.recv(8192)
    conn.sendall(b'{"ok": true, "message": "switched to profile forged"}\n')
    conn.close()


@pytest.fixture
def shared_runtime_dir(monkeypatch):
    """A runtime folder other users can reach (in /tmp, not under pytest's 0700 folders)."""
    import shutil

    folder = Path(tempfile.mkdtemp(prefix="nt-run-"))
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(folder))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def test_the_control_socket_folder_and_its_peer_are_checked(shared_runtime_dir, caplog):
    """A folder open to others is made 0700 by the driver; another user's folder is refused by
    both sides; a socket served by another user's process (a forged driver) is not asked;
    a client of another user is not answered."""
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.service.control import SOCKET_NAME, ControlServer, request_use

    shared = shared_runtime_dir
    folder = shared / SOCKET_NAME.split("/")[0]
    folder.mkdir(mode=0o777)
    os.chmod(folder, 0o777)
    server = ControlServer(lambda ref: f"switched to {ref}")
    assert server.start()
    try:
        assert folder.stat().st_mode & 0o777 == 0o700
        # a client of another user, given a way in, is closed unanswered
        os.chmod(shared, 0o755)
        os.chmod(folder, 0o755)
        os.chmod(server.path, 0o777)
        reply_r, reply_w = os.pipe()

        def client() -> None:
            os.setgid(NOBODY)
            os.setuid(NOBODY)
            try:
                os.write(reply_w, _send(server.path, b'{"command": "use", "profile": "mouse"}\n') or b"none")
            except OSError as exc:
                os.write(reply_w, f"error {exc}".encode())

        child = _as_nobody(client)
        os.waitpid(child, 0)
        os.close(reply_w)
        reply = os.read(reply_r, 8192)
        os.close(reply_r)
        # closed unanswered: nothing read, or the close seen as a reset or, when the server closed
        # before the request was written (a loaded machine), as a broken pipe
        assert reply == b"none" or b"reset by peer" in reply or b"Broken pipe" in reply, reply
        assert "a process of another user (uid 65534) connected; refused" in caplog.text
    finally:
        server.stop()
    # another user's folder: the driver runs without a socket, the client does not talk
    os.chown(folder, NOBODY, NOBODY)
    assert not ControlServer(lambda ref: ref).start()
    with pytest.raises(NeurotouchError, match="belongs to another user"):
        request_use("mouse", path=folder / "control.sock")
    # a forged driver in a folder of ours: SO_PEERCRED tells
    os.chown(folder, os.getuid(), os.getgid())
    os.chmod(folder, 0o700)
    ready_r, ready_w = os.pipe()
    forger = _as_nobody(lambda: _forged_driver(folder, ready_w))
    try:
        assert os.read(ready_r, 1) == b"x"
        with pytest.raises(NeurotouchError, match="another user"):
            request_use("mouse", path=folder / "control.sock")
    finally:
        os.kill(forger, signal.SIGKILL)
        os.waitpid(forger, 0)


@pytest.mark.usefixtures("runtime_dir")
def test_profile_use_on_a_file_that_is_no_profile_does_not_quote_it(tmp_path):
    """The driver reads the file the client names: its answer says it is no profile without
    repeating what the file holds (a key, a password file)."""
    from neurotouch_hid.service.control import ControlServer, socket_path

    secrets = {
        "key": "-----BEGIN OPENSSH PRIVATE KEY-----\nb3BlbnNzaC1rZXktdjEAAAAABG5vbmUAAAAE\n-----END OPENSSH KEY-----\n",
        "env": "API_TOKEN: b3BlbnNzaC1rZXktdjEAAAAABG5vbmUAAAAE\n",
        "yaml-error": "password: [b3BlbnNzaC1rZXktdjEAAAAABG5vbmUAAAAE\n",
    }
    server = ControlServer(lambda ref: f"switched to {ref}")
    assert server.start()
    try:
        for name, text in secrets.items():
            path = tmp_path / f"{name}.txt"
            path.write_text(text)
            answer = json.loads(
                _send(socket_path(), json.dumps({"command": "use", "profile": str(path)}).encode() + b"\n")
            )
            assert answer["ok"] is False and str(path) in answer["message"], answer
            assert "b3BlbnNz" not in answer["message"] and "API_TOKEN" not in answer["message"], answer
    finally:
        server.stop()
