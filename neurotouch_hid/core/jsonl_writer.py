"""The JSON-lines writer every JSON-lines output shares: predictions (docs/dataset.md,
"Predictions (JSON lines)"), a run's records and the views' streams.

One compact JSON object a line (RFC 8259 text, jsonlines.org), to a path, ``-`` (stdout) or an
open text stream; a path is written temp-file-then-rename (:class:`~neurotouch_hid.core.atomic.AtomicFile`),
or published at its first line for a live output, and what an error cut short is kept beside
it as ``NAME.partial``.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import IO

from neurotouch_hid.core.atomic import DISK_ERRNOS, AtomicFile, check_output, disk_error, is_stream
from neurotouch_hid.core.errors import DatasetError, NeurotouchError


class JsonlWriter:
    """Writes one JSON object a line. Context manager.

    A file is written as a temporary file beside it and renamed over it when the writer is
    closed without an error (:class:`~neurotouch_hid.core.atomic.AtomicFile`): a command that fails
    leaves what was there. With ``live``, it is renamed at its first line instead, so that another
    process can follow it from then on, when there is no file at its name to lose (a file there
    is replaced only at a clean end). A FIFO or a character device is written in place.

    With ``keep_partial``, a writer closed by an error (:meth:`__exit__`) after lines were
    written puts them beside the file, as ``NAME.partial`` (replacing an earlier one), and never
    at ``NAME`` (a live file published there goes to ``NAME.partial`` too): what was at ``NAME``
    stays byte-identical, and the error gets a note (PEP 678, printed by the CLI) saying both.

    Args:
        out: a file path, ``"-"`` for stdout, or an open text stream (not closed by
            :meth:`close`).
        flush: flush after every line (for live outputs read by another process).
        live: publish the file at its first line (see above) rather than at the end.
        inputs: the command's input files: ``out`` may not be one of them.
        keep_partial: keep what was written before an error as ``NAME.partial`` (see above).
        stops: the exceptions that end the writer as a stop asked for, not a failure (a live
            run's Ctrl-C): the file is closed as at a clean end.
    Raises:
        DatasetError: the file cannot be opened for writing (names it and why).
        OutputError: ``out`` is a symbolic link, a folder, or one of ``inputs``.
    """

    def __init__(
        self,
        out: str | Path | IO[str],
        *,
        flush: bool = False,
        live: bool = False,
        inputs: Iterable[str | Path | None] = (),
        keep_partial: bool = False,
        stops: tuple[type[BaseException], ...] = (),
    ) -> None:
        self._flush, self._live = flush, live
        self._keep_partial, self._stops = keep_partial, stops
        self._atomic: AtomicFile | None = None
        #: lines written
        self.lines = 0
        #: where the lines written before an error went (``NAME.partial``), None when nowhere
        self.partial: Path | None = None
        self._had_file = False
        if isinstance(out, (str, Path)) and str(out) == "-":
            self._fh, self._owned = sys.stdout, False
        elif isinstance(out, (str, Path)):
            try:
                self._atomic = AtomicFile(out, inputs, what="output file")
            except OSError as exc:
                raise DatasetError(f"{out}: cannot write JSON lines: {exc.strerror or exc}") from None
            self._had_file = not self._atomic.published and os.path.lexists(self._atomic.path)
            self._fh, self._owned = self._atomic.file, True
        else:
            self._fh, self._owned = out, False

    def write_dict(self, data: dict) -> None:
        """Write ``data`` as one compact JSON line. Raises OutputError naming the file when the
        disk refuses it (full, read-only)."""
        try:
            self._fh.write(json.dumps(data, separators=(", ", ": ")) + "\n")
            if self._flush:
                self._fh.flush()
        except OSError as exc:
            if self._atomic is None or exc.errno not in DISK_ERRNOS:
                raise
            raise disk_error(self._atomic.path, exc) from None
        self.lines += 1
        if self._live and self._atomic is not None and not self._atomic.published and not self._had_file:
            self._atomic.publish()

    def close(self, keep: bool = True) -> None:
        """Flush, and close the file if this writer opened it: renamed into place when ``keep``;
        else, with ``keep_partial`` and lines written, moved to ``NAME.partial``
        (:attr:`partial`), otherwise removed unless it was already published (a live file)."""
        if self._atomic is None:
            if self._owned:
                self._fh.close()
            else:
                self._fh.flush()
            return
        if keep or not self._keep_partial or not self.lines:
            self._atomic.close(keep=keep)
            return
        target = self._atomic.path
        partial = target.with_name(target.name + ".partial")
        if self._atomic.published:  # a live file with nothing before it: not left as a whole output
            self._atomic.close(keep=True)
            if not is_stream(target):
                os.replace(target, partial)
                self.partial = partial
            return
        tmp = self._atomic.pending()
        try:
            self._atomic.close(keep=False, leave=True)
            self.lines = _count_lines(tmp)  # what reached the file (a full disk keeps less)
            if not self.lines:
                raise OSError("nothing reached the file")
            check_output(partial, (), "partial output")
            os.replace(tmp, partial)
            self.partial = partial
        except (OSError, NeurotouchError):
            tmp.unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        stopped = exc_type is not None and issubclass(exc_type, self._stops)
        self.close(keep=exc_type is None or stopped)
        if self.partial is not None and exc is not None and self._atomic is not None:
            kept = "is left as it was" if self._had_file else "was not written"
            exc.add_note(
                f"{self._atomic.path} {kept}; the {self.lines} lines written before the error are in {self.partial}"
            )


def _count_lines(path: Path) -> int:
    """The complete lines of ``path`` (its newlines), read 1 MiB at a time."""
    count = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            count += chunk.count(b"\n")
    return count
