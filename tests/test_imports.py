"""The import rule of docs/architecture.md: no import circle, and no stage imports a later one."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "neurotouch_hid"

#: Stage order (docs/architecture.md, "The import rule"); a module not listed is a base value.
ORDER = {
    "sources": 1,
    "calibration": 2,
    "pipeline": 2,
    "mapping": 3,
    "evaluation": 3,
    "enrolment": 5,
    "views": 4,
    "targets": 4,
    "inputs": 4,
    "core.stages": 3,
    "engine": 5,
    # the one loop every descriptor waits on: a base value (the standard library's selectors)
    "engine.loop": 0,
    "service.control": 5,
    "service.games": 5,
    "service.serve": 5,
    "service.warmup": 5,
    "service.kernel_groups": 5,
    "engine.driver": 6,
    "views.pictures": 3,
    "service.doctor": 7,
    "cli": 7,
    # the wire formats and the protocol table are data (descriptors, report layouts, ids): base
    # values, so that a profile names a protocol and the CLI lists them without the devices
    "targets.reports": 0,
    "targets.protocols": 0,
    "targets.identity": 0,
}


def _modules() -> dict[str, Path]:
    found = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found[name] = path
    return found


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Every module's imports of the package's modules, at any depth (function-level too)."""
    edges: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("neurotouch_hid"):
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            edges[name] |= {t for t in targets if t in modules and t != name}
    return edges


def _rank(module: str) -> int:
    parts = module.split(".")[1:]
    for depth in range(len(parts), 0, -1):  # the most specific entry: targets.reports before targets
        if ".".join(parts[:depth]) in ORDER:
            return ORDER[".".join(parts[:depth])]
    return 0


def test_no_stage_imports_a_later_stage():
    edges = _imports(_modules())
    upward = sorted(f"{a} -> {b}" for a, targets in edges.items() for b in targets if _rank(b) > _rank(a))
    assert upward == []


def test_there_is_no_import_circle():
    modules = _modules()
    edges = _imports(modules)
    packages = {name for name, path in modules.items() if path.name == "__init__.py"}
    circles = []

    def visit(node: str, path: list[str], done: set[str]) -> None:
        for nxt in sorted(edges[node] - packages):  # importing a submodule imports its package
            if nxt in path:
                circles.append(" -> ".join(path[path.index(nxt) :] + [nxt]))
            elif nxt not in done:
                done.add(nxt)
                visit(nxt, path + [nxt], done)

    for start in sorted(edges):
        visit(start, [start], set())
    assert circles == []


def test_the_rule_sees_an_upward_import():
    """The checker itself: a sources module importing the runtime would be reported."""
    assert (
        _rank("neurotouch_hid.engine.engine")
        > _rank("neurotouch_hid.sources.davis")
        > _rank("neurotouch_hid.core.sensor")
    )
