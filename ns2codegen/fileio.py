"""Atomic file output: a file is either the old one or the complete new one, and
a set of files (an export folder) is either the old set or the complete new set."""
from __future__ import annotations

import ctypes
import os
import shutil
import tempfile
from pathlib import Path
from .errors import Ns2Error


def file_mode() -> int:
    """Mode of a newly created file under the current umask (mkstemp makes 0600)."""
    return 0o666 & ~_umask()


class OutputError(Ns2Error, OSError):
    """An output location cannot be written."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="." + path.name, suffix=".tmp")
    except OSError as e:
        raise OutputError(f"cannot write to {path.parent}: {e.strerror or e}") from e
    try:
        os.chmod(tmp, file_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_files(folder: Path, files: dict[str, str]) -> None:
    """Write several text files so that none is replaced unless all could be staged.

    All contents are first written to temporary files in ``folder``; only when every
    one succeeded are they renamed into place (each rename is atomic)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create output folder {folder}: {e.strerror or e}") from e
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {folder} is not writable")
    staged: list[tuple[str, Path]] = []
    try:
        for name, text in files.items():
            fd, tmp = tempfile.mkstemp(dir=folder, prefix="." + name, suffix=".tmp")
            staged.append((tmp, folder / name))
            os.chmod(tmp, file_mode())
            with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
    except OSError as e:
        for tmp, _ in staged:
            Path(tmp).unlink(missing_ok=True)
        raise OutputError(f"cannot write to {folder}: {e.strerror or e}") from e
    for tmp, dst in staged:
        os.replace(tmp, dst)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two directories in one atomic step (Linux renameat2 RENAME_EXCHANGE);
    False where the C library or the file system cannot."""
    fn = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if fn is None:
        return False
    at_fdcwd, rename_exchange = -100, 2
    return fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


def write_folder_set(folder: Path, files: dict[str, str]) -> None:
    """Replace the files of ``folder`` as one set: all are written to a new sibling
    folder ``.<name>.tmp-XXXX`` (with the folder's other plain files, e.g. a README,
    copied along), which is then swapped in for ``folder`` in one atomic step
    (rename exchange; two renames where that is not available, so that ``folder``
    is briefly absent but never mixed).  The old set is kept until the swap and
    removed after it.  A kill at any point leaves ``folder`` with the complete old
    or the complete new set; leftover ``.<name>.tmp-*`` / ``.old-*`` folders of a
    killed run are removed by the next one, which first puts back an old set left
aside by a kill between the two renames (one writer per folder at a time)."""
    folder = Path(folder)
    parent = folder.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create the folder {parent}: {e.strerror or e}") from e
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"output folder {folder} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write to {parent} (the new set is written next to {folder.name})")
    olds = sorted(parent.glob(f".{folder.name}.old-*"))
    if not folder.exists() and olds:  # killed between the two renames: put the old set back first
        os.rename(olds.pop(0), folder)
    for left in list(parent.glob(f".{folder.name}.tmp-*")) + olds:
        shutil.rmtree(left, ignore_errors=True)
    others = []
    if folder.is_dir():
        for p in folder.iterdir():
            if p.is_dir() and not p.is_symlink():
                raise OutputError(f"output folder {folder} holds the folder {p.name}: give the export a folder "
                                  "of its own")
            if p.name not in files and not (p.name.startswith(".") and p.name.endswith(".tmp")):
                others.append(p)
    try:
        tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{folder.name}.tmp-"))
    except OSError as e:
        raise OutputError(f"cannot write to {parent}: {e.strerror or e}") from e
    try:
        os.chmod(tmp, (folder.stat().st_mode & 0o7777) if folder.is_dir() else (0o777 & ~_umask()))
        for p in others:
            shutil.copy2(p, tmp / p.name, follow_symlinks=False)
        for name, text in files.items():
            with open(tmp / name, "w", encoding="utf-8", newline="\n") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp / name, file_mode())
        _fsync_dir(tmp)
        if not folder.is_dir():
            os.rename(tmp, folder)
        else:
            if not _exchange(tmp, folder):
                old = Path(str(tmp).replace(".tmp-", ".old-", 1))
                os.rename(folder, old)
                os.rename(tmp, folder)
                tmp = old
            shutil.rmtree(tmp)  # now the old set
        _fsync_dir(parent)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(f"cannot write the set of files to {folder}: {e.strerror or e}") from e
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask
