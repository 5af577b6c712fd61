"""A damaged or hostile AEDAT4 file: what is checked before the decoder reads it, and what one
pass over it found wrong.

The AEDAT4 format (iniVation's AEDAT4 specification, docs.inivation.com: a version line, a
uint32 size and an ``IOHeader`` flatbuffer, then packets of int32 stream id, uint32 size and a
payload, and an index table) is read here only as far as the bounds need: the file's path, its
header (every offset checked, :func:`_read_header`), each packet's stored and inflated size
before the ``aedat`` decoder reads it (:class:`_InflateGuard`, from the packet's LZ4/zstd framing,
:mod:`neurotouch_hid.sources.packet_bounds`), and the tally of skipped packets and cuts that
:class:`~neurotouch_hid.sources.recording.RecordingReader` raises as one RecordingError
(:class:`_Damage`; docs/limits.md).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from neurotouch_hid.core.errors import RecordingError
from neurotouch_hid.sources.packet_bounds import Unbounded, inflated_bound

#: The first bytes of every AEDAT4 file (the format's version line).
AEDAT4_MAGIC = b"#!AER-DAT4.0\r\n"
#: dv-processing refuses other file name endings (and its writer aborts the process on them).
AEDAT4_SUFFIX = ".aedat4"
#: The largest AEDAT4 header read (a real one is a few kB; a damaged size field must not make
#: the reader allocate gigabytes).
MAX_HEADER_BYTES = 16 << 20
#: Timestamps above this (us, ~146 000 years) are damaged data: they would overflow int64 maths.
MAX_TIMESTAMP_US = 1 << 62
#: A pass over a file ends after this many damaged packets in a row (nothing left to read).
MAX_CONSECUTIVE_ERRORS = 64
#: The most one packet may be, stored or inflated (bytes): the decoder holds a packet whole. A
#: DAVIS-346 packet is 10-200 KB (a 10 ms batch, or a 90 KB APS frame); 64 MiB is 5 million events.
MAX_PACKET_BYTES = 64 << 20
#: Inflated bytes (bounded from the packets' framing, packet_bounds.py) per stored byte, over the
#: file read so far, beyond :data:`MIN_INFLATE_BUDGET`: real event data compresses 3-10x, and the
#: bound counts up to a block's maximum for a tiny block (single-event packets reach ~2000x).
MAX_INFLATE_RATIO = 4096
#: Inflated bytes any recording may reach before :data:`MAX_INFLATE_RATIO` applies.
MIN_INFLATE_BUDGET = 1 << 30


# --- opening a file ---------------------------------------------------------------------------
def _check_path(path: Path) -> None:
    """Raise RecordingError unless ``path`` is an existing, readable regular file named ``*.aedat4``."""
    try:
        path.stat()
    except OSError as exc:  # missing, a name too long, a loop of links
        why = "no such file" if isinstance(exc, FileNotFoundError) else exc.strerror
        raise RecordingError(f"{path}: {why}") from None
    if not path.is_file():  # a pipe would block the reader, a device never ends
        what = "a directory" if path.is_dir() else "not a regular file (a pipe or a device)"
        raise RecordingError(f"{path}: is {what}, not an AEDAT4 recording")
    if not os.access(path, os.R_OK):
        raise RecordingError(f"{path}: cannot read the file (permission denied)")
    if path.suffix != AEDAT4_SUFFIX:
        raise RecordingError(
            f"{path}: not an AEDAT4 recording (its name must end in '{AEDAT4_SUFFIX}', which dv-processing requires)"
        )


def _read_header(path: Path) -> tuple[int, str, int, int]:
    """Read the AEDAT4 header: ``(dataTablePosition, infoNode XML, compression, end of header)``.

    The header is the version line, a little-endian uint32 size and an ``IOHeader`` flatbuffer
    (fields: compression, dataTablePosition int64 default -1 = no table, infoNode string, the
    streams' description as XML). Raises RecordingError when the file is not AEDAT4 or its
    header is incomplete or corrupt.
    """
    with open(path, "rb") as fh:
        head = fh.read(len(AEDAT4_MAGIC) + 4)
        if not head.startswith(AEDAT4_MAGIC):
            if head.startswith(b"#!AER-DAT") and not AEDAT4_MAGIC.startswith(head):
                version = head.split(b"\r")[0].decode("ascii", "replace")[2:]
                raise RecordingError(f"{path}: is {version}, only AEDAT4 is supported")
            if not head or not AEDAT4_MAGIC.startswith(head):
                raise RecordingError(f"{path}: not an AEDAT4 recording (it does not start with '#!AER-DAT4.0')")
        if len(head) < len(AEDAT4_MAGIC) + 4:
            raise RecordingError(f"{path}: truncated: the file ends inside its AEDAT4 header ({len(head)} bytes)")
        (size,) = struct.unpack_from("<I", head, len(AEDAT4_MAGIC))
        header = fh.read(min(size, MAX_HEADER_BYTES))
    if len(header) < size:
        raise RecordingError(f"{path}: truncated or corrupt: the file ends inside its AEDAT4 header")

    def read(fmt: str, offset: int) -> tuple:
        # every offset checked: the decoder reads this header unchecked (a Rust panic, or an
        # abort, on an offset out of the buffer or a description that is not UTF-8)
        if offset < 0 or offset + struct.calcsize(fmt) > len(header):
            raise struct.error("out of the header")
        return struct.unpack_from(fmt, header, offset)

    try:
        (root,) = read("<I", 0)
        (vtable_back,) = read("<i", root)
        vtable = root - vtable_back
        (vtable_size,) = read("<H", vtable)
        read(f"<{vtable_size}s", vtable)
        fields = [read("<H", vtable + 4 + 2 * i)[0] if vtable_size >= 6 + 2 * i else 0 for i in range(3)]
        position = read("<q", root + fields[1])[0] if fields[1] else -1
        compression = read("<i", root + fields[0])[0] if fields[0] else 0
        xml = ""
        if fields[2]:
            start = root + fields[2] + read("<I", root + fields[2])[0]
            (length,) = read("<I", start)
            xml = read(f"<{length}s", start + 4)[0].decode("utf-8")
    except (struct.error, UnicodeDecodeError):
        raise RecordingError(f"{path}: corrupt AEDAT4 header") from None
    return position, xml, compression, len(AEDAT4_MAGIC) + 4 + size


def _camera_name(xml: str) -> str:
    """The event stream's ``source`` (the camera name) in the header's XML, or "unknown"."""
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError:
        return "unknown"
    for node in root.iter("node"):
        attrs = {a.get("key"): a.text for a in node.findall("attr")}
        if attrs.get("typeIdentifier") == "EVTS":
            for info in node.iter("node"):
                source = {a.get("key"): a.text for a in info.findall("attr")}.get("source")
                if source:
                    return source
    return "unknown"


class _InflateGuard:
    """Follows the decoder through the file (packets are int32 stream id, uint32 size, payload)
    and bounds each packet before the decoder reads it: its stored size, its inflated size (from
    its compression framing, :func:`~neurotouch_hid.sources.packet_bounds.inflated_bound`) and
    the inflated total so far (:data:`MAX_INFLATE_RATIO`)."""

    def __init__(self, path: Path, start: int, table_position: int, compression: int) -> None:
        self.path, self.pos, self.table, self.compression = path, start, table_position, compression
        self.fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
        self.size = os.fstat(self.fd).st_size
        self.inflated = 0

    def close(self) -> None:
        os.close(self.fd)

    def check_next(self) -> str | None:
        """Why the next packet must not be read (the pass ends there), or None: read it. A packet
        that runs past the end of the file is not read either ("cut"): the decoder would reserve
        its declared size first."""
        if self.pos == self.table or self.pos + 8 > self.size:
            return None  # the decoder stops by itself here (it stops at the table only when exactly there)
        (length,) = struct.unpack("<I", os.pread(self.fd, 4, self.pos + 4))
        if self.pos + 8 + length > self.size:
            return "cut"
        if length > MAX_PACKET_BYTES:
            return f"a packet at byte {self.pos} stores {length} bytes (at most {MAX_PACKET_BYTES >> 20} MiB)"
        payload = os.pread(self.fd, length, self.pos + 8)
        try:
            bound = inflated_bound(payload, self.compression)
        except Unbounded as exc:
            return f"a packet at byte {self.pos} is {exc}, whose size cannot be bounded"
        if bound > MAX_PACKET_BYTES:
            return (
                f"a packet at byte {self.pos} of {length} bytes would inflate to up to {bound} bytes "
                f"(at most {MAX_PACKET_BYTES >> 20} MiB): a decompression bomb or a damaged file"
            )
        self.pos += 8 + length
        self.inflated += bound
        if self.inflated > max(MIN_INFLATE_BUDGET, MAX_INFLATE_RATIO * self.pos):
            return (
                f"its first {self.pos} bytes would inflate to up to {self.inflated} bytes (more than "
                f"{MAX_INFLATE_RATIO}x): a decompression bomb or a damaged file"
            )
        return None


class _Damage:
    """What one pass over a file found wrong: skipped packets, whether the file was cut, and why
    it was refused (a bound of :class:`_InflateGuard`)."""

    def __init__(self) -> None:
        self.skipped = 0
        self.first: str | None = None
        self.cut = False
        self.consecutive = 0
        self.refused: str | None = None

    def refuse(self, problem: str) -> None:
        """End the pass: ``problem`` is "cut" or why a packet was not read."""
        if problem == "cut":
            self.cut = True
        else:
            self.refused = problem

    def add(self, problem: str) -> bool:
        """Count a damaged packet; True when the pass must end (the file ends inside a packet, or
        :data:`MAX_CONSECUTIVE_ERRORS` packets in a row are damaged)."""
        if "fill whole buffer" in problem:  # Rust's UnexpectedEof: the file ends inside a packet
            self.cut = True
            return True
        self.skipped += 1
        self.first = self.first or problem
        self.consecutive += 1
        return self.consecutive >= MAX_CONSECUTIVE_ERRORS

    def describe(self) -> str | None:
        parts = [f"refused: {self.refused} (docs/limits.md)"] if self.refused else []
        if self.skipped:
            parts.append(f"corrupt: {self.skipped} damaged packet(s) skipped (the first: {self.first})")
        if self.cut:
            parts.append(
                "truncated: the file ends inside a packet (cut short, or a damaged packet size); "
                "the rest of the recording is missing"
            )
        return "; ".join(parts) or None
