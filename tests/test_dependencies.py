"""The install holds nothing the driver does not use (docs/performance.md, "Install size"): every
runtime dependency in pyproject.toml is imported by the package's own code.

Each requirement's import names come from its installed distribution's files (``importlib.metadata``:
its top-level modules and packages); the package's imports from its sources' syntax trees
(``ast``), so an import inside a function counts as one at the top.
"""

from __future__ import annotations

import ast
import importlib.metadata

from helpers import REPO, project_requirements


def import_names(distribution: str) -> set[str]:
    """The top-level names ``import`` takes for the installed ``distribution`` (``cv2`` for
    opencv-contrib-python-headless, ``usb`` for pyusb), from the files it installed."""
    names = set()
    for file in importlib.metadata.files(distribution) or ():
        top = file.parts[0]
        if top.endswith((".dist-info", ".libs", ".data")) or top in ("__pycache__", "..", "bin"):
            continue
        if len(file.parts) > 1:
            names.add(top)
        elif file.suffix in (".py", ".so", ".pyd"):
            names.add(top.split(".")[0])
    return names


def imported_by_the_package() -> set[str]:
    """The top-level module names any ``import`` or ``from ... import`` in neurotouch_hid names."""
    names = set()
    for source in (REPO / "neurotouch_hid").rglob("*.py"):
        for node in ast.walk(ast.parse(source.read_text(), str(source))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names


def test_import_names_come_from_the_distributions_files():
    assert import_names("opencv-contrib-python-headless") >= {"cv2"}
    assert "usb" in import_names("pyusb")
    assert "dv_processing" in import_names("dv-processing")  # a lone extension module


def test_every_runtime_dependency_is_imported_by_the_driver():
    used = imported_by_the_package()
    unused = {}
    for requirement in project_requirements():  # those installed on this platform
        names = import_names(requirement.name)
        assert names, f"{requirement.name} is not installed, or installed no module"
        if not names & used:
            unused[requirement.name] = sorted(names)
    assert not unused, f"dependencies the driver never imports (drop them, or say in pyproject.toml why): {unused}"
