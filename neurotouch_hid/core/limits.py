"""Bounds on what comes from outside: the small files the driver reads and the YAML in them.

Profiles and ``sensor.yaml`` files are handed around, so they are read as if crafted to break
the driver (docs/limits.md has every limit, its value and why it is there):

- :func:`read_text_file` reads only a regular file (a FIFO or a device would block or never end)
  of at most a given size, without following the read past it; :func:`read_outside_text` is
  that read with each way it fails (missing, too large, unreadable, not UTF-8) told as one error
  line of the caller's error class;
- :func:`load_yaml` parses with ruamel.yaml's safe loader (pure Python, so its composer's
  ``max_depth`` applies; duplicate keys refused, its default), plus two counts kept in the
  composer's own hooks: nodes after alias expansion (a "billion laughs" of a few KB would make
  a billion values for the schema to walk) and the length of a number (Python refuses ints of
  more than 4300 digits with a ValueError; floats of thousands of digits are no number a person
  writes). Every refusal is one :class:`YamlError` with the line, the problem and, for the
  common slips (tabs, indentation), a hint. A string longer than :data:`MAX_STRING_CHARS` is
  refused the same way;
- :func:`read_proc_file` reads a file of ``/proc`` (another process's environment, command
  line) up to a size, however much the process put there;
- :func:`printable` is how any outside text reaches a message or the terminal: a short excerpt,
  control characters (escape sequences, newlines) written as Python escapes.

Library: ruamel.yaml (``YAML(typ="safe", pure=True)``, ``max_depth``, ``allow_duplicate_keys``).
"""

from __future__ import annotations

import itertools
import logging
import os
import reprlib
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

#: Largest profile or sensor.yaml read (bytes). The shipped profiles are 1-4 KB; a profile with
#: every possible mapping stays under 64 KB.
MAX_YAML_BYTES = 256 * 1024
#: Deepest nesting of lists and mappings in a profile or sensor.yaml. A profile's deepest value
#: is 5 levels down (mappings -> item -> filter -> field); Python's recursion limit is 1000.
MAX_YAML_DEPTH = 32
#: Most values (scalars, lists, mappings) a YAML document may stand for once its aliases are
#: expanded: 100x the largest profile's ~1000, and walked by the schema in milliseconds.
MAX_YAML_NODES = 100_000
#: Largest image size, gel radius and scale in a sensor.yaml (px, px/mm): a DAVIS-346 is
#: 346x260 and the largest event cameras 1280x720; images of this side are allocated per frame.
MAX_SENSOR_PX = 4096
#: Longest number written in YAML (characters). A float has 17 significant digits; the rest
#: is sign, point and exponent.
MAX_NUMBER_CHARS = 64

#: Longest string value in YAML (characters): a profile name, a path (PATH_MAX is 4096 bytes), a
#: description of a few lines.
MAX_STRING_CHARS = 4096
#: Characters of an outside value quoted in a message (:func:`short`, :func:`printable`).
EXCERPT_CHARS = 60

_SHORT = reprlib.Repr()  # keyword arguments only from Python 3.12
_SHORT.maxlevel, _SHORT.maxlist, _SHORT.maxtuple, _SHORT.maxdict, _SHORT.maxstring = 2, 4, 4, 4, 40
_NUMBER_TAGS = ("tag:yaml.org,2002:int", "tag:yaml.org,2002:float")


class YamlError(ValueError):
    """A YAML text is not valid or breaks a bound: ``line`` (1-based, 0 when unknown) and a
    one-line ``problem`` that ends with a hint when one helps."""

    def __init__(self, line: int, problem: str) -> None:
        super().__init__(problem)
        self.line = line
        self.problem = problem


class FileLimitError(OSError):
    """A file is not a regular file, or is larger than allowed; the message says which."""


def _open_regular(path: str | os.PathLike, max_bytes: int, what: str) -> tuple[BinaryIO, FileLimitError]:
    """``path`` opened for reading in binary without blocking, checked with ``fstat`` on the open
    descriptor to be a regular file of at most ``max_bytes``; with the error to raise when more
    than ``max_bytes`` are read from it after all (it grew)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    too_large = FileLimitError(f"{path}: larger than {max_bytes // 1024} KB, the most a {what} may be (docs/limits.md)")
    fh = os.fdopen(fd, "rb")
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise FileLimitError(f"{path}: not a regular file (a {what} must be a file, not a pipe or a device)")
        if info.st_size > max_bytes:
            raise too_large
    except BaseException:
        fh.close()
        raise
    return fh, too_large


def read_text_file(path: str | os.PathLike, max_bytes: int, what: str) -> str:
    """The UTF-8 text of ``path``, a regular file of at most ``max_bytes`` bytes.

    The file is opened without blocking (a FIFO given by mistake or malice would wait for a
    writer for ever) and checked with ``fstat`` on the open descriptor (no race with a rename).

    Raises:
        FileNotFoundError, PermissionError, OSError: as ``open`` does.
        FileLimitError: not a regular file, or larger than ``max_bytes`` (message names ``what``).
        UnicodeDecodeError: the bytes are not UTF-8.
    """
    fh, too_large = _open_regular(path, max_bytes, what)
    with fh:
        chunks, size = [], 0  # in pieces: read(n) reserves n bytes before it reads
        while size <= max_bytes:
            chunk = fh.read(min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    if size > max_bytes:  # the file grew while read
        raise too_large
    data = b"".join(chunks)
    return data.decode("utf-8")


def _outside_read_error(exc: BaseException, path: str | os.PathLike, kind: str, missing: str | None) -> str:
    """The one-line message of :func:`read_outside_text` for a failed read; re-raises a
    ``FileNotFoundError`` when ``missing`` is None."""
    shown = printable(path, None)
    if isinstance(exc, FileLimitError):
        return printable(exc, None)
    if isinstance(exc, UnicodeDecodeError):
        return f"{shown}: not a {kind} (not UTF-8 text)"
    assert isinstance(exc, OSError)
    gone = isinstance(exc, FileNotFoundError)
    if gone and missing is None:
        raise exc
    if gone and missing:
        return f"{shown}: no such {kind} ({missing})"
    return f"{shown}: cannot read the {kind}: {exc.strerror or exc}"


def read_outside_text(
    path: str | os.PathLike,
    max_bytes: int,
    kind: str,
    error: type[Exception],
    missing: str | None = "",
) -> str:
    """The UTF-8 text of ``path`` (:func:`read_text_file`), every way the read fails told as one
    ``error(message)``: one line that starts with the file and names its ``kind`` (words for the
    user: ``"profile"``, ``"sensor file"``), control characters in the path escaped
    (:func:`printable`).

    - missing, ``missing`` a non-empty hint: ``FILE: no such KIND (MISSING)``; ``missing`` empty:
      told as any file that cannot be read (below); ``missing`` None: the ``FileNotFoundError``
      is raised as it is (a caller for which no file is a valid state);
    - not a regular file, larger than ``max_bytes``: :class:`FileLimitError`'s message;
    - cannot be read (permissions, a folder, I/O): ``FILE: cannot read the KIND: REASON``;
    - not UTF-8: ``FILE: not a KIND (not UTF-8 text)``.

    Raises:
        error: as above.
        FileNotFoundError: ``missing`` is None and there is no file at ``path``.
    """
    try:
        return read_text_file(path, max_bytes, kind)
    except (OSError, UnicodeDecodeError) as exc:
        message = _outside_read_error(exc, path, kind, missing)
    raise error(message)


def read_outside_lines(
    path: str | os.PathLike, max_bytes: int, max_line_bytes: int, kind: str, error: type[Exception]
) -> Iterator[tuple[int, str]]:
    """The lines of ``path``'s UTF-8 text, read as they are asked for: ``(number from 1, line
    without its newline)``; lines end at a newline only (as JSON lines do: U+2028 inside a string
    is no line end). The file is opened and checked as :func:`read_text_file` does when the first
    line is asked for; what is held at once is one line.

    Raises:
        error: as :func:`read_outside_text` says (a missing file is one that cannot be read), and
            ``FILE:LINE: not a KIND (not UTF-8 text)``, ``FILE:LINE: longer than N bytes, the most
            a line of a KIND may be (docs/limits.md)``, or the file over ``max_bytes``.
    """
    try:
        fh, too_large = _open_regular(path, max_bytes, kind)
    except OSError as exc:
        raise error(_outside_read_error(exc, path, kind, "")) from None
    shown = printable(path, None)
    with fh:
        size = 0
        for number in itertools.count(1):
            try:
                raw = fh.readline(max_line_bytes + 1)
            except OSError as exc:
                raise error(f"{shown}:{number}: cannot read the {kind}: {exc.strerror or exc}") from None
            if not raw:
                return
            size += len(raw)
            if size > max_bytes:  # the file grew while read
                raise error(printable(too_large, None))
            line = raw[:-1] if raw.endswith(b"\n") else raw
            if len(line) > max_line_bytes:
                raise error(
                    f"{shown}:{number}: longer than {max_line_bytes // 1024} KB, the most a line of a {kind} "
                    "may be (docs/limits.md)"
                )
            try:
                text = line.decode("utf-8")
            except UnicodeDecodeError:
                raise error(f"{shown}:{number}: not a {kind} (not UTF-8 text)") from None
            yield number, text


def _hint(problem: str) -> str:
    """A plain-words hint for YAML's usual parser messages (empty when none fits)."""
    if "could not find expected ':'" in problem:
        return " (hint: a key on this line has no ':' after it; write 'key: value')"
    if "'\\t'" in problem or "tab" in problem:
        return " (hint: YAML indents with spaces, never tabs: replace the tabs on this line)"
    if any(s in problem for s in ("expected <block end>", "mapping values are not allowed")):
        return (
            " (hint: check this line's indentation against the lines above: keys of one mapping "
            "start in the same column, and a value on its own line is indented more than its key)"
        )
    if "found undefined alias" in problem:
        return " (hint: '*' starts an alias in YAML: quote a value that begins with '*')"
    if "while scanning a quoted scalar" in problem or "found unexpected end of stream" in problem:
        return " (hint: a quote is not closed)"
    return ""


def _keyless_line_before(text: str, line: int) -> int:
    """The 1-based line before ``line`` (blank and comment lines skipped) when it holds a plain
    word with no ``:`` (a key whose ``:`` is missing: YAML reads it as the start of a value and
    stumbles on the next line's ``:``), else 0."""
    lines = text.split("\n")
    for index in range(line - 2, -1, -1):
        content = lines[index].split(" #")[0].strip()
        if not content or content.startswith("#"):
            continue
        plain = ":" not in content and not content.startswith(("-", "'", '"', "[", "{", "|", ">", "&", "*", "!"))
        return index + 1 if plain else 0
    return 0


def _lines(text: str) -> int:
    """The number of lines of ``text`` (at least 1; a final newline ends the last line)."""
    return max(1, text.count("\n") + (not text.endswith("\n")))


def _composer_class():
    from ruamel.yaml.composer import Composer
    from ruamel.yaml.nodes import MappingNode, SequenceNode

    class BoundedComposer(Composer):
        """ruamel's composer counting expanded nodes and refusing long numbers."""

        def __init__(self, loader: Any = None) -> None:
            super().__init__(loader)
            self.nodes = 0
            self._sizes: dict[int, int] = {}

        def _count(self, n: int, mark: Any) -> None:
            self.nodes += n
            if self.nodes > MAX_YAML_NODES:
                raise YamlError(
                    mark.line + 1,
                    f"more than {MAX_YAML_NODES} values once its aliases ('*name') are expanded: "
                    "no profile, sensor or games file is that large (docs/limits.md)",
                )

        def _size(self, node: Any) -> int:
            """Values ``node`` stands for, aliases expanded (memoised; depth is bounded)."""
            known = self._sizes.get(id(node))
            if known is None:
                if isinstance(node, SequenceNode):
                    known = 1 + sum(self._size(child) for child in node.value)
                elif isinstance(node, MappingNode):
                    known = 1 + sum(self._size(k) + self._size(v) for k, v in node.value)
                else:
                    known = 1
                self._sizes[id(node)] = known = min(known, MAX_YAML_NODES + 1)
            return known

        def return_alias(self, a: Any) -> Any:
            self._count(self._size(a), a.start_mark)
            return a

        def compose_scalar_node(self, anchor: Any) -> Any:
            node = super().compose_scalar_node(anchor)
            self._count(1, node.start_mark)
            if str(node.tag) in _NUMBER_TAGS and len(node.value) > MAX_NUMBER_CHARS:
                raise YamlError(
                    node.start_mark.line + 1,
                    f"a number of {len(node.value)} characters (at most {MAX_NUMBER_CHARS}); "
                    "write it with fewer digits",
                )
            if len(node.value) > MAX_STRING_CHARS:
                raise YamlError(
                    node.start_mark.line + 1,
                    f"a value of {len(node.value)} characters (at most {MAX_STRING_CHARS}, docs/limits.md): "
                    f"{printable(node.value, 30)}",
                )
            return node

        def compose_sequence_node(self, anchor: Any) -> Any:
            self._count(1, self.parser.peek_event().start_mark)
            return super().compose_sequence_node(anchor)

        def compose_mapping_node(self, anchor: Any) -> Any:
            self._count(1, self.parser.peek_event().start_mark)
            return super().compose_mapping_node(anchor)

    return BoundedComposer


def _loader():
    """A fresh ruamel.yaml safe loader with the bounds (its depth count does not reset after an
    error, so one loader parses one text)."""
    from ruamel.yaml import YAML

    yaml = YAML(typ="safe", pure=True)
    yaml.max_depth = MAX_YAML_DEPTH
    yaml.allow_duplicate_keys = False
    yaml.Composer = _composer_class()
    return yaml


def load_yaml(text: str) -> tuple[Any, Any]:
    """Parse one YAML document within the bounds: ``(data, root node)``.

    ``data`` is plain Python (dict, list, str, int, float, bool, None); the root node (ruamel's
    ``MappingNode``/``SequenceNode``/``ScalarNode``, None for an empty text) gives the line of
    each key for error messages (``node.start_mark.line`` is 0-based).

    Raises:
        YamlError: not YAML, larger than :data:`MAX_YAML_BYTES`, deeper than
            :data:`MAX_YAML_DEPTH`, more than :data:`MAX_YAML_NODES` values with aliases
            expanded, a number longer than :data:`MAX_NUMBER_CHARS`, a string longer than
            :data:`MAX_STRING_CHARS`, or a key given twice.
    """
    from ruamel.yaml.error import MarkedYAMLError, YAMLError
    from ruamel.yaml.reader import ReaderError

    if len(text) > MAX_YAML_BYTES:
        raise YamlError(0, f"larger than {MAX_YAML_BYTES // 1024} KB (docs/limits.md)")
    try:
        root = _loader().compose(text)
        data = _loader().load(text)
    except YamlError:
        raise
    except ReaderError as exc:  # a character YAML forbids: a position, no mark
        code = ord(exc.character) if isinstance(exc.character, str) else exc.character
        raise YamlError(
            text.count("\n", 0, exc.position) + 1, f"character #x{code:04x} is not allowed in YAML"
        ) from None
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        if exc.context_mark is not None and (exc.context or "").startswith(
            ("while scanning a simple key", "while scanning a quoted scalar")
        ):
            # the scanner notices a key without ':' (or an open quote) only on a later line; the
            # line to fix is where that key (or quote) starts
            mark = exc.context_mark
        problem = " ".join((exc.problem or exc.context or "not valid YAML").split())
        if "duplicate key" in problem:
            problem = problem.split(" with value")[0] + " (each key may appear once in a mapping)"
        elif "maximum depth" in problem:
            problem = f"nested more than {MAX_YAML_DEPTH} levels deep (docs/limits.md)"
        # a problem found at the end of the text is on its last line, never past it
        line = min(mark.line + 1, _lines(text)) if mark is not None else 0
        keyless = _keyless_line_before(text, line) if "mapping values are not allowed" in problem else 0
        if keyless:  # `input pinch` then `output: A`: the ':' is missing on the line before
            line, problem = keyless, "could not find expected ':'"
        raise YamlError(line, problem + _hint(problem)) from None
    except YAMLError as exc:
        raise YamlError(0, " ".join(str(exc).split())[:200]) from None
    except (ValueError, OverflowError) as exc:  # a value the constructor cannot make
        raise YamlError(0, " ".join(str(exc).split())[:200]) from None
    return data, root


def short(value: Any) -> str:
    """``repr(value)`` cut to :data:`EXCERPT_CHARS` characters: error messages never echo a file
    at length (a value may be a list of a million items, or an alias to one); ``repr`` escapes a
    string's control characters."""
    text = _SHORT.repr(value)
    return text if len(text) <= EXCERPT_CHARS else text[: EXCERPT_CHARS - 3] + "..."


def printable(value: Any, limit: int | None = EXCERPT_CHARS) -> str:
    """``str(value)`` safe for a terminal and a log line: every character ``str.isprintable``
    refuses (C0 and C1 controls such as ESC, which starts the terminal's escape sequences, DEL,
    newlines, bidirectional overrides) written as its Python escape (``\\x1b``, ``\\n``,
    ``\\u202e``), and the text cut to ``limit`` characters of the original
    (``...`` and the length after it; None: never cut)."""
    text = str(value)
    cut = limit is not None and len(text) > limit
    part = text[:limit] if cut else text
    if not part.isprintable():
        part = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in part)
    return f"{part}... ({len(text)} characters)" if cut else part


class PrintableFormatter(logging.Formatter):
    """A :mod:`logging` formatter whose lines have their control characters escaped
    (:func:`printable`, line by line, never cut): a value quoted in a log message (a file name, a
    process's name) never drives the terminal the log is read on."""

    def format(self, record: logging.LogRecord) -> str:
        return "\n".join(printable(line, None) for line in super().format(record).split("\n"))


def read_proc_file(path: str | os.PathLike, max_bytes: int) -> tuple[bytes, bool]:
    """The first ``max_bytes`` bytes of a ``/proc`` file (``/proc/PID/environ``, ``cmdline``) and
    whether there was more. ``/proc`` files say size 0, so the size is only known by reading:
    at most ``max_bytes + 1`` bytes are read, whatever the process holds.

    Raises:
        FileNotFoundError, ProcessLookupError, PermissionError, OSError: as ``open``/``read`` do
        (the process is gone, or is not ours to read).
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb", buffering=0) as fh:
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = fh.read(min(1 << 16, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    data = b"".join(chunks)
    return data[:max_bytes], size > max_bytes


def read_proc_once(path: str | os.PathLike, max_bytes: int) -> bytes | None:
    """One read of at most ``max_bytes`` of a small ``/proc`` file (``/proc/PID/comm``: a process's
    name, 15 bytes and a newline), or None when it cannot be read (the process gone, or hidden by
    ``hidepid``): an open, a read and a close, for what is read often (a scan of every process);
    :func:`read_proc_file` reads to the end."""
    fd = -1
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        return os.read(fd, max_bytes)
    except OSError:
        return None
    finally:
        if fd >= 0:
            os.close(fd)


def key_line(root: Any, *keys: object) -> int:
    """The 1-based line of the key reached by ``keys`` from ``root`` (a node of :func:`load_yaml`;
    each key compared as its text, e.g. ``4242``, a boolean as YAML writes it, ``true`` in any
    case), else of the deepest node reached; 0 for no root (an empty document). For error
    messages (:func:`where`)."""
    if root is None:
        return 0
    node, line = root, root.start_mark.line + 1
    for key in keys:
        pairs = node.value if node is not None and node.id == "mapping" else ()
        text, fold = (str(key).lower(), str.lower) if isinstance(key, bool) else (str(key), str)
        match = next((pair for pair in pairs if pair[0].id == "scalar" and fold(pair[0].value) == text), None)
        if match is None:
            break
        line, node = match[0].start_mark.line + 1, match[1]
    return line


def where(source: str | os.PathLike | Path, line: int) -> str:
    """``FILE:LINE`` (or ``FILE`` when the line is unknown) for messages."""
    return f"{source}:{line}" if line else str(source)
