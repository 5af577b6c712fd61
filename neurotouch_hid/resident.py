"""What the process keeps resident: the pages of its mapped files that it no longer reads.

Half of a run's resident memory is shared libraries' pages mapped from their files, not memory
of its own: numba's compiler, LLVM (llvmlite's ``libllvmlite.so``, 170 MB), alone is ~70 MB of
it after numba's import and the pipeline's kernels loaded from numba's cache, though the kernels
then run as machine code of their own and LLVM is not read again unless something compiles. The
kernel keeps every page a process has read mapped in it (its resident set, what ``top`` shows)
until memory runs short. :func:`release_file_pages` unmaps the pages that are exact copies of
their file (``madvise(MADV_DONTNEED)`` on the read-only file mappings that hold no page of the
process's own): they stay in the page cache, and the next read of one maps it again, as the
first read did; what the run keeps reading comes back, the rest stays out.

Linux only (``/proc/self/smaps``); elsewhere nothing is released.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import mmap
import sys

from neurotouch_hid.limits import read_proc_file


def release_file_pages() -> int:
    """Unmap the resident pages of the process's file mappings that are copies of the file: the
    mappings without write permission and without an anonymous page (a relocated table made
    read-only after it was written has some: it is left alone). A later read of a released page
    maps it again from the page cache (or the file); nothing the process wrote is touched.

    Returns:
        the bytes that were resident in the released mappings (0 off Linux, or when
        ``/proc/self/smaps`` cannot be read).
    """
    madvise = _madvise()
    if madvise is None:
        return 0
    released = 0
    for start, end, resident in _clean_file_mappings():
        if resident and madvise(start, end - start, mmap.MADV_DONTNEED) == 0:
            released += resident
    return released


#: At most this much of ``/proc/self/smaps`` is read (~1 KiB a mapping; a run has ~1 000).
MAX_SMAPS_BYTES = 16 * 1024 * 1024


def _clean_file_mappings() -> list[tuple[int, int, int]]:
    """(start, end, resident bytes) of the read-only file mappings without anonymous pages, from
    ``/proc/self/smaps`` read bounded (:func:`~neurotouch_hid.limits.read_proc_file`); a mapping
    whose ``Anonymous:`` line was not read (past the bound) is left out; [] when it cannot be read."""
    try:
        data, _ = read_proc_file("/proc/self/smaps", MAX_SMAPS_BYTES)
    except OSError:
        return []
    found, current = [], None
    for line in data.decode("ascii", errors="replace").splitlines():
        fields = line.split()
        if not fields:
            continue
        if not fields[0].endswith(":"):  # a mapping's first line: range, flags, ..., path
            current = None
            if len(fields) >= 6 and fields[5].startswith("/") and "w" not in fields[1]:
                start, end = (int(x, 16) for x in fields[0].split("-"))
                current = [start, end, 0, None]
                found.append(current)
        elif current is not None and fields[0] == "Rss:":
            current[2] = int(fields[1]) * 1024
        elif current is not None and fields[0] == "Anonymous:":
            current[3] = int(fields[1])
    return [(start, end, resident) for start, end, resident, anonymous in found if anonymous == 0]


@functools.cache
def _madvise():
    """libc's ``madvise(addr, length, advice)``, None off Linux."""
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    function = libc.madvise
    function.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    function.restype = ctypes.c_int
    return function
