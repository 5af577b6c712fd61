"""Releasing the pages of mapped files a run no longer reads (neurotouch_hid/resident.py): the
process's own pages stay, a released page reads the same, and loading the warm pipeline releases
LLVM's pages as it goes (neurotouch_hid/warmup.py)."""

from __future__ import annotations

import mmap
import sys

import pytest

from neurotouch_hid import resident, warmup

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/smaps: Linux")


def _resident_pages(path) -> int:
    """Pages of the mapping of ``path`` in this process's resident set (``/proc/self/smaps``' Rss)."""
    with open("/proc/self/smaps") as smaps:
        lines = smaps.read().splitlines()
    for k, line in enumerate(lines):
        if line.endswith(" " + str(path)):
            rss = next(x for x in lines[k + 1 :] if x.startswith("Rss:"))
            return int(rss.split()[1]) // 4
    raise LookupError(f"{path} is not mapped")


def test_a_read_only_file_mapping_is_released_and_reads_the_same_after(tmp_path):
    path = tmp_path / "pages.bin"
    data = bytes(range(256)) * (64 * 4096 // 256)
    path.write_bytes(data)
    with open(path, "rb") as file, mmap.mmap(file.fileno(), 0, prot=mmap.PROT_READ) as view:
        assert view[:] == data  # every page read: mapped
        assert _resident_pages(path) == 64
        assert resident.release_file_pages() >= 64 * 4096
        assert _resident_pages(path) == 0
        assert view[:] == data  # read again from the page cache


def test_pages_the_process_wrote_are_kept(tmp_path):
    """A private mapping written to (its pages are the process's own copies) keeps what was written."""
    path = tmp_path / "pages.bin"
    path.write_bytes(bytes(16 * 4096))
    with open(path, "r+b") as file, mmap.mmap(file.fileno(), 0, flags=mmap.MAP_PRIVATE) as view:
        view[:4] = b"kept"
        resident.release_file_pages()
        assert view[:4] == b"kept"
    assert path.read_bytes() == bytes(16 * 4096)


def test_loading_the_warm_pipeline_releases_the_pages_before_after_its_first_kernel_and_at_the_end(monkeypatch):
    """Released before the load, once numba's set-up at the first kernel is done, and after the
    last: what the loading read never adds up."""
    from numba.core.compiler_lock import global_compiler_lock

    calls: list[str] = []
    monkeypatch.setattr(warmup.resident, "release_file_pages", lambda: calls.append("released") or 0)

    def warm():
        calls.append("loading")
        for name in ("first", "second"):
            with global_compiler_lock, global_compiler_lock:  # a kernel loaded, nested inside
                calls.append(name)

    monkeypatch.setattr(warmup, "_call", lambda spec: warm())
    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: ["a signature"])
    warmup.Warmup([warmup.TRACKER], say=lambda line: None, interpreted=False).start()
    assert calls == ["released", "loading", "first", "released", "second", "released"]


def test_a_warm_simulator_is_loaded_from_the_cache_before_the_run_starts_its_pages_released(monkeypatch):
    """Its kernels' cached code is loaded at the start, not at the simulated gel's first chunk
    (after the pipeline's pages were released: LLVM's would be read again and kept)."""
    calls: list[str] = []
    loaded: list[object] = []
    monkeypatch.setattr(warmup.resident, "release_file_pages", lambda: calls.append("released") or 0)
    monkeypatch.setattr(warmup, "cached_signatures", lambda dispatcher: ["a signature"])
    monkeypatch.setattr(warmup, "_load_cached", lambda found: loaded.extend(found) or calls.append("loaded"))
    monkeypatch.setattr(warmup, "_call", lambda spec: pytest.fail("the simulator is not simulated to load"))
    warmup.Warmup([warmup.SIMULATOR], say=lambda line: None).start()
    assert sorted(loaded) == sorted(warmup.kernels(warmup.SIMULATOR)) and loaded
    assert calls == ["released", "loaded", "released"]


def test_a_mapping_whose_anonymous_pages_were_not_read_is_kept(monkeypatch):
    """``/proc/self/smaps`` is read bounded: a mapping cut off before its ``Anonymous:`` line may
    hold pages the process wrote, so it is not released; one whose line says 0 is."""
    text = (
        "7f0000000000-7f0000004000 r--p 00000000 08:01 11 /usr/lib/a.so\n"
        "Rss:                  16 kB\n"
        "Anonymous:             0 kB\n"
        "7f0000010000-7f0000014000 r-xp 00000000 08:01 12 /usr/lib/b.so\n"
        "Rss:                  16 kB\n"
    )
    monkeypatch.setattr(resident, "read_proc_file", lambda path, max_bytes: (text.encode(), True))
    assert resident._clean_file_mappings() == [(0x7F0000000000, 0x7F0000004000, 16 * 1024)]
