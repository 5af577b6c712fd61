"""Damage for AEDAT4 recordings (tests/test_damaged_files.py, benchmarks/bench_damaged_recordings.py):
flipped bits, cuts and swapped packets, as a bad disk, an interrupted copy or another tool makes them."""

from __future__ import annotations

import random
import struct

from neurotouch_hid.sources.recording_checks import AEDAT4_MAGIC


def packets(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of each complete packet (int32 stream id, uint32 size, payload) before
    the index table: the AEDAT4 layout after the header."""
    (size,) = struct.unpack_from("<I", data, len(AEDAT4_MAGIC))
    pos, found = len(AEDAT4_MAGIC) + 4 + size, []
    while pos + 8 <= len(data):
        length = 8 + struct.unpack_from("<I", data, pos + 4)[0]
        if pos + length > len(data):
            break
        found.append((pos, length))
        pos += length
    return found[:-1]  # the last one is the index table


def damage(data: bytes, kind: str, seed: int) -> bytes:
    """``data`` with ``kind`` of damage: "flip" (1-32 bits anywhere after the version line),
    "cut" (at a random byte), "swap" (two neighbouring packets exchanged)."""
    rng = random.Random(seed)
    if kind == "flip":
        out = bytearray(data)
        for _ in range(rng.randint(1, 32)):
            i = rng.randrange(len(AEDAT4_MAGIC), len(out))
            out[i] ^= 1 << rng.randrange(8)
        return bytes(out)
    if kind == "cut":
        return data[: rng.randrange(len(AEDAT4_MAGIC), len(data))]
    found = packets(data)
    i = rng.randrange(len(found) - 1)
    (p1, l1), (p2, l2) = found[i], found[i + 1]
    return data[:p1] + data[p2 : p2 + l2] + data[p1 : p1 + l1] + data[p2 + l2 :]
