"""Inputs crafted to break the driver (tests/test_hostile_*.py, benchmarks/fuzz_inputs.py):
decompression bombs in AEDAT4 recordings and bombs in YAML."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from neurotouch_hid.sources import EVENT_DTYPE
from neurotouch_hid.sources.recording_checks import AEDAT4_MAGIC
from neurotouch_hid.sources.recording_writer import RecordingWriter

#: YAML's "billion laughs": 9 levels of 9 aliases, 9^9 strings once expanded (under 1 KB of text).
ALIAS_BOMB = 'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' + "".join(
    f"{c}: &{c} [{', '.join(['*' + p] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi")
)
#: 8000 nested lists.
DEEP_YAML = "mappings: " + "[" * 8000 + "]" * 8000 + "\n"


def small_events(n: int = 2000, width: int = 346, height: int = 260) -> np.ndarray:
    """``n`` time-ordered events spread over the sensor."""
    events = np.zeros(n, EVENT_DTYPE)
    events["timestamp"] = np.arange(n, dtype=np.int64) * 50
    events["x"] = np.arange(n) % width
    events["y"] = (np.arange(n) // width) % height
    events["polarity"] = np.arange(n) % 2
    return events


def zstd_rle_bomb(inflated: int) -> bytes:
    """A zstd frame of RLE blocks (4 bytes each for 128 KiB) inflating to ``inflated`` bytes."""
    block = 128 * 1024
    n = max(1, inflated // block)
    frame = struct.pack("<IBB", 0xFD2FB528, 0x00, 0x38)  # no content size, 128 KiB window
    blocks = [struct.pack("<I", (block << 3) | (1 << 1) | (i == n - 1))[:3] + b"\x00" for i in range(n)]
    return frame + b"".join(blocks)


def bomb_recording(path: Path, inflated: int = 3 << 30, table_at: int = -1) -> Path:
    """A real zstd AEDAT4 recording (dv-processing) whose index table is replaced by one more
    event packet that inflates to ``inflated`` bytes (3 GiB: a file of ~100 KB). The header says
    the table is at ``table_at`` (-1: none; the decoder stops only at exactly that byte)."""
    with RecordingWriter(path, frames=False, compression="ZSTD") as writer:
        writer.write_events(small_events())
    data = bytearray(path.read_bytes())
    (size,) = struct.unpack_from("<I", data, len(AEDAT4_MAGIC))
    header = bytes(data[len(AEDAT4_MAGIC) + 4 : len(AEDAT4_MAGIC) + 4 + size])
    root = struct.unpack_from("<I", header, 0)[0]
    vtable = root - struct.unpack_from("<i", header, root)[0]
    table_field = struct.unpack_from("<H", header, vtable + 6)[0]
    at = len(AEDAT4_MAGIC) + 4 + root + table_field
    table = struct.unpack_from("<q", data, at)[0]
    struct.pack_into("<q", data, at, table_at)  # the decoder reads to the end unless exactly there
    payload = zstd_rle_bomb(inflated)
    path.write_bytes(bytes(data[:table]) + struct.pack("<II", 0, len(payload)) + payload)
    return path


# --- fuzzing: the targets and the inputs they get (tests/test_fuzz_inputs.py, benchmarks/fuzz_inputs.py)
#: Longest message a refusal may carry (characters).
MAX_MESSAGE_CHARS = 4096


def check_message(exc: BaseException) -> None:
    """A refusal's message: not empty, not a file echoed at length."""
    text = str(exc)
    assert text and len(text) <= MAX_MESSAGE_CHARS, f"{type(exc).__name__} of {len(text)} characters"


def fuzz_profile(text: str) -> None:
    """A profile's YAML text: a Profile or one ProfileError."""
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.mapping.profile import parse_profile

    try:
        parse_profile(text, "fuzz.yaml")
    except ProfileError as exc:
        check_message(exc)


def fuzz_sensor(text: str, folder: Path) -> None:
    """A sensor.yaml's text, read from a file: a SensorGeometry or one SensorError."""
    from neurotouch_hid.core.errors import SensorError
    from neurotouch_hid.core.sensor import SensorGeometry

    path = folder / "sensor.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        SensorGeometry.load(path)
    except SensorError as exc:
        check_message(exc)


def fuzz_set(items: list[str]) -> None:
    """``--set NAME=VALUE`` strings, for each method: its config or one NeurotouchError."""
    from neurotouch_hid.core.errors import NeurotouchError
    from neurotouch_hid.evaluation.runner import pipeline_config

    for method in ("default", "paper"):
        try:
            pipeline_config(items, method=method)
        except NeurotouchError as exc:
            check_message(exc)


def fuzz_control(line: bytes) -> None:
    """One request line on the control socket: an answer ``{"ok": bool, "message": str}``, never
    an exception (the switch itself is a stand-in that refuses unknown profiles)."""
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.service.control import ControlServer

    def use(ref: str) -> str:
        if ref != "default":
            raise ProfileError(f"no profile named {ref[:40]!r}")
        return "switched"

    answer = ControlServer(use, path=Path("/nonexistent"))._answer(line)
    assert set(answer) == {"ok", "message"} and isinstance(answer["ok"], bool), answer
    assert len(answer["message"]) <= MAX_MESSAGE_CHARS


def fuzz_games(text: str, folder: Path) -> None:
    """A games.yaml's text, read from a file: the map, or one GameMapError; the round-trip path of
    ``profile auto remove`` too (it rewrites the file only when the entry is there)."""
    from neurotouch_hid.service.games import GameMapError, load_game_map, remove_game

    path = folder / "games.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        load_game_map(path)
    except GameMapError as exc:
        check_message(exc)
    try:
        remove_game("supertuxkart", path)
    except GameMapError as exc:
        check_message(exc)


def fuzz_control_socket(path: Path, data: bytes) -> None:
    """Bytes sent on the running server's real socket, then the write side closed: one JSON
    answer line or none (a line too long, a peer refused), never a crash of the server: a valid
    request right after is answered."""
    import socket

    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(20)
        sock.connect(str(path))
        try:
            sock.sendall(data)
            sock.shutdown(socket.SHUT_WR)
            line = sock.makefile("rb").readline()
        except (BrokenPipeError, ConnectionResetError):  # the server closed first: an answer was not due
            line = b""
    if line:
        answer = json.loads(line)
        assert set(answer) == {"ok", "message"} and isinstance(answer["ok"], bool), answer
        assert len(answer["message"]) <= MAX_MESSAGE_CHARS
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(20)
        sock.connect(str(path))
        sock.sendall(b'{"command": "use", "profile": "default"}\n')
        assert json.loads(sock.makefile("rb").readline()) == {"ok": True, "message": "switched"}


def control_server(folder: Path):
    """A started ControlServer on ``folder``/neurotouch-hid/control.sock whose switch accepts
    "default" only (the fuzzing's stand-in for the driver); stop it when done."""
    from neurotouch_hid.core.errors import ProfileError
    from neurotouch_hid.service.control import ControlServer

    def use(ref: str) -> str:
        if ref != "default":
            raise ProfileError(f"no profile named {ref[:40]!r}")
        return "switched"

    folder.chmod(0o700)
    server = ControlServer(use, path=folder / "neurotouch-hid" / "control.sock")
    assert server.start()
    return server


def fuzz_recording(original: bytes, edits: list[tuple[int, int]], cut: int | None, folder: Path) -> None:
    """A real recording with bytes replaced (position, value) and maybe cut: read by ``info`` and
    ``stream``, it gives data or one RecordingError, never anything else."""
    from neurotouch_hid.core.errors import RecordingError
    from neurotouch_hid.sources import Frame
    from neurotouch_hid.sources.packet_bounds import Unbounded, inflated_bound
    from neurotouch_hid.sources.recording import RecordingReader

    data = bytearray(original)
    for position, value in edits:
        data[len(AEDAT4_MAGIC) + position % (len(data) - len(AEDAT4_MAGIC))] = value
    if cut is not None:
        data = data[: len(AEDAT4_MAGIC) + cut % (len(data) - len(AEDAT4_MAGIC))]
    tail = bytes(data[-4096:])
    for compression in range(5):  # any bytes: a bound, or Unbounded for a pre-1.0 zstd frame only
        try:
            bound = inflated_bound(tail, compression)
        except Unbounded:
            assert compression in (3, 4), compression
            continue
        assert bound == len(tail) if compression == 0 else isinstance(bound, int), (compression, bound)
    path = folder / "fuzz.aedat4"
    path.write_bytes(bytes(data))
    try:
        with RecordingReader(path) as reader:
            info = reader.info
            events = frames = 0
            for item in reader.stream():
                if isinstance(item, Frame):
                    frames += 1
                else:
                    events += len(item)
            assert (events, frames) == (info.n_events, info.n_frames)  # the exact counts are what it streams
    except RecordingError as exc:
        check_message(exc)


def small_recording(folder: Path, compression: str) -> bytes:
    """The bytes of a real recording (dv-processing) of 2000 events and two APS frames."""
    from neurotouch_hid.sources import Frame

    path = folder / f"small-{compression}.aedat4"
    with RecordingWriter(path, compression=compression) as writer:
        events = small_events()
        writer.write_frame(Frame(0, np.full((260, 346), 100, np.uint8)))
        writer.write_events(events[:1000])
        writer.write_frame(Frame(int(events["timestamp"][1000]), np.full((260, 346), 120, np.uint8)))
        writer.write_events(events[1000:])
    return path.read_bytes()


def strategies():
    """The hypothesis strategies of each target's input, by target name."""
    from hypothesis import strategies as st

    from neurotouch_hid.mapping.profile import shipped_profiles_dir

    scalars = st.one_of(
        st.none(),
        st.booleans(),
        st.integers(),
        st.floats(allow_nan=True, allow_infinity=True),
        st.text(max_size=20),
        st.sampled_from(["push", "A", "left_stick", "KEY_SYSRQ", "KEY_A+KEY_B", "hold", ".inf", "*x", "&x"]),
    )
    values = st.recursive(
        scalars,
        lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=12), inner, max_size=5),
        max_leaves=30,
    )
    keys = st.sampled_from(["mappings", "layers", "device", "description", "input", "output", "width", "px_per_mm"])
    documents = st.dictionaries(keys | st.text(max_size=8), values, max_size=6).map(
        lambda d: json.dumps(d, default=str)
    )
    shipped = [p.read_text() for p in sorted(shipped_profiles_dir().glob("*.yaml"))]
    sensor_text = "width: 346\nheight: 260\npx_per_mm: 2.5\ngel_center_px: [173.0, 130.0]\ngel_radius_px: 75.0\n"

    def mutated(texts: list[str]):
        return st.tuples(
            st.sampled_from(texts), st.lists(st.tuples(st.integers(0, 10**6), st.text(max_size=4)), max_size=6)
        ).map(lambda t: _splice(*t))

    yaml_text = st.one_of(st.text(max_size=300), documents, mutated(shipped + [ALIAS_BOMB, sensor_text]))
    games_text = "steam:\n  4242: mouse\n  570: /home/me/p.yaml\nexecutable:\n  supertuxkart: spacecraft\n"
    game_keys = st.sampled_from(["steam", "executable"]) | st.text(max_size=8)
    game_values = st.dictionaries(st.integers() | st.text(max_size=12) | st.booleans(), values, max_size=4)
    game_documents = st.dictionaries(game_keys, game_values | values, max_size=3).map(
        lambda d: json.dumps(d, default=str)
    )
    games_yaml = st.one_of(
        st.text(max_size=300), game_documents, mutated([games_text, ALIAS_BOMB, "steam: " + DEEP_YAML])
    )
    settings_items = st.lists(
        st.one_of(
            st.text(max_size=40),
            st.tuples(
                st.sampled_from(
                    [
                        "contacts.r_mm",
                        "window_us",
                        "tracker.assoc_px",
                        "noise.kind",
                        "noise.time_us",
                        "tracker",
                        "x.y",
                    ]
                ),
                st.one_of(st.text(max_size=12), st.sampled_from(["inf", "nan", "-1", "1e999", "9" * 5000, "none"])),
            ).map(lambda t: f"{t[0]}={t[1]}"),
        ),
        max_size=4,
    )
    request = {"command": "use", "profile": "default"}
    lines = st.one_of(
        st.binary(max_size=200),
        values.map(lambda v: json.dumps(v, default=str).encode()),
        st.dictionaries(st.sampled_from(["command", "profile"]), values, max_size=2).map(
            lambda d: json.dumps({**request, **d}, default=str).encode()
        ),
        st.integers(1, 20000).map(lambda n: b"[" * n),
    )
    edits = st.lists(st.tuples(st.integers(0, 10**7), st.integers(0, 255)), min_size=1, max_size=16)
    return {
        "profile": yaml_text,
        "sensor": yaml_text,
        "set": settings_items,
        "control": lines,
        "games": games_yaml,
        "socket": lines | st.binary(min_size=8000, max_size=9000),
        "recording": st.tuples(st.sampled_from(["LZ4", "ZSTD", "NONE"]), edits, st.none() | st.integers(0, 10**7)),
    }


def _splice(text: str, edits: list[tuple[int, str]]) -> str:
    for position, piece in edits:
        at = position % (len(text) + 1)
        text = text[:at] + piece + text[at + len(piece) :]
    return text
