"""A dataset folder written whole (docs/dataset.md): every file of a dataset goes to a new hidden
folder beside the one named, which is put in its place in one step at the end (a rename, or a
``renameat2`` exchange over a dataset replaced with ``--force``, :mod:`neurotouch_hid.core.atomic`),
so that a reader sees the old dataset or the new one, and a command that fails changes nothing.

The simulator (``simulate``) and an enrolment (``enrol``) write their datasets through it.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path

from neurotouch_hid.core.atomic import _umask, exchange
from neurotouch_hid.core.errors import DatasetError
from neurotouch_hid.core.limits import printable

#: The files a dataset folder holds (docs/dataset.md, and what the commands write beside it: the
#: simulator's true markers and families, an enrolment's plan): a folder holding anything else
#: is never replaced, even with ``--force``.
DATASET_FILES = ("sensor.yaml", "physics.json")
DATASET_SUFFIXES = (".aedat4", ".labels.csv", ".pressed.csv", ".plan.json", ".markers.npz")


def _held(folder: Path) -> list[str]:
    """The names in ``folder`` (none when it is missing or not a folder)."""
    try:
        return sorted(os.listdir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return []
    except OSError as exc:
        raise DatasetError(f"{printable(folder, 200)}: cannot read the folder: {exc.strerror or exc}") from None


class DatasetOut:
    """A dataset folder written whole: the files go to a new hidden folder beside ``out``
    (``.OUT.RANDOM.part``), which :meth:`commit` puts in ``out``'s place in one step, or
    :meth:`discard` removes. An ``out`` that holds a dataset is refused unless ``force``, and
    then replaced whole (``renameat2`` exchange: a reader sees the old dataset or the new one);
    a folder holding other files is never replaced. Two commands writing into one new folder
    at once: the first to commit wins whole, the other says it lost and leaves it as it is.

    Args:
        out: the dataset folder to write (docs/dataset.md).
        force: replace a dataset already in ``out``.
        what: the command's option, for the messages (``--out``).
    Raises:
        DatasetError: ``out`` holds a dataset (and not ``force``) or other files, is a file, or
            its parent cannot be written (full, read-only); nothing is changed then.
    """

    def __init__(self, out: str | Path, *, force: bool = False, what: str = "--out") -> None:
        self.out = Path(out)
        self.force = force
        shown = printable(self.out, 200)
        if self.out.is_symlink() or (self.out.exists() and not self.out.is_dir()):
            raise DatasetError(f"{shown}: {what} is not a folder: give a folder for the dataset (docs/dataset.md)")
        self._check(_held(self.out), what)
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            self.work = Path(tempfile.mkdtemp(dir=self.out.parent, prefix=f".{self.out.name}.", suffix=".part"))
            os.chmod(self.work, 0o777 & ~_umask())
        except OSError as exc:
            raise DatasetError(
                f"{shown}: cannot write the dataset: {exc.strerror or exc}; nothing was changed"
            ) from None

    def _check(self, names: list[str], what: str) -> None:
        shown = printable(self.out, 200)
        other = [n for n in names if n not in DATASET_FILES and not n.endswith(DATASET_SUFFIXES)]
        if other:
            raise DatasetError(
                f"{shown}: the folder holds files that are no dataset's ({printable(', '.join(other[:3]), 120)}"
                f"{', ...' if len(other) > 3 else ''}): give another {what} folder; nothing was changed"
            )
        if names and not self.force:
            raise DatasetError(
                f"{shown}: the folder holds a dataset already ({printable(', '.join(names[:3]), 120)}"
                f"{', ...' if len(names) > 3 else ''}): give another {what} folder, or add --force to replace it whole"
            )

    def commit(self) -> Path:
        """Put the written folder in ``out``'s place; returns ``out``.

        Raises:
            DatasetError: another command wrote a dataset into ``out`` meanwhile (without
                ``force``: it is kept, and what was written here is removed), or the rename
                failed (the disk).
        """
        try:
            if self.force and _held(self.out):
                exchange(self.work, self.out)
                shutil.rmtree(self.work, ignore_errors=True)  # the old dataset, now here
            else:
                os.rename(self.work, self.out)  # fails when another command put a dataset there first
        except OSError as exc:
            self.discard()
            if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
                raise DatasetError(
                    f"{printable(self.out, 200)}: another command wrote a dataset there meanwhile: it is kept, and "
                    "this one is not written (run it again into another folder)"
                ) from None
            raise DatasetError(
                f"{printable(self.out, 200)}: cannot put the dataset in place: {exc.strerror or exc}; nothing changed"
            ) from None
        return self.out

    def discard(self) -> None:
        """Remove what was written (``out`` is as it was)."""
        shutil.rmtree(self.work, ignore_errors=True)
