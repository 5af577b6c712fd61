"""Inputs crafted to break the driver (tests/test_hostile_inputs.py, benchmarks/fuzz_inputs.py):
decompression bombs in AEDAT4 recordings and bombs in YAML."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from neurotouch_hid.sources import EVENT_DTYPE
from neurotouch_hid.sources.recording import AEDAT4_MAGIC, RecordingWriter

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


def bomb_recording(path: Path, inflated: int = 3 << 30) -> Path:
    """A real zstd AEDAT4 recording (dv-processing) whose index table is replaced by one more
    event packet that inflates to ``inflated`` bytes (3 GiB: a file of ~100 KB)."""
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
    struct.pack_into("<q", data, at, -1)  # no index table: the decoder reads to the end
    payload = zstd_rle_bomb(inflated)
    path.write_bytes(bytes(data[:table]) + struct.pack("<II", 0, len(payload)) + payload)
    return path
