"""Inputs crafted to break the driver (docs/limits.md): each ends with exit 0 or 2, one short
message, no traceback, and bounded memory; the running driver refuses them and keeps going.

Commands run in child processes, measured with ``wait4`` (their peak memory) and guarded by an
address-space limit, so that a bound that does not hold fails the test without taking the
machine's memory."""

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
from helpers import started, wait_until
from hostile_inputs import ALIAS_BOMB, DEEP_YAML, bomb_recording
from test_control import runtime_dir  # noqa: F401 (a fixture)

import neurotouch_hid
from neurotouch_hid.core.errors import ProfileError, SensorError

#: The tree whose package the tests import (children import the same one).
ROOT = Path(neurotouch_hid.__file__).resolve().parents[1]
#: Peak memory a crafted input may cost a command (KB, ru_maxrss): "well under 1 GiB".
MAX_RSS_KB = 512 * 1024
#: Most a refusal may print (bytes): one line, a few KB at most.
MAX_OUTPUT = 4096


#: Runs in the child in place of the command: it forks the command from its own small process,
#: limits the command's address space, waits for it and writes the command's peak memory (wait4's
#: ru_maxrss, KB) to the file descriptor given. Forked straight from the test process, the command
#: would report that process's memory as its own peak (exec records the high-water mark of the
#: memory the child was forked with), and the suite's process passes 512 MB.
_LAUNCHER = """
import os, resource, sys
fd, limit, argv = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3:]
pid = os.fork()
if pid == 0:
    os.close(fd)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    os.execv(argv[0], argv)
_, status, usage = os.wait4(pid, 0)
os.write(fd, str(usage.ru_maxrss).encode())
code = os.waitstatus_to_exitcode(status)
os._exit(code if code >= 0 else 128 - code)
"""


def bounded_run(args: list[str], *, env: dict | None = None, timeout_s: float = 30.0, address_space_gib: float = 3):
    """Run ``args``; (exit code, stdout, stderr, peak RSS in KB). Killed after ``timeout_s`` (exit
    code None then); its address space is limited so that a runaway allocation fails in it. A
    command killed by a signal exits 128 + the signal's number."""
    size = int(address_space_gib * (1 << 30))
    read_fd, write_fd = os.pipe()
    launcher = [sys.executable, "-c", _LAUNCHER, str(write_fd), str(size), *args]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        try:
            proc = subprocess.Popen(
                launcher, stdout=out, stderr=err, env=env, cwd=ROOT, pass_fds=(write_fd,), start_new_session=True
            )
        finally:
            os.close(write_fd)
        end = time.monotonic() + timeout_s
        code = None
        while time.monotonic() < end:
            pid, status, _ = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
                break
            time.sleep(0.05)
        else:
            os.killpg(proc.pid, signal.SIGKILL)  # the launcher and the command
            os.wait4(proc.pid, 0)
        proc.returncode = code  # reaped here: keep Popen from waiting again
        with os.fdopen(read_fd, "rb") as report:
            rss = int(report.read() or 0)
        out.seek(0)
        err.seek(0)
        return code, out.read().decode(errors="replace"), err.read().decode(errors="replace"), rss


def cli(*args: str, env: dict | None = None, **kw):
    return bounded_run([sys.executable, "-m", "neurotouch_hid.cli", *args], env=env or _env(), **kw)


def _env(**extra) -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT), **extra)


def assert_refused(result, *must_say: str) -> None:
    """Exit 2, one short line naming the problem, no traceback, bounded memory."""
    code, out, err, rss = result
    assert code == 2, f"exit {code}: {err[-2000:]}"
    assert "Traceback" not in err and len(out) + len(err) <= MAX_OUTPUT, err[-2000:]
    assert len(err.strip().splitlines()) == 1, err
    for words in must_say:
        assert words in err, err
    assert rss < MAX_RSS_KB, f"peak memory {rss // 1024} MB"


# --- recordings ---------------------------------------------------------------------------------
def test_a_decompression_bomb_is_refused_before_it_is_inflated(tmp_path):
    """~100 KB of zstd RLE blocks declaring 3 GiB in one packet: ``info`` refuses the packet from
    its framing, without inflating it."""
    path = bomb_recording(tmp_path / "bomb.aedat4", inflated=3 << 30)
    assert path.stat().st_size < 200_000
    assert_refused(cli("info", str(path)), "decompression bomb", "docs/limits.md")


def test_a_bomb_behind_a_table_position_the_packets_skip_over_is_refused_too(tmp_path):
    """The decoder stops at the index table only when a packet ends exactly on it: a header
    naming a byte inside a packet does not hide the packets after it from the checks."""
    path = bomb_recording(tmp_path / "bomb.aedat4", inflated=3 << 30, table_at=200)
    assert_refused(cli("info", str(path)), "decompression bomb")


def test_the_reader_refuses_a_bomb_after_yielding_what_comes_before(tmp_path):
    """The stream every command reads gives the packets before the bomb, then one RecordingError."""
    from neurotouch_hid.core.errors import RecordingError
    from neurotouch_hid.sources.recording import RecordingReader

    path = bomb_recording(tmp_path / "bomb.aedat4", inflated=256 << 20)
    read = []
    with RecordingReader(path) as reader, pytest.raises(RecordingError, match="would inflate to up to 268435456"):
        for item in reader.stream():
            read.append(len(item))
    assert sum(read) == 2000  # every event before the bomb


def test_a_bomb_spread_over_many_small_packets_meets_the_file_budget():
    """Packets of 32 MiB each stay under the packet bound; their total against the file's size
    does not (MAX_INFLATE_RATIO beyond MIN_INFLATE_BUDGET)."""
    from hostile_inputs import zstd_rle_bomb

    from neurotouch_hid.sources.packet_bounds import COMPRESSION_ZSTD, inflated_bound
    from neurotouch_hid.sources.recording_checks import MAX_INFLATE_RATIO, MAX_PACKET_BYTES, MIN_INFLATE_BUDGET

    payload = zstd_rle_bomb(32 << 20)
    bound = inflated_bound(payload, COMPRESSION_ZSTD)
    assert bound == 32 << 20 and bound <= MAX_PACKET_BYTES
    packets_to_budget = MIN_INFLATE_BUDGET // bound + 1
    assert packets_to_budget * bound > max(MIN_INFLATE_BUDGET, MAX_INFLATE_RATIO * packets_to_budget * len(payload))


# --- YAML ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text, says",
    [
        (ALIAS_BOMB, "aliases"),
        (DEEP_YAML, "nested more than"),
        ("mappings: {}\ndescription: " + "1" * 5000 + "\n", "a number of 5000 characters"),
        ("mappings: {}\ndescription: x\ndescription: y\n", "duplicate key"),
    ],
    ids=["alias-bomb", "8000-deep", "5000-digits", "duplicate-key"],
)
def test_profile_validate_refuses_yaml_bombs_in_one_line(tmp_path, text, says):
    path = tmp_path / "crafted.yaml"
    path.write_text(text)
    assert_refused(cli("profile", "validate", str(path)), says, f"{path}:")


def test_profile_numbers_must_be_finite():
    text = "mappings:\n  move: {input: push, output: left_stick, deadzone_mm: .inf}\n"
    with pytest.raises(ProfileError, match="finite number"):
        from neurotouch_hid.mapping.profile import parse_profile

        parse_profile(text, "inf.yaml")


def test_yaml_errors_carry_a_plain_hint_beside_file_and_line():
    from neurotouch_hid.mapping.profile import parse_profile

    with pytest.raises(ProfileError) as tab:
        parse_profile("mappings:\n\tjump: {input: push, output: A}\n", "tabs.yaml")
    assert str(tab.value).startswith("tabs.yaml:2: not valid YAML") and "never tabs" in str(tab.value)
    with pytest.raises(ProfileError) as indent:
        parse_profile("mappings:\n  jump: {input: push, output: A}\n kick: x\n", "indent.yaml")
    assert str(indent.value).startswith("indent.yaml:3:") and "indentation" in str(indent.value)


def _load_sensor_in_child(path: Path):
    code = (
        "import sys\nfrom neurotouch_hid.core.errors import SensorError\n"
        "from neurotouch_hid.core.sensor import SensorGeometry\n"
        "try:\n    SensorGeometry.load(sys.argv[1])\nexcept SensorError as exc:\n"
        "    print(exc, file=sys.stderr)\n    sys.exit(2)\n"
    )
    return bounded_run([sys.executable, "-c", code, str(path)], env=_env())


@pytest.mark.parametrize(
    "text, says",
    [
        (ALIAS_BOMB, "aliases"),
        (DEEP_YAML, "nested more than"),
        ("width: " + "3" * 5000 + "\n", "a number of 5000 characters"),
        ("px_per_mm: .inf\n", "finite number"),
        ("gel_radius_px: 1e300\n", "gel_radius_px"),
        ("gel_center_px: [1e300, 130]\n", "gel_center_px"),
        ("rotation_deg: 1e300\n", "rotation_deg"),
        ("width: 346\nwidth: 640\n", "duplicate key"),
    ],
    ids=["alias-bomb", "8000-deep", "5000-digits", "inf", "huge", "huge-centre", "huge-rotation", "duplicate-key"],
)
def test_sensor_yaml_bombs_are_one_line(tmp_path, text, says):
    path = tmp_path / "sensor.yaml"
    path.write_text(text)
    assert_refused(_load_sensor_in_child(path), says)


def test_a_fifo_as_sensor_yaml_does_not_hang(tmp_path):
    fifo = tmp_path / "sensor.yaml"
    os.mkfifo(fifo)
    assert_refused(_load_sensor_in_child(fifo), "not a regular file")
    with pytest.raises(SensorError, match="not a regular file"):
        from neurotouch_hid.core.sensor import SensorGeometry

        SensorGeometry.load(fifo)


def test_a_fifo_or_a_huge_file_as_profile_is_refused(tmp_path):
    from neurotouch_hid.mapping.profile import load_profile

    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ProfileError, match="not a regular file"):
        load_profile(fifo)
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (300 * 1024) + "\nmappings: {}\n")
    with pytest.raises(ProfileError, match="larger than 256 KB"):
        load_profile(big)


def test_error_messages_do_not_echo_long_values():
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.evaluation.runner import pipeline_config
    from neurotouch_hid.mapping.profile import parse_profile

    with pytest.raises(ProfileError) as err:
        parse_profile("mappings:\n  m: {input: push, output: A, press_mm: [" + "1, " * 20000 + "1]}\n", "long.yaml")
    assert len(str(err.value)) < 600
    many = "mappings:\n" + "".join(f"  m{i}: {{input: nope, output: A}}\n" for i in range(500))
    with pytest.raises(ProfileError, match="and 490 more") as err:
        parse_profile(many, "many.yaml")
    assert len(str(err.value)) < 4096
    with pytest.raises(NeurotouchError) as err:
        pipeline_config(["contacts.r_mm=" + "x" * 100_000])
    assert len(str(err.value)) < 600
    with pytest.raises(NeurotouchError, match="finite"):
        pipeline_config(["contacts.r_mm=inf"])


# --- the keyboard: SysRq and what the device offers --------------------------------------------
@pytest.mark.parametrize(
    "output, says",
    [("KEY_LEFTALT+KEY_SYSRQ+KEY_B", "KEY_SYSRQ"), ("KEY_SYSRQ", "reboots")],
)
def test_sysrq_is_refused_at_validation_with_the_reason(output, says):
    from neurotouch_hid.mapping.profile import parse_profile

    with pytest.raises(ProfileError, match=says):
        parse_profile(f"mappings:\n  boom: {{input: push_intensity, output: {output}}}\n", "sysrq.yaml")


@pytest.mark.parametrize(
    "output", ["KEY_POWER", "KEY_POWER2", "KEY_RESTART", "KEY_SLEEP", "KEY_LEFTCTRL+KEY_SUSPEND", "KEY_RFKILL"]
)
def test_keys_the_machine_acts_on_are_refused_and_never_offered(output):
    """logind powers off, reboots, suspends or hibernates on these keys, rfkill-input turns the
    radios off: no profile may press them, and the virtual keyboard never has them."""
    from evdev import ecodes

    from neurotouch_hid.mapping.profile import KERNEL_COMMAND_KEYS, keyboard_keys, parse_profile
    from neurotouch_hid.targets.uinput.desktop import keyboard_codes

    with pytest.raises(ProfileError, match="the system acts on it"):
        parse_profile(f"mappings:\n  off: {{input: push_intensity, output: {output}}}\n", "power.yaml")
    offered = set(keyboard_codes(keyboard_keys()))
    assert not offered & {ecodes.ecodes[name] for name in KERNEL_COMMAND_KEYS}


def test_a_chord_or_a_profile_cannot_ask_for_every_key():
    """A chord holds at most MAX_CHORD_KEYS keys, a profile presses at most MAX_PROFILE_KEYS."""
    from neurotouch_hid.mapping.profile import (
        KERNEL_COMMAND_KEYS,
        MAX_CHORD_KEYS,
        MAX_PROFILE_KEYS,
        keyboard_keys,
        parse_profile,
    )

    keys = sorted(keyboard_keys() - KERNEL_COMMAND_KEYS)
    chord = "+".join(keys[:300])
    with pytest.raises(ProfileError, match=f"a chord of at most {MAX_CHORD_KEYS} keys") as err:
        parse_profile(f"mappings:\n  all: {{input: push_intensity, output: {chord}}}\n", "chord.yaml")
    assert len(str(err.value)) < 1000
    plain = [k for k in keys if k[4:].isalnum() and k not in ("KEY_DELETE", "KEY_KPDOT")][: MAX_PROFILE_KEYS + 1]
    many = "mappings:\n" + "".join(f"  m{i}: {{input: push_intensity, output: {k}}}\n" for i, k in enumerate(plain))
    with pytest.raises(ProfileError, match=f"at most {MAX_PROFILE_KEYS} different keyboard keys"):
        parse_profile(many, "many.yaml")
    assert len(parse_profile(many.rsplit("  m", 1)[0] + "\n", "fits.yaml").keyboard_keys) == MAX_PROFILE_KEYS


def test_ctrl_alt_delete_is_refused_even_over_several_mappings():
    from neurotouch_hid.mapping.profile import parse_profile

    text = (
        "mappings:\n  a: {input: push_intensity, output: KEY_LEFTCTRL+KEY_LEFTALT}\n"
        "  b: {input: pinch, output: KEY_DELETE}\n"
    )
    with pytest.raises(ProfileError, match="Ctrl\\+Alt\\+Delete"):
        parse_profile(text, "cad.yaml")


class _FakeUinput:
    def __init__(self, capabilities):
        self.capabilities, self.events, self.closed, self.device = capabilities, [], False, None

    def write(self, etype, code, value):
        self.events.append((etype, code, value))

    def syn(self):
        self.events.append((0, 0, 0))

    def close(self):
        self.closed = True


class _Pad:
    device_path = None

    def write(self, state):
        pass

    def neutralise(self):
        pass

    close = neutralise


def test_keyboard_offers_only_the_profiles_keys_and_is_made_again_for_new_ones(monkeypatch):
    """The keyboard offers the loaded profiles' keys and udev's keyboard block, never SysRq; a
    profile needing more replaces it by one offering both, after releasing what was held."""
    from evdev import ecodes

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.mapping.profile import parse_profile
    from neurotouch_hid.targets.uinput import desktop

    made: list[_FakeUinput] = []
    monkeypatch.setattr(
        desktop, "create_uinput", lambda what, caps, *a, **k: made.append(_FakeUinput(caps)) or made[-1]
    )
    monkeypatch.setattr(desktop, "RELEASE_GRACE_S", 0.0, raising=False)
    first = parse_profile("mappings:\n  jump: {input: push_intensity, output: KEY_F5}\n", "a.yaml")
    known = parse_profile("mappings:\n  go: {input: pinch, output: KEY_F6}\n", "b.yaml")
    outputs = desktop.UinputOutputs(_Pad(), first, known=[known])
    codes = set(made[0].capabilities[ecodes.EV_KEY])
    assert codes == set(range(1, 32)) | {ecodes.KEY_F5, ecodes.KEY_F6}
    assert ecodes.KEY_SYSRQ not in codes and ecodes.KEY_POWER not in codes
    outputs.write(ControllerState(keys=frozenset({"KEY_F5", "KEY_POWER"})))
    assert (ecodes.EV_KEY, ecodes.KEY_F5, 1) in made[0].events
    assert all(code != ecodes.KEY_POWER for _, code, _ in made[0].events)  # not offered: not written
    outputs.prepare(known)  # offered already: the same device
    assert len(made) == 1
    more = parse_profile("mappings:\n  save: {input: push_intensity, output: KEY_LEFTCTRL+KEY_S+KEY_F9}\n", "c.yaml")
    outputs.prepare(more)
    assert len(made) == 2 and made[0].closed and (ecodes.EV_KEY, ecodes.KEY_F5, 0) in made[0].events
    assert set(made[1].capabilities[ecodes.EV_KEY]) == codes | {ecodes.KEY_F9}
    outputs.close()


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


# --- the running driver -------------------------------------------------------------------------
def _predictions(folder: Path, seconds: float) -> Path:
    """Estimates alternating a 2 s push and 0.3 s of rest: the states change all the time, and a
    push holds A long enough to stop the process while it is held."""
    from neurotouch_hid.core.dataset import write_predictions
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType

    step_us, estimates = 10_000, []
    for i in range(int(seconds * 1e6 / step_us)):
        pushing = i % 230 < 200
        estimates.append(
            GestureEstimate(
                t_us=i * step_us,
                gesture=GestureType.PUSH if pushing else GestureType.NONE,
                intensity_mm=4.0 if pushing else 0.0,
                translation_mm=(3.0, 0.0) if pushing else (0.0, 0.0),
                resting=not pushing,
            )
        )
    path = folder / "preds.jsonl"
    write_predictions(path, estimates)
    return path


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


def test_a_predictions_file_that_is_a_fifo_or_nests_deeply_is_one_line(tmp_path):
    """``run --source PRED.jsonl`` replays predictions: a FIFO does not hang it, a line of 100 000
    '[' is one error naming the line (it was a RecursionError traceback)."""
    fifo = tmp_path / "fifo.jsonl"
    os.mkfifo(fifo)
    assert_refused(cli("run", "--source", str(fifo), "--output", "jsonl", "--seconds", "1"), "not a regular file")
    deep = tmp_path / "deep.jsonl"
    deep.write_text("[" * 100_000 + "\n")
    assert_refused(cli("run", "--source", str(deep), "--output", "jsonl", "--seconds", "1"), f"{deep}:1:")


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


def test_reading_a_small_file_reserves_no_more_than_it_holds(tmp_path):
    """The bounded read of a predictions file (at most 1 GiB) reserved its bound before reading:
    a MemoryError in a guest of 1 GiB. A run reading a small one fits a 1.5 GiB address space."""
    preds = _predictions(tmp_path, 2.0)
    code, out, err, _ = cli("run", "--source", str(preds), "--output", "jsonl", "--seconds", "1", address_space_gib=1.5)
    assert code == 0 and "Traceback" not in err, err[-2000:]
    assert out.strip()


# --- games.yaml and the processes the driver looks at -----------------------------------------
def _games_yaml(tmp_path: Path) -> tuple[Path, dict]:
    config = tmp_path / "config"
    (config / "neurotouch-hid").mkdir(parents=True)
    return config / "neurotouch-hid" / "games.yaml", _env(XDG_CONFIG_HOME=str(config))


@pytest.mark.parametrize(
    "text, says",
    [
        (ALIAS_BOMB.replace("a: &a", "steam: {}\nexecutable: {}\na: &a"), "aliases"),
        (DEEP_YAML.replace("mappings", "steam"), "nested more than"),
        ("executable:\n  game: " + "x" * 200_000 + "\n", "a value of 200000 characters"),
        ("steam:\n  " + "4" * 5000 + ": mouse\n", "a number of 5000 characters"),
        ("steam:\n  " + "4" * 12 + ": mouse\n", "is not a Steam app id"),
        ('executable:\n  "a\\nb\\e]0;x\\a": mouse\n', "'a\\nb\\x1b]0;x\\x07' is not a name"),
    ],
    ids=["alias-bomb", "8000-deep", "200k-value", "5000-digits", "12-digit-app", "control-characters"],
)
def test_games_yaml_goes_through_the_bounded_reader(tmp_path, text, says):
    """``profile auto list`` on a crafted games.yaml: one short line (the value never echoed
    whole, control characters escaped), bounded time and memory."""
    path, env = _games_yaml(tmp_path)
    path.write_text(text)
    assert_refused(cli("profile", "auto", "list", env=env), says, str(path))


@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_games_yaml_that_never_ends_blocks_neither_the_command_nor_the_watcher(tmp_path, kind):
    """A FIFO (a read would wait for a writer for ever) or a link to /dev/zero (a read never
    ends) as games.yaml: refused by ``profile auto list``; the running driver's watcher says so
    and goes on polling."""
    import threading

    from neurotouch_hid.service.games import GameProfiles

    path, env = _games_yaml(tmp_path)
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to("/dev/zero")
    assert_refused(cli("profile", "auto", "list", env=env), "not a regular file")

    class NoGames:
        def games(self, game_map):
            return []

    watcher = GameProfiles(lambda ref, why: ref, "default", path=path, scanner=NoGames())
    polled = threading.Thread(target=lambda: [watcher.poll() for _ in range(3)], daemon=True)
    polled.start()
    polled.join(30.0)
    assert not polled.is_alive(), "the watcher blocked on games.yaml"


def test_a_process_with_a_huge_steam_app_id_does_not_hide_the_game_beside_it(tmp_path):
    """A process whose SteamAppId is 5000 digits (Python refuses to convert it) and one whose
    environment is 800 KB of padding before SteamAppId: the game beside them is still found, and
    neither is taken for a game."""
    from neurotouch_hid.service.games import GameMap, ProcessScanner

    sleeper = [sys.executable, "-c", "import time; time.sleep(120)"]
    base = {"PATH": os.environ.get("PATH", "")}
    # app ids no other process has (the scanner sees all of this user's, other test runs' too):
    # past every real Steam app's, holding this process's pid
    game = 3_000_000_000 + os.getpid() * 256
    padded = game + 1
    procs = [
        subprocess.Popen(sleeper, env=dict(base, SteamAppId="9" * 5000)),
        subprocess.Popen(
            sleeper, env=dict(base, **{f"PAD{i}": "p" * 100_000 for i in range(8)}, SteamAppId=str(padded))
        ),
        subprocess.Popen(sleeper, env=dict(base, SteamAppId=str(game))),
    ]
    try:
        for proc in procs:
            started(proc)
        game_map = GameMap({game: "mouse", padded: "spacecraft", int("9" * 10): "x"}, {})
        found = ProcessScanner().games(game_map)
        assert [(g.key, g.pid) for g in found] == [(game, procs[2].pid)], found
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


# --- outputs never destroy an input -------------------------------------------------------------
def test_track_never_writes_over_its_recording_a_link_or_what_a_failure_would_lose(tmp_path, sim_gel_short_recording):
    """``track X --out X`` (the recording emptied), ``--out`` a symbolic link (written through
    to wherever it points), and a track that fails (a recording without APS frames): each is
    one line, and every file is as it was."""
    from hostile_inputs import small_events

    from neurotouch_hid.sources.recording_writer import RecordingWriter

    recording = tmp_path / "rec.aedat4"
    recording.write_bytes(sim_gel_short_recording.read_bytes())
    size = recording.stat().st_size
    assert_refused(cli("track", str(recording), "--out", str(recording)), "same file as the input")
    assert recording.stat().st_size == size
    hard = tmp_path / "hard.aedat4"
    os.link(recording, hard)
    assert_refused(cli("track", str(recording), "--out", str(hard)), "same file as the input")
    precious, link = tmp_path / "precious.txt", tmp_path / "link.jsonl"
    precious.write_text("keep me\n")
    link.symlink_to(precious)
    assert_refused(cli("track", str(recording), "--out", str(link)), "symbolic link")
    assert precious.read_text() == "keep me\n"
    no_frames = tmp_path / "noframes.aedat4"
    with RecordingWriter(no_frames, frames=False) as writer:
        writer.write_events(small_events())
    out = tmp_path / "pred.jsonl"
    out.write_text("earlier predictions\n")
    code, _, err, _ = cli("track", str(no_frames), "--out", str(out), timeout_s=300)
    assert code == 2 and "Traceback" not in err, err
    assert out.read_text() == "earlier predictions\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "a temporary file was left"


def test_a_cut_recording_keeps_every_window_before_the_cut_and_says_where(tmp_path, sim_gel_short_recording):
    """A recording cut short: ``track`` writes the windows before the cut beside its output
    (``NAME.partial``: a failed run is never the output), exits 2, and says how many and up to
    when."""
    cut = tmp_path / "cut.aedat4"
    data = sim_gel_short_recording.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    out = tmp_path / "pred.jsonl"
    code, _, err, _ = cli("track", str(cut), "--out", str(out), timeout_s=300)
    assert code == 2 and "Traceback" not in err, err
    windows = len(out.with_name("pred.jsonl.partial").read_text().splitlines())
    assert not out.exists(), "a failed run's windows at the output's name"
    assert windows > 10 and f"the {windows} windows before it are in {out}.partial" in err and "up to t=" in err, err


def test_run_never_writes_its_states_over_its_source_or_through_a_link(tmp_path):
    """``run --source P.jsonl --output jsonl --out P.jsonl`` replaced the source it was
    replaying; a link as ``--out`` was written through."""
    preds = _predictions(tmp_path, 0.5)
    before = preds.read_bytes()
    run = ["run", "--fast", "--profile", "default", "--output", "jsonl"]
    assert_refused(cli(*run, "--source", str(preds), "--out", str(preds)), "same file as the input")
    assert preds.read_bytes() == before
    link = tmp_path / "states.jsonl"
    link.symlink_to(preds)
    assert_refused(cli(*run, "--source", str(preds), "--out", str(link)), "symbolic link")
    assert preds.read_bytes() == before
    states = tmp_path / "real-states.jsonl"
    states.write_text("old\n")
    code, _, err, _ = cli(*run, "--source", str(preds), "--out", str(states), timeout_s=300)
    assert code == 0, err
    assert [json.loads(line)["t_us"] for line in states.read_text().splitlines()][-1] >= 0


# --- per-game profiles under the unit as shipped ------------------------------------------------
_SCAN = (
    "import sys\nfrom neurotouch_hid.service.games import GameMap, ProcessScanner\n"
    "print(' '.join(str(g.pid) for g in ProcessScanner().games(GameMap({4242: 'mouse'}, {}))))\n"
)


def test_the_shipped_unit_lets_the_driver_see_the_users_games():
    """The scanner run as the unit runs it (in the user namespace ``PrivateUsers=`` would make,
    ``unshare --user --map-current-user``, if the unit asked for it): a Steam game of the same
    user beside it is found. In such a namespace the kernel refuses to show the driver any other
    process's environment and executable, so no game was ever found under the service; the unit
    asks for no namespace (test_packaging.py, tests/kernel/checks_user_unit.py)."""
    from test_packaging import UNIT, _rule_lines

    private_users = "PrivateUsers=yes" in set(_rule_lines(UNIT.read_text()))
    wrap = ["unshare", "--user", "--map-current-user"] if private_users else []
    game = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(120)"], env={"PATH": os.environ["PATH"], "SteamAppId": "4242"}
    )
    try:
        started(game)
        found = subprocess.run(
            [*wrap, sys.executable, "-c", _SCAN], env=_env(), capture_output=True, text=True, timeout=60, cwd=ROOT
        )
        assert found.returncode == 0, found.stderr
        assert str(game.pid) in found.stdout.split(), f"the game (pid {game.pid}) was not found: {found.stdout!r}"
    finally:
        game.kill()
        game.wait()


# --- the profile editor and info read through the bounded reader --------------------------------
def _user_profiles(config: Path) -> Path:
    folder = config / "neurotouch-hid" / "profiles"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def assert_refused_briefly(result, *must_say: str) -> None:
    """Exit 2, a short message (a line and a hint) naming the problem, no traceback, bounded
    memory."""
    code, out, err, rss = result
    assert code == 2, f"exit {code}: {err[-2000:]}"
    assert "Traceback" not in err and len(out) + len(err) <= 1000, err[-2000:]
    for words in must_say:
        assert words in err, err
    assert rss < MAX_RSS_KB, f"peak memory {rss // 1024} MB"


@pytest.mark.parametrize(
    "args",
    [
        ("set", "deep", "description", "x"),
        ("unset", "deep", "description"),
        ("set", "zero", "description", "x"),
        ("unset", "zero", "description"),
        ("show", "zero"),
        ("new", "copy", "--from", "zero"),
    ],
)
def test_the_editor_reads_user_profiles_within_the_bounds(user_config_in_tmp, args):
    """A user profile nested 8000 deep (``profile set`` raised RecursionError), and one that is
    a link to /dev/zero (``profile show`` read gigabytes): a short message, bounded memory."""
    folder = _user_profiles(user_config_in_tmp)
    (folder / "deep.yaml").write_text(DEEP_YAML)
    (folder / "zero.yaml").symlink_to("/dev/zero")
    says = "nested more than" if "deep" in args else "not a regular file"
    assert_refused_briefly(cli("profile", *args), says)


@pytest.mark.parametrize("command", ["validate", "show", "new", "use"])
@pytest.mark.parametrize("suffix", ["", ".yaml"])
def test_a_300_character_profile_name_is_one_short_line(command, suffix):
    """A name (or a file name) of 300 characters: the file system refuses it (ENAMETOOLONG),
    which was a traceback; the message quotes an excerpt."""
    name = "p" * 300 + suffix
    code, out, err, _ = cli("profile", command, name, env=_env(XDG_RUNTIME_DIR=tempfile.mkdtemp()))
    assert code == 2 and "Traceback" not in err and len(err) < 1000, err
    assert len(err.strip().splitlines()) == 1 and "p" * 300 not in err, err


def test_info_on_a_fifo_is_refused_not_waited_on(tmp_path):
    fifo = tmp_path / "camera.aedat4"
    os.mkfifo(fifo)
    assert_refused(cli("info", str(fifo)), "not a regular file")


# --- terminal escapes ---------------------------------------------------------------------------
OSC = "\x1b]52;c;cm0gLXJmIH4K\x07\x1b]0;pwned\x07"  # a clipboard write and a window title


def test_descriptions_file_names_and_game_names_reach_the_terminal_escaped(user_config_in_tmp):
    """A profile whose description holds OSC sequences (clipboard write, window title), a
    profile file whose name holds one, a game name with a newline: printed with their control
    characters escaped, never as they are."""
    folder = _user_profiles(user_config_in_tmp)
    (folder / "evil.yaml").write_text(f'description: "{OSC.encode("unicode_escape").decode()}"\nmappings: {{}}\n')
    (folder / f"name{OSC}.yaml").write_text("mappings: {}\n")
    code, out, err, _ = cli("profile", "list")
    assert code == 0, err
    assert "\x1b" not in out + err and "\x07" not in out + err, repr(out)
    assert "\\x1b]52;c;" in out, out
    code, out, err, _ = cli("profile", "validate", str(folder / f"missing{OSC}.yaml"))
    assert code == 2 and "\x1b" not in out + err and "\\x1b]0;pwned" in err, repr(err)
    code, out, err, _ = cli("profile", "auto", "add", "game\nname\x1b[2J", "default")
    assert code == 2 and "\x1b" not in out + err and "game\\nname\\x1b[2J" in err, repr(err)
    assert len(err.strip().splitlines()) == 1, err


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


# --- numbers past what the kernel and int64 hold --------------------------------------------------
@pytest.mark.parametrize("t_us", ["1e30", "Infinity", "9223372036854775807"])
def test_a_predictions_time_past_int64_is_one_line(tmp_path, t_us):
    """``run --source P.jsonl`` with a line whose t_us is 1e30 (an OverflowError traceback),
    infinite, negative or past 2^62."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0}\n'
        f'{{"t_us": {t_us}, "gesture": "none", "resting": true, "intensity_mm": 0.0}}\n'
    )
    assert_refused(cli("run", "--source", str(preds), "--fast", "--output", "jsonl"), f"{preds}:2:")


@pytest.mark.parametrize(
    "field",
    [
        '"intensity_mm": 1e999',
        '"intensity_mm": 1.0, "translation_mm": [-1e400, 0.0]',
        '"intensity_mm": 1.0, "rotation_rad": 1e309',
    ],
)
def test_a_predictions_number_past_a_float_is_refused_with_its_line(tmp_path, field):
    """JSON's 1e999 is no constant: it read as infinity, and ``profile test`` went on (exit 0)
    with a push of infinite intensity that moved nothing."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0}\n'
        f'{{"t_us": 10000, "gesture": "push", "resting": false, {field}}}\n'
    )
    assert_refused(cli("profile", "test", "default", "--source", str(preds)), f"{preds}:2:")


@pytest.mark.parametrize(
    ("field", "named"),
    [
        ('"resting": "no", "intensity_mm": 1.0', "resting"),
        ('"resting": false, "intensity_mm": -5', "intensity_mm"),
        ('"resting": false, "intensity_mm": "5"', "intensity_mm"),
        ('"resting": false, "intensity_mm": 1.0, "translation_mm": [1, 2, 3]', "translation_mm"),
        ('"resting": false, "intensity_mm": 1.0, "contacts_mm": [[1, "a"]], "contacts_px": [[1, 2]]', "contacts_mm"),
        ('"resting": false, "intensity_mm": 1.0, "scale": true', "scale"),
    ],
)
def test_a_predictions_field_of_the_wrong_type_is_refused_by_name(tmp_path, field, named):
    """``"resting": "no"`` read as resting (a non-empty string is true), a negative or quoted
    intensity and a three-number translation were taken as they came: each is refused with its
    line and field (docs/dataset.md, Predictions)."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0}\n'
        f'{{"t_us": 10000, "gesture": "push", {field}}}\n'
    )
    result = cli("profile", "test", "default", "--source", str(preds))
    assert_refused(result, f"{preds}:2: {named}")


def test_a_line_separator_inside_a_predictions_string_is_no_line_break(tmp_path):
    """JSON lines end at "\\n" only: a raw U+2028 inside a string split the line in two (refused as
    an unterminated string), and every line number after it was off."""
    preds = tmp_path / "p.jsonl"
    preds.write_text(
        '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0, "note": "a\u2028b"}\r\n'
        '{"t_us": 10000, "gesture": "wave", "resting": true, "intensity_mm": 0.0}\n',
        encoding="utf-8",
    )
    assert_refused(cli("profile", "test", "default", "--source", str(preds)), f"{preds}:2:", "wave")


def _prediction_line(t_us: int, gesture: str = "none") -> str:
    return json.dumps({"t_us": t_us, "gesture": gesture, "resting": True, "intensity_mm": 0.0}) + "\n"


def test_a_predictions_file_is_read_a_line_at_a_time_and_a_replay_refuses_it_before_it_starts(tmp_path):
    """An hour of predictions (80 MB) was read whole, split and kept as estimates: 0.6 GB. The
    estimates come now as they are asked for, each line bounded; a replay checks the file first."""
    from neurotouch_hid.core.dataset import MAX_PREDICTION_LINE_BYTES, iter_predictions, open_predictions
    from neurotouch_hid.core.errors import DatasetError

    preds = tmp_path / "p.jsonl"
    preds.write_text(_prediction_line(0) + _prediction_line(10_000, "wave"))
    estimates = iter_predictions(preds)
    assert next(estimates).t_us == 0  # the first line's estimate before the second is read
    with pytest.raises(DatasetError, match=rf"^{preds}:2: bad value: .*wave"):
        next(estimates)
    with pytest.raises(DatasetError, match=rf"^{preds}:2: bad value: .*wave"):
        open_predictions(preds)  # nothing handed on from a file that breaks a rule

    padded = '{"t_us": 0, "gesture": "none", "resting": true, "intensity_mm": 0.0, "note": "%s"}\n'
    preds.write_text(_prediction_line(0) + padded % ("x" * MAX_PREDICTION_LINE_BYTES))
    with pytest.raises(DatasetError, match=rf"^{preds}:2: longer than 64 KB, the most a line of a predictions file"):
        open_predictions(preds)
    preds.write_text(_prediction_line(0) + padded % ("x" * (MAX_PREDICTION_LINE_BYTES - 100)))
    assert [e.t_us for e in open_predictions(preds)] == [0, 0]  # a long line within the bound is read


def test_a_pressed_file_has_at_most_as_many_rows_as_a_labels_file(tmp_path, monkeypatch):
    from neurotouch_hid.core import dataset
    from neurotouch_hid.core.errors import DatasetError

    monkeypatch.setattr(dataset, "MAX_LABEL_ROWS", 3)
    pressed = tmp_path / "s.pressed.csv"
    pressed.write_text("t_start_us,pressed_us\n" + "".join(f"{t},{t + 5}\n" for t in range(0, 30, 10)))
    assert len(dataset.read_pressed(pressed)) == 3
    pressed.write_text("t_start_us,pressed_us\n" + "".join(f"{t},{t + 5}\n" for t in range(0, 40, 10)))
    with pytest.raises(DatasetError, match=rf"^{pressed}:5: more than 3 rows"):
        dataset.read_pressed(pressed)


def test_relative_counts_per_step_stay_within_an_event():
    """2000 wheel mappings at the highest speed sum to more hi-res counts in a step than an
    event's signed 32 bits hold (python-evdev raised OverflowError): the step is clamped."""
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType
    from neurotouch_hid.mapping.mapper import Mapper
    from neurotouch_hid.mapping.profile import parse_profile
    from neurotouch_hid.mapping.rel_motion import MAX_REL_COUNTS_PER_STEP

    text = "mappings:\n" + "".join(
        f"  w{i}: {{input: intensity, output: {'REL_WHEEL' if i % 2 else 'REL_X'}, speed: 100000}}\n"
        for i in range(2000)
    )
    mapper = Mapper(parse_profile(text, "wheels.yaml"))
    push = dict(gesture=GestureType.PUSH, intensity_mm=20.0, translation_mm=(1.0, 0.0), resting=False)
    for t_us in (0, 100_000, 200_000):
        state = mapper.update(GestureEstimate(t_us=t_us, **push))
        assert all(abs(v) <= MAX_REL_COUNTS_PER_STEP < 2**31 for v in state.rel.values()), state.rel
    assert state.rel["REL_X"] == MAX_REL_COUNTS_PER_STEP and state.rel["REL_WHEEL_HI_RES"] == MAX_REL_COUNTS_PER_STEP


def test_a_labels_file_that_is_a_fifo_or_a_huge_header_is_one_line(tmp_path):
    """Labels (``eval``, ``enrol``) are read through the bounded reader: a FIFO was waited on for
    ever; a header line of a million cells was quoted whole."""
    from neurotouch_hid.core.dataset import read_labels
    from neurotouch_hid.core.errors import DatasetError

    fifo = tmp_path / "x.labels.csv"
    os.mkfifo(fifo)
    with pytest.raises(DatasetError, match="not a regular file"):
        read_labels(fifo)
    wide = tmp_path / "wide.labels.csv"
    wide.write_text(",".join(["x"] * 1_000_000) + "\n")
    with pytest.raises(DatasetError) as err:
        read_labels(wide)
    assert len(str(err.value)) < 1000


def test_log_lines_reach_the_terminal_escaped():
    """Whatever a log message quotes (a file name, a process's name) is printed with its control
    characters escaped: the command's log handler formats every line through limits.printable."""
    code = (
        "import logging, sys\nimport neurotouch_hid.cli as cli\n"
        "shout = lambda: logging.getLogger('neurotouch_hid.x').warning('game \\x1b]0;pwned\\x07 runs')\n"
        "cli.app.command('shout')(shout)\n"
        "sys.argv = ['neurotouch-hid', 'shout']\ncli.main()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "\x1b" not in done.stderr and "game \\x1b]0;pwned\\x07 runs" in done.stderr, repr(done.stderr)
