"""Editing profiles in the user's folder (the ``profile new/set/unset/edit/tune`` commands).

Shipped profiles are read-only: editing one writes a user copy of the same name, which shadows
it. Changes go through ruamel.yaml's round-trip mode (comments, order and number formats kept),
and the changed text is validated (:func:`~neurotouch_hid.mapping.profile.parse_profile`)
*before* anything is written: a change that breaks the profile raises ProfileError and leaves
the file as it was.
"""

from __future__ import annotations

import io
import os
import re
import shlex
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap
from ruamel.yaml.error import YAMLError

from neurotouch_hid.errors import NeurotouchError, ProfileError
from neurotouch_hid.mapping.profile import find_profile, parse_profile, user_profiles_dir

_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_-]*$")
_MISSING = object()


def _yaml() -> YAML:
    yaml = YAML()  # round-trip
    yaml.preserve_quotes = True
    yaml.width = 4096
    return yaml


def user_profile_path(name: str) -> Path:
    """Where the user's profile ``name`` lives (it may not exist). Raises ProfileError for a name
    that is not a plain file name (letters, digits, ``_``, ``-``)."""
    if not _NAME.match(name):
        raise ProfileError(f"profile name '{name}' is not allowed: use letters, digits, '_' and '-' only")
    return user_profiles_dir() / f"{name}.yaml"


def _write(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` atomically (a crash leaves the old or the new file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".yaml")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def new_profile(name: str, from_name: str = "default") -> Path:
    """Create the user's profile ``name`` as a copy of ``from_name`` (a name or a path).

    Raises:
        ProfileError: bad name, ``name`` already exists in the user folder, or no such source.
    """
    target = user_profile_path(name)
    if target.exists():
        raise ProfileError(f"profile '{name}' already exists: {target} (edit it, or delete it first)")
    source = find_profile(from_name)
    _write(target, source.read_text(encoding="utf-8"))
    return target


def user_copy(name: str) -> Path:
    """The user's file of profile ``name``, copying the shipped one there first if needed."""
    target = user_profile_path(name)
    if not target.exists():
        _write(target, find_profile(name).read_text(encoding="utf-8"))
    return target


def _load_rt(name: str) -> tuple[Path, Any]:
    source = find_profile(name)
    try:
        return source, _yaml().load(source.read_text(encoding="utf-8"))
    except YAMLError as exc:
        raise ProfileError(f"{source}: not valid YAML: {exc}") from None


def _dump(document: Any) -> str:
    buffer = io.StringIO()
    _yaml().dump(document, buffer)
    return buffer.getvalue()


def _parent(document: Any, key: str, create: bool) -> tuple[CommentedMap, str]:
    """The mapping holding the last part of a dotted ``key``, and that part."""
    parts = key.split(".")
    if not key or any(not p for p in parts):
        raise ProfileError(f"key '{key}': expected a dotted path like mappings.push.deadzone_mm")
    node = document
    for depth, part in enumerate(parts):
        where = ".".join(parts[:depth]) or "the top level"
        if not isinstance(node, CommentedMap):
            raise ProfileError(f"key '{key}': {where} is a value ({node!r}), not a mapping")
        if depth < len(parts) - 1:
            if part not in node:
                if not create:
                    raise ProfileError(f"key '{key}': there is no '{part}' in {where}")
                node[part] = CommentedMap()
            node = node[part]
    return node, parts[-1]


def parse_value(text: str) -> Any:
    """A command-line VALUE parsed as YAML (``1.5`` -> float, ``true`` -> bool, ``ABS_RX`` -> str,
    ``0x045e`` -> int, ``{beta: 0.1}`` -> mapping). Raises ProfileError if it is not YAML."""
    try:
        return _yaml().load(text)
    except YAMLError as exc:
        raise ProfileError(f"value {text!r} is not a YAML value: {exc}") from None


def _save_validated(name: str, document: Any) -> Path:
    target = user_profile_path(name)
    text = _dump(document)
    try:
        parse_profile(text, target)
    except ProfileError as exc:
        raise ProfileError(
            f"{exc}\n  nothing was changed ({target if target.exists() else 'no user copy'} kept as it was)"
        ) from None
    _write(target, text)
    return target


def set_values(name: str, changes: dict[str, Any]) -> tuple[Path, dict[str, Any]]:
    """Set dotted keys (e.g. ``mappings.push.deadzone_mm``) in profile ``name`` and save it as the
    user's copy, comments and order kept. Missing intermediate mappings are created.

    Returns:
        (the user's file, key -> previous value or None).
    Raises:
        ProfileError: bad key, or the result is not a valid profile (the file is left unchanged).
    """
    _, document = _load_rt(name)
    previous = {}
    for key, value in changes.items():
        parent, last = _parent(document, key, create=True)
        previous[key] = parent.get(last)
        parent[last] = value
    return _save_validated(name, document), previous


def unset_value(name: str, key: str) -> tuple[Path, Any]:
    """Remove a dotted key (its default applies again) from profile ``name``, saved as the user's
    copy. Returns (file, removed value). Raises ProfileError for a key that is not there or when the
    result is invalid (the file is left unchanged)."""
    _, document = _load_rt(name)
    parent, last = _parent(document, key, create=False)
    if last not in parent:
        raise ProfileError(f"key '{key}' is not set in profile '{name}'")
    removed = parent[last]
    del parent[last]
    return _save_validated(name, document), removed


def run_editor(path: Path) -> None:
    """Open ``path`` in ``$VISUAL`` or ``$EDITOR`` (default ``vi``) and wait for it.

    Raises:
        NeurotouchError: the editor cannot be started or exits with an error.
    """
    command = shlex.split(os.environ.get("VISUAL") or os.environ.get("EDITOR") or "vi")
    try:
        done = subprocess.run([*command, str(path)], check=False)
    except OSError as exc:
        raise NeurotouchError(f"cannot start the editor {command[0]!r} ({exc}); set $EDITOR") from None
    if done.returncode != 0:
        raise NeurotouchError(f"the editor {command[0]!r} exited with code {done.returncode}; {path} kept as it is")
