"""How large an AEDAT4 packet can inflate, read from its compression framing before it is inflated.

The ``aedat`` decoder inflates each packet whole (``read_to_end`` over LZ4 or zstd), so one packet
of a few KB that declares gigabytes of output would be allocated before anything can check it:
a decompression bomb. The framing of both formats bounds the output without inflating anything:

- zstd (RFC 8878, section 3.1.1.2): a frame is a header and blocks, each with a 3-byte header
  giving its type and size; a block never regenerates more than Block_Maximum_Size = 128 KiB
  (raw and RLE blocks: exactly their size), and libzstd refuses blocks that would. A frame's
  window above 2^27 bytes is refused by libzstd's default ``windowLogMax`` (nothing allocated).
  Skippable frames regenerate nothing; legacy (v0.x) frames cannot be bounded and are refused.
- LZ4 frames (lz4_Frame_format.md): a header declaring the block maximum size (64 KiB .. 4 MiB)
  and blocks, each with a 4-byte size; liblz4 decompresses a block into a buffer of the declared
  maximum, and an LZ4 sequence regenerates at most 255 bytes per input byte (plus a small tail).
- no compression: the packet is its own size.

:func:`inflated_bound` walks these headers (reading only them) and returns the most bytes the
decoder can produce for a packet: a safe upper bound, never an estimate. Malformed framing gives
the bound 0: the decoder refuses such a packet itself, before inflating (it is then skipped as
damaged, like any packet that does not decode).

Sources: RFC 8878 (zstd), https://github.com/lz4/lz4/blob/dev/doc/lz4_Frame_format.md, the
AEDAT4 IOHeader (``compression``: 0 none, 1 LZ4, 2 LZ4 high, 3 zstd, 4 zstd high).
"""

from __future__ import annotations

import struct

COMPRESSION_NONE, COMPRESSION_LZ4, COMPRESSION_LZ4_HIGH, COMPRESSION_ZSTD, COMPRESSION_ZSTD_HIGH = range(5)

_ZSTD_MAGIC = 0xFD2FB528
_ZSTD_LEGACY_MAGICS = frozenset(range(0xFD2FB522, 0xFD2FB528)) | {0xFD2FB51E}
_SKIPPABLE_MASK, _SKIPPABLE_MAGIC = 0xFFFFFFF0, 0x184D2A50
_ZSTD_BLOCK_MAX = 128 * 1024
_ZSTD_WINDOWLOG_MAX = 27  # libzstd's default windowLogMax when decompressing
_LZ4_MAGIC = 0x184D2204
_LZ4_BLOCK_MAX = {4: 64 << 10, 5: 256 << 10, 6: 1 << 20, 7: 4 << 20}
#: An LZ4 sequence's match length grows by 255 per extra byte: output <= 255 x input + a tail.
_LZ4_RATIO, _LZ4_TAIL = 255, 1024


class Unbounded(ValueError):
    """The framing is valid but its output cannot be bounded (a legacy zstd frame)."""


class _Malformed(ValueError):
    """The framing breaks at some point; ``bound`` is what the frame's blocks before it give."""

    def __init__(self, bound: int) -> None:
        super().__init__(bound)
        self.bound = bound


def _zstd_frame(data: bytes, pos: int) -> tuple[int, int]:
    """(bound, end) of the zstd frame at ``pos`` (after its magic); raises _Malformed (with the
    bound of the blocks before the fault) when the frame is malformed."""
    (fhd,) = struct.unpack_from("<B", data, pos)
    pos += 1
    fcs_flag, single_segment, dict_flag = fhd >> 6, (fhd >> 5) & 1, fhd & 3
    if fhd & 0x08:
        raise _Malformed(0)  # reserved bit: libzstd refuses the frame
    if not single_segment:
        (window_descriptor,) = struct.unpack_from("<B", data, pos)
        if (window_descriptor >> 3) + 10 > _ZSTD_WINDOWLOG_MAX:
            raise _Malformed(0)  # libzstd refuses the window before allocating it
        pos += 1
    pos += (0, 1, 2, 4)[dict_flag]
    pos += (1 if single_segment else 0, 2, 4, 8)[fcs_flag]
    bound = 0
    while True:
        if pos + 3 > len(data):
            raise _Malformed(bound)
        header = int.from_bytes(data[pos : pos + 3], "little")
        last, kind, size = header & 1, (header >> 1) & 3, header >> 3
        pos += 3 + (1 if kind == 1 else size)
        if kind == 3 or size > _ZSTD_BLOCK_MAX or pos > len(data):
            raise _Malformed(bound)  # libzstd stops at this block
        bound += size if kind in (0, 1) else _ZSTD_BLOCK_MAX
        if last:
            return bound, pos + (4 if fhd & 0x04 else 0)


def _lz4_frame(data: bytes, pos: int) -> tuple[int, int]:
    """(bound, end) of the LZ4 frame at ``pos`` (after its magic)."""
    flg, bd = struct.unpack_from("<BB", data, pos)
    block_max = _LZ4_BLOCK_MAX.get((bd >> 4) & 7)
    if flg >> 6 != 1 or block_max is None:
        raise _Malformed(0)  # liblz4 refuses the descriptor
    pos += 2 + (8 if flg & 0x08 else 0) + (4 if flg & 0x01 else 0) + 1
    bound = 0
    while True:
        if pos + 4 > len(data):
            raise _Malformed(bound)
        (size,) = struct.unpack_from("<I", data, pos)
        pos += 4
        if size == 0:
            return bound, pos + (4 if flg & 0x04 else 0)
        stored, size = size >> 31, size & 0x7FFFFFFF
        pos += size + (4 if flg & 0x10 else 0)
        if pos > len(data):
            raise _Malformed(bound)  # liblz4 needs the whole block
        bound += min(block_max, size if stored else _LZ4_RATIO * size + _LZ4_TAIL)


def inflated_bound(data: bytes, compression: int) -> int:
    """The most bytes the ``aedat`` decoder can inflate packet payload ``data`` to.

    Args:
        data: one packet's payload as stored in the file (after its stream id and size).
        compression: the file's IOHeader compression (0 none, 1-2 LZ4, 3-4 zstd).

    Returns:
        an upper bound in bytes; 0 when the framing is malformed (the decoder refuses the packet
        before inflating it).

    Raises:
        Unbounded: a legacy zstd frame, whose output cannot be bounded from its framing.
    """
    if compression == COMPRESSION_NONE:
        return len(data)
    zstd = compression in (COMPRESSION_ZSTD, COMPRESSION_ZSTD_HIGH)
    pos = bound = 0
    while pos + 4 <= len(data):
        (magic,) = struct.unpack_from("<I", data, pos)
        pos += 4
        if magic & _SKIPPABLE_MASK == _SKIPPABLE_MAGIC:
            pos += 4 + (struct.unpack_from("<I", data, pos)[0] if pos + 4 <= len(data) else 0)
            continue
        if zstd and magic in _ZSTD_LEGACY_MAGICS:
            raise Unbounded("a zstd frame of a pre-1.0 format")
        if magic != (_ZSTD_MAGIC if zstd else _LZ4_MAGIC):
            return bound  # the decoder stops here with an error
        try:
            size, pos = (_zstd_frame if zstd else _lz4_frame)(data, pos)
        except (_Malformed, struct.error) as exc:
            return bound + (exc.bound if isinstance(exc, _Malformed) else 0)
        bound += size
    return bound
