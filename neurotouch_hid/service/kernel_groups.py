"""The first run's kernel groups: which numba kernels each group holds, how a child process
compiles a group into numba's cache, and how a cold group's kernels are swapped for their Python
form and back (:mod:`neurotouch_hid.service.warmup` orchestrates them; docs/performance.md,
"Start-up")."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Callable, Iterator, Literal


@dataclass(frozen=True)
class KernelGroup:
    """Kernels compiled together by one child process.

    Attributes:
        name: the group's name (the child's argument).
        imports: the module whose import defines every kernel of the group.
        packages: module-name prefixes whose numba kernels belong to the group.
        warm: ``"module:function"`` run by the child: calls every kernel of the group with the
            argument types a run gives them, so numba compiles and caches them.
        load_when_warm: on a warm cache, how the run's process loads the group's cached code
            before it starts (~2 s for the pipeline, which the first window would otherwise wait
            for): ``"call"`` runs ``warm`` (the signatures a run calls: the pipeline's cache also
            holds other commands'), ``"cache"`` loads every signature numba's cache holds (the
            simulator's: one a kernel).
        only: when given, the group's kernels are these (``module.name``) alone.
        excludes: kernels (``module.name``) left to another group.
        background: in a run that goes on while it compiles, the child starts once the other
            groups are compiled: what the first gestures do not wait for leaves both cores to
            what they do, then has one.
        waits: interpreted only until the run's first window is out (:meth:`Warmup.progress_now`
            is first asked), then waited for: its Python form is so much slower than its
            compile that waiting comes first sooner (the simulated gel, the tracker).
    """

    name: str
    imports: str
    packages: tuple[str, ...]
    warm: str
    load_when_warm: Literal["call", "cache"] = "cache"
    only: tuple[str, ...] = ()
    excludes: tuple[str, ...] = ()
    background: bool = False
    waits: bool = False


#: The pipeline's per-event kernels: the tracker's (its APS-frame correction aside) and the
#: noise filter's.
TRACKER_KERNELS = (
    *(
        f"neurotouch_hid.pipeline.tracker_kernels.{name}"
        # (track_events and check_lost: _track's and _check_lost's public names, the same kernels)
        for name in ("_track", "_check_lost", "track_events", "check_lost", "_claim", "_release", "_repaint")
        + ("_lose", "_paint_all")
    ),
    "neurotouch_hid.pipeline.noise.background_activity_keep",
    "neurotouch_hid.pipeline.rest_window.rest_window",
)

TRACKER = KernelGroup(
    "tracker",
    "neurotouch_hid.pipeline.methods",
    ("neurotouch_hid.pipeline.",),
    "neurotouch_hid.service.kernel_groups:compile_tracker",
    load_when_warm="call",
    only=TRACKER_KERNELS,
    waits=True,  # ~3 s of CPU to compile; interpreted, ~0.5 s of events a second
)
PIPELINE = KernelGroup(
    "pipeline",
    "neurotouch_hid.pipeline.methods",
    ("neurotouch_hid.pipeline.",),
    "neurotouch_hid.service.kernel_groups:compile_windows",
    load_when_warm="call",
    excludes=TRACKER_KERNELS,
    background=True,
)
SIMULATOR = KernelGroup(
    "simulator",
    "neurotouch_hid.sources.simulator",
    ("neurotouch_hid.sources.esim", "neurotouch_hid.sources.gel", "neurotouch_hid.sources.simulator"),
    "neurotouch_hid.service.kernel_groups:simulate_briefly",
    waits=True,  # ~3 s of CPU to compile, while interpreted it gives ~0.1 s of gel a second
)
PAPER_PIPELINE = KernelGroup(
    "paper-pipeline",
    "neurotouch_hid.pipeline.methods",
    ("neurotouch_hid.pipeline.",),
    "neurotouch_hid.service.kernel_groups:compile_paper_windows",
    load_when_warm="call",
    excludes=TRACKER_KERNELS,
    background=True,
)
#: The pipeline's groups of each method (``pipeline.methods``): both methods track alike.
PIPELINE_OF = {"default": (TRACKER, PIPELINE), "paper": (TRACKER, PAPER_PIPELINE)}
GROUPS = {g.name: g for g in (TRACKER, PIPELINE, PAPER_PIPELINE, SIMULATOR)}


def compile_pipeline(method: str = "default") -> None:
    """Compile (or load from numba's cache) every kernel of the ``method``'s gesture pipeline now
    (:meth:`GesturePipeline.compile_kernels`, ``pipeline.methods``), on the default sensor: what
    a real-time run that cannot wait does before it opens its source, and a pipeline group's child
    does."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.pipeline.methods import METHODS

    METHODS[method][1](SensorGeometry()).compile_kernels()


def compile_tracker() -> None:
    """The tracker group's warm-up: the per-event part of :func:`compile_pipeline`
    (:meth:`GesturePipeline.compile_tracker_kernels`), for both methods."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.pipeline.methods import METHODS

    for _, pipeline in METHODS.values():
        pipeline(SensorGeometry()).compile_tracker_kernels()


def compile_windows(method: str = "default") -> None:
    """The pipeline group's warm-up: the per-window part of :func:`compile_pipeline`
    (:meth:`GesturePipeline.compile_window_kernels`) of ``method``."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.pipeline.methods import METHODS

    METHODS[method][1](SensorGeometry()).compile_window_kernels()


def compile_paper_windows() -> None:
    """:func:`compile_windows` of the paper's method (``run --method paper``), then of the
    product's: both groups hold every per-window kernel of the pipeline's package
    (``packages``), so the paper's alone would leave the group cold and every later run
    compiling again."""
    compile_windows("paper")
    compile_windows("default")


def simulate_briefly() -> None:
    """The simulator's warm-up: the simulated gel up to its first gesture (its frame, event and
    finger kernels; ~1 s of simulated time)."""
    from neurotouch_hid.core.estimate import GestureType
    from neurotouch_hid.sources.simulator import SimulatedSource

    for chunk in SimulatedSource(seed=0).chunks(seconds=10.0):
        if chunk.label.gesture is not GestureType.NONE:
            break


def child_command(group: KernelGroup) -> list[str]:
    """The command of ``group``'s child: this Python on ``python -m neurotouch_hid.service.warmup GROUP``,
    with ``-P`` (Python 3.11) so that the working directory is not put first on ``sys.path``: run
    from a source checkout (as the README's first command is), ``-m`` alone imports the
    checkout's ``neurotouch_hid``, compiles its kernels into the checkout's cache and leaves the
    installed package's cold, so every later run compiles again."""
    return [sys.executable, "-P", "-m", "neurotouch_hid.service.warmup", group.name]


def kernels(group: KernelGroup) -> dict[str, object]:
    """The group's numba dispatchers, by ``module.name``, importing the group's module.

    Kernels compiled only inside others (``inline="always"``) are left out: they have no cached
    code of their own (:func:`inlined_kernels`)."""
    return {
        name: dispatcher
        for name, dispatcher in _dispatchers(group)
        if dispatcher.targetoptions.get("inline", "never") == "never"
        and (not group.only or name in group.only)
        and name not in group.excludes
    }


def inlined_kernels(group: KernelGroup) -> dict[str, object]:
    """The kernels of the group's packages compiled only inside others (``inline="always"``), by
    ``module.name``, whatever ``only`` and ``excludes`` say (the tracker's and the rest's kernels
    share them).

    They have no cached code of their own, yet an interpreted kernel (its ``py_func``) calls them
    from Python, where numba would compile each one in the run's own process, on the run's
    thread (0.5-1.4 s of CPU apiece, four of them, before the first gesture and the first state):
    :class:`Warmup` interprets them while any group is."""
    return {
        name: dispatcher
        for name, dispatcher in _dispatchers(group)
        if dispatcher.targetoptions.get("inline", "never") != "never"
    }


def _dispatchers(group: KernelGroup) -> Iterator[tuple[str, object]]:
    """(``module.name``, dispatcher) of every numba kernel defined in the group's packages,
    importing the group's module first."""
    import importlib

    from numba.core.registry import CPUDispatcher

    importlib.import_module(group.imports)
    for name, module in list(sys.modules.items()):
        if module is None or not name.startswith(group.packages):
            continue
        for attr, value in list(vars(module).items()):
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == name:
                yield f"{name}.{attr}", value


def _every_module_name(dispatchers: dict[object, object]) -> Iterator[tuple[object, str, object]]:
    """(module, attribute, replacement) for every global name of the package bound to a key of
    ``dispatchers`` (a kernel or its py_func)."""
    for name, module in list(sys.modules.items()):
        if module is None or not name.startswith("neurotouch_hid"):
            continue
        for attr, value in list(vars(module).items()):
            try:
                if value in dispatchers:
                    yield module, attr, dispatchers[value]
            except TypeError:  # unhashable module globals
                continue


def interpret(group_kernels: dict[str, object]) -> None:
    """Point every global name of the package bound to one of these kernels at its pure-Python
    form (``py_func``): calls from Python and from the other interpreted kernels alike."""
    swap = {d: d.py_func for d in group_kernels.values()}
    for module, attr, value in _every_module_name(swap):
        setattr(module, attr, value)


def compiled(group_kernels: dict[str, object]) -> None:
    """Undo :func:`interpret`: every name points at the compiled kernel again."""
    swap = {d.py_func: d for d in group_kernels.values()}
    for module, attr, value in _every_module_name(swap):
        setattr(module, attr, value)


def _on_each_compiled(group_kernels: dict[str, object], on_kernel: Callable[[str], None]):
    """A context in which ``on_kernel(name)`` is called each time numba has compiled one of
    ``group_kernels`` (numba's ``numba:compile`` event, nested compiles included)."""
    from numba.core import event

    names = {d: name for name, d in group_kernels.items()}

    class Reporting(event.Listener):
        def on_start(self, ev):
            pass

        def on_end(self, ev):
            name = names.get(ev.data.get("dispatcher"))
            if name is not None:
                on_kernel(name)

    return event.install_listener("numba:compile", Reporting())


def _call(spec: str) -> None:
    import importlib

    module, function = spec.split(":")
    getattr(importlib.import_module(module), function)()
