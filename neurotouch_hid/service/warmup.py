"""A run's first start on a cold numba cache: progress from the first second, a first gesture in seconds.

The gesture pipeline and the simulated gel are numba kernels (``@numba.njit(cache=True)``). On a
fresh install numba has nothing cached: compiling them takes ~25 s of CPU (~22 s for the
pipeline, ~3 s for the simulator; docs/performance.md, "Start-up"), during which a run used to
show nothing. This module orchestrates that first compile around the kernels' modules, without
changing them:

* **what is cold**: a :class:`KernelGroup` (the pipeline's kernels, the simulator's) is warm when
  every one of its kernels has code in numba's cache for this machine (numba's cache index,
  :func:`cached_signatures`); only cold groups are compiled, and only the groups the run needs.
* **compiled in parallel processes into the cache**: each cold group is compiled by its own
  child process (``python -P -m neurotouch_hid.service.warmup GROUP``, the same warm-up that
  ``GesturePipeline.compile_kernels`` or a short simulation is), which writes numba's cache; the
  groups use both cores. The pipeline is two groups: the per-event tracker and noise filter
  (what an interpreted run spends most on) and the per-window rest (the tracker's APS-frame
  correction among them, compiled last: the tracker's kernels it calls are in the cache by
  then), whose child starts once the simulator's and the tracker's, which the first gestures
  wait for, are done. The child reports each kernel it compiled (one line on stdout), so
  :class:`Warmup` can show progress.
* **waited for, or interpreted until compiled**: the simulator's and the tracker's groups compile
  in a few seconds each (~3 s of CPU apiece), much sooner than their Python form would get far, so the
  run waits for them (:attr:`KernelGroup.waits`) once its first window is out: that window
  (one APS frame, 10 ms of events) costs the Python form a fraction of a second, so a run shows
  its first state at once instead of after the compile, then waits, leaving both cores to the
  compiles, and the first gesture comes as soon as they are done.
  The rest of the pipeline is interpreted meanwhile: the run calls the kernels' pure-Python/NumPy
  form (numba's ``Dispatcher.py_func``; the same code, ~50x slower): every module's global name
  of a cold kernel points at its ``py_func`` (:func:`interpret`), and so does each kernel
  inlined into others (:func:`inlined_kernels`): called from an interpreted kernel, numba would
  compile it in this process, on the run's threads. A source that can wait (the simulated gel)
  waits instead of dropping data.
* **switched back at a safe point**: when a child is done, a thread of this process loads the
  group's compiled code from the cache (``Dispatcher.compile(signature)``, a cache hit), then,
  while no call of the group runs (:meth:`Warmup.guard`, held by the callers around each call
  while the group is interpreted), points every name back at the compiled kernels. No kernel is
  compiled in this process.

A run that cannot be interpreted (the camera cannot wait; ``--fast`` replays must be
deterministic) waits for the same children before it starts. Where numba cannot cache
(:mod:`neurotouch_hid.service.jit_cache`, "memory"), a child's work would be lost: the run compiles
in-process before it starts instead, showing the same progress.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, ContextManager, Iterable, Iterator, TypeVar

import numpy as np

from neurotouch_hid.core.stages import CompileProgress
from neurotouch_hid.service import jit_cache
from neurotouch_hid.service.kernel_groups import (  # noqa: F401 (the groups, importable from here)
    GROUPS,
    PAPER_PIPELINE,
    PIPELINE,
    PIPELINE_OF,
    SIMULATOR,
    TRACKER,
    TRACKER_KERNELS,
    KernelGroup,
    _call,
    _on_each_compiled,
    child_command,
    compile_paper_windows,
    compile_pipeline,
    compile_tracker,
    compile_windows,
    compiled,
    inlined_kernels,
    interpret,
    kernels,
    simulate_briefly,
)

if TYPE_CHECKING:
    from neurotouch_hid.core.estimate import GestureEstimate
    from neurotouch_hid.core.stages import MarkerPositions, Pipeline, RestingDetection
    from neurotouch_hid.pipeline.resting import RestingResult
    from neurotouch_hid.sources import Frame, StreamItem

T = TypeVar("T")

#: How long after every compiled group is loaded numba's linking modules are freed (s;
#: :meth:`Warmup._release_linking`); a group warm in the cache has them freed as it is loaded.
RELEASE_AFTER_S = 3.0
#: How much nicer than the run a compile's child is (``nice(2)``): while the run computes its
#: first window (and later its interpreted windows) it has a core before the compiles do; the
#: compiles lose no CPU they would have had (the run waits for them once its first window is out).
CHILD_NICE = 5
#: What the user is told while the kernels compile.
COMPILING = "compiling the gesture pipeline, first run only"
#: What the first run's compile costs, as measured (docs/performance.md, "Start-up"): ~25 s of
#: CPU (simulator 3 s, tracker 3 s, the rest of the pipeline 19 s); the first gesture ~5 s and
#: full speed ~25 s after the start on two idle cores; the children share the CPU with whatever
#: else runs, so 80-90 s were seen on a busy two-core machine.
COMPILE_COST = (
    "about 25 s of CPU: full speed after ~25 s on two idle cores, a minute or more on a busy machine "
    "(the progress shows below; nothing is frozen)"
)


def cached_signatures(dispatcher) -> list:
    """The argument types numba's cache holds compiled code for, for this machine (its index;
    numba's ``FunctionCache``, which ``cache=True`` gives). Empty when nothing (or, with another
    numba, nothing readable) is cached."""
    try:
        magic = dispatcher.targetctx.codegen().magic_tuple()
        index = dispatcher._cache._cache_file._load_index()
    except Exception:  # a numba whose cache is laid out otherwise: treated as cold
        return []
    return [key[0] for key in index if len(key) > 1 and key[1] == magic]


def is_cold(group: KernelGroup) -> bool:
    """Whether some kernel of ``group`` has no cached code (numba would compile it)."""
    return any(not cached_signatures(d) for d in kernels(group).values())


def compile_before(say: Callable[[str], None], method: str = "default", *, simulator: bool = False) -> None:
    """Before a command that runs the ``method``'s pipeline from its first item and does not
    interpret it (``track``, ``enrol``, ``calibrate``): the cold kernel groups (the simulated
    gel's too with ``simulator``) compiled by child processes, on both cores, saying so
    (:data:`COMPILING`, :data:`COMPILE_COST`) and when it is done, as a run from the camera does;
    nothing done on a warm cache (the command loads the kernels it calls)."""
    groups = [SIMULATOR, *PIPELINE_OF[method]] if simulator else list(PIPELINE_OF[method])
    cold = [group for group in groups if any(not cached_signatures(d) for d in kernels(group).values())]
    if cold:
        Warmup(cold, say=say, interpreted=False).start().close()


@dataclass
class GroupProgress:
    """One group's compile, as the user sees it.

    Attributes:
        state: ``"cold"`` (compiling, interpreted meanwhile), ``"loading"`` (compiled, loading
            the cache), ``"ready"`` (compiled code in use), ``"failed"`` (the child failed: numba
            compiles in this process when the kernels are first called).
        done, total: kernels compiled so far, kernels in the group.
    """

    name: str
    total: int
    done: int = 0
    state: str = "cold"
    seen: set = field(default_factory=set, repr=False)

    def add(self, kernel: str) -> None:
        """``kernel`` (``module.name``) was compiled."""
        self.seen.add(kernel)
        self.done = len(self.seen)


class Warmup:
    """The cold groups of a run, compiled in child processes while the run interprets them.

    Args:
        groups: the groups the run needs (e.g. ``[PIPELINE, SIMULATOR]`` for the demo).
        say: one line to the user (the child's error when one fails).
        interpreted: True: interpret cold groups and compile them in children while the run goes
            on; False: compile the cold groups now (:meth:`start` returns when done), in the
            same children (in this process where numba cannot cache), with the same progress
            (for sources that cannot wait, and deterministic ``--fast`` replays, which must not
            mix the two forms' rounding).
        lines: say how far the compile is at each quarter (:meth:`describe`), for a log or a
            pipe that shows no progress bar (a service's journal); None: when stderr is no
            terminal.
    """

    def __init__(
        self,
        groups: list[KernelGroup],
        *,
        say: Callable[[str], None] = print,
        interpreted: bool = True,
        lines: bool | None = None,
    ):
        self._groups = groups
        self._say = say
        self._interpreted = interpreted
        self._lines = not sys.stderr.isatty() if lines is None else lines
        self._said_quarter = 0  # the last quarter of the compile said (:meth:`_progressed`)
        self._said_lock = threading.Lock()
        self._locks = {g.name: threading.Lock() for g in groups}
        self._settled = {g.name: threading.Event() for g in groups}  # ready or failed
        self._first_window = threading.Event()  # the run's first window is out: waits groups wait
        self._kernels: dict[str, dict[str, object]] = {}
        self._inlined: dict[str, object] = {}  # interpreted inline kernels (:func:`inlined_kernels`)
        self._inlined_lock = threading.Lock()
        self.progress: dict[str, GroupProgress] = {}
        self._threads: list[threading.Thread] = []
        self._children: list[subprocess.Popen] = []
        self.started_s = time.monotonic()
        self._closing = False
        self._release_cancelled = threading.Event()  # (set by close: the run is over)

    # --- what the run sees -------------------------------------------------------------------
    @property
    def compiling(self) -> bool:
        """Some group is still cold or loading."""
        return any(p.state in ("cold", "loading") for p in self.progress.values())

    def fraction(self) -> float:
        """Kernels compiled over kernels to compile, across the cold groups (1.0 when none)."""
        total = sum(p.total for p in self.progress.values())
        done = sum(p.total if p.state in ("ready", "failed") else min(p.done, p.total) for p in self.progress.values())
        return 1.0 if total == 0 else done / total

    def describe(self) -> str:
        """One line: why the run is slow and how far the compile is, or '' when it is not."""
        if not self.compiling:
            return ""
        elapsed = time.monotonic() - self.started_s
        how = "interpreted meanwhile" if self._interpreted else "the run starts after it"
        return f"{COMPILING}: {self.fraction():.0%}, {elapsed:.0f} s ({how})"

    @contextlib.contextmanager
    def guard(self, group: KernelGroup) -> Iterator[None]:
        """Hold around a call that may run ``group``'s kernels: while the group is interpreted,
        its switch to compiled code waits for the call to end (never mixed within a call)."""
        progress = self.progress.get(group.name)
        if progress is None or progress.state in ("ready", "failed"):
            yield
            return
        if group.waits and self._first_window.is_set():
            self._settled[group.name].wait()
            yield
            return
        with self._locks[group.name], np.errstate(all="ignore"):  # numba's error_model="numpy"
            yield

    # --- the compile -----------------------------------------------------------------------
    def start(self) -> "Warmup":
        """Find the cold groups and compile them (see the class), each group's child started as
        soon as the group is found cold. Returns self. Whatever interrupts it (a SIGTERM's
        :class:`~neurotouch_hid.engine.stopping.StopRequested` while a run that cannot wait
        waits for its children, Ctrl-C) stops the children first (:meth:`close`), then goes on up."""
        try:
            in_memory = jit_cache.chosen().kind == jit_cache.MEMORY
            for group in self._groups:
                found = kernels(group)
                if not any(not cached_signatures(d) for d in found.values()):
                    if group.load_when_warm == "call":
                        _call(group.warm)
                    else:
                        _load_cached(found)
                    # freed now, before the next group loads: the start's peak (docs/performance.md, "Memory")
                    jit_cache.release_linking_modules(found.values())
                    self._settled[group.name].set()
                    continue
                self._kernels[group.name] = found
                self.progress[group.name] = GroupProgress(group.name, len(found))
                if in_memory:
                    continue
                if len(self.progress) == 1:
                    how = "before the run starts"
                    if self._interpreted:
                        how = "starting in seconds, partly interpreted (slowly) meanwhile"
                    self._say(f"{COMPILING}: {how}; {COMPILE_COST}")
                if self._interpreted:  # a waits group only until the first window (guard)
                    with self._inlined_lock:
                        inlined = inlined_kernels(group)  # (those interpreted already are not found again)
                        self._inlined.update(inlined)
                        interpret({**found, **inlined})
                thread = threading.Thread(
                    target=self._child, args=(group,), name=f"nt-compile-{group.name}", daemon=True
                )
                self._threads.append(thread)
                thread.start()
            if in_memory:
                for group in self._groups:
                    if group.name in self.progress:
                        self._compile_here(group)
            elif not self._interpreted:
                self.wait()
            if not self.compiling:
                self._release_linking()
        except BaseException:  # a stop before the run (SIGTERM, Ctrl-C): the children go with it
            self.close()
            raise
        return self

    def _release_linking(self) -> None:
        """Every group is loaded: free what numba keeps only for later compiles
        (:func:`~neurotouch_hid.service.jit_cache.release_linking_modules`), :data:`RELEASE_AFTER_S`
        later in a thread of its own, for the groups compiled by this run's children (those warm
        in the cache had theirs freed as :meth:`start` loaded them, one group after the other, so
        that no two groups' modules are held at once: ~40 ms of the start's CPU here, and the
        start's anonymous memory 10 MiB lower, docs/performance.md "Memory")."""
        dispatchers = [d for group in self._groups for d in kernels(group).values()]

        def release() -> None:
            if not self._release_cancelled.wait(RELEASE_AFTER_S):
                jit_cache.release_linking_modules(dispatchers)

        threading.Thread(target=release, name="nt-release", daemon=True).start()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for every child and the switch to compiled code; whether all ended in time."""
        deadline = None if timeout is None else time.monotonic() + timeout
        for thread in self._threads:
            thread.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
        return not any(t.is_alive() for t in self._threads)

    def close(self) -> None:
        """Stop the children still compiling (the run ended first; what they cached stays) and
        point the names of the groups still interpreted back at the compiled kernels (a later run
        in this process compiles or loads them when it first calls them)."""
        self._closing = True
        self._release_cancelled.set()
        for child in self._children:
            if child.poll() is None:
                child.terminate()
        for child in self._children:
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.wait(5)
        for name, progress in self.progress.items():
            with self._locks[name]:
                if progress.state == "cold":
                    compiled(self._kernels[name])
                    progress.state = "failed"
            self._settled[name].set()
        self._inlined_back()

    def progress_now(self) -> CompileProgress | None:
        """The compile while it lasts (what the engine publishes in each window's record), else
        None. Its first call means the run's first window is out: from then on a call of a
        :attr:`KernelGroup.waits` group waits for its compile (:meth:`guard`)."""
        self._first_window.set()
        if not self.compiling:
            return None
        return CompileProgress(self.describe(), self.fraction())

    def guarded(self, *groups: KernelGroup) -> Callable[[], ContextManager[None]]:
        """A zero-argument callable giving :meth:`guard` of every one of ``groups`` (in the
        order given: callers name a pipeline's groups in :data:`PIPELINE_OF`'s order); once
        every one is settled (compiled, warm or given up, for good), an empty context: a call
        then costs what an unguarded one does."""
        # a group this warmup does not compile (the simulator of a replay) is not waited for
        settled = [self._settled[group.name] for group in groups if group.name in self._settled]

        @contextlib.contextmanager
        def guard_all() -> Iterator[None]:
            with contextlib.ExitStack() as stack:
                for group in groups:
                    stack.enter_context(self.guard(group))
                yield

        done = False  # every group settled: for good

        def guard() -> ContextManager[None]:
            nonlocal done
            if not done:
                done = all(event.is_set() for event in settled)
            return _UNGUARDED if done else guard_all()

        return guard

    def _inlined_back(self) -> None:
        """Point the inline kernels' names back at their dispatchers: every group is compiled,
        or numba is to compile some here (a failed child, a kernel that did not load from the
        cache, the run's end), whose typing needs them. A kernel still interpreted then has
        numba compile the inline ones it calls, here: slower, never wrong."""
        with self._inlined_lock:
            if self._inlined:
                compiled(self._inlined)
                self._inlined = {}

    def _compile_here(self, group: KernelGroup) -> None:
        progress = self.progress[group.name]
        self._say(f"{COMPILING}: the {group.name} kernels ({progress.total}), before the run starts ...")
        with _on_each_compiled(self._kernels[group.name], progress.add):
            _call(group.warm)
        progress.state = "ready"
        self._settled[group.name].set()
        self._say(
            f"compiled the {group.name} kernels in {time.monotonic() - self.started_s:.0f} s; cached for next time"
        )

    def _progressed(self) -> None:
        """A kernel was compiled: with ``lines``, say how far the compile is when it passes 25,
        50 or 75 % (any child's thread)."""
        if not self._lines:
            return
        with self._said_lock:
            quarter = int(self.fraction() * 4)
            if 0 < quarter < 4 and quarter > self._said_quarter:
                self._said_quarter = quarter
                self._say(self.describe())

    def _child(self, group: KernelGroup) -> None:
        """Thread: run the group's child (a background group's once the others are settled),
        count its progress lines, then switch to its code."""
        progress = self.progress[group.name]
        if group.background and self._interpreted:  # (a run that waits for all: all at once)
            for other in self._groups:
                if not other.background:
                    self._settled[other.name].wait()
        if self._closing:
            return
        try:
            child = subprocess.Popen(
                child_command(group),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                env=os.environ.copy(),
            )
        except OSError as exc:
            self._failed(group, f"could not start the compile ({exc})")
            return
        self._children.append(child)
        if self._closing:  # closed while the child started: it goes too
            child.terminate()
        for line in child.stdout:
            if line.strip() in self._kernels[group.name]:
                progress.add(line.strip())
                self._progressed()
        error = child.stderr.read().strip()
        if child.wait() != 0 and self._closing:  # the run ended first: what it cached stays
            return
        if child.wait() != 0:
            last = error.splitlines()[-1] if error else f"exit status {child.returncode}"
            self._failed(group, f"the {group.name} compile failed ({last})")
            return
        progress.state = "loading"
        group_kernels = self._kernels[group.name]
        if _load_cached(group_kernels):  # compiled at its first call, which types the inline kernels
            self._inlined_back()
        with self._locks[group.name]:
            compiled(group_kernels)
            progress.state = "ready"
        self._settled[group.name].set()
        if not self.compiling:
            self._inlined_back()
            if self._interpreted:  # (else start() releases, after the last child)
                self._release_linking()
            done = "full speed now" if self._interpreted else "starting"
            self._say(f"compiled in {time.monotonic() - self.started_s:.0f} s, cached for next time: {done}")

    def _failed(self, group: KernelGroup, why: str) -> None:
        self._inlined_back()  # numba compiles the group's kernels here: they inline these
        if not self._interpreted:  # nothing runs yet: compile here before it does
            self._say(f"{why}: compiling it in this process instead")
            self._compile_here(group)
            return
        with self._locks[group.name]:
            compiled(self._kernels[group.name])
            self.progress[group.name].state = "failed"
        self._settled[group.name].set()
        self._say(f"{why}: numba compiles it in this process instead")


class GuardedPipeline:
    """A pipeline built on kernels that may still be interpreted: each call runs inside ``guard()``
    (:meth:`Warmup.guard`), so the kernels never switch form within a call. A
    :class:`~neurotouch_hid.core.stages.Pipeline` like the one it wraps."""

    def __init__(self, pipeline: Pipeline, guard: Callable[[], ContextManager[None]]):
        self._pipeline = pipeline
        self._guard = guard

    def process(self, item: StreamItem | GestureEstimate) -> list[GestureEstimate]:
        """The wrapped pipeline's estimates for ``item``."""
        guard = self._guard()
        if guard is _UNGUARDED:  # every kernel settled: the call alone (each item of a run comes here)
            return self._pipeline.process(item)
        with guard:
            return self._pipeline.process(item)

    def process_newest(self, events: np.ndarray) -> tuple[list[GestureEstimate], list[int]]:
        """The wrapped pipeline's ``process_newest``."""
        with self._guard():
            return self._pipeline.process_newest(events)

    def set_resting(self, result: RestingResult | None, t_us: int) -> None:
        """Hands the resting verdict on."""
        self._pipeline.set_resting(result, t_us)

    def restart(self) -> None:
        """Restarts the wrapped pipeline."""
        with self._guard():
            self._pipeline.restart()

    def set_type_wait(self, wait: bool) -> None:
        """Hands the type wait on (``Pipeline.set_type_wait``)."""
        self._pipeline.set_type_wait(wait)

    def markers(self) -> MarkerPositions | None:
        """The wrapped pipeline's markers."""
        return self._pipeline.markers()


class GuardedResting:
    """A resting detection whose kernels are the pipeline's: each verdict inside ``guard()``."""

    def __init__(self, detection: RestingDetection, guard: Callable[[], ContextManager[None]]):
        self._detection = detection
        self._guard = guard

    def update(self, frame: Frame) -> RestingResult | None:
        """The wrapped detector's verdict for ``frame``."""
        guard = self._guard()
        if guard is _UNGUARDED:  # every kernel settled: the call alone
            return self._detection.update(frame)
        with guard:
            return self._detection.update(frame)


def guarded_items(items: Iterable[T], guard: Callable[[], ContextManager[None]]) -> Iterator[T]:
    """``items`` with each one made inside ``guard()`` (the simulated gel's kernels)."""
    iterator = iter(items)
    while True:
        with guard():
            item = next(iterator, _END)
        if item is _END:
            return
        yield item


_END = object()
#: What a guard gives once its groups are settled (a reusable empty context).
_UNGUARDED = contextlib.nullcontext()


def _load_cached(group_kernels: dict[str, object]) -> int:
    """Load every signature numba's cache holds for these kernels (``Dispatcher.compile``, a cache
    hit); one it cannot load is compiled at its first call. Returns how many could not be loaded
    (numba compiled them here and failed: their inline kernels were interpreted)."""
    failed = 0
    for dispatcher in group_kernels.values():
        for signature in cached_signatures(dispatcher):
            try:
                dispatcher.compile(signature)
            except Exception:
                failed += 1
    return failed


def main(argv: list[str]) -> int:
    """The child: compile one group (its name in ``argv``) into numba's cache, at
    :data:`CHILD_NICE` more than it was started with, printing the ``module.name`` of each of
    its kernels as it is compiled. Exit status 2 for an unknown group."""
    if len(argv) != 1 or argv[0] not in GROUPS:
        print(f"expected one group among: {', '.join(GROUPS)}", file=sys.stderr)
        return 2
    group = GROUPS[argv[0]]
    with contextlib.suppress(OSError):
        os.nice(CHILD_NICE)
    with _on_each_compiled(kernels(group), lambda name: print(name, flush=True)):
        _call(group.warm)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
