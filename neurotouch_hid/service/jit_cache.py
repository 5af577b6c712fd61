"""Where numba keeps the pipeline's compiled code (``@numba.njit(cache=True)``), on any install.

numba caches a jitted function next to its source (``__pycache__``), else in the user's
``~/.cache/numba``; when neither is writable (a system package, a service with
``ProtectSystem=strict`` / ``ProtectHome=read-only``, a kiosk account) defining the function
raises ``RuntimeError: cannot cache function ...: no locator available``, and the driver could
not start. :func:`configure` runs once, from ``neurotouch_hid/__init__.py``, before any module
with jitted code is imported, and picks the first of:

1. ``$NUMBA_CACHE_DIR`` when the user set it and it is writable (numba's own setting);
2. the package's folders (numba's default, next to the source) when they are writable;
3. the cache folder systemd gives the service (``$CACHE_DIRECTORY``, the unit's
   ``CacheDirectory=``; packaging/neurotouch-hid.service);
4. the user's XDG cache folder, ``platformdirs.user_cache_dir("neurotouch-hid")/numba``
   (``$XDG_CACHE_HOME/neurotouch-hid/numba``);
5. ``$XDG_RUNTIME_DIR/neurotouch-hid/numba`` (a tmpfs: kept until the user logs out);
6. none: numba compiles the pipeline at every start (seconds more each time), said in one line
   on stderr, into a temporary folder removed at exit, or, when not even that can be made, in
   memory.

Cases 3 to 6 point numba's documented ``NUMBA_CACHE_DIR`` setting (``numba.config.CACHE_DIR``)
at the folder, without importing numba (a command that needs no compiled code stays fast); in
memory, caching is turned off for the dispatchers created afterwards (numba's
``Dispatcher.enable_caching`` becomes a no-op, so they keep their in-memory ``NullCache``).
``neurotouch-hid doctor`` reports the choice (:func:`chosen`).
"""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

#: numba's environment variable for its cache folder.
CACHE_ENV = "NUMBA_CACHE_DIR"
#: The package's folders whose modules hold ``cache=True`` functions (numba caches in their
#: ``__pycache__`` by default).
JIT_PACKAGES = ("pipeline", "sources")

ENV, PACKAGE, SERVICE_CACHE, USER_CACHE, RUNTIME_DIR, TEMPORARY, MEMORY = (
    "NUMBA_CACHE_DIR",
    "package",
    "service cache",
    "user cache",
    "runtime dir",
    "temporary",
    "memory",
)
#: What the user is told (stderr, doctor) when no cache folder of theirs is writable.
NO_FOLDER = "no writable cache folder (package, XDG cache, $XDG_RUNTIME_DIR): numba compiles the pipeline"


@dataclass(frozen=True)
class JitCache:
    """Where compiled code is cached: ``kind`` (one of ENV, PACKAGE, SERVICE_CACHE, USER_CACHE,
    RUNTIME_DIR, TEMPORARY, MEMORY) and ``folder`` (None for MEMORY; for PACKAGE, the package
    folder)."""

    kind: str
    folder: Path | None

    def describe(self) -> str:
        """One line for the user, e.g. ``user cache: /home/me/.cache/neurotouch-hid/numba``."""
        if self.kind == MEMORY:
            return f"{NO_FOLDER} in memory at every start"
        if self.kind == TEMPORARY:
            return f"{NO_FOLDER} at every start (temporary folder {self.folder}, removed at exit)"
        return f"{self.kind}: {self.folder}"


_chosen: JitCache | None = None


def _writable(folder: Path) -> bool:
    """Whether ``folder`` exists or can be made, and a file can be created in it (numba's own test)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False


def _candidates() -> list[JitCache]:
    package = Path(__file__).resolve().parents[1]  # the package folder, beside whose modules numba caches
    found = []
    if os.environ.get(CACHE_ENV):
        found.append(JitCache(ENV, Path(os.environ[CACHE_ENV])))
    found.append(JitCache(PACKAGE, package))
    if os.environ.get("CACHE_DIRECTORY"):  # systemd: one or more folders, colon-separated
        found.append(JitCache(SERVICE_CACHE, Path(os.environ["CACHE_DIRECTORY"].split(":")[0]) / "numba"))
    try:
        import platformdirs

        found.append(JitCache(USER_CACHE, Path(platformdirs.user_cache_dir("neurotouch-hid")) / "numba"))
    except Exception:  # no usable home folder at all: skip to the runtime dir  # pragma: no cover
        pass
    if os.environ.get("XDG_RUNTIME_DIR"):
        found.append(JitCache(RUNTIME_DIR, Path(os.environ["XDG_RUNTIME_DIR"]) / "neurotouch-hid" / "numba"))
    return found


def _usable(cache: JitCache) -> bool:
    if cache.kind == PACKAGE:
        return all(_writable(cache.folder / sub / "__pycache__") for sub in JIT_PACKAGES)
    return _writable(cache.folder)


def configure() -> JitCache:
    """Choose where numba caches (see the module's docstring) and set numba up for it.

    Idempotent: the first call decides. Must run before the modules with jitted functions are
    imported (``neurotouch_hid/__init__.py`` calls it). Never raises. Returns the choice.
    """
    global _chosen
    if _chosen is not None:
        return _chosen
    choice = next((c for c in _candidates() if _usable(c)), None)
    if choice is None:
        try:
            choice = JitCache(TEMPORARY, Path(tempfile.mkdtemp(prefix="neurotouch-hid-numba-")))
            atexit.register(shutil.rmtree, choice.folder, ignore_errors=True)
        except OSError:
            choice = JitCache(MEMORY, None)
        print(f"neurotouch-hid: {choice.describe()}", file=sys.stderr, flush=True)
    if choice.kind in (SERVICE_CACHE, USER_CACHE, RUNTIME_DIR, TEMPORARY):
        os.environ[CACHE_ENV] = str(choice.folder)  # read by numba when it is first imported
        if "numba" in sys.modules:  # imported already: its config was read
            sys.modules["numba"].config.CACHE_DIR = str(choice.folder)
    elif choice.kind == MEMORY:
        os.environ.pop(CACHE_ENV, None)  # an unwritable NUMBA_CACHE_DIR would be tried again
        from numba.core import config
        from numba.core.dispatcher import Dispatcher

        config.CACHE_DIR = ""
        Dispatcher.enable_caching = _compile_in_memory
    _chosen = choice
    return choice


def _compile_in_memory(dispatcher) -> None:
    """Replaces numba's ``Dispatcher.enable_caching`` when no folder is writable: the dispatcher
    keeps its in-memory NullCache instead of failing with "no locator available"."""


def chosen() -> JitCache:
    """The choice :func:`configure` made (making it now if it has not run)."""
    return configure()


def release_linking_modules(dispatchers) -> int:
    """Free the parsed LLVM modules numba keeps beside each kernel loaded from its cache; give
    the C heap's free pages back. Returns the number of modules released.

    numba's ``CPUCodeLibrary._unserialize`` (numba/core/codegen.py) loads a cached kernel's
    machine code and also parses the bitcode stored with it into an LLVM module
    (``_shared_module``), kept in case a later compile links the kernel into another one.
    The running pipeline never compiles again, yet those modules were ~13 MiB of the run's
    anonymous memory (docs/performance.md, "Memory"). Each is replaced by its bitcode (bytes,
    ~1.5 MiB for the whole pipeline) and a per-library ``_get_module_for_linking`` that parses it
    again if a compile ever links that library: numba's own path, the same module. Then glibc's
    ``malloc_trim(0)`` returns the freed heap pages to the system (a no-op elsewhere).

    Args:
        dispatchers: numba ``Dispatcher`` objects; those with no compiled overload, or a numba
            whose libraries are laid out otherwise, are left as they are.
    """
    released = 0
    for dispatcher in dispatchers:
        for result in list(getattr(dispatcher, "overloads", {}).values()):
            library = getattr(result, "library", None)
            module = getattr(library, "_shared_module", None)
            if module is None or not hasattr(library, "_get_module_for_linking"):
                continue
            library._get_module_for_linking = _linking_from_bitcode(library, module.as_bitcode())
            library._shared_module = None
            released += 1
    if released:
        _trim_heap()
    return released


def _linking_from_bitcode(library, bitcode: bytes):
    """A ``_get_module_for_linking`` for ``library`` that parses ``bitcode`` back when asked."""

    def module_for_linking():
        if library._shared_module is None:
            import llvmlite.binding as ll

            library._shared_module = ll.parse_bitcode(bitcode)
        return library._shared_module

    return module_for_linking


def _trim_heap() -> None:
    """glibc's ``malloc_trim(0)``: free pages at the heap's top and inside it go back to the kernel."""
    import ctypes

    trim = getattr(ctypes.CDLL(None), "malloc_trim", None)  # the process's libc, as atomic.py's renameat2
    if trim is not None:  # (not glibc: musl has no malloc_trim)
        trim(0)
