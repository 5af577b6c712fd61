"""Where profiles live and how one is read: bounded YAML, the schema, and every problem at once
as a :class:`~neurotouch_hid.core.errors.ProfileError` naming the file, the line and the field."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path
from typing import Any

from pydantic import (
    BaseModel,
    ValidationError,
)
from ruamel.yaml.nodes import MappingNode, ScalarNode, SequenceNode

from neurotouch_hid.core.errors import ProfileError, did_you_mean, in_plain_words
from neurotouch_hid.core.limits import (
    MAX_YAML_BYTES,
    YamlError,
    load_yaml,
    printable,
    read_outside_text,
    short,
    where,
)
from neurotouch_hid.mapping.profile.copilot import (
    CopilotDevice,
)
from neurotouch_hid.mapping.profile.models import (
    _TAG_MODELS,
    DeviceSpec,
    LayerSwitch,
    OneEuroSmoothing,
)
from neurotouch_hid.mapping.profile.outputs import (
    MAX_PROBLEMS_SHOWN,
    MAX_PROFILE_NAME_CHARS,
    SCALAR_INPUTS,
    VECTOR_INPUTS,
)
from neurotouch_hid.mapping.profile.schema import (
    Profile,
)
from neurotouch_hid.mapping.profile.touch import (
    TouchClick,
    TouchpadMapping,
)


# --- where profiles live ------------------------------------------------------------------------
def shipped_profiles_dir() -> Path:
    """The read-only profiles shipped in the package (``neurotouch_hid/profiles``)."""
    return Path(str(resources.files("neurotouch_hid") / "profiles"))


def user_profiles_dir() -> Path:
    """The user's profiles: ``platformdirs.user_config_dir("neurotouch-hid")/profiles``
    (``$XDG_CONFIG_HOME/neurotouch-hid/profiles`` on Linux). Not created here."""
    import platformdirs

    return Path(platformdirs.user_config_dir("neurotouch-hid")) / "profiles"


def _is_path(name_or_path: str | os.PathLike) -> bool:
    text = str(name_or_path)
    return os.sep in text or text.endswith((".yaml", ".yml"))


def available_profiles() -> dict[str, Path]:
    """Profile name -> file, user profiles shadowing shipped ones of the same name, sorted."""
    found: dict[str, Path] = {}
    for folder in (shipped_profiles_dir(), user_profiles_dir()):
        if folder.is_dir():
            found.update({p.stem: p for p in folder.glob("*.yaml")})
    return dict(sorted(found.items()))


def find_profile(name_or_path: str | os.PathLike) -> Path:
    """The file of a profile: a path (contains ``/`` or ends in ``.yaml``) as is, else the user's
    ``NAME.yaml``, else the shipped one. Raises ProfileError when there is none, or for a name
    longer than :data:`MAX_PROFILE_NAME_CHARS` (the message quotes an excerpt of it, escaped)."""
    if _is_path(name_or_path):
        path = Path(name_or_path)
        try:
            path.stat()
        except FileNotFoundError:
            raise ProfileError(f"profile file {printable(path, 200)} does not exist") from None
        except OSError as exc:  # a name too long, a loop of links, a folder not ours
            raise ProfileError(f"profile file {printable(path, 200)}: {exc.strerror or exc}") from None
        return path
    name = str(name_or_path)
    if len(name) > MAX_PROFILE_NAME_CHARS:
        raise ProfileError(
            f"no profile named '{printable(name)}': a profile name has at most {MAX_PROFILE_NAME_CHARS} characters"
        )
    found = available_profiles().get(name)
    if found is None:
        names = ", ".join(printable(n) for n in available_profiles()) or "none"
        raise ProfileError(
            f"no profile named '{printable(name)}' (available: {names}; user folder: {user_profiles_dir()})"
        )
    return found


def read_profile_text(path: str | os.PathLike) -> str:
    """The text of profile file ``path``, read within the bounds (:func:`~neurotouch_hid.core.limits.
    read_outside_text`: a regular file of at most :data:`~neurotouch_hid.core.limits.MAX_YAML_BYTES`,
    opened without blocking: a FIFO or a link to ``/dev/zero`` is refused, not waited on).

    Raises:
        ProfileError: missing, unreadable, not a regular file, too large, or not UTF-8.
    """
    return read_outside_text(path, MAX_YAML_BYTES, "profile", ProfileError)


def load_profile(name_or_path: str | os.PathLike) -> Profile:
    """Read and validate a profile by name (user folder first, then shipped) or path.

    Raises:
        ProfileError: the file is missing, not YAML, or breaks the schema; the message lists every
            problem as ``FILE:LINE: field: found VALUE; expected ...``.
    """
    path = find_profile(name_or_path)
    return parse_profile(read_profile_text(path), path)


def parse_profile(text: str, source: str | os.PathLike, lines: bool = True) -> Profile:
    """Validate a profile's YAML text; ``source`` (a file name) is only used in error messages,
    with the line of each problem unless ``lines`` is False (a text that is in no file: a change
    about to be written).

    Raises:
        ProfileError: YAML syntax error (with its line) or every schema problem at once.
    """
    try:
        data, root = load_yaml(text)
    except YamlError as exc:
        raise ProfileError(f"{where(source, exc.line)}: not valid YAML: {exc.problem}") from None
    if data is None:
        raise ProfileError(f"{source}:1: the profile is empty; expected a mapping with 'mappings:'")
    layers = data.get("layers") if isinstance(data, dict) else None
    context = {"layers": [str(k) for k in layers] if isinstance(layers, dict) else []}
    try:
        return Profile.model_validate(data, context=context)
    except ValidationError as exc:
        problems = [
            line
            for _, line in sorted((_describe(err, root, source, lines) for err in exc.errors()), key=lambda p: p[0])
        ]
        shown = problems[:MAX_PROBLEMS_SHOWN] + (
            [f"... and {len(problems) - MAX_PROBLEMS_SHOWN} more"] if len(problems) > MAX_PROBLEMS_SHOWN else []
        )
        raise ProfileError(
            f"profile {source} is invalid ({len(problems)} problem{'s' * (len(problems) > 1)}):\n  "
            + "\n  ".join(shown)
        ) from None


# --- error messages -----------------------------------------------------------------------------
def _line_of(root: Any, loc: tuple) -> tuple[int, tuple]:
    """The 1-based line of the YAML node at pydantic's ``loc`` and the loc without union tags.

    A loc element that is no key of the current mapping (a union tag, a missing field) is skipped
    for the walk; the deepest node reached gives the line (a key's own line for mappings).
    """
    node, line, path = root, (root.start_mark.line + 1 if root is not None else 1), []
    for part in loc:
        match = None
        if isinstance(node, MappingNode):
            match = next(((k, v) for k, v in node.value if isinstance(k, ScalarNode) and k.value == str(part)), None)
        elif isinstance(node, SequenceNode) and isinstance(part, int) and 0 <= part < len(node.value):
            match = (node.value[part], node.value[part])
        if match is not None:
            line, node = match[0].start_mark.line + 1, match[1]
            path.append(part)
        elif part not in _TAG_MODELS:
            path.append(part)
            node = None
    return line, tuple(path)


def _model_at(loc: tuple) -> type[BaseModel] | None:
    """The schema model that holds the field at ``loc`` (tags included), for listing its fields."""
    parent = loc[:-1]
    if not parent:
        return Profile
    if parent[-1] in _TAG_MODELS:
        return _TAG_MODELS[parent[-1]]
    if len(parent) == 2 and parent[0] == "layers":
        return LayerSwitch
    if len(parent) == 2 and parent[0] == "copilot":
        return CopilotDevice
    if parent == ("touchpad", "click"):
        return TouchClick
    return {"device": DeviceSpec, "smoothing": OneEuroSmoothing, "touchpad": TouchpadMapping}.get(str(parent[-1]))


def _describe(err: dict, root: Any, source: str | os.PathLike, lines: bool = True) -> tuple[int, str]:
    """(line, ``FILE:LINE: field: found VALUE; expected ...``) for one pydantic error (``FILE:``
    without lines)."""
    line, path = _line_of(root, tuple(err["loc"]))
    at = where(source, line if lines else 0)
    field = ".".join(str(p) for p in path) or "(top level)"
    kind = err["type"]
    if kind == "missing":
        return line, f"{at}: {field}: missing; expected a value (this field is required)"
    if kind == "extra_forbidden":
        model = _model_at(tuple(err["loc"]))
        allowed = f": one of {', '.join(model.model_fields)}" if model is not None else ""
        close = did_you_mean(str(path[-1]), model.model_fields) if model is not None and path else ""
        return (
            line,
            f"{at}: {field}: unknown field (found {short(err['input'])}{close}); expected a known field{allowed}",
        )
    if kind == "string_pattern_mismatch" and path[-1:] == ("[key]",):
        field = ".".join(str(p) for p in path[:-1])
        return line, (
            f"{at}: {field}: found the name {short(err['input'])}; expected a name of letters, "
            "digits and '_' that does not start with a digit"
        )
    if kind == "value_error" and not path and isinstance(err["input"], dict):  # about the whole profile
        message = in_plain_words(err["msg"])
        return line, f"{at}: {message[:1].upper()}{message[1:]}" if message.startswith("this ") else (
            f"{at}: the profile: expected {message.removeprefix('expected ')}"
        )
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return line, f"{at}: {field}: found {short(err['input'])}; expected a mapping (key: value lines)"
    message = in_plain_words(err["msg"])
    expected = message[0].lower() + message[1:] if message else message
    expected = expected.removeprefix("expected ")
    if kind == "literal_error" and path[-1:] == ("input",) and isinstance(err["input"], str):
        expected += did_you_mean(err["input"], VECTOR_INPUTS + SCALAR_INPUTS)
    return line, f"{at}: {field}: found {short(err['input'])}; expected {expected}"
