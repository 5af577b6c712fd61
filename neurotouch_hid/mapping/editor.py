"""Editing profiles in the user's folder (the ``profile new/set/unset/edit/tune/delete/reset``
commands).

Shipped profiles are read-only: editing one writes a user copy of the same name, which shadows
it (the commands say so; ``reset`` removes the copy). A profile made with ``new --from`` a shipped
one remembers it in its first line (:data:`COPY_MARK`), so that ``unset`` puts back the shipped
value rather than the schema's default. Changes go through ruamel.yaml's round-trip mode
(comments, order and number formats kept), and the changed text is validated
(:func:`~neurotouch_hid.mapping.profile.parse_profile`) *before* anything is written: a change
that breaks the profile raises ProfileError and leaves the file as it was. ``edit`` works on a
temporary copy and saves it only when valid, asking to edit again otherwise, as ``crontab -e``.
"""

from __future__ import annotations

import contextlib
import copy
import io
import os
import re
import shlex
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap
from ruamel.yaml.error import YAMLError

from neurotouch_hid.core.atomic import temporary_beside
from neurotouch_hid.core.errors import NeurotouchError, ProfileError, did_you_mean, nearest
from neurotouch_hid.core.limits import YamlError, load_yaml, printable, short, where
from neurotouch_hid.mapping.profile import (
    MAX_PROFILE_NAME_CHARS,
    DeviceSpec,
    LayerSwitch,
    OneEuroSmoothing,
    Profile,
    TouchClick,
    TouchpadMapping,
    find_profile,
    parse_profile,
    read_profile_text,
    shipped_profiles_dir,
    user_profiles_dir,
)
from neurotouch_hid.mapping.profile.models import _ANY_MAPPING_FIELDS, _TAG_MODELS, _output_kind

_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_-]*$")
_MISSING = object()
#: The first line of a user profile made from a shipped one (``profile new NAME --from SHIPPED``).
COPY_MARK = "# neurotouch-hid: a copy of the shipped profile '{}' (profile unset goes back to its values)"
_COPY_MARK = re.compile(r"^# neurotouch-hid: a copy of the shipped profile '([A-Za-z0-9_-]+)'")


def _yaml() -> YAML:
    yaml = YAML()  # round-trip
    yaml.preserve_quotes = True
    yaml.width = 4096
    return yaml


def user_profile_path(name: str) -> Path:
    """Where the user's profile ``name`` lives (it may not exist). Raises ProfileError for a name
    that is not a plain file name (letters, digits, ``_``, ``-``)."""
    if len(name) > MAX_PROFILE_NAME_CHARS:
        raise ProfileError(f"profile name '{printable(name)}' is too long: at most {MAX_PROFILE_NAME_CHARS} characters")
    if not _NAME.fullmatch(name):
        raise ProfileError(f"profile name '{printable(name)}' is not allowed: use letters, digits, '_' and '-' only")
    return user_profiles_dir() / f"{name}.yaml"


def _write(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` atomically (a crash leaves the old or the new file). A
    symbolic link is written through: the file it points to is replaced, the link kept.

    Raises ProfileError (the file, why, and that nothing was changed) when the folder cannot be
    made or written: full, read-only, or a file where a folder should be."""
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".yaml")
    except OSError as exc:
        raise ProfileError(
            f"{printable(path, 200)}: cannot write: {exc.strerror or exc}; nothing was changed"
        ) from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise ProfileError(
            f"{printable(path, 200)}: cannot write: {exc.strerror or exc}; nothing was changed"
        ) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def _editing(folder: Path, what: str):
    """The lock around a read-modify-write of the files in ``folder`` (:func:`~neurotouch_hid.core.atomic.locked`):
    commands run side by side land one after the other. Raises ProfileError when it cannot be taken."""
    from neurotouch_hid.core.atomic import OutputError, locked

    try:
        with locked(folder, what):
            yield
    except OutputError as exc:
        raise ProfileError(str(exc)) from None


def shipped_profile(name: str) -> Path | None:
    """The shipped file of profile ``name``, or None when no shipped profile has that name."""
    path = shipped_profiles_dir() / f"{name}.yaml"
    return path if path.is_file() else None


def shipped_base(name: str) -> Path | None:
    """The shipped profile the user's profile ``name`` is a copy of: the shipped one of the same
    name (which it shadows), else the one its first line names (:data:`COPY_MARK`), else None."""
    same = shipped_profile(name)
    if same is not None:
        return same
    path = user_profile_path(name)
    if not path.is_file():
        return None
    found = _COPY_MARK.match(read_profile_text(path).partition("\n")[0])
    return shipped_profile(found.group(1)) if found else None


def new_profile(name: str, from_name: str = "default") -> Path:
    """Create the user's profile ``name`` as a copy of ``from_name`` (a name or a path); a copy
    of a shipped profile starts with :data:`COPY_MARK`. The source is validated first
    (:func:`~neurotouch_hid.mapping.profile.parse_profile`): a broken one is not copied.

    Raises:
        ProfileError: bad name, ``name`` already exists in the user folder, no such source, or
            the source is not a valid profile (every problem as ``FILE:LINE: field: found VALUE;
            expected ...``, as ``profile validate`` says it); nothing is written then.
    """
    target = user_profile_path(name)
    with _editing(target.parent, f"profile '{name}'"):
        return _new_profile(target, name, from_name)


def _new_profile(target: Path, name: str, from_name: str) -> Path:
    if target.exists():
        raise ProfileError(f"profile '{name}' already exists: {target} (edit it, or delete it first)")
    source = find_profile(from_name)
    text = read_profile_text(source)
    try:
        parse_profile(text, source)
    except ProfileError as exc:
        raise ProfileError(f"{exc}\nnothing written: {printable(target, None)} was not created") from None
    if source.parent == shipped_profiles_dir():
        text = COPY_MARK.format(source.stem) + "\n" + text
    _write(target, text)
    return target


def creates_shadow(name: str) -> bool:
    """True when changing profile ``name`` would first make a user copy of the shipped profile of
    that name (which then shadows it everywhere)."""
    return shipped_profile(name) is not None and not user_profile_path(name).exists()


def backup_path(target: Path) -> Path:
    """Where ``delete`` and ``reset`` keep the profile they take away: ``NAME.yaml.bak`` beside it
    (no profile: only ``*.yaml`` files are profiles); renaming it back restores it."""
    return target.with_name(target.name + ".bak")


def _keep_aside(target: Path) -> None:
    try:
        os.replace(target, backup_path(target))
    except OSError as exc:
        raise ProfileError(f"{target}: cannot move it aside to {backup_path(target).name}: {exc.strerror}") from None


def delete_profile(name: str) -> tuple[Path, Path | None]:
    """Delete the user's profile ``name``, kept as :func:`backup_path` (an older backup
    replaced). Returns (the deleted file, the shipped profile that applies again under that name,
    or None).

    Raises:
        ProfileError: bad name, or no user profile of that name (a shipped one cannot be deleted).
    """
    target = user_profile_path(name)
    if not target.is_file():
        if shipped_profile(name) is not None:
            raise ProfileError(f"'{name}' is a shipped profile: it cannot be deleted (and you have no copy of it)")
        raise ProfileError(f"no user profile named '{name}' in {target.parent}")
    _keep_aside(target)
    return target, shipped_profile(name)


def reset_profile(name: str) -> tuple[Path | None, Path]:
    """Put the shipped profile ``name`` back: delete the user's copy that shadows it, kept as
    :func:`backup_path`. Returns (the deleted copy, or None when there was none, the shipped file).

    Raises:
        ProfileError: ``name`` is not a shipped profile (nothing to go back to).
    """
    shipped = shipped_profile(name)
    if shipped is None:
        shipped_names = sorted(p.stem for p in shipped_profiles_dir().glob("*.yaml"))
        message = f"'{name}' is not a shipped profile, so there is nothing to reset it to"
        close = nearest(name, shipped_names)
        if close is not None:
            message += f"; did you mean 'neurotouch-hid profile reset {close}'?"
        message += f" (shipped: {', '.join(shipped_names)})"
        if user_profile_path(name).is_file():
            message += f"; to remove your profile '{name}': neurotouch-hid profile delete {name}"
        raise ProfileError(message)
    target = user_profile_path(name)
    if not target.is_file():
        return None, shipped
    _keep_aside(target)
    return target, shipped


def _load_rt(name: str) -> tuple[Path, Any]:
    """The profile's file and its round-trip document. Raises ProfileError when it is not YAML,
    at the line to fix (the bounded loader's report), with the command that fixes it."""
    source = find_profile(name)
    text = read_profile_text(source)
    try:
        load_yaml(text)
        return source, _yaml().load(text)
    except YamlError as exc:
        problem = f"{where(source, exc.line)}: not valid YAML: {exc.problem}"
    except YAMLError as exc:
        problem = f"{source}: not valid YAML: {' '.join(str(exc).split())}"
    raise ProfileError(f"{problem}\n  fix it first: neurotouch-hid profile edit {name}")


def _dump(document: Any) -> str:
    buffer = io.StringIO()
    _yaml().dump(document, buffer)
    return buffer.getvalue()


def yaml_text(value: Any) -> str:
    """``value`` as YAML writes it (``null``, ``true``, ``1.5``, ``0x045e``, ``{beta: 0.1}``), for
    the change reports of ``set`` and ``unset``."""
    yaml = _yaml()
    yaml.default_flow_style = True
    buffer = io.StringIO()
    yaml.dump(value, buffer)
    return buffer.getvalue().removesuffix("\n").removesuffix("\n...")


def schema_fields(parts: list[str], node: Any = None) -> tuple[str, ...] | None:
    """The fields the schema allows in the mapping ``node`` at the dotted path ``parts`` (the top
    level for ``[]``; for ``["mappings", NAME]`` those of the mapping's kind, which its ``output``
    decides), or None where it does not say (a name under ``mappings:`` or ``layers:``)."""
    if not parts:
        return tuple(Profile.model_fields)
    if parts[-1] == "smoothing":
        return tuple(OneEuroSmoothing.model_fields)
    if parts == ["device"]:
        return tuple(DeviceSpec.model_fields)
    if parts == ["touchpad"]:
        return tuple(TouchpadMapping.model_fields)
    if parts == ["touchpad", "click"]:
        return tuple(TouchClick.model_fields)
    if len(parts) == 2 and parts[0] == "mappings":
        kind = _output_kind(dict(node)) if isinstance(node, dict) else "unknown"
        return tuple(_ANY_MAPPING_FIELDS if kind == "unknown" else _TAG_MODELS[kind].model_fields)
    if len(parts) == 2 and parts[0] == "layers":
        return tuple(LayerSwitch.model_fields)
    return None


#: Most parts a dotted key of ``profile set``/``unset`` may have: the schema's deepest key has 6.
MAX_KEY_PARTS = 8


def _parent(document: Any, key: str, create: bool) -> tuple[CommentedMap, str]:
    """The mapping holding the last part of a dotted ``key``, and that part."""
    parts = key.split(".")
    if not key or any(not p for p in parts):
        raise ProfileError(f"key '{printable(key)}': expected a dotted path like mappings.push.deadzone_mm")
    if len(parts) > MAX_KEY_PARTS:
        raise ProfileError(
            f"key '{printable(key, 200)}': {len(parts)} parts; a profile's keys have at most {MAX_KEY_PARTS} "
            "(the deepest: layers.NAME.mappings.NAME.smoothing.beta)"
        )
    node = document
    for depth, part in enumerate(parts):
        where = ".".join(parts[:depth]) or "the top level"
        if not isinstance(node, CommentedMap):
            raise ProfileError(
                f"key '{printable(key)}': {where} is a value ({printable(yaml_text(node))}), not a mapping"
            )
        if depth < len(parts) - 1:
            if part not in node:
                if not create:
                    there = ", ".join(map(str, node)) or "nothing"
                    raise ProfileError(
                        f"key '{printable(key)}': there is no '{printable(part)}' in {printable(where)}"
                        f"{did_you_mean(part, node)} (it has: {printable(there, 200)})"
                    )
                node[part] = CommentedMap()
            node = node[part]
    return node, parts[-1]


def parse_value(text: str) -> Any:
    """A command-line VALUE parsed as YAML (``1.5`` -> float, ``true`` -> bool, ``ABS_RX`` -> str,
    ``0x045e`` -> int, ``{beta: 0.1}`` -> mapping). Raises ProfileError if it is not YAML."""
    try:
        load_yaml(text)  # the bounds first: depth, aliases, lengths
        return _yaml().load(text)
    except YamlError as exc:
        raise ProfileError(f"value {short(text)} is not a YAML value: {exc.problem}") from None
    except YAMLError as exc:
        raise ProfileError(f"value {short(text)} is not a YAML value: {printable(exc, 300)}") from None


def _save_validated(name: str, document: Any) -> Path:
    target = user_profile_path(name)
    text = _dump(document)
    try:  # the changed text is in no file yet: its lines would point into nothing
        parse_profile(text, target, lines=False)
    except ProfileError as exc:
        problem = str(exc).replace(f"profile {target} is invalid", f"the change would make profile {target} invalid", 1)
        raise ProfileError(
            f"{problem}\n  nothing was changed ({target if target.exists() else 'no user copy'} kept as it was)"
        ) from None
    _write(target, text)
    return target


def _known_mapping(name: str, document: Any, key: str) -> None:
    """A key under ``mappings.NAME.`` must name a mapping the profile has: setting one field of a
    mapping that is not there cannot make a valid mapping. Raises ProfileError naming them."""
    parts = key.split(".")
    if len(parts) < 3 or parts[0] != "mappings":
        return
    mappings = document.get("mappings") if isinstance(document, CommentedMap) else None
    mappings = mappings if isinstance(mappings, CommentedMap) else {}
    if parts[1] not in mappings:
        there = ", ".join(map(str, mappings)) or "none"
        raise ProfileError(
            f"profile '{name}' has no mapping '{parts[1]}' (its mappings: {there}); set a key of one of "
            f"those, or add the mapping with: neurotouch-hid profile edit {name}"
        )


def _output_takes_the_fields(name: str, document: Any, key: str, value: Any) -> None:
    """A new ``mappings.NAME.output`` of another kind (an axis made a button) must take every
    field the mapping has: otherwise ProfileError names the fields it cannot take and the one
    command that sets the whole mapping at once, without them."""
    parts = key.split(".")
    if len(parts) != 3 or parts[0] != "mappings" or parts[2] != "output" or not isinstance(value, str):
        return
    mapping = document["mappings"][parts[1]]
    if not isinstance(mapping, CommentedMap):
        return
    kind = _output_kind({"output": value})
    if kind == "unknown":
        return  # the schema names the output and what it expected
    allowed = _TAG_MODELS[kind].model_fields
    refused = [str(f) for f in mapping if f not in allowed]
    if not refused:
        return
    kept = {str(f): v for f, v in mapping.items() if f in allowed}
    kept["output"] = value
    candidate = copy.deepcopy(document)
    candidate["mappings"][parts[1]] = CommentedMap(kept)
    target = user_profile_path(name)
    try:  # the command printed must work: else what is wrong with the change itself is said
        parse_profile(_dump(candidate), target, lines=False)
    except ProfileError as exc:
        problem = str(exc).replace(f"profile {target} is invalid", f"{key} {printable(value)} cannot work", 1)
        raise ProfileError(f"{problem}\n  nothing was changed") from None
    whole = yaml_text(CommentedMap(kept))
    raise ProfileError(
        f"{key} {printable(value)}: a {kind} output takes no {', '.join(refused)} (the fields of what "
        f"mapping '{parts[1]}' was); nothing was changed. To change the mapping in one command, without them:\n"
        f"  neurotouch-hid profile set {name} mappings.{parts[1]} '{whole}'"
    )


def set_values(name: str, changes: dict[str, Any]) -> tuple[Path, dict[str, Any]]:
    """Set dotted keys (e.g. ``mappings.push.deadzone_mm``) in profile ``name`` and save it as the
    user's copy, comments and order kept. Missing intermediate mappings are created, except a
    mapping the profile does not have.

    Returns:
        (the user's file, key -> previous value; a key that was not set is absent).
    Raises:
        ProfileError: bad key, a mapping the profile does not have (its mappings named), or the
            result is not a valid profile (the file is left unchanged).
    """
    with _editing(user_profile_path(name).parent, f"profile '{name}'"):
        _, document = _load_rt(name)
        previous = {}
        for key, value in changes.items():
            _known_mapping(name, document, key)
            _output_takes_the_fields(name, document, key, value)
            parent, last = _parent(document, key, create=True)
            if last in parent:
                previous[key] = parent[last]
            parent[last] = value
        return _save_validated(name, document), previous


def unset_value(name: str, key: str) -> tuple[Path, Any, Any, bool]:
    """Undo a dotted key of profile ``name``, saved as the user's copy: back to the value of the
    shipped profile it is a copy of (:func:`shipped_base`) where that has the key and the copy
    holds another value, else removed (the schema's default applies; a mapping removed maps
    nothing): on a copy, a first unset puts the shipped value back, a second removes the key.

    Returns:
        (file, the value taken away, the shipped value put back or None when the key was removed,
        whether it was removed because it held the shipped value already).
    Raises:
        ProfileError: a key that is not there, or the result is invalid (the file is left
            unchanged).
    """
    with _editing(user_profile_path(name).parent, f"profile '{name}'"):
        _, document = _load_rt(name)
        parent, last = _parent(document, key, create=False)
        if last not in parent:
            fields = schema_fields(key.split(".")[:-1], parent)
            if fields is not None and last not in fields:
                raise ProfileError(
                    f"key '{printable(key)}': '{printable(last)}' is not a field there{did_you_mean(last, fields)} "
                    f"(fields: {', '.join(fields)})"
                )
            raise ProfileError(f"key '{printable(key)}' is not set in profile '{name}': its default applies already")
        removed = parent[last]
        shipped = _MISSING
        base = shipped_base(name)
        if base is not None:
            try:
                base_parent, base_last = _parent(_yaml().load(read_profile_text(base)), key, create=False)
                shipped = base_parent.get(base_last, _MISSING)
            except ProfileError:  # the shipped profile does not have that part: the default applies
                pass
        already = shipped is not _MISSING and removed == shipped  # nothing to put back: remove it
        if shipped is _MISSING or already:
            del parent[last]
            return _save_validated(name, document), removed, None, already
        parent[last] = shipped
        return _save_validated(name, document), removed, shipped, False


def rejected_path(name: str) -> Path:
    """Where ``profile edit`` keeps an invalid edit of the user's profile ``name``
    (``NAME.yaml.rejected`` beside it)."""
    target = user_profile_path(name)
    return target.with_name(f"{target.name}.rejected")


def edit_profile(
    name: str, edit_again: Callable[[str], bool], note: Callable[[str], None] = lambda _: None
) -> Path | None:
    """Edit profile ``name`` in the user's editor (:func:`run_editor`), as ``crontab -e`` does: on
    a temporary copy, saved to the user's file only when it is a valid profile. On an invalid
    save, ``edit_again(problem)`` decides: True reopens the editor on the edited text (the problem
    names the temporary file the editor shows, at its lines), False gives up. An edit rejected
    before (:func:`rejected_path`) is where the editing starts again (``note`` says so), and it is
    removed once a valid edit is saved. Returns the saved file, or None when nothing was changed.

    Raises:
        ProfileError: the edit was not valid and not edited again; the user's file is left as it
            was and the edited text is kept in :func:`rejected_path`, which the message's lines
            refer to.
        NeurotouchError: the editor cannot be started or fails.
    """
    target = user_profile_path(name)
    rejected = rejected_path(name)
    original = read_profile_text(find_profile(name))
    text = original
    if rejected.is_file():
        try:
            text = read_profile_text(rejected)
        except ProfileError as exc:
            raise ProfileError(
                f"{exc}\nyour earlier edit, as the editor saved it, is in {rejected}: make it UTF-8 text there "
                "(or copy what you need from it), or delete it to start from the profile"
            ) from None
        note(f"starting from your earlier edit that was not saved, {rejected} (delete it to start from the profile)")
    fd, tmp = tempfile.mkstemp(prefix=f"neurotouch-hid-{name}.", suffix=".yaml")
    os.close(fd)
    work: Path | None = Path(tmp)
    try:
        while True:
            work.write_text(text, encoding="utf-8")
            run_editor(work)
            try:
                text = read_profile_text(work)
            except ProfileError as exc:  # not text, or too large: the edit is kept byte for byte
                kept = f"{target} kept as it was" if target.exists() else f"no user copy of '{name}' made"
                try:
                    rejected.parent.mkdir(parents=True, exist_ok=True)
                    part = temporary_beside(rejected)
                    shutil.copyfile(work, part)
                    os.replace(part, rejected)
                except (OSError, NeurotouchError) as why:
                    work = None  # not deleted: the edit stays where the editor saved it
                    raise ProfileError(f"{exc}\nnot saved: {kept}; your edit stays in {tmp} ({why})") from None
                raise ProfileError(
                    f"{exc}\nnot saved: {kept}; your edit is in {rejected}, as the editor saved it"
                ) from None
            try:
                parse_profile(text, work)
            except ProfileError as exc:
                if edit_again(str(exc)):
                    continue
                _write(rejected, text)
                kept = f"{target} kept as it was" if target.exists() else f"no user copy of '{name}' made"
                try:
                    parse_profile(text, rejected)
                except ProfileError as in_rejected:
                    exc = in_rejected
                raise ProfileError(
                    f"{exc}\nnot saved: {kept}; your edit is in {rejected} (profile edit {name} starts from it)"
                ) from None
            if text != original:
                _write(target, text)
            rejected.unlink(missing_ok=True)
            return target if text != original else None
    finally:
        if work is not None:
            work.unlink(missing_ok=True)


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
