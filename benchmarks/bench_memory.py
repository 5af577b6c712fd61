"""Where a run's resident memory goes: the process's resident set after each step of its start,
in one process, the way ``run`` takes them (docs/performance.md, "track").

    python3 benchmarks/bench_memory.py

Per step: resident MiB (``/proc/self/status`` VmRSS), of it the process's own pages (RssAnon) and
pages mapped from files (RssFile: shared libraries), the peak so far (VmHWM), the resident MiB of
LLVM's library (``libllvmlite.so``, ``/proc/self/smaps``), and the anonymous memory
(``Anonymous:`` of ``/proc/self/smaps_rollup``: the process's own pages, what the kernel cannot
reclaim by dropping a file's page; the figure the driver's memory target is on). The steps: the
interpreter, numpy, numba, OpenCV, the CLI and the driver, the warm pipeline loaded as ``run``
loads it (``warmup.Warmup``: its kernels from numba's cache, each group's linking modules freed
as it is loaded, ``jit_cache.release_linking_modules``), dv-processing (the live camera's source
only). Run it once before on a warm cache (``run`` or ``track`` once): a cold cache
compiles first.
"""

from __future__ import annotations

import os


def status() -> dict[str, float]:
    """MiB of VmRSS, RssAnon, RssFile and VmHWM of this process."""
    with open("/proc/self/status") as file:
        fields = dict(line.split(":", 1) for line in file if ":" in line)
    return {key: int(fields[key].split()[0]) / 1024 for key in ("VmRSS", "RssAnon", "RssFile", "VmHWM")}


def anonymous_mib(pid: int | str = "self") -> float:
    """MiB of ``Anonymous:`` in ``/proc/PID/smaps_rollup``."""
    with open(f"/proc/{pid}/smaps_rollup") as file:
        return next(int(line.split()[1]) for line in file if line.startswith("Anonymous:")) / 1024


def llvm_mib() -> float:
    """Resident MiB of the mappings of libllvmlite.so."""
    total, current = 0, False
    with open("/proc/self/smaps") as file:
        for line in file:
            fields = line.split()
            if fields and not fields[0].endswith(":"):
                current = len(fields) >= 6 and os.path.basename(fields[5]) == "libllvmlite.so"
            elif current and fields[0] == "Rss:":
                total += int(fields[1])
    return total / 1024


def show(step: str) -> None:
    s = status()
    print(
        f"{step:28s} {s['VmRSS']:6.1f} MiB resident: own {s['RssAnon']:5.1f}, files {s['RssFile']:5.1f} "
        f"(LLVM {llvm_mib():4.1f}); peak so far {s['VmHWM']:6.1f}; anonymous {anonymous_mib():5.1f}",
        flush=True,
    )


def main() -> None:
    show("interpreter")
    import numpy  # noqa: F401

    show("numpy")
    import numba  # noqa: F401

    show("numba")
    import cv2  # noqa: F401

    show("cv2")
    import neurotouch_hid.cli  # noqa: F401
    import neurotouch_hid.engine.driver  # noqa: F401

    show("CLI and driver")
    from neurotouch_hid.service.warmup import PIPELINE_OF, Warmup

    Warmup(list(PIPELINE_OF["default"]), say=print, interpreted=False).start()
    show("pipeline loaded")
    import dv_processing  # noqa: F401

    show("dv-processing")


if __name__ == "__main__":
    main()
